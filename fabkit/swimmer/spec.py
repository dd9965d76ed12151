"""The swimmer spec: a bilayer disc, its layers' directors and material laws, the stimulus path.

A TOML file (see ``docs/swimmer.md`` and ``examples/swimmer.toml``) with sections
``[sheet]``, ``[stimuli]``, ``[[layers]]`` (bottom layer first), and optionally
``[mechanics]``, ``[hydrodynamics]`` and ``[fabrication]``. Lengths are in mm. Every
problem is a one-line :class:`FabkitError` naming the file and the key path
(:mod:`fabkit.files.tomlfile`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fabkit.errors import FabkitError
from fabkit.field.flat import PlaneFunction, check_finite_on_sheet, planar_expression
from fabkit.field.outlines import parse_shape
from fabkit.files.readfile import size_text
from fabkit.files.shipped import user_or_example
from fabkit.files.tomlfile import Table, expected, read_toml, real, whole
from fabkit.limits import MAGNITUDE, SWIMMER_MESH_RINGS, SWIMMER_SHAPES, WORK_BYTES
from fabkit.problem.expr import Expression, parse, shorten


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
    per leg; ``layers`` bottom first; ``fabrication`` the ``[fabrication]`` table, read
    when the swimmer is made (:func:`fabkit.swimmer.fabricate.fabrication_settings`).
    """

    radius: float
    thickness: float
    stimuli: tuple[str, ...]
    path: np.ndarray
    stations: int
    layers: tuple[Layer, ...]
    mechanics: Mechanics
    hydrodynamics: Hydrodynamics
    fabrication: Table

    def with_path(self, path: np.ndarray, stations: int | None = None) -> SwimmerSpec:
        """The same swimmer walking another polygon (P, k), optionally with other stations."""
        path = _path(np.asarray(path, dtype=float).tolist(), len(self.stimuli), "stimuli.path")
        stations = self.stations if stations is None else whole(stations, "--stations")
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
    path = user_or_example(path)
    return build_swimmer(read_toml(path, "swimmer"), str(path))


def build_swimmer(table: Mapping[str, Any], shown: str = "swimmer") -> SwimmerSpec:
    """Validate a swimmer given as nested tables (a parsed TOML file); ``shown`` names the
    file in errors."""
    top = Table(table, shown)
    top.check_keys({"sheet", "stimuli", "layers", "mechanics", "hydrodynamics", "fabrication"})
    top.require(("sheet", "stimuli"), lambda key: f"a table [{key}]")
    top.require(("layers",), "one or more [[layers]] tables, bottom first")
    sheet = top.table("sheet")
    sheet.check_keys({"radius", "thickness"})
    radius = sheet.number("radius", positive=True, bound=MAGNITUDE)
    thickness = sheet.number("thickness", positive=True, bound=MAGNITUDE)
    if thickness >= radius:
        sheet.expected("thickness", f"much less than radius = {radius:g}", sheet["thickness"])
    stimuli = top.table("stimuli")
    stimuli.check_keys({"names", "path", "stations"})
    names = _names(stimuli)
    path = _path(stimuli.get("path"), len(names), stimuli.at("path"))
    stations = stimuli.integer("stations", default=6)
    _check_shapes(stations, path, stimuli.at("stations"))
    layers = top.array("layers", "one or more [[layers]] tables, bottom first")
    if not layers:
        top.expected("layers", "one or more [[layers]] tables, bottom first", layers)
    built = tuple(_layer(top.item("layers", i), names, i, radius, path) for i in range(len(layers)))
    mechanics = _settings(top.table("mechanics", default={}), Mechanics)
    hydrodynamics = _settings(top.table("hydrodynamics", default={}), Hydrodynamics)
    _check_rings(mechanics.rings, hydrodynamics.rings, top)
    fabrication = top.table("fabrication", default={})
    return SwimmerSpec(
        radius, thickness, names, path, stations, built, mechanics, hydrodynamics, fabrication
    )


def _names(t: Table) -> tuple[str, ...]:
    what = 'a list of distinct names, e.g. ["L1", "L2"]'
    value = t.raw("names", what)
    if (
        not isinstance(value, list)
        or not value
        or not all(isinstance(v, str) for v in value)
        or len(set(value)) != len(value)
    ):
        t.expected("names", what, value)
    return tuple(value)


def _path(value: Any, count: int, where: str) -> np.ndarray:
    what = f"a list of at least two stimulus vectors of {count} values, no two consecutive equal"
    if not isinstance(value, list) or len(value) < 2:
        expected(where, what, value)
    rows = []
    for i, row in enumerate(value):
        if not isinstance(row, list) or len(row) != count:
            expected(f"{where}[{i}]", f"a stimulus vector of {count} values", row)
        rows.append([real(v, f"{where}[{i}][{j}]") for j, v in enumerate(row)])
    path = np.array(rows)
    if np.any(np.all(np.diff(path, axis=0) == 0, axis=1)):
        expected(where, what, value)
    return path


def _check_shapes(stations: int, path: np.ndarray, where: str = "stimuli.stations") -> None:
    """At most SWIMMER_SHAPES equilibrium shapes along the cycle (stations per leg)."""
    shapes = stations * (len(path) - 1)
    if shapes > SWIMMER_SHAPES:
        raise FabkitError(
            f"{where}: {stations} stations on {len(path) - 1} legs make {shapes} "
            f"shapes, more than the limit of {SWIMMER_SHAPES}"
        )


def _check_rings(mesh_rings: int, stokes_rings: int, top: Table) -> None:
    """The elastic mesh at most SWIMMER_MESH_RINGS rings; the dense Stokeslet matrix of
    about 1 + pi R (R + 1) points (112 N^2 bytes with its work arrays) within WORK_BYTES."""
    if mesh_rings > SWIMMER_MESH_RINGS:
        top.expected("mechanics.rings", f"at most {SWIMMER_MESH_RINGS}", mesh_rings)
    points = 1 + math.pi * stokes_rings * (stokes_rings + 1)
    need = 112 * points**2
    if need > WORK_BYTES:
        raise FabkitError(
            f"{top.at('hydrodynamics.rings')}: {stokes_rings} rings make about {points:.3g} "
            f"Stokeslet points whose matrix needs {size_text(need)}, more than the limit of "
            f"{size_text(WORK_BYTES)}"
        )


PATH_SAMPLES = 64
"""Points per leg of the stimulus path at which the layers' stretches must be finite."""


def _layer(
    t: Table, stimuli: tuple[str, ...], index: int, radius: float, path: np.ndarray
) -> Layer:
    """One layer; its director must be finite on the disc of ``radius`` (mm) and its
    stretches finite along the stimulus ``path`` (P, k), vertices and legs."""
    where = t.at()
    table = t
    t.check_keys({"name", "director", "lambda1", "lambda2"})
    t.require(("director",), "an expression in x, y, r and phi (radians)")
    t.require(("lambda1", "lambda2"), "an expression in the stimuli")
    name = t.text("name", default=f"layer {index}")
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


def _settings(t: Table, kind: type) -> Any:
    defaults = kind()
    t.check_keys(set(defaults.__dataclass_fields__))
    values = {}
    for key, default in vars(defaults).items():
        if isinstance(default, int):
            values[key] = t.integer(key, default=default)
        else:
            values[key] = t.number(key, positive=key != "poisson", default=default)
    if "poisson" in values and not -1.0 < values["poisson"] <= 0.5:
        t.expected("poisson", "-1 < nu <= 0.5", values["poisson"])
    return kind(**values)
