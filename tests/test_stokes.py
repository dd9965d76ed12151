"""Regularised Stokeslets against exact Stokes drags and the three-sphere swimmer."""

from __future__ import annotations

import numpy as np
import pytest

from fabkit.errors import FabkitError
from fabkit.swimmer.motion import align, exponential, swim
from fabkit.swimmer.stokes import (
    Stokes,
    default_epsilon,
    disc_points,
    sphere_points,
    stokeslet_matrix,
)


def sphere(count: int, radius: float = 1.0) -> Stokes:
    epsilon = default_epsilon(4 * np.pi * radius**2, count)
    return Stokes.of(sphere_points(count, radius), epsilon, viscosity=2.0)


def disc(rings: int, radius: float = 1.0) -> Stokes:
    flat = disc_points(radius, rings)
    points = np.column_stack([flat, np.zeros(len(flat))])
    return Stokes.of(points, default_epsilon(np.pi * radius**2, len(points)))


def disc_errors(rings: int) -> tuple[float, float]:
    """Relative errors of broadside (16 mu a U) and edgewise (32/3 mu a U) disc drag."""
    resistance = disc(rings).resistance
    return resistance[2, 2] / 16.0 - 1.0, resistance[0, 0] / (32.0 / 3.0) - 1.0


def test_kernel_is_symmetric_and_far_field_is_the_stokeslet():
    points = np.array([[0.0, 0.0, 0.0], [3.0, 4.0, 12.0]])
    matrix = stokeslet_matrix(points, epsilon=1e-3, viscosity=1.0)
    assert np.allclose(matrix, matrix.T)
    d = points[0] - points[1]
    r = np.linalg.norm(d)
    exact = (np.eye(3) / r + np.outer(d, d) / r**3) / (8 * np.pi)
    assert np.allclose(matrix[:3, 3:], exact, rtol=1e-6)
    assert np.allclose(matrix[:3, :3], np.eye(3) / (4 * np.pi * 1e-3))


@pytest.mark.slow
def test_sphere_drag_and_torque_within_2_percent():
    stokes = sphere(400, radius=0.5)
    drag = 6 * np.pi * 2.0 * 0.5
    assert np.allclose(np.diag(stokes.resistance)[:3], drag, rtol=0.02)
    assert np.allclose(np.diag(stokes.resistance)[3:], 8 * np.pi * 2.0 * 0.5**3, rtol=0.05)
    assert np.allclose(stokes.resistance, stokes.resistance.T, atol=1e-9)


@pytest.mark.slow
def test_sphere_drag_converges():
    errors = [abs(sphere(n).resistance[0, 0] / (6 * np.pi * 2.0) - 1) for n in (100, 200, 400)]
    assert errors[0] > errors[1] > errors[2]


@pytest.mark.slow
def test_disc_drag_broadside_and_edgewise_within_5_percent():
    broadside, edgewise = disc_errors(14)
    assert abs(broadside) < 0.05
    assert abs(edgewise) < 0.05


@pytest.mark.slow
def test_disc_drag_converges_as_points_and_epsilon_are_refined():
    errors = np.abs([disc_errors(rings) for rings in (6, 10, 14)])
    assert np.all(np.diff(errors, axis=0) < 0)


def test_forces_reproduce_the_prescribed_velocity():
    stokes = sphere(200)
    velocities = np.random.default_rng(1).normal(size=(200, 3))
    forces = stokes.forces(velocities)
    assert np.allclose(
        stokeslet_matrix(stokes.points, stokes.epsilon, 2.0) @ forces.ravel(), velocities.ravel()
    )


def test_rigid_deformation_is_cancelled_and_motion_is_linear():
    stokes = disc(6)
    twist = np.array([0.1, -0.2, 0.3, 0.05, -0.02, 0.01])
    rigid = (stokes.modes @ twist).reshape(-1, 3)
    assert np.allclose(stokes.rigid_motion(rigid), -twist, atol=1e-10)
    bend = np.zeros_like(stokes.points)
    bend[:, 2] = np.sum(stokes.points[:, :2] ** 2, axis=1)
    assert np.allclose(stokes.rigid_motion(7.0 * bend), 7.0 * stokes.rigid_motion(bend))


def test_coincident_points_are_a_user_error():
    with pytest.raises(FabkitError, match="singular"):
        Stokes.of(np.zeros((2, 3)), epsilon=0.1)


def test_align_removes_a_rigid_motion():
    shape = np.random.default_rng(2).normal(size=(50, 3))
    turn, shift = exponential(np.array([1.0, 2.0, 3.0, 0.3, -0.4, 0.5]))
    moved = shape @ turn.T + shift
    assert np.allclose(align(moved, shape), shape - shape.mean(axis=0))


def three_spheres(lengths: np.ndarray, radius: float, count: int) -> np.ndarray:
    """Points of three spheres on the x axis, arm lengths ``lengths`` (2,)."""
    ball = sphere_points(count, radius)
    centers = [0.0, lengths[0], lengths[0] + lengths[1]]
    return np.concatenate([ball + [x, 0.0, 0.0] for x in centers])


def golestanian_ajdari(corners: np.ndarray, radius: float) -> float:
    """Net displacement around the polygon ``corners`` (P, 2) of arm lengths (L1, L2).

    Golestanian & Ajdari, Phys. Rev. E 77, 036308 (2008), to first order in a / L and any
    amplitude: V = (a/6) [(2 L1^2 - L2^2) L1' + (L1^2 - 2 L2^2) L2'] / (L1 L2 (L1 + L2)),
    integrated along the loop with Gauss-Legendre quadrature. For small loops this is
    2 K x (area), K = (a/6) [1/L1^2 + 1/L2^2 - 1/(L1 + L2)^2].
    """
    nodes, weights = np.polynomial.legendre.leggauss(20)
    total = 0.0
    for start, end in zip(corners[:-1], corners[1:], strict=True):
        l1, l2 = (start[:, None] + np.outer(end - start, (nodes + 1) / 2)).reshape(2, -1)
        denominator = 6 * l1 * l2 * (l1 + l2)
        rate = (2 * l1**2 - l2**2) * (end - start)[0] + (l1**2 - 2 * l2**2) * (end - start)[1]
        total += radius * np.sum(weights / 2 * rate / denominator)
    return total


def three_sphere_displacement(corners: np.ndarray, radius: float, per_leg: int) -> np.ndarray:
    lengths = [
        a + (b - a) * t
        for a, b in zip(corners[:-1], corners[1:], strict=True)
        for t in np.arange(per_leg) / per_leg
    ] + [corners[-1]]
    shapes = [three_spheres(length, radius, 200) for length in lengths]
    epsilon = default_epsilon(4 * np.pi * radius**2, 200)
    return swim(shapes, epsilon).displacement


@pytest.mark.slow
def test_three_sphere_swimmer_matches_golestanian_ajdari_within_2_percent():
    radius = 0.02
    corners = np.array([[1.0, 1.0], [1.2, 1.0], [1.2, 1.2], [1.0, 1.2], [1.0, 1.0]])
    displacement = three_sphere_displacement(corners, radius, per_leg=3)
    expected = golestanian_ajdari(corners, radius)
    assert expected > 0
    assert displacement[0] == pytest.approx(expected, rel=0.02)
    assert np.all(np.abs(displacement[1:]) < 1e-5 * expected)
    small = np.array([[1.0, 1.0], [1.01, 1.0], [1.01, 1.01], [1.0, 1.01], [1.0, 1.0]])
    area_formula = 2 * radius / 6 * (2 - 1 / 4) * 1e-4
    assert golestanian_ajdari(small, radius) == pytest.approx(area_formula, rel=0.02)
