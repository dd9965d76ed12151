"""Surfaces given by formulas: plane, sphere, graph, parametric, metric."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import sympy as sp

from fabkit.errors import FabkitError
from fabkit.expr import Expression, parse
from fabkit.surfaces.base import UNBOUNDED, Bounds, Surface, SymbolicGeometry, graph_geometry


def check_keys(table: Mapping[str, Any], allowed: set[str], where: str) -> None:
    """Refuse unknown keys with a message naming them and the allowed ones."""
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise FabkitError(
            f"{where}: unknown key '{unknown[0]}' (allowed: {', '.join(sorted(allowed))})"
        )


def number(value: Any, where: str, positive: bool = False) -> float:
    """A finite float from a spec value, with a one-line error otherwise."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise FabkitError(f"{where}: expected a number, got {value!r}")
    value = float(value)
    if not np.isfinite(value) or (positive and value <= 0):
        raise FabkitError(f"{where}: expected a {'positive ' if positive else ''}finite number")
    return value


def domain_bounds(table: Mapping[str, Any], where: str) -> Bounds:
    """Optional ``domain = [r1_min, r1_max, r2_min, r2_max]``; unbounded if absent."""
    if "domain" not in table:
        return UNBOUNDED
    values = table["domain"]
    if not isinstance(values, list) or len(values) != 4:
        raise FabkitError(f"{where}.domain: expected [r1_min, r1_max, r2_min, r2_max]")
    low1, high1, low2, high2 = (number(v, f"{where}.domain") for v in values)
    if not (low1 < high1 and low2 < high2):
        raise FabkitError(f"{where}.domain: each minimum must be below its maximum")
    return ((low1, high1), (low2, high2))


class Plane(Surface):
    """The Euclidean plane, chart (x, y): g = identity, Gamma = 0, K = 0."""

    kind = "plane"
    chart = ("x", "y")

    def __init__(self, name: str, bounds: Bounds = UNBOUNDED):
        self.name, self.bounds = name, bounds

    @classmethod
    def from_table(cls, name: str, table: Mapping[str, Any], where: str, base_dir) -> Plane:
        check_keys(table, {"kind", "domain"}, where)
        return cls(name, domain_bounds(table, where))

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
    def from_table(cls, name: str, table: Mapping[str, Any], where: str, base_dir) -> Sphere:
        check_keys(table, {"kind", "radius"}, where)
        return cls(name, number(table.get("radius", 1.0), f"{where}.radius", positive=True))

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
        x, y = height.symbols
        f = height.sympy
        derivatives = [
            sp.diff(f, x),
            sp.diff(f, y),
            sp.diff(f, x, 2),
            sp.diff(f, x, y),
            sp.diff(f, y, 2),
        ]
        self._derivatives = sp.lambdify((x, y), derivatives, modules="numpy", cse=True)

    @classmethod
    def from_table(cls, name: str, table: Mapping[str, Any], where: str, base_dir) -> Graph:
        check_keys(table, {"kind", "z", "domain"}, where)
        if "z" not in table:
            raise FabkitError(f'{where}: a graph needs z = "f(x, y)"')
        return cls(name, parse(table["z"], ("x", "y"), f"{where}.z"), domain_bounds(table, where))

    def geometry(self, r):
        r = np.asarray(r, dtype=float)
        shape = r.shape[:-1]
        with np.errstate(all="ignore"):
            derivatives = np.stack(
                [
                    np.broadcast_to(np.asarray(d, dtype=float), shape)
                    for d in self._derivatives(r[..., 0], r[..., 1])
                ]
            )
            return graph_geometry(derivatives)

    def embed(self, r):
        r = np.asarray(r, dtype=float)
        z = self.height(r[..., 0], r[..., 1])
        return np.concatenate([r, z[..., None]], axis=-1)

    def describe(self) -> str:
        return f"graph z = {self.height.text} (chart x, y)"


class Parametric(Surface):
    """Surface X(a, b) = (x, y, z) in 3D, chart (a, b); g = J^T J, K by Brioschi's formula."""

    kind = "parametric"
    chart = ("a", "b")

    def __init__(
        self,
        name: str,
        coordinates: tuple[Expression, Expression, Expression],
        bounds: Bounds = UNBOUNDED,
    ):
        self.name, self.coordinates, self.bounds = name, coordinates, bounds
        a, b = coordinates[0].symbols
        position = sp.Matrix([c.sympy for c in coordinates])
        jacobian = position.jacobian([a, b])
        self._geometry = SymbolicGeometry((a, b), jacobian.T * jacobian).compile()

    @classmethod
    def from_table(cls, name: str, table: Mapping[str, Any], where: str, base_dir) -> Parametric:
        check_keys(table, {"kind", "x", "y", "z", "domain"}, where)
        missing = [k for k in ("x", "y", "z") if k not in table]
        if missing:
            raise FabkitError(f'{where}: a parametric surface needs {missing[0]} = "...(a, b)"')
        coordinates = tuple(parse(table[k], ("a", "b"), f"{where}.{k}") for k in ("x", "y", "z"))
        return cls(name, coordinates, domain_bounds(table, where))

    def geometry(self, r):
        return self._geometry(r)

    def embed(self, r):
        r = np.asarray(r, dtype=float)
        return np.stack([c(r[..., 0], r[..., 1]) for c in self.coordinates], axis=-1)


class Metric(Surface):
    """An intrinsic surface given only by its metric g11, g12, g22 in (a, b); no embedding."""

    kind = "metric"
    chart = ("a", "b")

    def __init__(
        self,
        name: str,
        components: tuple[Expression, Expression, Expression],
        bounds: Bounds = UNBOUNDED,
    ):
        self.name, self.components, self.bounds = name, components, bounds
        a, b = components[0].symbols
        g11, g12, g22 = (c.sympy for c in components)
        self._geometry = SymbolicGeometry((a, b), sp.Matrix([[g11, g12], [g12, g22]])).compile()

    @classmethod
    def from_table(cls, name: str, table: Mapping[str, Any], where: str, base_dir) -> Metric:
        check_keys(table, {"kind", "g11", "g12", "g22", "domain"}, where)
        missing = [k for k in ("g11", "g22") if k not in table]
        if missing:
            raise FabkitError(f'{where}: a metric surface needs {missing[0]} = "...(a, b)"')
        components = tuple(
            parse(table.get(k, "0"), ("a", "b"), f"{where}.{k}") for k in ("g11", "g12", "g22")
        )
        return cls(name, components, domain_bounds(table, where))

    def geometry(self, r):
        return self._geometry(r)

    def contains(self, r):
        inside = super().contains(r)
        g = self.metric(np.where(inside[..., None], r, 0.0))
        with np.errstate(invalid="ignore"):
            regular = (g[..., 0, 0] > 0) & (np.linalg.det(g) > 0)
        return inside & regular
