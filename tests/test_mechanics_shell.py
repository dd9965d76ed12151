"""The shell energy: analytic derivatives against finite differences, signs, stiffness."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import Delaunay

from fabkit.errors import FabkitError
from fabkit.mechanics.kernels import fold_angles
from fabkit.mechanics.mesh import disc_mesh, topology
from fabkit.mechanics.metric import (
    edge_lengths,
    metric_from_director,
    metric_from_lengths,
)
from fabkit.mechanics.shell import Sheet, build_shell


@pytest.fixture(scope="module")
def small_disc():
    points, triangles = disc_mesh(1.0, 3)
    return Sheet.build(points, triangles)


def bilayer(sheet: Sheet, thickness: float = 0.1):
    """An azimuthal top layer and a radial bottom layer: stretching and bending coupled."""
    centres = sheet.points[sheet.triangles].mean(1) + 1e-3
    faces = len(centres)
    stretch = np.full(faces, 0.9), np.full(faces, 1.1)
    azimuthal = metric_from_director(np.stack([-centres[:, 1], centres[:, 0]], -1), *stretch)
    radial = metric_from_director(centres, *stretch)
    return build_shell(sheet, np.stack([radial, azimuthal]), thickness, poisson=0.4)


def random_positions(sheet: Sheet, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x = np.concatenate([sheet.points, 0.1 * rng.standard_normal((sheet.vertex_count, 1))], 1)
    return x + 0.05 * rng.standard_normal(x.shape)


def test_gradient_matches_finite_differences(small_disc):
    shell, x = bilayer(small_disc), random_positions(small_disc)
    gradient, numeric, h = shell.gradient(x), np.zeros_like(x), 1e-6
    for index in np.ndindex(x.shape):
        step = np.zeros_like(x)
        step[index] = h
        numeric[index] = (shell.energy(x + step) - shell.energy(x - step)) / (2 * h)
    assert np.max(np.abs(numeric - gradient)) <= 1e-7 * np.max(np.abs(gradient))


def test_exact_hessian_matches_finite_differences_of_gradient(small_disc):
    shell, x = bilayer(small_disc), random_positions(small_disc, seed=2)
    hessian = shell.hessian(x, projected=False).toarray()
    numeric, h = np.zeros_like(hessian), 1e-6
    for row, index in enumerate(np.ndindex(x.shape)):
        step = np.zeros_like(x)
        step[index] = h
        numeric[row] = ((shell.gradient(x + step) - shell.gradient(x - step)) / (2 * h)).ravel()
    assert np.max(np.abs(numeric - hessian)) <= 1e-7 * np.max(np.abs(hessian))
    assert np.allclose(hessian, hessian.T, atol=1e-14 * np.max(np.abs(hessian)))


def test_projected_hessian_is_positive_semidefinite(small_disc):
    shell, x = bilayer(small_disc), random_positions(small_disc, seed=3)
    exact = np.linalg.eigvalsh(shell.hessian(x, projected=False).toarray())
    projected = np.linalg.eigvalsh(shell.hessian(x, projected=True).toarray())
    assert exact.min() < -1e-6 * exact.max()  # the exact one is indefinite here
    assert projected.min() >= -1e-12 * projected.max()


def test_fold_angle_gradient_and_sign():
    # Two faces folded up about the x axis: a valley opening towards +z (the normal side).
    x = np.array([[0.0, 0, 0], [1, 0, 0], [0.5, 1, 0.3], [0.5, -1, 0.3]])
    hinge = np.array([[0, 1, 2, 3]])
    phi, gradient, hessian = fold_angles(x, hinge, order=2)
    assert phi[0] == pytest.approx(2 * np.arctan(0.3))
    h = 1e-6
    for k in range(12):
        step = np.zeros(12)
        step[k] = h
        up = fold_angles(x + step.reshape(4, 3), hinge, 1)
        down = fold_angles(x - step.reshape(4, 3), hinge, 1)
        assert (up[0] - down[0])[0] / (2 * h) == pytest.approx(gradient[0, k], abs=1e-8)
        assert (up[1] - down[1])[0] / (2 * h) == pytest.approx(hessian[0, k], abs=1e-6)


def test_flat_sheet_at_rest_has_no_energy(small_disc):
    faces = len(small_disc.triangles)
    shell = build_shell(small_disc, np.broadcast_to(np.eye(2), (faces, 2, 2)), 0.05)
    flat = np.concatenate([small_disc.points, np.zeros((small_disc.vertex_count, 1))], 1)
    assert abs(shell.energy(flat)) < 1e-15
    assert np.max(np.abs(shell.gradient(flat))) < 1e-14


@pytest.mark.parametrize("poisson", [0.0, 0.3, 0.5])
def test_cylinder_bending_energy_is_classical(poisson):
    """Wrapping a flat sheet isometrically on a cylinder of radius R costs D A / (2 R^2)."""
    grid = np.linspace(-1, 1, 41)
    points = np.stack(np.meshgrid(grid, grid), -1).reshape(-1, 2)
    sheet = Sheet.build(points, Delaunay(points).simplices)
    thickness, radius = 0.01, 2.0
    identity = np.broadcast_to(np.eye(2), (len(sheet.triangles), 2, 2))
    shell = build_shell(sheet, identity, thickness, poisson)
    angle = points[:, 0] / radius
    x = np.stack([radius * np.sin(angle), points[:, 1], radius * (1 - np.cos(angle))], -1)
    rigidity = thickness**3 / (12 * (1 - poisson**2))
    expected = rigidity * sheet.area.sum() / (2 * radius**2)
    assert shell.energy(x) == pytest.approx(expected, rel=0.05)


def test_edge_length_metric_is_exact_for_a_constant_metric():
    points, triangles = disc_mesh(1.0, 4)
    constant = metric_from_director(np.array([0.6, 0.8]), np.array(1.3), np.array(0.7))
    lengths = edge_lengths(points, triangles, lambda p: np.broadcast_to(constant, (*p.shape, 2)))
    assert np.allclose(metric_from_lengths(points, triangles, lengths), constant, atol=1e-12)


def test_metric_from_director_stretches_along_and_across():
    metric = metric_from_director(np.array([[3.0, 4.0]]), np.array([2.0]), np.array([0.5]))[0]
    along, across = np.array([0.6, 0.8]), np.array([-0.8, 0.6])
    assert along @ metric @ along == pytest.approx(4.0)
    assert across @ metric @ across == pytest.approx(0.25)
    assert along @ metric @ across == pytest.approx(0.0, abs=1e-15)


def test_impossible_edge_lengths_are_refused():
    points = np.array([[0.0, 0], [1, 0], [0, 1]])
    with pytest.raises(FabkitError, match="triangle inequality"):
        metric_from_lengths(points, np.array([[0, 1, 2]]), np.array([[3.0, 1.0, 1.0]]))


def test_non_manifold_mesh_is_refused():
    triangles = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    with pytest.raises(FabkitError, match="more than two"):
        topology(triangles)
