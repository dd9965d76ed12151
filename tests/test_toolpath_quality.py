"""The fill metrics against cases whose answer is known in closed form."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
import shapely.affinity

from fabkit.field.flat import field_from_expression
from fabkit.toolpath.quality import measure_quality

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
