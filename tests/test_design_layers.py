"""A layered sheet: the natural-curvature formula, the layering of Fig. 3, the file format."""

from __future__ import annotations

import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import Delaunay, cKDTree

from fabkit.design.design import Design
from fabkit.design.layers import layered
from fabkit.design.solver import solve
from fabkit.errors import FabkitError
from fabkit.field.design_field import field_from_design
from fabkit.field.flat import director_angle
from fabkit.mechanics.simulate import simulate
from fabkit.problem.spec import build_spec
from fabkit.toolpath.job import ToolpathJob, plan_job
from tests.conftest import coarse_design
from tests.test_mechanics_simulate import fit_circle

SPECS = Path(__file__).parent / "data" / "specs"
THICKNESS = 0.078  # Fig. 3 at 60 mm: two 0.3 mm layers, in design units


def strip_curvature(count: int, strain: float, thickness: float = 0.02) -> float:
    """A strip of ``count`` equal layers whose reference metric along x falls linearly
    with height (by 2 ``strain`` over the thickness), Poisson 0: its curvature."""
    x, y = np.linspace(-1, 1, 41), np.linspace(-0.15, 0.15, 7)
    points = np.stack(np.meshgrid(x, y), -1).reshape(-1, 2)
    triangles = Delaunay(points).simplices
    heights = (np.arange(count) - (count - 1) / 2) * thickness / count
    gradient = -2 * strain / thickness
    metrics = np.stack(
        [np.broadcast_to(np.diag([1 + z * gradient, 1.0]), (len(triangles), 2, 2)) for z in heights]
    )
    result = simulate(points, triangles, metrics, thickness, poisson=0.0)
    assert result.converged
    _, radius = fit_circle(result.positions[np.abs(points[:, 1]) < 1e-9])
    return 1 / radius


@pytest.mark.parametrize("count", [2, 3, 4])
def test_a_layered_strip_bends_as_the_least_squares_fit_says(count):
    # b̄ = -c_K D, c_K = (K^2 - 1) / (2 K^2), D the metric's gradient through the thickness
    # (fabkit.design.layers); for two layers this is Timoshenko's bimetal curvature
    # 3 (strain mismatch) / (2 H), which the brief's 6 h1 h2 / H^3 would double
    strain, thickness = 0.01, 0.02
    expected = (count**2 - 1) / (2 * count**2) * 2 * strain / thickness
    assert strip_curvature(count, strain, thickness) == pytest.approx(expected, rel=0.02)
    if count == 2:
        # the layers' metrics differ by `strain` along x: a linear strain mismatch of half
        assert expected == pytest.approx(1.5 * (strain / 2) / thickness, rel=1e-12)


@pytest.fixture(scope="module")
def fig3() -> Design:
    return coarse_design("three_shapes.toml", step=0.1, diagonals=100)


def test_second_forms_of_the_sphere_are_its_metric_over_its_radius(fig3):
    # a sphere of radius R is umbilic: II = A / R in any coordinates, here (u, v), where the
    # designed metric at its stimulus is diag((alpha lambda1)^2, (beta lambda2)^2)
    forms = fig3.second_forms
    assert np.all(forms[0][:, fig3.valid] == 0)  # the flat sheet
    response = fig3.problem.material.response(np.nan_to_num(fig3.eps), fig3.stimuli[1:2])
    a_uu = (fig3.alpha * response.lambda1[0]) ** 2
    a_vv = (fig3.beta * response.lambda2[0]) ** 2
    inside = fig3.valid & np.isfinite(forms[1]).all(axis=0)
    assert np.median(np.abs(forms[1, 0][inside] / a_uu[inside])) == pytest.approx(0.1, rel=0.02)
    assert np.median(np.abs(forms[1, 2][inside] / a_vv[inside])) == pytest.approx(0.1, rel=0.02)
    assert np.median(np.abs(forms[1, 1][inside]) / a_uu[inside]) < 0.01


def test_the_layers_program_the_wavy_sheet_and_keep_the_metric(fig3):
    design, report = layered(fig3, 2, THICKNESS)
    matched = dict(zip(report.names, report.matched, strict=True))
    side = dict(zip(report.names, report.right_side, strict=True))
    assert matched["wavy"] > 0.6 and side["wavy"] > 0.95  # its II_vv is reachable (eps2)
    assert report.metric_error < 0.01  # second order in the thickness
    assert 0 <= report.metric_error_p99 <= report.metric_error
    assert design.layers == 2 and np.isnan(design.layering.turn[~design.valid]).all()
    bottom, top = design.layer(0), design.layer(1)
    assert np.allclose(0.5 * (bottom.eps + top.eps)[:, fig3.valid], fig3.eps[:, fig3.valid])
    with pytest.raises(FabkitError, match="--layers 1: expected 2 to 64 layers"):
        layered(fig3, 1, THICKNESS)


def test_bounds_hold_every_layer_within_the_process_range(fig3):
    eps = fig3.eps[:, fig3.valid]
    bounds = np.stack([eps.min(axis=1), eps.max(axis=1)], axis=1)
    design, report = layered(fig3, 3, THICKNESS, bounds=bounds)
    for k in range(3):
        layer = design.layer(k).eps[:, fig3.valid]
        assert (layer >= bounds[:, :1] - 1e-12).all() and (layer <= bounds[:, 1:] + 1e-12).all()
    assert (report.limited > 0).any()  # the extreme points had no room


def test_a_layered_design_file_round_trips_and_says_so(fig3, tmp_path):
    design, _ = layered(fig3, 2, THICKNESS)
    design.save(tmp_path / "layered.npz")
    back = Design.load(tmp_path / "layered.npz")
    assert back.layers == 2 and back.layering.thickness == pytest.approx(THICKNESS)
    assert np.allclose(back.layering.slope[:, fig3.valid], design.layering.slope[:, fig3.valid])
    with np.load(tmp_path / "layered.npz", allow_pickle=False) as archive:
        assert str(archive["format"]) == "fabkit-design/3"
        arrays = {key: archive[key] for key in archive.files if key != "slope"}
    np.savez(tmp_path / "broken.npz", **arrays)
    with pytest.raises(FabkitError, match="a layered design without its 'slope' array"):
        Design.load(tmp_path / "broken.npz")
    arrays["slope"] = design.layering.slope
    arrays["layering"] = np.array([1.0, THICKNESS])
    np.savez(tmp_path / "one.npz", **arrays)
    with pytest.raises(FabkitError, match="2 to 64 layers of a positive thickness, got 1 layers"):
        Design.load(tmp_path / "one.npz")


def unseen_design(name: str) -> Design:
    """A spec of tests/data/specs (made for issue 35, not tuned) on a coarse grid."""
    with open(SPECS / name, "rb") as handle:
        table = tomllib.load(handle)
    table["solver"].update(step=0.1, diagonals=50)
    return solve(build_spec(table, SPECS)).design


def test_a_target_whose_curvature_is_out_of_reach_is_told_why():
    design = unseen_design("bowl_saddle.toml")
    names = [t.name for t in design.problem.targets]
    bowl, saddle = names.index("bowl"), names.index("saddle")
    _, report = layered(design, 2, THICKNESS, weights=np.array([0.0, 1.0, 1.0]))
    reach = report.reach
    # lambda1 = 1: nothing acts along the director; eps acts across it at both stimuli
    assert reach.out_of_reach[bowl, 0] > 0.5 and reach.out_of_reach[bowl, 2] < 0.01
    # across it the one feature bends bowl and saddle alike, where they need opposite bends
    assert reach.held_back[bowl].sum() > 0.2 and reach.opposed[bowl, saddle] > 0.2
    assert reach.held_back[saddle].sum() > 0.2 and reach.opposed[saddle, bowl] > 0.2
    assert report.matched[bowl] < 0.1
    line = report.lines()[bowl - 1]
    assert "along the director, which no feature reaches" in line
    assert "held back where saddle needs the opposite bend" in line
    assert "what would change it: a feature acting along the director" in line


def test_what_the_layers_of_fig3_can_reach_and_what_not(fig3):
    _, report = layered(fig3, 2, THICKNESS)
    reach, lines = report.reach, report.lines()
    # the wavy sheet (L = (0, 2)) is reached: told nothing
    assert report.matched[3] > 0.5 and "why:" not in lines[2]
    assert reach.out_of_reach[3].sum() < 0.05
    # the face (L = (2, 0)) curves across the director, where eps2 acts on nothing at L2 = 0
    assert reach.out_of_reach[2, 2] > 0.8 and report.matched[2] < 0.1
    assert "of its curvature is across the director, which no feature reaches" in lines[1]


def test_the_layers_are_printed_along_one_set_of_lines_turned_to_each_layer(fig3):
    """The print's roads wander about a degree from the director; a layer's turn is a
    fraction of one. Printed along one set of lines, turned per layer, the layers differ
    by the designed turn and nothing else; planned apart (a turn too large to share), by
    their roads' wander."""
    design, _ = layered(fig3, 2, THICKNESS)

    def turn_error_deg(layered_design: Design) -> np.ndarray:
        """Per top-layer segment: its angle less the nearest bottom segment's, less the
        designed turn between the layers there (degrees)."""
        job = ToolpathJob(inputs=("fig3.npz",), design=layered_design, size_mm=20.0)
        result = plan_job(job)
        plan, part = result.plan, result.parts[0]
        fields = [field_from_design(layered_design.layer(k), part=part) for k in (0, 1)]
        middles, angles = [], []
        for layer in plan.toolpath.layers:
            lines = [m.xyz[:, :2] for m in layer.moves if m.kind == "print"]
            step = np.concatenate([np.diff(line, axis=0) for line in lines])
            middles.append(
                np.concatenate([line[:-1] + 0.5 * np.diff(line, axis=0) for line in lines])
            )
            angles.append(np.arctan2(step[:, 1], step[:, 0]))
        _, nearest = cKDTree(middles[0]).query(middles[1])
        designed = fields[1].theta(middles[1]) - fields[0].theta(middles[1])
        error = angles[1] - angles[0][nearest] - designed
        return np.degrees(np.abs(director_angle(error)))

    shared = turn_error_deg(design)
    assert np.median(shared) < 0.01 and np.percentile(shared, 90) < 0.05
    # a turn too large to share (3 degrees between the layers): planned apart, they wander apart
    spread = design.layering.heights[-1] - design.layering.heights[0]
    wide = replace(design.layering, turn=np.where(fig3.valid, np.radians(3.0) / spread, np.nan))
    apart = turn_error_deg(design.with_layering(wide))
    assert np.percentile(apart, 90) > 0.5
