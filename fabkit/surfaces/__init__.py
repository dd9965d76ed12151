"""Target surfaces that know their geometry: metric, Christoffel symbols, K, embedding.

``build_surface(name, geometry_table, where, base_dir)`` turns a spec's
``geometry = { kind = ..., ... }`` table into a :class:`Surface`.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from fabkit.errors import FabkitError
from fabkit.surfaces.analytic import Graph, Metric, Parametric, Plane, Sphere
from fabkit.surfaces.base import Surface
from fabkit.surfaces.data import HeightMap, MeshSurface

KINDS = {
    "plane": Plane,
    "sphere": Sphere,
    "graph": Graph,
    "parametric": Parametric,
    "metric": Metric,
    "heightmap": HeightMap,
    "mesh": MeshSurface,
}
"""Geometry kinds by name; each class has ``from_table(name, table, where, base_dir)``."""


def build_surface(
    name: str, geometry: Mapping[str, Any], where: str, base_dir: Path = Path(".")
) -> Surface:
    """The surface described by a spec's geometry table.

    ``where`` names the table in error messages; ``base_dir`` resolves data files.
    """
    if not isinstance(geometry, Mapping):
        raise FabkitError(f'{where}: expected a table like {{ kind = "plane" }}')
    kind = geometry.get("kind")
    if kind not in KINDS:
        raise FabkitError(
            f"{where}.kind: unknown surface kind {kind!r} (known: {', '.join(KINDS)})"
        )
    return KINDS[kind].from_table(name, geometry, where, base_dir)


__all__ = ["KINDS", "Surface", "build_surface"]
