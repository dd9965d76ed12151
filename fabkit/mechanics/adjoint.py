"""How a simulated sheet's distance to its target changes with its reference metrics: the
adjoint method.

A simulation ends at an equilibrium x of the shell energy E(x; m), the per-face,
per-layer reference metrics m held fixed (:mod:`fabkit.mechanics.shell`): g(x, m) =
dE/dx = 0. For a distance J(x) (:func:`aligned_distance`) the implicit function theorem
gives, with H = d²E/dx² the exact Hessian at x,

    dJ/dm = -lambda^T d²E/dx dm,    H lambda = dJ/dx,

one linear solve whatever the number of metrics (H is singular only along the rigid
motions, which J does not see: both sides are solved orthogonally to them). The mixed
term is a sum over faces of the face's energy gradient in its coordinates y = (a11, a12,
a22, s0, s1, s2) along the change of y that lambda makes, dy = (dy/dx) lambda:

    lambda^T dE/dx = sum_f dy_f^T K_f(m) (y_f - rest_f(m)),

a function of each face's own metrics only, differentiated by central differences in
every metric component (all faces at once: they are independent). dy is a central
difference of y along lambda. The result is exact to the differences' rounding
(tests/test_mechanics_adjoint.py checks it against simulations of perturbed metrics).

It holds on the branch the equilibrium sits on: a change of metrics that makes the sheet
snap to another shape is not seen (the optimiser that uses it re-simulates).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sparse

from fabkit.mechanics.compare import proper_rotation
from fabkit.mechanics.factor import factorise
from fabkit.mechanics.shell import Sheet, build_shell
from fabkit.mechanics.simulate import SHIFT, rigid_modes

METRIC_STEP = 1e-6
"""Central-difference step of a metric component, relative to the largest metric entry."""
POSITION_STEP = 1e-7
"""Central-difference step along the adjoint, relative to the mean edge over its largest
vertex move."""


@dataclass(frozen=True)
class Distance:
    """``value``: (RMS / size)^2 of the points after the proper rigid motion that fits them
    best to their target (never a mirror image); ``gradient`` (V, 3): its derivative in the
    points (the motion held at its best, which changes nothing to first order)."""

    value: float
    gradient: np.ndarray

    @property
    def rms(self) -> float:
        """RMS distance over size (a share: 0.01 is 1 %)."""
        return float(np.sqrt(self.value))


def aligned_distance(points: np.ndarray, target: np.ndarray, size: float) -> Distance:
    """The squared RMS distance, as a share of ``size`` (design units), from ``points``
    (V, 3) to ``target`` (V, 3) after the best proper rigid motion, with its gradient."""
    rotation = proper_rotation(points, target)
    residual = (points - points.mean(0)) @ rotation + target.mean(0) - target
    scale = 1.0 / (len(points) * size**2)
    value = scale * float(np.sum(residual**2))
    return Distance(value, 2 * scale * residual @ rotation.T)


def metric_gradient(
    sheet: Sheet,
    metrics: np.ndarray,
    thickness: float,
    poisson: float,
    positions: np.ndarray,
    gradient: np.ndarray,
) -> np.ndarray:
    """dJ/dm (L, F, 3) for a quantity J of the equilibrium ``positions`` (V, 3) of ``sheet``
    under reference ``metrics`` (F, 2, 2) or (L, F, 2, 2), given dJ/dx ``gradient`` (V, 3)
    (module docstring). Component 1 of the last axis is the off-diagonal entry, both of its
    places changed together (a metric stays symmetric)."""
    metrics = np.asarray(metrics, dtype=float)
    metrics = metrics[None] if metrics.ndim == 3 else metrics
    shell = build_shell(sheet, metrics, thickness, poisson)
    adjoint = _adjoint(shell.hessian(positions, projected=False), positions, gradient)
    largest = float(np.max(np.linalg.norm(adjoint, axis=1)))
    if largest == 0.0:
        return np.zeros((*metrics.shape[:2], 3))
    step = POSITION_STEP * sheet.edge_length() / largest
    plus = shell.coordinates(positions + step * adjoint, 0)[0]
    minus = shell.coordinates(positions - step * adjoint, 0)[0]
    along = (plus - minus) / (2 * step)
    y = shell.coordinates(positions, 0)[0]

    def paired(trial: np.ndarray) -> np.ndarray:
        form = build_shell(sheet, trial, thickness, poisson)
        return np.einsum("fi,fij,fj->f", along, form.stiffness, y - form.rest)

    return -_by_component(metrics, paired)


def energy_difference(
    sheet: Sheet,
    metrics: np.ndarray,
    thickness: float,
    poisson: float,
    held: np.ndarray,
    other: np.ndarray,
    gradient: bool = False,
) -> tuple[float, np.ndarray | None]:
    """The energy of ``sheet`` held at positions ``held`` (V, 3) less that held at ``other``
    (V, 3), under ``metrics`` (F, 2, 2) or (L, F, 2, 2); with ``gradient``, also its
    derivative in the metrics (L, F, 3) (components as :func:`metric_gradient`'s), the
    positions fixed (else None: a twelfth of the shells built)."""
    metrics = np.asarray(metrics, dtype=float)
    metrics = metrics[None] if metrics.ndim == 3 else metrics

    def faces(trial: np.ndarray) -> np.ndarray:
        shell = build_shell(sheet, trial, thickness, poisson)
        return shell.face_energy(held) - shell.face_energy(other)

    value = float(faces(metrics).sum())
    return value, (_by_component(metrics, faces) if gradient else None)


def _by_component(metrics: np.ndarray, per_face) -> np.ndarray:
    """Central differences (L, F, 3) of a per-face function ``per_face(metrics)`` (F,) of
    each face's own metrics, in every layer's every component, all faces at once."""
    h = METRIC_STEP * float(np.max(np.abs(metrics)))
    result = np.zeros((*metrics.shape[:2], 3))
    for layer in range(len(metrics)):
        for component, (i, j) in enumerate(((0, 0), (0, 1), (1, 1))):
            change = np.zeros_like(metrics)
            change[layer, :, i, j] = change[layer, :, j, i] = h
            result[layer, :, component] = per_face(metrics + change) - per_face(metrics - change)
    return result / (2 * h)


def _adjoint(hessian: sparse.csr_matrix, positions: np.ndarray, gradient: np.ndarray) -> np.ndarray:
    """lambda (V, 3) with H lambda = ``gradient`` orthogonally to the rigid motions."""
    diagonal = float(np.mean(np.abs(hessian.diagonal()))) or np.finfo(float).tiny
    matrix = hessian + sparse.diags(np.full(hessian.shape[0], SHIFT * diagonal))
    modes = rigid_modes(positions)
    right = gradient.ravel() - modes @ (modes.T @ gradient.ravel())
    solution = factorise(matrix).solve(right)
    solution -= modes @ (modes.T @ solution)
    return solution.reshape(-1, 3)
