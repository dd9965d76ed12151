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
from dataclasses import dataclass

import numpy as np
import sympy as sp

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

    def describe(self) -> str:
        """One line for summaries."""
        return f"{self.kind} (chart {self.chart[0]}, {self.chart[1]})"


@dataclass(frozen=True)
class SymbolicGeometry:
    """Metric, Christoffel symbols and K derived symbolically from a metric in (a, b)."""

    variables: tuple[sp.Symbol, sp.Symbol]
    metric: sp.Matrix

    def christoffel(self) -> list[list[list[sp.Expr]]]:
        """Gamma^i_jk = 1/2 g^il (d_j g_lk + d_k g_lj - d_l g_jk), as nested lists [i][j][k]."""
        g, x = self.metric, self.variables
        inverse = _inverse_2x2(g)
        gamma = [[[sp.Integer(0)] * 2 for _ in range(2)] for _ in range(2)]
        for i in range(2):
            for j in range(2):
                for k in range(j, 2):
                    term = sum(
                        inverse[i, m]
                        * (sp.diff(g[m, k], x[j]) + sp.diff(g[m, j], x[k]) - sp.diff(g[j, k], x[m]))
                        for m in range(2)
                    )
                    gamma[i][j][k] = gamma[i][k][j] = term / 2
        return gamma

    def gaussian_curvature(self) -> sp.Expr:
        """K by Brioschi's formula, from the metric and its first and second derivatives."""
        (a, b), g = self.variables, self.metric
        E, F, G = g[0, 0], g[0, 1], g[1, 1]
        Ea, Eb, Fa, Fb, Ga, Gb = (sp.diff(f, v) for f in (E, F, G) for v in (a, b))
        first = sp.Matrix(
            [
                [
                    -sp.diff(E, b, 2) / 2 + sp.diff(F, a, b) - sp.diff(G, a, 2) / 2,
                    Ea / 2,
                    Fa - Eb / 2,
                ],
                [Fb - Ga / 2, E, F],
                [Gb / 2, F, G],
            ]
        )
        second = sp.Matrix([[0, Eb / 2, Ga / 2], [Eb / 2, E, F], [Ga / 2, F, G]])
        return (first.det(method="berkowitz") - second.det(method="berkowitz")) / (
            E * G - F**2
        ) ** 2

    def compile(self):
        """numpy function (a, b) -> (g, gamma, K), compiled once with common subexpressions."""
        gamma = self.christoffel()
        outputs = [
            self.metric[0, 0],
            self.metric[0, 1],
            self.metric[1, 1],
            *(gamma[i][j][k] for i in range(2) for j, k in ((0, 0), (0, 1), (1, 1))),
            self.gaussian_curvature(),
        ]
        function = sp.lambdify(self.variables, outputs, modules="numpy", cse=True)
        return _packer(function)


def _inverse_2x2(g: sp.Matrix) -> sp.Matrix:
    det = g[0, 0] * g[1, 1] - g[0, 1] ** 2
    return sp.Matrix([[g[1, 1], -g[0, 1]], [-g[0, 1], g[0, 0]]]) / det


def _packer(function):
    """Wrap a lambdified list of 10 scalars into (g, gamma, K) arrays broadcast to r's shape."""

    def geometry(r: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        r = np.asarray(r, dtype=float)
        shape = r.shape[:-1]
        with np.errstate(all="ignore"):
            values = [np.broadcast_to(v, shape) for v in function(r[..., 0], r[..., 1])]
        g11, g12, g22, c100, c101, c111, c200, c201, c211, k = values
        g = np.stack([np.stack([g11, g12], -1), np.stack([g12, g22], -1)], -2)
        first = np.stack([np.stack([c100, c101], -1), np.stack([c101, c111], -1)], -2)
        second = np.stack([np.stack([c200, c201], -1), np.stack([c201, c211], -1)], -2)
        return g, np.stack([first, second], -3), np.array(k, dtype=float)

    return geometry


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
