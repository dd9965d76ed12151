"""The fill metrics against cases whose answer is known in closed form."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
import shapely.affinity
from hypothesis import given, settings
from hypothesis import strategies as st

from fabkit.field.flat import field_from_expression
from fabkit.toolpath.quality import _Raster, _samples, measure_quality

W = 0.4
LENGTH = 20.0


def _strip(theta: str = "0") -> object:
    """A 20 mm x 2w strip along x with a constant director."""
    return field_from_expression(theta, shapely.box(0, 0, LENGTH, 2 * W))


def test_two_abutting_roads_fill_the_strip():
    lines = [np.array([[W / 2, y], [LENGTH - W / 2, y]]) for y in (W / 2, 1.5 * W)]
    quality = measure_quality(lines, W, _strip(), W)
    corners = 4 * (W / 2) ** 2 * (1 - np.pi / 4) / (LENGTH * 2 * W)  # round road ends
    assert quality.empty_fraction == pytest.approx(corners, abs=2e-3)
    assert quality.mean_overlap == pytest.approx(0.0, abs=2e-3)
    assert quality.mean_angle_error_deg == pytest.approx(0.0, abs=1e-9)
    assert quality.print_length_mm == pytest.approx(2 * (LENGTH - W))
    assert quality.paths == 2


def test_overlap_counts_distinct_paths():
    # tilted by 30 degrees so that pixel rows do not line up with the road edges
    tilt = np.radians(30)
    rotation = np.array([[np.cos(tilt), np.sin(tilt)], [-np.sin(tilt), np.cos(tilt)]])
    strip = field_from_expression("pi/6", shapely.affinity.rotate(_strip().outline, 30, (0, 0)))
    spacing = 0.75 * W  # roads overlap by w/4 along their length
    lines = [np.array([[0.0, y], [LENGTH, y]]) @ rotation for y in (0.5 * W, 0.5 * W + spacing)]
    quality = measure_quality(lines, W, strip, W)
    covered = (W + spacing) * LENGTH
    assert quality.mean_overlap == pytest.approx((W - spacing) * LENGTH / covered, abs=0.01)
    # a path doubling back on itself is one path: no overlap with itself
    hairpin = np.array([[0.0, W], [LENGTH, W], [LENGTH, W + 0.01], [0.0, W + 0.01]])
    assert measure_quality([hairpin], W, _strip(), W).mean_overlap == 0


def test_angle_error_is_length_weighted_and_head_tail_symmetric():
    tilt = np.radians(5.0)
    line = np.array([[0.0, 0.4], [10 * np.cos(tilt), 0.4 + 10 * np.sin(tilt)]])
    backwards = line[::-1] + [0, 0.0]
    short = np.array([[0.0, 0.2], [1.0, 0.2]])  # along the director, one tenth the length
    quality = measure_quality([line, backwards, short], W, _strip(), W)
    assert quality.mean_angle_error_deg == pytest.approx(5.0 * 20 / 21, rel=1e-6)
    flipped = measure_quality([line], W, _strip("pi"), W)
    assert flipped.mean_angle_error_deg == pytest.approx(5.0, rel=1e-6)


def test_empty_domain_is_all_empty():
    quality = measure_quality([np.array([[100.0, 100.0], [101.0, 100.0]])], W, _strip(), W)
    assert quality.empty_fraction == 1.0 and quality.mean_overlap == 0.0


def numpy_hits(grid: _Raster, paths: list[np.ndarray], width: float) -> np.ndarray:
    """Distinct paths a pixel: the numpy formulation the compiled paint replaced, every
    (sample, pixel) pair of a window around each sample gathered, then deduplicated."""
    hits = np.zeros(grid.size, np.int32)
    for path in paths:
        points, radius, _ = _samples(path, np.full(len(path), width), grid.pixel)
        reach = int(np.ceil(radius.max() / grid.pixel)) + 1
        offsets = np.arange(-reach, reach + 1)
        di, dj = (a.ravel() for a in np.meshgrid(offsets, offsets, indexing="ij"))
        ci = np.floor((points[:, 0] - grid.x0) / grid.pixel).astype(int)
        cj = np.floor((points[:, 1] - grid.y0) / grid.pixel).astype(int)
        i, j = ci[:, None] + di, cj[:, None] + dj
        dx = grid.x0 + (i + 0.5) * grid.pixel - points[:, :1]
        dy = grid.y0 + (j + 0.5) * grid.pixel - points[:, 1:]
        keep = (dx * dx + dy * dy <= (radius * radius)[:, None]) & (i >= 0) & (i < grid.nx)
        keep &= (j >= 0) & (j < grid.ny)
        hits[np.unique((i * grid.ny + j)[keep])] += 1
    return hits


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**16), count=st.integers(1, 12), width=st.floats(0.1, 1.0))
def test_the_compiled_paint_counts_what_the_numpy_formulation_counted(seed, count, width):
    rng = np.random.default_rng(seed)
    outline = shapely.box(0, 0, 6, 4)
    grid = _Raster.covering(outline, width / 10)
    paths = [
        np.cumsum(rng.normal(0, 0.7, (int(rng.integers(2, 30)), 2)), axis=0) + (3, 2)
        for _ in range(count)
    ]  # some run past the raster's edges
    hits = np.zeros(grid.size, np.int32)
    owner = np.full(grid.size, -1, np.int64)
    for index, path in enumerate(paths):
        points, radius, _ = _samples(path, np.full(len(path), width), grid.pixel)
        grid.paint(points, radius, index, hits, owner)
    assert np.array_equal(hits, numpy_hits(grid, paths, width))
    assert hits.max() >= 1
