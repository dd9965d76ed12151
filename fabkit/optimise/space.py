"""The search space: which numbers of a spec a search varies, and between which bounds.

A dimension is either a parameter of the spec's ``[optimise.parameters]`` table (a name
its initial data or its targets' start points and directors use: the way to vary a curve,
``v_curve = ["R*(1 - cos(t/R))", "R*sin(t/R)"]``), or a number of the spec named by its
key (``--vary KEY=LO:HI``, see :data:`KEY_FORMS`):

* ``NAME``: a declared parameter (the bounds replace the table's);
* ``initial.eps[i]``, ``initial.slope[i]``: a constant eps or slope of feature i;
* ``surfaces.NAME.start[k]``, ``surfaces.NAME.director[k]`` (or ``surfaces[j]...``):
  component k of a target's start point or director (chart coordinates).

A key of the second kind becomes a parameter of the spec (its number is replaced by the
parameter's name), so every candidate is the spec with other parameter values
(:meth:`fabkit.problem.spec.Spec.with_parameters`). Only initial data can vary: candidates of one
search share the material, the surfaces and the solver settings, and are solved together.
"""

from __future__ import annotations

import copy
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fabkit.errors import FabkitError
from fabkit.problem.expr import parse
from fabkit.problem.spec import Spec, build_spec

KEY_FORMS = (
    "NAME (a parameter of [optimise.parameters])",
    "initial.eps[i]",
    "initial.slope[i]",
    "surfaces.NAME.start[k]",
    "surfaces.NAME.director[k]",
)
"""What ``--vary`` accepts, for its error message."""
_INITIAL = re.compile(r"initial\.(eps|slope)\[(\d+)\]")
_SURFACE = re.compile(
    r"surfaces(?:\.([A-Za-z0-9][A-Za-z0-9_.+-]*?)|\[(\d+)\])\.(start|director)\[(\d)\]"
)


@dataclass(frozen=True)
class Dimension:
    """One varied number: ``key`` as the user named it, ``name`` the spec parameter that
    carries it, its bounds and its value in the spec (the search's start). ``path`` locates
    a key of the spec in its table (None for a declared parameter)."""

    key: str
    name: str
    low: float
    high: float
    start: float
    path: tuple[str | int, ...] | None = None


@dataclass(frozen=True)
class Space:
    """The dimensions of a search and the spec they vary (its table with every varied key
    turned into a parameter, read from ``base_dir``)."""

    dimensions: tuple[Dimension, ...]
    table: dict[str, Any]
    base_dir: Path

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(d.name for d in self.dimensions)

    @property
    def bounds(self) -> list[tuple[float, float]]:
        return [(d.low, d.high) for d in self.dimensions]

    @property
    def start(self) -> list[float]:
        return [d.start for d in self.dimensions]

    def spec(self) -> Spec:
        return build_spec(self.table, self.base_dir)

    def values(self, x: Sequence[float]) -> dict[str, float]:
        """Parameter values (name -> number) of a point x of the space."""
        return {d.name: float(v) for d, v in zip(self.dimensions, x, strict=True)}

    def table_at(self, x: Sequence[float]) -> dict[str, Any]:
        """The spec table at x, as a user would write it: every key of the spec holds its
        number again (its parameter removed), every declared parameter its new value."""
        table = copy.deepcopy(self.table)
        parameters = table["optimise"]["parameters"]
        for dimension, value in zip(self.dimensions, x, strict=True):
            if dimension.path is None:
                parameters[dimension.name]["value"] = float(value)
                continue
            *parents, last = dimension.path
            holder = table
            for part in parents:
                holder = holder[part]
            holder[last] = float(value)
            del parameters[dimension.name]
        if not parameters:
            del table["optimise"]["parameters"]
        if not table["optimise"]:
            del table["optimise"]
        return table


def search_space(table: Mapping[str, Any], base_dir: Path, varies: Sequence[str]) -> Space:
    """The space of a spec table: its declared parameters, then every ``--vary KEY=LO:HI``
    (a declared parameter named again takes the new bounds). A key that names nothing
    varies nothing: a one-line error."""
    table = copy.deepcopy(dict(table))
    optimise = table.setdefault("optimise", {})
    if not isinstance(optimise, dict):
        raise FabkitError("optimise: expected a table [optimise]")
    declared = optimise.setdefault("parameters", {})
    if not isinstance(declared, dict):
        raise FabkitError("optimise.parameters: expected a table of parameters")
    dimensions: dict[str, Dimension] = {}
    for name, entry in declared.items():
        if isinstance(entry, Mapping) and {"value", "min", "max"} <= set(entry):
            dimensions[name] = Dimension(name, name, entry["min"], entry["max"], entry["value"])
    for text in varies:
        key, low, high = _vary(text)
        if key in declared:
            declared[key] = {**declared[key], "min": low, "max": high}
            dimensions[key] = Dimension(key, key, low, high, declared[key].get("value", low))
            continue
        path, where = _path(table, key)
        name = _parameter_name(key, declared)
        holder = table
        for part in path[:-1]:
            holder = holder[part]
        start = _number_at(holder[path[-1]], where, declared)
        holder[path[-1]] = name
        declared[name] = {"value": min(max(start, low), high), "min": low, "max": high}
        dimensions[name] = Dimension(key, name, low, high, declared[name]["value"], path)
    if not dimensions:
        raise FabkitError(
            "nothing to vary: declare parameters in [optimise.parameters] or give --vary "
            "KEY=LO:HI (docs/optimise.md)"
        )
    return Space(tuple(dimensions.values()), table, base_dir)


def _vary(text: str) -> tuple[str, float, float]:
    """KEY, LO, HI of ``KEY=LO:HI``."""
    key, equals, bounds = text.partition("=")
    low_text, colon, high_text = bounds.partition(":")
    try:
        low, high = float(low_text), float(high_text)
    except ValueError:
        low = high = math.nan
    if not (equals and colon and key.strip()) or not (math.isfinite(low) and math.isfinite(high)):
        raise FabkitError(f"--vary {text}: expected KEY=LO:HI, like initial.eps[0]=0.2:0.8")
    if not low < high:
        raise FabkitError(f"--vary {text}: LO must be below HI")
    return key.strip(), low, high


def _path(table: Mapping[str, Any], key: str) -> tuple[tuple[str | int, ...], str]:
    """Where ``key`` sits in the spec table, and its name for errors; refused unless it
    names a number the search can vary."""
    known = "; known keys: " + ", ".join(KEY_FORMS)
    match = _INITIAL.fullmatch(key)
    if match:
        kind, index = match.group(1), int(match.group(2))
        values = table.get("initial", {}).get(kind)
        if not isinstance(values, list) or index >= len(values):
            raise FabkitError(f"--vary {key}: the spec has no {key}{known}")
        return ("initial", kind, index), key
    match = _SURFACE.fullmatch(key)
    if match:
        name, position, kind, component = match.groups()
        surfaces = table.get("surfaces", [])
        names = [s.get("name", f"surface{i}") for i, s in enumerate(surfaces)]
        index = names.index(name) if name in names else None
        if position is not None and int(position) < len(surfaces):
            index = int(position)
        if not index:  # None, or the flat sheet, whose start comes from the curves
            raise FabkitError(
                f"--vary {key}: no target surface {name or position} (targets: "
                f"{', '.join(names[1:])})"
            )
        values = surfaces[index].get(kind)
        if not isinstance(values, list) or int(component) >= len(values):
            raise FabkitError(f"--vary {key}: surfaces[{index}] has no {kind}[{component}]")
        return ("surfaces", index, kind, int(component)), key
    raise FabkitError(f"--vary {key}: not a key the search can vary{known}")


def _parameter_name(key: str, taken: Mapping[str, Any]) -> str:
    """A parameter name for a key of the spec: its words joined by '_' (``sphere_start_0``)."""
    words = re.findall(r"[A-Za-z0-9]+", key.removeprefix("surfaces.").removeprefix("initial."))
    name = "_".join(words)
    if not name[0].isalpha():
        name = f"p_{name}"
    while name in taken:
        name += "_"
    return name


def _number_at(value: Any, where: str, declared: Mapping[str, Any]) -> float:
    """The number a spec entry holds (a number or a constant expression, which may use the
    declared parameters' values)."""
    if isinstance(value, bool):
        raise FabkitError(f"--vary {where}: holds {value!r}, not a number")
    if isinstance(value, int | float):
        return float(value)
    if isinstance(value, str):
        values = {
            name: entry["value"]
            for name, entry in declared.items()
            if isinstance(entry, Mapping) and isinstance(entry.get("value"), int | float)
        }
        expression = parse(value, ("t",), f"--vary {where}", values)
        if expression.is_constant:
            return float(expression(0.0))
        raise FabkitError(
            f"--vary {where}: '{value}' depends on t; declare a parameter for it in "
            "[optimise.parameters] and use it in the expression (docs/optimise.md)"
        )
    raise FabkitError(f"--vary {where}: holds {value!r}, not a number")
