"""Print lines along the director: the fill bounds on standard patterns, exact spacing on
uniform fields, the staggered set, and the rules for stopping and extending lines."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

from fabkit.field.flat import field_from_expression
from fabkit.field.outlines import parse_shape
from fabkit.toolpath.lines import print_lines, trim_lines
from fabkit.toolpath.quality import measure_quality
from fabkit.toolpath.stripes import _near_boundary

W = 0.2
BOUND = 0.03  # empty <= 3 %, overlap <= 3 %, angle <= 3 degrees


@pytest.mark.slow
@pytest.mark.parametrize(
    ("theta", "shape"),
    [("arctan2(y, x)", "disc:10"), ("phi + pi/2", "disc:10"), ("phi/2", "square:20")],
    ids=["radial disc", "azimuthal disc", "+1/2 defect square"],
)
def test_standard_patterns_meet_the_fill_bounds(theta, shape):
    field = field_from_expression(theta, parse_shape(shape))
    (lines,) = print_lines(field, W)
    quality = measure_quality(lines, W, field, W)
    assert quality.empty_fraction <= BOUND
    assert quality.mean_overlap <= BOUND
    assert quality.mean_angle_error_deg <= 100 * BOUND
    inner = field.outline.buffer(-0.45 * W + 1e-6)  # road ends reach <= 0.05 w past the edge
    assert all(inner.covers(shapely.LineString(line)) for line in lines)


def test_uniform_field_gives_straight_lines_one_road_apart():
    field = field_from_expression("0.3", parse_shape("square:12"))
    same, staggered = print_lines(field, W, phases=(0.0, np.pi))
    normal = np.array([-np.sin(0.3), np.cos(0.3)])
    offsets = np.sort([np.mean(line @ normal) for line in same])
    assert np.diff(offsets) == pytest.approx(W, abs=1e-3)
    for line in same:
        assert np.ptp(line @ normal) < 2e-3  # straight
    middle = np.sort([np.mean(line @ normal) for line in staggered])
    gaps = np.abs(middle[:, None] - offsets[None, :]).min(axis=1)
    assert gaps == pytest.approx(W / 2, abs=2e-3)  # halfway between


def test_line_spacing_can_vary_in_space():
    field = field_from_expression("0", parse_shape("rect:12,8"))
    (lines,) = print_lines(field, W, spacing=lambda p: np.where(p[:, 1] > 0, 2 * W, W))
    heights = np.sort([np.mean(line[:, 1]) for line in lines if np.ptp(line[:, 0]) > 8])
    below, above = heights[heights < -0.6], heights[heights > 0.6]
    # (a whole number of lines must fit each band: spacings within a few per cent)
    assert np.median(np.diff(below)) == pytest.approx(W, rel=0.05)
    assert np.median(np.diff(above)) == pytest.approx(2 * W, rel=0.05)


def test_lines_too_close_stop_and_the_shorter_one_yields():
    field = field_from_expression("0", parse_shape("square:10"))
    long = np.column_stack([np.linspace(-4, 4, 161), np.zeros(161)])
    short = np.column_stack([np.linspace(-1, 3, 81), np.full(81, 0.1)])  # w/2 from `long`
    apart = np.column_stack([np.linspace(-1, 3, 81), np.full(81, W)])  # one road away
    kept = trim_lines([long, short, apart], field, 0.75 * W, np.radians(25), 0.05)
    assert len(kept) == 2
    assert any(np.array_equal(k, long) for k in kept)
    assert any(np.array_equal(k, apart) for k in kept)


@settings(max_examples=60, deadline=None)
@given(
    corners=st.integers(3, 12),
    seed=st.integers(0, 2**16),
    reach=st.floats(0.05, 3.0),
)
def test_the_nodes_near_the_outline_are_those_a_distance_to_every_node_finds(corners, seed, reach):
    # the stripes' boundary pins measure the distance only in a band around the outline
    rng = np.random.default_rng(seed)
    angles = (np.arange(corners) + rng.uniform(0.1, 0.9, corners)) * 2 * np.pi / corners
    radii = rng.uniform(2.0, 10.0, corners)  # star-shaped, with concave corners
    outline = shapely.Polygon(np.column_stack([radii * np.cos(angles), radii * np.sin(angles)]))
    assert outline.is_valid
    nodes = rng.uniform(-12, 12, (2000, 2))
    reaches = rng.uniform(0.2, 1.0, len(nodes)) * reach
    exact = shapely.distance(outline.boundary, shapely.points(nodes))
    found = _near_boundary(outline, nodes, reaches)
    assert found.tolist() == np.flatnonzero(exact <= reaches).tolist()
