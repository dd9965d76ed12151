"""The swimmer spec: a bilayer disc, its layers' directors and material laws, the stimulus path.

A TOML file (see ``docs/swimmer.md`` and ``examples/swimmer.toml``) with sections
``[sheet]``, ``[stimuli]``, ``[[layers]]`` (bottom layer first), and optionally
``[mechanics]``, ``[hydrodynamics]`` and ``[fabrication]``. Lengths are in mm. Every
problem is a one-line :class:`FabkitError` naming the key.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fabkit.errors import FabkitError
from fabkit.field.flat import PlaneFunction, check_finite_on_sheet, parse_shape, planar_expression
from fabkit.limits import MAGNITUDE, SWIMMER_MESH_RINGS, SWIMMER_SHAPES, WORK_BYTES
from fabkit.problem.expr import Expression, parse, shorten
from fabkit.readfile import size_text
from fabkit.shipped import user_or_example
from fabkit.tomlfile import check_keys, number, read_toml


@dataclass(frozen=True)
class Layer:
    """One layer of the sheet: a director pattern and its material law.

    ``director`` is the expression text of the director angle theta(x, y, r, phi) (rad,
    x, y, r in mm), ``theta`` its function; ``lambda1``, ``lambda2`` the stretches along
    and across the director, expressions in the stimuli.
    """

    name: str
    director: str
    theta: PlaneFunction
    lambda1: Expression
    lambda2: Expression

    def stretches(self, stimulus: np.ndarray) -> tuple[float, float]:
        """(lambda1, lambda2) at one stimulus (k,)."""
        return float(self.lambda1(*stimulus)), float(self.lambda2(*stimulus))


@dataclass(frozen=True)
class Mechanics:
    """Elastic model: ``rings`` of the disc mesh (about 6 rings^2 triangles), Young's
    modulus ``young`` (Pa, scales the energy bound only) and ``poisson`` ratio."""

    rings: int = 12
    young: float = 1.0e6
    poisson: float = 0.5


@dataclass(frozen=True)
class Hydrodynamics:
    """Stokes model: ``rings`` of the Stokeslet point disc (about pi rings^2 points),
    ``epsilon_ratio`` regularisation / point spacing, ``viscosity`` (Pa s; the
    displacement does not depend on it)."""

    rings: int = 20
    epsilon_ratio: float = 0.35
    viscosity: float = 1.0


@dataclass(frozen=True)
class SwimmerSpec:
    """A validated swimmer.

    ``radius`` and ``thickness`` (mm, the whole sheet; layers are equal); ``stimuli``
    names (k); ``path`` (P, k) the polygon walked in stimulus space, ``stations`` shapes
    per leg; ``layers`` bottom first; ``fabrication`` the raw ``[fabrication]`` table.
    """

    radius: float
    thickness: float
    stimuli: tuple[str, ...]
    path: np.ndarray
    stations: int
    layers: tuple[Layer, ...]
    mechanics: Mechanics
    hydrodynamics: Hydrodynamics
    fabrication: Mapping[str, Any]

    def with_path(self, path: np.ndarray, stations: int | None = None) -> SwimmerSpec:
        """The same swimmer walking another polygon (P, k), optionally with other stations."""
        path = _path(np.asarray(path, dtype=float).tolist(), len(self.stimuli))
        stations = self.stations if stations is None else _count(stations, "stations")
        _check_shapes(stations, path)
        return SwimmerSpec(
            self.radius,
            self.thickness,
            self.stimuli,
            path,
            stations,
            self.layers,
            self.mechanics,
            self.hydrodynamics,
            self.fabrication,
        )


def load_swimmer(path: str | Path) -> SwimmerSpec:
    """Read and validate a swimmer TOML file."""
    return build_swimmer(read_toml(user_or_example(path), "swimmer"))


def build_swimmer(table: Mapping[str, Any]) -> SwimmerSpec:
    """Validate a swimmer given as nested tables (a parsed TOML file)."""
    allowed = {"sheet", "stimuli", "layers", "mechanics", "hydrodynamics", "fabrication"}
    check_keys(table, allowed, "swimmer")
    for key in ("sheet", "stimuli", "layers"):
        if key not in table:
            raise FabkitError(f"swimmer: missing section [{key}]")
    sheet = _table(table["sheet"], "sheet")
    check_keys(sheet, {"radius", "thickness"}, "sheet")
    radius = _length(sheet.get("radius"), "sheet.radius")
    thickness = _length(sheet.get("thickness"), "sheet.thickness")
    if thickness >= radius:
        raise FabkitError("sheet.thickness: a sheet must be much thinner than its radius")
    stimuli_table = _table(table["stimuli"], "stimuli")
    check_keys(stimuli_table, {"names", "path", "stations"}, "stimuli")
    names = _names(stimuli_table.get("names"))
    path = _path(stimuli_table.get("path"), len(names))
    stations = _count(stimuli_table.get("stations", 6), "stimuli.stations")
    _check_shapes(stations, path)
    layers = table["layers"]
    if not isinstance(layers, list) or not layers:
        raise FabkitError("layers: expected one or more [[layers]] tables, bottom first")
    built = tuple(
        _layer(_table(layer, f"layers[{i}]"), names, i, radius, path)
        for i, layer in enumerate(layers)
    )
    mechanics = _settings(table.get("mechanics", {}), Mechanics, "mechanics")
    hydrodynamics = _settings(table.get("hydrodynamics", {}), Hydrodynamics, "hydrodynamics")
    _check_rings(mechanics.rings, hydrodynamics.rings)
    fabrication = _table(table.get("fabrication", {}), "fabrication")
    return SwimmerSpec(
        radius, thickness, names, path, stations, built, mechanics, hydrodynamics, fabrication
    )


def _table(value: Any, where: str) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise FabkitError(f"{where}: expected a table")
    return value


def _names(value: Any) -> tuple[str, ...]:
    if not isinstance(value, list) or not value or not all(isinstance(v, str) for v in value):
        raise FabkitError('stimuli.names: expected a list of names, e.g. ["L1", "L2"]')
    if len(set(value)) != len(value):
        raise FabkitError("stimuli.names: names must differ")
    return tuple(value)


def _path(value: Any, count: int) -> np.ndarray:
    where = "stimuli.path"
    if not isinstance(value, list) or len(value) < 2:
        raise FabkitError(f"{where}: expected a list of at least two stimulus vectors")
    rows = []
    for row in value:
        if not isinstance(row, list) or len(row) != count:
            raise FabkitError(f"{where}: every vertex needs {count} stimulus values")
        rows.append([number(v, where) for v in row])
    path = np.array(rows)
    if np.any(np.all(np.diff(path, axis=0) == 0, axis=1)):
        raise FabkitError(f"{where}: two consecutive vertices are equal")
    return path


def _length(value: Any, where: str) -> float:
    """A positive length (mm) within +-MAGNITUDE."""
    length = number(value, where, positive=True)
    if length > MAGNITUDE:
        raise FabkitError(f"{where}: {length:g} is beyond the plausible {MAGNITUDE:g} mm")
    return length


def _check_shapes(stations: int, path: np.ndarray) -> None:
    """At most SWIMMER_SHAPES equilibrium shapes along the cycle (stations per leg)."""
    shapes = stations * (len(path) - 1)
    if shapes > SWIMMER_SHAPES:
        raise FabkitError(
            f"stimuli.stations: {stations} stations on {len(path) - 1} legs make {shapes} "
            f"shapes, more than the limit of {SWIMMER_SHAPES}"
        )


def _check_rings(mesh_rings: int, stokes_rings: int) -> None:
    """The elastic mesh at most SWIMMER_MESH_RINGS rings; the dense Stokeslet matrix of
    about 1 + pi R (R + 1) points (112 N^2 bytes with its work arrays) within WORK_BYTES."""
    if mesh_rings > SWIMMER_MESH_RINGS:
        raise FabkitError(
            f"mechanics.rings: {mesh_rings} is more than the limit of {SWIMMER_MESH_RINGS}"
        )
    points = 1 + math.pi * stokes_rings * (stokes_rings + 1)
    need = 112 * points**2
    if need > WORK_BYTES:
        raise FabkitError(
            f"hydrodynamics.rings: {stokes_rings} rings make about {points:.3g} Stokeslet points "
            f"whose matrix needs {size_text(need)}, more than the limit of {size_text(WORK_BYTES)}"
        )


def _count(value: Any, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise FabkitError(f"{where}: expected a positive integer, got {value!r}")
    return value


PATH_SAMPLES = 64
"""Points per leg of the stimulus path at which the layers' stretches must be finite."""


def _layer(
    table: Mapping[str, Any], stimuli: tuple[str, ...], index: int, radius: float, path: np.ndarray
) -> Layer:
    """One layer; its director must be finite on the disc of ``radius`` (mm) and its
    stretches finite along the stimulus ``path`` (P, k), vertices and legs."""
    where = f"layers[{index}]"
    check_keys(table, {"name", "director", "lambda1", "lambda2"}, where)
    for key in ("director", "lambda1", "lambda2"):
        if key not in table:
            raise FabkitError(f"{where}: missing key '{key}'")
    name = table.get("name", f"layer {index}")
    if not isinstance(name, str):
        raise FabkitError(f"{where}.name: expected a string")
    theta = planar_expression(table["director"], f"{where}.director")
    disc = parse_shape(f"disc:{radius:.12g}", "sheet.radius")
    check_finite_on_sheet(theta, disc, f"{where}.director", str(table["director"]))
    fractions = np.linspace(0.0, 1.0, PATH_SAMPLES + 1)[:, None, None]
    samples = (path[:-1] + fractions * np.diff(path, axis=0)).reshape(-1, len(stimuli))
    stretches = []
    for key in ("lambda1", "lambda2"):
        stretch = parse(table[key], stimuli, f"{where}.{key}")
        values = stretch(*samples.T)
        if not np.all(np.isfinite(values)):
            at = samples[np.argmin(np.isfinite(values))]
            shown = ", ".join(f"{n} = {v:.6g}" for n, v in zip(stimuli, at, strict=True))
            raise FabkitError(
                f"{where}.{key}: not finite at the stimulus ({shown}) on stimuli.path: "
                f"'{shorten(stretch.text)}'"
            )
        stretches.append(stretch)
    return Layer(name, str(table["director"]), theta, *stretches)


def _settings(value: Any, kind: type, where: str) -> Any:
    table = _table(value, where)
    defaults = kind()
    check_keys(table, set(defaults.__dataclass_fields__), where)
    values = {}
    for key, default in vars(defaults).items():
        raw = table.get(key, default)
        if isinstance(default, int):
            values[key] = _count(raw, f"{where}.{key}")
        else:
            values[key] = number(raw, f"{where}.{key}", positive=key != "poisson")
    if "poisson" in values and not -1.0 < values["poisson"] <= 0.5:
        raise FabkitError(f"{where}.poisson: expected -1 < nu <= 0.5")
    return kind(**values)
