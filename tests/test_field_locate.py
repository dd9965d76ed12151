"""The compiled triangle locator (fabkit.field.design_field.TriangleLocator) against the
numpy formulation it replaced, written out here: the same triangle (the lowest index that
holds the point) and the same barycentric weights, to the last bit, on meshes that fold
over themselves, with points inside, outside, on edges and corners, and not finite."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from fabkit.field.design_field import TriangleLocator


def numpy_locate(locator: TriangleLocator, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every candidate of a point's bucket tested at once (the replaced formulation)."""
    with np.errstate(invalid="ignore"):  # points not finite: no cell
        cells = np.floor((points - locator.origin) / locator.size).astype(int)
    inside = ((cells >= 0) & (cells < locator.shape)).all(axis=1)
    bucket = np.where(inside, cells[:, 0] * locator.shape[1] + cells[:, 1], 0)
    counts = np.where(inside, locator.starts[bucket + 1] - locator.starts[bucket], 0)
    query = np.repeat(np.arange(len(points)), counts)
    offset = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    candidate = locator.members[locator.starts[bucket[query]] + offset]
    corners = locator.points[locator.triangles[candidate]]
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    v0, v1, v2 = b - a, c - a, points[query] - a
    det = v0[:, 0] * v1[:, 1] - v0[:, 1] * v1[:, 0]
    det = np.where(np.abs(det) > 1e-300, det, np.nan)
    l1 = (v2[:, 0] * v1[:, 1] - v2[:, 1] * v1[:, 0]) / det
    l2 = (v0[:, 0] * v2[:, 1] - v0[:, 1] * v2[:, 0]) / det
    weights = np.column_stack([1 - l1 - l2, l1, l2])
    weights = np.where(np.isfinite(weights), weights, -1.0)
    hit = np.flatnonzero((weights >= -1e-9).all(axis=1))
    first = hit[np.concatenate([[True], np.diff(query[hit]) != 0])] if len(hit) else hit
    triangle = np.full(len(points), -1)
    triangle[query[first]] = candidate[first]
    result = np.zeros((len(points), 3))
    result[query[first]] = weights[first]
    return triangle, result


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**16), rows=st.integers(2, 12), fold=st.floats(0.0, 0.9))
def test_the_compiled_locator_finds_what_the_numpy_one_found_to_the_last_bit(seed, rows, fold):
    rng = np.random.default_rng(seed)
    u, v = np.meshgrid(np.linspace(0, 1, rows), np.linspace(0, 1, rows), indexing="ij")
    # a jittered grid whose right part folds back over the left (overlapping images)
    x = u + 0.2 * rng.uniform(-1, 1, u.shape) / rows
    x = np.where(u > 0.5, 0.5 - fold * (u - 0.5), x)
    points = np.column_stack([x.ravel(), (v + 0.1 * u * v).ravel()])
    index = np.arange(rows * rows).reshape(rows, rows)
    lower = np.column_stack(
        [index[:-1, :-1].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel()]
    )
    upper = np.column_stack(
        [index[:-1, :-1].ravel(), index[1:, 1:].ravel(), index[:-1, 1:].ravel()]
    )
    triangles = np.vstack([lower, upper, [[0, 0, 1]]])  # and a degenerate one
    locator = TriangleLocator(points, triangles)
    queries = np.vstack(
        [
            rng.uniform(-0.2, 1.2, (500, 2)),
            points,  # corners
            0.5 * (points[triangles[:, 0]] + points[triangles[:, 1]]),  # on edges
            [[np.nan, 0.5], [0.5, np.inf], [-np.inf, -np.inf]],
        ]
    )
    found, weights = locator.locate(queries)
    expected, expected_weights = numpy_locate(locator, queries)
    assert found.tolist() == expected.tolist()
    assert np.array_equal(weights, expected_weights)
    assert (found >= 0).sum() > len(points)  # most corners and edge points are held
