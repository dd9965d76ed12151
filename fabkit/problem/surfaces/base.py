"""The surface protocol: intrinsic geometry of a target in its chart, vectorised.

A surface is a 2D chart (coordinates ``r = (r1, r2)``) with a Riemannian metric.
Every method takes an array ``r`` of shape ``(..., 2)`` and returns arrays with
the same leading shape:

* :meth:`Surface.geometry` -> ``(g, gamma, K)``: metric ``(..., 2, 2)``,
  Christoffel symbols ``gamma[..., i, j, k] = Gamma^i_jk`` ``(..., 2, 2, 2)`` and
  Gaussian curvature ``(...)``, all in one call (the solver's hot path);
* :meth:`Surface.embed` -> 3D points ``(..., 3)`` where an embedding exists;
* :meth:`Surface.contains` -> ``(...)`` bool, True inside the chart's domain.

Lengths are in the chart's own units (design units; millimetres once scaled).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from fabkit.problem.expr import Expression

Bounds = tuple[tuple[float, float], tuple[float, float]]
"""Chart domain as ((r1_min, r1_max), (r2_min, r2_max)); infinite bounds allowed."""

UNBOUNDED: Bounds = ((-np.inf, np.inf), (-np.inf, np.inf))


class Surface(ABC):
    """A target surface: metric, Christoffel symbols and curvature in a chart."""

    name: str
    kind: str
    chart: tuple[str, str]
    bounds: Bounds

    @abstractmethod
    def geometry(self, r: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Metric (..., 2, 2), Christoffel symbols (..., 2, 2, 2), K (...) at r (..., 2)."""

    def metric(self, r: np.ndarray) -> np.ndarray:
        return self.geometry(r)[0]

    def christoffel(self, r: np.ndarray) -> np.ndarray:
        return self.geometry(r)[1]

    def curvature(self, r: np.ndarray) -> np.ndarray:
        return self.geometry(r)[2]

    def embed(self, r: np.ndarray) -> np.ndarray | None:
        """3D points (..., 3), or None for an intrinsic (metric-only) surface."""
        return None

    def contains(self, r: np.ndarray) -> np.ndarray:
        """True where r (..., 2) lies inside the chart domain and the metric is regular."""
        r = np.asarray(r, dtype=float)
        inside = np.all(np.isfinite(r), axis=-1)
        for axis, (low, high) in enumerate(self.bounds):
            with np.errstate(invalid="ignore"):
                inside &= (r[..., axis] > low) & (r[..., axis] < high)
        return inside

    def expressions(self) -> dict[str, Expression]:
        """The user expressions the surface is made of, by spec key (none for most kinds)."""
        return {}

    def describe(self) -> str:
        """One line for summaries."""
        return f"{self.kind} (chart {self.chart[0]}, {self.chart[1]})"


def metric_geometry(
    components: np.ndarray, first: np.ndarray, second: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Metric (..., 2, 2), Christoffel symbols (..., 2, 2, 2) and K (...) of a metric given
    by its components and their derivatives in the chart (a, b).

    ``components`` (3, ...) are (E, F, G) = (g11, g12, g22); ``first`` (3, 2, ...) their
    derivatives by (a, b); ``second`` (3, 3, ...) their second derivatives by (aa, ab, bb).
    Gamma^i_jk = 1/2 g^il (d_j g_lk + d_k g_lj - d_l g_jk); K by Brioschi's formula.
    Computed in floating point from the derivatives, so no symbolic product of user
    expressions is ever formed (see docs/spec.md#limits).
    """
    E, F, G = components
    g = np.stack([np.stack([E, F], -1), np.stack([F, G], -1)], -2)
    component = np.array([[0, 1], [1, 2]])  # component[l, k]: E, F or G of g_lk
    derivative = np.moveaxis(first[component], (0, 1, 2), (-3, -2, -1))  # [..., l, k, j]
    with np.errstate(all="ignore"):
        lowered = 0.5 * (
            derivative + np.swapaxes(derivative, -1, -2) - np.swapaxes(derivative, -3, -1)
        )  # lowered[..., l, k, j] = 1/2 (d_j g_lk + d_k g_lj - d_l g_kj)
        gamma = np.einsum("...il,...lkj->...ijk", _inverse(g), lowered)
        (Ea, Eb), (Fa, Fb), (Ga, Gb) = first
        E_bb, F_ab, G_aa = second[0, 2], second[1, 1], second[2, 0]
        brioschi = _det3(
            (
                (-E_bb / 2 + F_ab - G_aa / 2, Ea / 2, Fa - Eb / 2),
                (Fb - Ga / 2, E, F),
                (Gb / 2, F, G),
            )
        ) - _det3(((0 * E, Eb / 2, Ga / 2), (Eb / 2, E, F), (Ga / 2, F, G)))
        curvature = brioschi / (E * G - F**2) ** 2
    return g, gamma, curvature


def immersion_geometry(
    first: np.ndarray, second: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Metric, Christoffel symbols and K of an immersion X(a, b) into 3D.

    ``first`` (2, 3, ...) are X_a, X_b; ``second`` (3, 3, ...) X_aa, X_ab, X_bb.
    g = J^T J, Gamma^i_jk = g^il X_l . X_jk, and K = (L N - M^2) / det(g)^2 with L, M, N
    the second derivatives dotted with the unnormalised normal X_a x X_b.
    """
    tangent = np.moveaxis(first, (0, 1), (-2, -1))  # (..., 2, 3)
    xaa, xab, xbb = (np.moveaxis(s, 0, -1) for s in second)  # (..., 3)
    hessian = np.stack([np.stack([xaa, xab], -2), np.stack([xab, xbb], -2)], -3)
    g = np.einsum("...ic,...jc->...ij", tangent, tangent)
    with np.errstate(all="ignore"):
        lowered = np.einsum("...lc,...jkc->...ljk", tangent, hessian)
        gamma = np.einsum("...il,...ljk->...ijk", _inverse(g), lowered)
        normal = np.cross(tangent[..., 0, :], tangent[..., 1, :])
        L, M, N = (np.einsum("...c,...c->...", s, normal) for s in (xaa, xab, xbb))
        curvature = (L * N - M**2) / (g[..., 0, 0] * g[..., 1, 1] - g[..., 0, 1] ** 2) ** 2
    return g, gamma, curvature


def _inverse(g: np.ndarray) -> np.ndarray:
    """Inverse of 2 x 2 matrices (..., 2, 2); inf or NaN where singular (no exception)."""
    det = g[..., 0, 0] * g[..., 1, 1] - g[..., 0, 1] * g[..., 1, 0]
    adjugate = np.stack(
        [np.stack([g[..., 1, 1], -g[..., 0, 1]], -1), np.stack([-g[..., 1, 0], g[..., 0, 0]], -1)],
        -2,
    )
    return adjugate / det[..., None, None]


def _det3(rows) -> np.ndarray:
    """Determinant of a 3 x 3 matrix given as nested tuples of arrays (broadcast)."""
    (a, b, c), (d, e, f), (g, h, i) = rows
    return a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)


def graph_geometry(derivatives: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Metric (..., 2, 2), Christoffel symbols (..., 2, 2, 2) and K (...) of a graph z = f(x, y)
    from (f_x, f_y, f_xx, f_xy, f_yy) stacked as (5, ...)."""
    fx, fy, fxx, fxy, fyy = derivatives
    grad = np.stack([fx, fy], axis=-1)
    hessian = np.stack([np.stack([fxx, fxy], -1), np.stack([fxy, fyy], -1)], -2)
    w = 1.0 + fx**2 + fy**2
    g = np.eye(2) + grad[..., :, None] * grad[..., None, :]
    gamma = grad[..., :, None, None] * hessian[..., None, :, :] / w[..., None, None, None]
    return g, gamma, (fxx * fyy - fxy**2) / w**2
