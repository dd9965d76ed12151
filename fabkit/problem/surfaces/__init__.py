"""Target surfaces that know their geometry: metric, Christoffel symbols, K, embedding.

``build_surface(name, geometry_table, base_dir)`` turns a spec's
``geometry = { kind = ..., ... }`` table into a :class:`Surface`.
"""

from __future__ import annotations

from pathlib import Path

from fabkit.files.tomlfile import Table
from fabkit.problem.surfaces.analytic import Graph, Metric, Parametric, Plane, Sphere
from fabkit.problem.surfaces.base import Surface

ANALYTIC = {
    "plane": Plane,
    "sphere": Sphere,
    "graph": Graph,
    "parametric": Parametric,
    "metric": Metric,
}
"""Analytic geometry kinds by name; each class has ``from_table(name, table, base_dir)``."""

KINDS = (*ANALYTIC, "heightmap", "mesh")
"""Every geometry kind; the data kinds' module (scipy) is imported only when a spec names one,
so that reading an analytic spec starts fast."""


def build_surface(name: str, geometry: Table, base_dir: Path = Path(".")) -> Surface:
    """The surface described by a spec's geometry table (which names the file and the
    key path in error messages); ``base_dir`` resolves data files."""
    kind = geometry.text("kind", KINDS)
    if kind in ANALYTIC:
        return ANALYTIC[kind].from_table(name, geometry, base_dir)
    from fabkit.problem.surfaces.data import HeightMap, MeshSurface

    data = {"heightmap": HeightMap, "mesh": MeshSurface}
    return data[kind].from_table(name, geometry, base_dir)


__all__ = ["KINDS", "Surface", "build_surface"]
