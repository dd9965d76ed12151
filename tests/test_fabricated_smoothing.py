"""The sheet as fabricated is simulated with its read-back fields averaged over a physical
length (the road width or the sheet's thickness, whichever is larger), and the report
says which."""

from __future__ import annotations

import numpy as np
import pytest

from fabkit.mechanics.simulate import STARTS, default_thickness
from fabkit.process import Resolution
from fabkit.verify.as_fabricated import sheet_fields, simulation_figures, simulation_note
from fabkit.verify.machine_file import VerifyOptions, _smoothing_mm
from fabkit.verify.raster import Readback
from tests.conftest import coarse_design

CELL_MM, WIDTH_MM, THETA = 0.1, 0.4, 0.3


def _noisy() -> Readback:
    """A 12 mm square read back on 0.1 mm cells: director THETA with +-0.1 rad of
    cell-to-cell noise (a checkerboard, as road edges and line ends leave it)."""
    i, j = np.indices((120, 120))
    theta = THETA + 0.1 * np.where((i + j) % 2 == 0, 1.0, -1.0)
    hits = np.ones(theta.shape, dtype=int)
    return Readback((0.0, 0.0), CELL_MM, hits, theta, {}, WIDTH_MM)


def _theta(smoothing_mm: float) -> np.ndarray:
    fields = sheet_fields(_noisy(), Resolution((), (), ()), None, 1.0, (), smoothing_mm)
    points = np.random.default_rng(1).uniform(2.0, 10.0, (200, 2))  # mm = design units
    return fields.theta(points)


def test_cell_noise_is_averaged_out_over_the_smoothing_length():
    raw = np.abs(_theta(0.0) - THETA)
    smoothed = np.abs(_theta(WIDTH_MM) - THETA)
    assert raw.max() > 0.05  # sampled raw, the noise reaches the metric
    assert smoothed.max() < 1e-3


@pytest.fixture(scope="module")
def design():
    return coarse_design()


@pytest.mark.parametrize("scale", [5.0, 50.0])
def test_the_default_length_is_the_road_width_or_the_thickness(design, scale):
    thickness_mm = default_thickness(design) * scale
    length = _smoothing_mm(VerifyOptions(), _noisy(), thickness_mm)
    assert length == pytest.approx(max(WIDTH_MM, thickness_mm))
    assert _smoothing_mm(VerifyOptions(smoothing_mm=0.0), _noisy(), thickness_mm) == 0.0


def test_the_report_says_what_the_simulation_used(design):
    figures = simulation_figures(0.6, _noisy(), default_thickness(design) * 25.0)
    assert figures["smoothing_mm"] == 0.6 and figures["seed"] == ", ".join(STARTS)
    assert figures["thickness_mm"] == pytest.approx(default_thickness(design) * 25.0)
    note = simulation_note(figures)
    assert "Gaussian of 0.6 mm" in note and "ramp steps" in note
    assert "from each start (dome, dome-down, saddle, saddle-down, random-1, random-2)" in note
