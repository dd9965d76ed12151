"""Low-Reynolds-number hydrodynamics with regularised Stokeslets (Cortez, Fauci, Medovikov 2005).

A body is a set of N points carrying point forces f_k (N,3). The fluid velocity they
induce at x is

    u(x) = sum_k S_eps(x - x_k) f_k,
    S_eps(d) = [(|d|^2 + 2 eps^2) I + d d^T] / (8 pi mu (|d|^2 + eps^2)^(3/2)),

the exact Stokes flow of forces spread over blobs 15 eps^4 / (8 pi (r^2 + eps^2)^(7/2)).
The kernel is positive definite, so the 3N x 3N matrix is factorised once per shape
(Cholesky) and reused for every right-hand side. No-slip on the points gives the forces
for prescribed point velocities; the rigid motion (U, Omega) of a deforming body that is
free of force and torque follows from the 6 x 6 resistance matrix.

Units: lengths in any unit L, viscosity mu, velocities L/T, forces mu L^2/T. Stokes flow
has no time scale, so a shape *increment* (L) in place of a velocity gives the rigid
*displacement* (L) and rotation (rad) over that increment: the result does not depend
on how fast the shapes are cycled.

The regularisation eps is chosen proportional to the point spacing h = sqrt(area / N),
``eps = EPSILON_RATIO * h``; refining the point set at this ratio converges (errors
roughly proportional to h, measured in ``docs/swimmer.md``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as la

from fabkit.errors import FabkitError

EPSILON_RATIO = 0.35
"""Regularisation / point spacing. Measured: sphere drag within 0.5 %, disc drag within
2 % from ~1300 points; the leading O(h) errors of the blob width and the quadrature nearly
cancel at this ratio."""

SINGULAR_PIVOT = 1e-7
"""Smallest Cholesky pivot, relative to the largest, of a usable Stokeslet matrix."""


def stokeslet_matrix(points: np.ndarray, epsilon: float, viscosity: float = 1.0) -> np.ndarray:
    """The regularised Stokeslet matrix (3N, 3N), point-major: row 3j + a, column 3k + b.

    ``points`` (N, 3); ``epsilon`` the blob width (length); ``viscosity`` mu.
    Entry (3j + a, 3k + b) is the velocity component a at point j per unit force
    component b at point k. Memory: 72 N^2 bytes for the matrix plus ~5 N^2 doubles.
    """
    points = np.asarray(points, dtype=float)
    count = len(points)
    matrix = np.empty((3 * count, 3 * count))
    deltas = [points[:, None, a] - points[None, :, a] for a in range(3)]
    scale = deltas[0] ** 2 + deltas[1] ** 2 + deltas[2] ** 2
    isotropic = scale + 2.0 * epsilon**2
    scale += epsilon**2
    scale **= -1.5
    scale /= 8.0 * np.pi * viscosity
    isotropic *= scale
    for a in range(3):
        for b in range(a, 3):
            block = deltas[a] * deltas[b]
            block *= scale
            if a == b:
                block += isotropic
            matrix[a::3, b::3] = block
            if a != b:
                matrix[b::3, a::3] = block
    return matrix


def rigid_modes(points: np.ndarray, center: np.ndarray) -> np.ndarray:
    """Point velocities (3N, 6) of the six rigid motions about ``center`` (3,).

    Column c < 3 is unit translation along axis c; column 3 + c is unit rotation about
    axis c through ``center``: velocity e_c x (x - center).
    """
    arm = np.asarray(points, dtype=float) - center
    count = len(arm)
    modes = np.zeros((count, 3, 6))
    modes[:, :, :3] = np.eye(3)
    for c in range(3):
        modes[:, :, 3 + c] = np.cross(np.eye(3)[c], arm)
    return modes.reshape(3 * count, 6)


@dataclass(frozen=True)
class Stokes:
    """The factorised no-slip problem for one configuration of points.

    ``points`` (N, 3), ``epsilon`` (length), ``viscosity`` mu, ``center`` (3,) the
    reference point for torques and rotations. ``factor`` is the Cholesky factor of the
    Stokeslet matrix, ``modes`` (3N, 6) the rigid motions, ``resistance`` (6, 6) the
    resistance matrix: (force, torque about center) = resistance @ (U, Omega).
    Build with :meth:`of`.
    """

    points: np.ndarray
    epsilon: float
    viscosity: float
    center: np.ndarray
    factor: tuple[np.ndarray, bool]
    modes: np.ndarray
    resistance: np.ndarray

    @classmethod
    def of(
        cls,
        points: np.ndarray,
        epsilon: float,
        viscosity: float = 1.0,
        center: np.ndarray | None = None,
    ) -> Stokes:
        """Assemble and factorise; ``center`` defaults to the origin."""
        points = np.asarray(points, dtype=float)
        if points.ndim != 2 or points.shape[1] != 3 or not np.isfinite(points).all():
            raise FabkitError("stokes: points must be a finite (N, 3) array")
        if not (epsilon > 0 and viscosity > 0):
            raise FabkitError("stokes: epsilon and viscosity must be positive")
        center = np.zeros(3) if center is None else np.asarray(center, dtype=float)
        matrix = stokeslet_matrix(points, epsilon, viscosity)
        try:
            factor = la.cho_factor(matrix, lower=True, overwrite_a=True, check_finite=False)
        except la.LinAlgError:
            factor = None
        pivots = None if factor is None else np.abs(np.diag(factor[0]))
        if pivots is None or pivots.min() < SINGULAR_PIVOT * pivots.max():
            raise FabkitError(
                "stokes: the Stokeslet matrix is singular: points coincide, or epsilon is "
                "much larger than the point spacing"
            )
        modes = rigid_modes(points, center)
        resistance = modes.T @ la.cho_solve(factor, modes, check_finite=False)
        return cls(points, float(epsilon), float(viscosity), center, factor, modes, resistance)

    def forces(self, velocities: np.ndarray) -> np.ndarray:
        """Point forces (N, 3) that move the points with ``velocities`` (N, 3)."""
        flat = np.asarray(velocities, dtype=float).reshape(-1)
        return la.cho_solve(self.factor, flat, check_finite=False).reshape(-1, 3)

    def rigid_motion(self, deformation: np.ndarray) -> np.ndarray:
        """Rigid motion (6,) = (U, Omega) of a free body whose points deform by ``deformation``.

        ``deformation`` (N, 3) is the point velocity (or increment) in the body frame. The
        body moves by U + Omega x (x - center) on top of it so that the total force and
        the torque about ``center`` vanish. Linear in ``deformation``; a rigid
        ``deformation`` is cancelled exactly.
        """
        solved = la.cho_solve(
            self.factor, np.asarray(deformation, dtype=float).reshape(-1), check_finite=False
        )
        return -np.linalg.solve(self.resistance, self.modes.T @ solved)


def default_epsilon(area: float, count: int) -> float:
    """Regularisation for ``count`` points spread evenly over ``area``: ratio x spacing."""
    return EPSILON_RATIO * float(np.sqrt(area / count))


def disc_points(radius: float, rings: int) -> np.ndarray:
    """Points (N, 2) on a disc: the centre and ``rings`` rings at radii k h, h = radius/rings.

    Ring k holds a multiple of 4 points, about 2 pi k evenly, at angles (j + 1/2) 2 pi / m:
    the set is symmetric under x -> -x, y -> -y and quarter turns. N ~ pi rings^2.
    """
    if rings < 1:
        raise FabkitError("stokes: a disc needs at least one ring of points")
    step = radius / rings
    parts = [np.zeros((1, 2))]
    for k in range(1, rings + 1):
        count = 4 * max(1, round(2 * np.pi * k / 4))
        angles = (np.arange(count) + 0.5) * 2 * np.pi / count
        parts.append(k * step * np.column_stack([np.cos(angles), np.sin(angles)]))
    return np.concatenate(parts)


def sphere_points(count: int, radius: float = 1.0) -> np.ndarray:
    """``count`` nearly even points (N, 3) on a sphere about the origin (Fibonacci spiral)."""
    k = np.arange(count) + 0.5
    z = 1.0 - 2.0 * k / count
    phi = np.pi * (1.0 + np.sqrt(5.0)) * k
    ring = np.sqrt(1.0 - z * z)
    return radius * np.column_stack([ring * np.cos(phi), ring * np.sin(phi), z])
