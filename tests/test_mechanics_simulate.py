"""Forward simulation against analytic shapes: cone, anticone, spherical cap, and Fig. 1."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial import Delaunay

from fabkit.errors import FabkitError
from fabkit.field.part import simulation_part
from fabkit.figures import cell_integral
from fabkit.mechanics.compare import align, compare, formed_shape, integrated_curvature
from fabkit.mechanics.mesh import design_mesh, disc_mesh
from fabkit.mechanics.metric import edge_lengths, metric_from_director, metric_from_lengths
from fabkit.mechanics.shell import Sheet
from fabkit.mechanics.simulate import (
    Settings,
    design_metrics,
    simulate,
    simulate_design,
    surface_index,
)
from tests.conftest import coarse_design

ALONG, ACROSS = 0.8, 0.8**-0.5
"""A nematic elastomer's contraction along the director and expansion across it."""


def director_metrics(points, triangles, field):
    """Edge-length metrics of a director field(p) with stretches ALONG, ACROSS."""

    def metric(p):
        shape = p.shape[:-1]
        return metric_from_director(field(p), np.full(shape, ALONG), np.full(shape, ACROSS))

    return metric_from_lengths(points, triangles, edge_lengths(points, triangles, metric))


def azimuthal(p):
    return np.stack([-p[..., 1], p[..., 0]], -1)


def radial(p):
    return p


@pytest.mark.slow
def test_azimuthal_director_makes_a_cone():
    points, triangles = disc_mesh(1.0, 20)  # 2400 triangles
    metrics = director_metrics(points, triangles, azimuthal)
    result = simulate(points, triangles, metrics, thickness=1e-3, settings=Settings(steps=1))
    exact = 2 * np.pi * (1 - ALONG / ACROSS)
    assert result.converged
    assert integrated_curvature(result.positions, triangles) == pytest.approx(exact, rel=0.01)


@pytest.mark.slow
def test_radial_director_makes_an_anticone():
    points, triangles = disc_mesh(1.0, 10)  # 600 triangles
    metrics = director_metrics(points, triangles, radial)
    settings = Settings(seed="saddle", max_iterations=300)
    result = simulate(points, triangles, metrics, thickness=1e-3, settings=settings)
    excess = 2 * np.pi * (ACROSS / ALONG - 1)
    assert result.converged
    assert integrated_curvature(result.positions, triangles) == pytest.approx(-excess, rel=0.01)


@pytest.mark.slow
def test_isotropic_stereographic_metric_makes_a_spherical_cap():
    """a = (2 / (1 + r^2))^2 I on the disc r <= 0.7 is a cap of the unit sphere."""
    points, triangles = disc_mesh(1.0, 10)
    points = 0.7 * points

    def metric(p):
        scale = 2 / (1 + np.sum(p**2, -1))
        return scale[..., None, None] ** 2 * np.eye(2)

    metrics = metric_from_lengths(points, triangles, edge_lengths(points, triangles, metric))
    result = simulate(points, triangles, metrics, thickness=0.01)
    r2 = np.sum(points**2, 1)[:, None]
    cap = np.concatenate([2 * points / (1 + r2), (1 - r2) / (1 + r2)], 1)
    alignment = align(result.positions, cap)
    assert alignment.max <= 0.02  # pointwise distance / R bounds the Hausdorff distance


@pytest.mark.slow
def test_bilayer_curls_with_timoshenko_curvature_towards_its_contracting_top():
    """Top layer contracting along x by 1 %, bottom unchanged, equal thicknesses, nu = 0:
    a cylinder of curvature 1.5 |strain| / h about y, bending towards the top layer."""
    grid = np.linspace(-1, 1, 15)
    points = np.stack(np.meshgrid(grid, grid), -1).reshape(-1, 2)
    triangles = Delaunay(points).simplices
    faces, thickness, stretch = len(triangles), 0.02, 0.99
    top = metric_from_director(
        np.tile([1.0, 0.0], (faces, 1)), np.full(faces, stretch), np.ones(faces)
    )
    bottom = np.broadcast_to(np.eye(2), (faces, 2, 2))
    result = simulate(points, triangles, np.stack([bottom, top]), thickness, poisson=0.0)
    assert result.converged
    middle = np.abs(points[:, 1]) < 1e-9  # the row y = 0, a circular arc after rolling
    centre, radius = fit_circle(result.positions[middle])
    expected = 0.75 * (1 - stretch**2) / thickness
    assert 1 / radius == pytest.approx(expected, rel=0.05)
    corners = result.positions[triangles]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    towards_centre = centre - corners.mean(1)
    assert np.all(np.einsum("fi,fi->f", normals, towards_centre) > 0)
    assert abs(integrated_curvature(result.positions, triangles)) < 0.01


def fit_circle(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre (3,) and radius of the circle through nearly coplanar points (n, 3)."""
    mean = points.mean(0)
    _, _, axes = np.linalg.svd(points - mean)
    plane = (points - mean) @ axes[:2].T
    system = np.concatenate([2 * plane, np.ones((len(plane), 1))], 1)
    (a, b, c), *_ = np.linalg.lstsq(system, np.sum(plane**2, 1), rcond=None)
    return mean + a * axes[0] + b * axes[1], float(np.sqrt(c + a * a + b * b))


@pytest.fixture(scope="module")
def fig1_design():
    return coarse_design()


@pytest.mark.slow
@pytest.mark.parametrize(("stimulus", "whole"), [("sphere", 0.075), ("bump", 0.026)])
def test_fig1_targets_are_reproduced_where_the_sheet_is_wide_enough(fig1_design, stimulus, whole):
    """Thickness 1 % of the flat domain's size. On the default part (fabkit simulate's:
    without the regions under 4 bending lengths across), each cell split 3 x 3, both
    targets are met within 2 % of the patch size. The whole domain misses (see
    docs/mechanics.md, Limits): the sphere's narrow arms unroll (measured 6.9 %), the bump
    relaxes towards a near-isometric shape of lower bending energy (2.4 %)."""
    surface = surface_index(fig1_design, stimulus)
    part, _ = simulation_part(fig1_design, None)
    report = compare(fig1_design, simulate_design(fig1_design, surface, part=part, refine=3))
    assert report.converged
    assert report.rms <= 0.02, report.table()
    assert report.strain_median <= 5e-3
    report = compare(fig1_design, simulate_design(fig1_design, surface))
    assert report.rms <= whole, report.table()


def test_the_formed_shape_is_the_compared_sheet_moved_rigidly_in_mm(fig1_design):
    """The mesh the pictures and as_fabricated/*.ply show: every vertex (those between the
    design's grid points too) moved by the rotation and translation compare() fits, scaled
    to mm; its RMS distance over the grid points is compare()'s."""
    simulation = simulate_design(fig1_design, 1, refine=2, settings=Settings(max_iterations=8))
    found = compare(fig1_design, simulation)
    scale = 3.0  # mm per design unit
    shape = formed_shape(fig1_design, simulation, scale)
    nodes, triangles = simulation.mesh.nodes, simulation.mesh.triangles
    assert not found.mirrored and not nodes.all()
    assert shape.vertices_mm.shape == shape.target_mm.shape == (len(nodes), 3)
    assert np.array_equal(shape.triangles, triangles)
    assert shape.diameter_mm == pytest.approx(scale * found.size)
    rms = np.sqrt(np.mean(shape.distance_mm[nodes] ** 2)) / shape.diameter_mm
    assert rms == pytest.approx(found.rms, rel=1e-9)
    apart = np.linalg.norm(shape.vertices_mm - shape.target_mm, axis=1)
    assert np.allclose(shape.distance_mm, apart)

    def edges(points):
        return np.linalg.norm(points[triangles[:, 1]] - points[triangles[:, 0]], axis=1)

    assert np.allclose(edges(shape.vertices_mm), scale * edges(simulation.result.positions))


def test_trimming_keeps_the_thickness_of_the_whole_sheet(fig1_design):
    settings = Settings(max_iterations=1)
    whole = simulate_design(fig1_design, 1, settings=settings)
    part, thickness = simulation_part(fig1_design, None)
    trimmed = simulate_design(fig1_design, 1, settings=settings, part=part)
    assert thickness == pytest.approx(whole.thickness, rel=0.05)
    assert trimmed.thickness == whole.thickness


def test_unknown_stimulus_is_a_one_line_error(fig1_design):
    with pytest.raises(FabkitError, match="expected a surface name"):
        surface_index(fig1_design, "cube")


def test_design_mesh_carries_material_coordinates(fig1_design):
    mesh = design_mesh(fig1_design)
    flat = fig1_design.r[0][mesh.grid[:, 0], mesh.grid[:, 1]]
    assert np.array_equal(flat, mesh.points)
    part, _ = simulation_part(fig1_design, None)
    assert len(design_mesh(fig1_design, part).triangles) < len(mesh.triangles)


def test_refined_design_mesh_splits_every_cell(fig1_design):
    mesh, fine = design_mesh(fig1_design), design_mesh(fig1_design, refine=3)
    assert len(fine.triangles) == 9 * len(mesh.triangles)
    nodes = fine.grid[fine.nodes] // 3
    assert np.array_equal(fine.points[fine.nodes], fig1_design.r[0][nodes[:, 0], nodes[:, 1]])
    assert np.count_nonzero(fine.nodes) == len(mesh.points)
    # the sheet as made: its area in the reference metric against the designed flat area
    # iint alpha beta du dv; unrefined cells are too long and curved to carry it
    design = fig1_design
    designed = cell_integral(design.alpha * design.beta, design.valid, design.step)
    coarse_error = abs(made_area(design, mesh) / designed - 1)
    fine_error = abs(made_area(design, fine) / designed - 1)
    assert fine_error < 0.005 and fine_error < 0.5 * coarse_error
    with pytest.raises(FabkitError, match="refine"):
        design_mesh(fig1_design, refine=0)


def made_area(design, mesh) -> float:
    """Area of the flat sheet as made in its reference metric (surface 0's stimulus)."""
    metrics = design_metrics(design, mesh, 0)
    flat = Sheet.build(mesh.points, mesh.triangles).area
    return float(np.sum(np.sqrt(np.linalg.det(metrics)) * flat))


@pytest.mark.slow
def test_simulate_cli_writes_the_mesh_and_reports(fig1_design, run_cli, tmp_path):
    path = tmp_path / "design.npz"
    fig1_design.save(path)
    mesh = tmp_path / "sphere.ply"
    code, out, _ = run_cli(
        "simulate", path, "--stimulus", "1", "--refine", "2", "--out", mesh, "--json"
    )
    assert code == 0 and mesh.stat().st_size > 0
    assert json.loads(out)["rms"] <= 0.02
    code, _, err = run_cli("simulate", path, "--stimulus", "1", "--out", tmp_path / "x.txt")
    assert code == 2 and "mesh format" in err


def test_simulate_cli_says_when_newton_stops_before_converging(fig1_design, run_cli, tmp_path):
    path = tmp_path / "design.npz"
    fig1_design.save(path)
    args = ("simulate", path, "--stimulus", "1")
    code, out, _ = run_cli(*args, "--max-iterations", "2")
    assert code == 0 and "not converged" in out and "--max-iterations" in out
    code, out, _ = run_cli(*args)
    assert code == 0 and "converged True" in out and "not converged" not in out
    # the verdict's words and limit, for this one start (issue 37: an RMS with no limit)
    (alone,) = [line for line in out.splitlines() if "from this start alone" in line]
    assert "sphere: formed, " in alone and "limit 3 % (" in alone, alone
    code, out, _ = run_cli(*args, "--seed", "dome-down", "--json")
    this_start = json.loads(out)["this_start"]
    assert this_start["mirror_image"] and not this_start["formed"], this_start
