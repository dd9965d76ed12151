"""Surfaces given by formulas: plane, sphere, graph, parametric, metric."""

from __future__ import annotations

from typing import Self

import numpy as np

from fabkit.files.tomlfile import Table, real
from fabkit.problem.expr import Expression, parse
from fabkit.problem.surfaces.base import (
    UNBOUNDED,
    Bounds,
    Surface,
    graph_geometry,
    immersion_geometry,
    metric_geometry,
)


def domain_bounds(t: Table) -> Bounds:
    """Optional ``domain = [r1_min, r1_max, r2_min, r2_max]``; unbounded if absent."""
    if "domain" not in t:
        return UNBOUNDED
    what = "[r1_min, r1_max, r2_min, r2_max] with each minimum below its maximum"
    values = t.array("domain", what)
    if len(values) != 4:
        t.expected("domain", what, values)
    low1, high1, low2, high2 = (real(v, t.at(f"domain[{i}]")) for i, v in enumerate(values))
    if not (low1 < high1 and low2 < high2):
        t.expected("domain", what, values)
    return ((low1, high1), (low2, high2))


class Plane(Surface):
    """The Euclidean plane, chart (x, y): g = identity, Gamma = 0, K = 0."""

    kind = "plane"
    chart = ("x", "y")

    def __init__(self, name: str, bounds: Bounds = UNBOUNDED):
        self.name, self.bounds = name, bounds

    @classmethod
    def from_table(cls, name: str, t: Table, base_dir) -> Plane:
        t.check_keys({"kind", "domain"})
        return cls(name, domain_bounds(t))

    def geometry(self, r):
        r = np.asarray(r, dtype=float)
        shape = r.shape[:-1]
        g = np.broadcast_to(np.eye(2), (*shape, 2, 2)).copy()
        return g, np.zeros((*shape, 2, 2, 2)), np.zeros(shape)

    def embed(self, r):
        r = np.asarray(r, dtype=float)
        return np.concatenate([r, np.zeros((*r.shape[:-1], 1))], axis=-1)


class Sphere(Surface):
    """Sphere of radius R, chart (theta, phi): g = R^2 diag(1, sin^2 theta), K = 1/R^2."""

    kind = "sphere"
    chart = ("theta", "phi")

    def __init__(self, name: str, radius: float):
        self.name, self.radius = name, radius
        self.bounds = ((0.0, np.pi), (-np.inf, np.inf))

    @classmethod
    def from_table(cls, name: str, t: Table, base_dir) -> Sphere:
        t.check_keys({"kind", "radius"})
        return cls(name, t.number("radius", positive=True, default=1.0))

    def geometry(self, r):
        r = np.asarray(r, dtype=float)
        theta = r[..., 0]
        sin, cos = np.sin(theta), np.cos(theta)
        shape = theta.shape
        g = np.zeros((*shape, 2, 2))
        g[..., 0, 0] = self.radius**2
        g[..., 1, 1] = self.radius**2 * sin**2
        gamma = np.zeros((*shape, 2, 2, 2))
        gamma[..., 0, 1, 1] = -sin * cos
        with np.errstate(divide="ignore", invalid="ignore"):
            cot = cos / sin
        gamma[..., 1, 0, 1] = gamma[..., 1, 1, 0] = cot
        return g, gamma, np.full(shape, 1.0 / self.radius**2)

    def embed(self, r):
        r = np.asarray(r, dtype=float)
        theta, phi = r[..., 0], r[..., 1]
        return self.radius * np.stack(
            [np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=-1
        )

    def describe(self) -> str:
        return f"sphere of radius {self.radius:g} (chart theta, phi)"


class Graph(Surface):
    """Graph z = f(x, y), chart (x, y); closed forms for g, Gamma and K from f's derivatives."""

    kind = "graph"
    chart = ("x", "y")

    def __init__(self, name: str, height: Expression, bounds: Bounds = UNBOUNDED):
        self.name, self.height, self.bounds = name, height, bounds
        self._derivatives = _jets((height,))

    @classmethod
    def from_table(cls, name: str, t: Table, base_dir) -> Graph:
        t.check_keys({"kind", "z", "domain"})
        z = t.raw("z", 'an expression in x and y, like z = "f(x, y)"')
        return cls(name, parse(z, ("x", "y"), t.at("z")), domain_bounds(t))

    def geometry(self, r):
        """Closed forms from f's derivatives; NaN wherever f itself is not finite."""
        (f,), first, second = self._derivatives(r)
        derivatives = np.stack([first[0, 0], first[0, 1], *second[0]])
        with np.errstate(all="ignore"):
            g, gamma, curvature = graph_geometry(derivatives)
        return _where_finite(f, g, gamma, curvature)

    def expressions(self) -> dict[str, Expression]:
        return {"z": self.height}

    def embed(self, r):
        r = np.asarray(r, dtype=float)
        z = self.height(r[..., 0], r[..., 1])
        return np.concatenate([r, z[..., None]], axis=-1)

    def describe(self) -> str:
        return f"graph z = {self.height.text} (chart x, y)"


class _Formulas(Surface):
    """A surface given by three expressions in the chart (a, b), under the spec keys
    ``keys`` (in that order): those in ``required`` must be given, an absent other is 0."""

    chart = ("a", "b")
    keys: tuple[str, str, str]
    required: tuple[str, ...]

    def __init__(
        self,
        name: str,
        formulas: tuple[Expression, Expression, Expression],
        bounds: Bounds = UNBOUNDED,
    ):
        self.name, self.formulas, self.bounds = name, formulas, bounds
        self._derivatives = _jets(formulas)

    @classmethod
    def from_table(cls, name: str, t: Table, base_dir) -> Self:
        t.check_keys({"kind", *cls.keys, "domain"})
        t.require(cls.required, "an expression in a and b")
        formulas = tuple(parse(t.get(k, "0"), cls.chart, t.at(k)) for k in cls.keys)
        return cls(name, formulas, domain_bounds(t))

    def expressions(self) -> dict[str, Expression]:
        return dict(zip(self.keys, self.formulas, strict=True))


class Parametric(_Formulas):
    """Surface X(a, b) = (x, y, z) in 3D, chart (a, b); g = J^T J, K by Brioschi's formula."""

    kind = "parametric"
    keys = required = ("x", "y", "z")

    def geometry(self, r):
        """g = J^T J and K from X's first and second derivatives; NaN where X is not finite."""
        position, first, second = self._derivatives(r)
        g, gamma, curvature = immersion_geometry(np.swapaxes(first, 0, 1), second.swapaxes(0, 1))
        return _where_finite(np.sum(position, axis=0), g, gamma, curvature)

    def embed(self, r):
        r = np.asarray(r, dtype=float)
        return np.stack([c(r[..., 0], r[..., 1]) for c in self.formulas], axis=-1)


class Metric(_Formulas):
    """An intrinsic surface given only by its metric g11, g12, g22 in (a, b); no embedding."""

    kind = "metric"
    keys = ("g11", "g12", "g22")
    required = ("g11", "g22")

    def geometry(self, r):
        """Christoffel symbols and K (Brioschi) from the components' derivatives."""
        return metric_geometry(*self._derivatives(r))

    def contains(self, r):
        inside = super().contains(r)
        g = self.metric(np.where(inside[..., None], r, 0.0))
        with np.errstate(invalid="ignore"):
            regular = (g[..., 0, 0] > 0) & (np.linalg.det(g) > 0)
        return inside & regular


def _jets(expressions: tuple[Expression, ...]):
    """numpy function r (..., 2) -> values (C, ...), first (C, 2, ...) and second (C, 3, ...)
    derivatives (by aa, ab, bb) of C expressions in the two chart coordinates, by
    automatic differentiation (fabkit.problem.expr): no symbolic work, cost linear in their size."""

    def evaluate(r: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        r = np.asarray(r, dtype=float)
        parts = [e.jets(r[..., 0], r[..., 1], wrt=e.names) for e in expressions]
        values = np.stack([value for value, _, _ in parts])
        first = np.stack([grad for _, grad, _ in parts])
        second = np.stack([np.stack([h[0, 0], h[0, 1], h[1, 1]]) for _, _, h in parts])
        return values, first, second

    return evaluate


def _where_finite(values: np.ndarray, g: np.ndarray, gamma: np.ndarray, curvature: np.ndarray):
    """(g, gamma, K) set to NaN wherever ``values`` (...) is not finite: the surface is not
    defined there (the solver stops at such a point, see docs/solver.md#stops)."""
    bad = ~np.isfinite(values)
    if not bad.any():
        return g, gamma, curvature
    return (
        np.where(bad[..., None, None], np.nan, g),
        np.where(bad[..., None, None, None], np.nan, gamma),
        np.where(bad, np.nan, curvature),
    )
