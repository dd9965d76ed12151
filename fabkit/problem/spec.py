"""The design problem as a researcher writes it: a TOML spec, validated into a :class:`Spec`.

See ``docs/spec.md`` for every key. Every problem a user can make in a spec is a
:class:`FabkitError` with one line naming the file, the key path and what to fix, read
with :class:`fabkit.files.tomlfile.Table` (whose module documents the wording).

The ``[initial]`` table is read by :mod:`fabkit.problem.initial_data`, the ``[solver]``
table by :mod:`fabkit.problem.solver_settings`.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from fabkit.errors import FabkitError
from fabkit.files.atomic import check_name
from fabkit.files.shipped import user_or_example
from fabkit.files.tomlfile import Table, read_toml, real
from fabkit.problem.expr import RESERVED, parse, shorten
from fabkit.problem.initial_data import InitialData, check_curves, read_initial
from fabkit.problem.material import ALONG, Material, MaterialLaw, check_unstretched
from fabkit.problem.material_table import TableMaterial, read_table
from fabkit.problem.solver_settings import SolverSettings, read_solver
from fabkit.problem.surfaces import Surface, build_surface
from fabkit.problem.surfaces.base import UNBOUNDED


@dataclass(frozen=True)
class Target:
    """One surface of the problem: geometry, stimulus, and (for targets) start point and director.

    ``start`` and ``director`` are chart coordinates (2,); the director is unit in the metric.
    Surface 0 (the flat sheet) takes both from the initial u-curve.
    """

    name: str
    surface: Surface
    stimulus: tuple[float, ...]
    start: np.ndarray
    director: np.ndarray


OBJECTIVES = ("flat", "smallest")
"""What ``fabkit optimise`` maximises: the realised area on the flat sheet, or the smallest
realised area over the targets (see docs/optimise.md)."""


@dataclass(frozen=True)
class Parameter:
    """A number the initial data and the targets' start points and directors may use by
    name (``[optimise.parameters]``), and the range a search may give it."""

    name: str
    value: float
    low: float
    high: float


@dataclass(frozen=True)
class OptimiseSettings:
    """The ``[optimise]`` table: the objective and the parameters (none without it)."""

    objective: str = "flat"
    parameters: tuple[Parameter, ...] = ()

    @property
    def values(self) -> dict[str, float]:
        return {p.name: p.value for p in self.parameters}


@dataclass(frozen=True)
class Spec:
    """A validated design problem."""

    material: MaterialLaw
    classes: tuple[str, ...]
    targets: tuple[Target, ...]
    initial: InitialData
    solver: SolverSettings
    normalised: dict[str, Any]
    optimise: OptimiseSettings = OptimiseSettings()

    @property
    def stimuli(self) -> np.ndarray:
        """(S, k) stimulus of every surface."""
        return np.array([t.stimulus for t in self.targets], dtype=float)

    def to_json(self) -> str:
        """The normalised spec as JSON; :func:`spec_from_json` rebuilds the same Spec."""
        return json.dumps(self.normalised, sort_keys=True)

    def with_solver(self, **changes: Any) -> Spec:
        """A copy with some solver settings replaced by command-line options (``step=``,
        ``diagonals=``, ``quadrants=``; None keeps the spec's); errors name the option."""
        solver_table = dict(self.normalised["solver"])
        labels = {}
        for key, value in changes.items():
            if value is not None:
                solver_table[key] = [list(q) for q in value] if key == "quadrants" else value
                labels[key] = f"--{key}"
        solver, normalised = read_solver(
            Table(solver_table, "spec", "solver"), len(self.material.features), labels
        )
        return replace(self, solver=solver, normalised={**self.normalised, "solver": normalised})

    def with_parameters(self, values: Mapping[str, float]) -> Spec:
        """A copy whose parameters (``[optimise.parameters]``) take ``values`` (name ->
        number; the others keep theirs): the initial data and the targets' start points
        and directors are read again with them, the material and surfaces are kept."""
        unknown = sorted(set(values) - set(self.optimise.values))
        if unknown:
            raise FabkitError(f"optimise.parameters: no parameter '{unknown[0]}'")
        parameters = tuple(
            replace(p, value=float(values.get(p.name, p.value))) for p in self.optimise.parameters
        )
        optimise = replace(self.optimise, parameters=parameters)
        table = Table(self.normalised, "spec")
        targets = [self.targets[0]]
        for index, target in enumerate(self.targets[1:], start=1):
            start, director = _placement(
                target.surface, table.item("surfaces", index), optimise.values
            )
            targets.append(replace(target, start=start, director=director))
        initial, _ = read_initial(
            table.table("initial"), self.material, self.classes, optimise.values
        )
        targets = _with_flat_start(tuple(targets), initial, table.at("initial"))
        _check_material_at_start(self.material, initial, targets, table.shown)
        normalised = {**self.normalised, "optimise": _optimise_table(optimise)}
        return replace(
            self, targets=targets, initial=initial, optimise=optimise, normalised=normalised
        )


def load_spec(path: str | Path) -> Spec:
    """Read and validate a TOML spec file (or a shipped example, see
    :func:`fabkit.files.shipped.user_or_example`)."""
    path = user_or_example(path)
    return build_spec(read_toml(path, "spec"), path.resolve().parent, str(path))


def spec_from_json(text: str) -> Spec:
    """Rebuild a Spec from :meth:`Spec.to_json` (file paths in it are absolute)."""
    try:
        table = json.loads(text)
    except json.JSONDecodeError as exc:
        raise FabkitError(f"embedded spec is not valid JSON: {exc}") from None
    return build_spec(table, Path("."), "embedded spec")


def build_spec(table: Mapping[str, Any], base_dir: Path, shown: str = "spec") -> Spec:
    """Validate a spec given as nested tables; ``base_dir`` resolves data file paths,
    ``shown`` names the file in errors."""
    top = Table(table, shown)
    top.check_keys({"material", "surfaces", "initial", "solver", "optimise"})
    top.require(("material",), "a table [material]")
    top.require(("surfaces",), "[[surfaces]] tables")
    top.require(("initial",), "a table [initial]")
    optimise = _optimise(top.table("optimise", default={}))
    material, material_table = _material(top.table("material"), base_dir)
    targets, surface_tables = _targets(top, material, base_dir, optimise.values)
    stimuli = np.array([t.stimulus for t in targets])
    classes = material.classify(stimuli[1:])
    initial, initial_table = read_initial(top.table("initial"), material, classes, optimise.values)
    targets = _with_flat_start(targets, initial, top.at("initial"))
    _check_material_at_start(material, initial, targets, shown)
    solver, solver_table = read_solver(top.table("solver", default={}), len(material.features))
    normalised = {
        "material": material_table,
        "surfaces": surface_tables,
        "initial": initial_table,
        "solver": solver_table,
    }
    if "optimise" in table:
        normalised["optimise"] = _optimise_table(optimise)
    return Spec(material, classes, targets, initial, solver, normalised, optimise)


def _with_flat_start(
    targets: tuple[Target, ...], initial: InitialData, where: str
) -> tuple[Target, ...]:
    """The targets with the flat sheet's start point and director from the initial curves
    (the ``[initial]`` table at ``where``)."""
    u_start, director = check_curves(initial, where)
    flat = targets[0]
    return (Target(flat.name, flat.surface, flat.stimulus, u_start, director), *targets[1:])


def _optimise(t: Table) -> OptimiseSettings:
    """The ``[optimise]`` table: ``objective`` and ``[optimise.parameters]``, each a table
    ``{ value = V, min = LO, max = HI }`` (LO < HI, LO <= V <= HI)."""
    t.check_keys({"objective", "parameters"})
    objective = t.text("objective", OBJECTIVES, default="flat")
    table = t.table("parameters", default={})
    parameters = []
    for name in table:
        if not name.isidentifier() or name in RESERVED or name == "t":
            table.fail(
                "expected a parameter name like 'radius' (letters, digits, _; not t, pi, e or "
                f"a function name), got {name!r}",
                name,
            )
        entry = table.table(name)
        entry.check_keys({"value", "min", "max"})
        value, low, high = (entry.number(k) for k in ("value", "min", "max"))
        if not low < high:
            entry.expected("min", f"a number below max = {high:g}", entry["min"])
        if not low <= value <= high:
            entry.expected("value", f"a number in [{low:g}, {high:g}]", entry["value"])
        parameters.append(Parameter(name, value, low, high))
    return OptimiseSettings(objective, tuple(parameters))


def _optimise_table(settings: OptimiseSettings) -> dict[str, Any]:
    """The normalised ``[optimise]`` table."""
    return {
        "objective": settings.objective,
        "parameters": {
            p.name: {"value": p.value, "min": p.low, "max": p.high} for p in settings.parameters
        },
    }


def _names(t: Table, key: str) -> tuple[str, ...]:
    what = 'a list of distinct names, like ["eps"]'
    value = t.array(key, what)
    if not all(isinstance(v, str) for v in value) or len(set(value)) != len(value):
        t.expected(key, what, value)
    return tuple(value)


def _material(t: Table, base_dir: Path) -> tuple[MaterialLaw, dict[str, Any]]:
    """The ``[material]`` table: expressions ``lambda1``, ``lambda2``, or a ``table`` (a
    file written by ``fabkit calibrate``, or in a normalised spec that file's content)."""
    if "table" in t:
        return _material_table(t, base_dir)
    t.check_keys({"features", "stimuli", "lambda1", "lambda2"})
    t.require(("features", "stimuli"), 'a list of names, like ["eps"]')
    t.require(("lambda1", "lambda2"), "an expression in the features and stimuli")
    features = _names(t, "features")
    stimuli = _names(t, "stimuli")
    if not features:
        t.expected("features", "at least one designable feature", [])
    if set(features) & set(stimuli):
        both = sorted(set(features) & set(stimuli))[0]
        t.expected("stimuli", "names that are not features", both)
    names = features + stimuli
    lambda1 = parse(t.get("lambda1"), names, t.at("lambda1"))
    lambda2 = parse(t.get("lambda2"), names, t.at("lambda2"))
    normalised = {
        "features": list(features),
        "stimuli": list(stimuli),
        "lambda1": lambda1.text,
        "lambda2": lambda2.text,
    }
    return Material(features, stimuli, lambda1, lambda2), normalised


def _material_table(t: Table, base_dir: Path) -> tuple[TableMaterial, dict[str, Any]]:
    """``[material] table = "FILE"`` (``features``, ``stimuli`` optional, and then the
    table's); the normalised table holds the file's content, so that a design file stands
    on its own and a changed table is a changed spec."""
    t.check_keys({"features", "stimuli", "table"})
    value = t.get("table")
    if isinstance(value, str):
        path = base_dir / value
        material = read_table(Table(read_toml(path, "material table", value), value))
    elif isinstance(value, Mapping):
        material = read_table(t.table("table"))
    else:
        t.expected("table", "the name of a material table file (fabkit calibrate --out)", value)
    for key in ("features", "stimuli"):
        if key in t and _names(t, key) != getattr(material, key):
            t.expected(key, f"the table's {key} {list(getattr(material, key))}", t[key])
    normalised = {
        "features": list(material.features),
        "stimuli": list(material.stimuli),
        "table": material.to_table(),
    }
    return material, normalised


def _vector(
    t: Table,
    key: str,
    length: int,
    what: str,
    parameters: Mapping[str, float] = MappingProxyType({}),
) -> np.ndarray:
    value = t.raw(key, f"{what}, a list of {length} numbers")
    if not isinstance(value, list) or len(value) != length:
        t.expected(key, f"{what}, a list of {length} numbers", value)
    return np.array([_constant(v, t.at(key), parameters) for v in value])


def _constant(
    value: Any, where: str, parameters: Mapping[str, float] = MappingProxyType({})
) -> float:
    """A number given as a TOML number or a constant expression such as "pi/2" (which may
    use the spec's ``parameters``)."""
    if isinstance(value, str):
        expression = parse(value, (), where, parameters)
        return real(float(expression()), where)
    return real(value, where)


def _targets(top: Table, material: MaterialLaw, base_dir: Path, parameters: Mapping[str, float]):
    count = len(material.features) + 2
    what = (
        f"{count} [[surfaces]] tables ({len(material.features)} feature(s): the flat sheet and "
        f"{count - 1} targets)"
    )
    value = top.array("surfaces", what)
    if len(value) != count:
        top.expected("surfaces", what, value)
    targets, tables, seen = [], [], set()
    for index in range(count):
        table = top.item("surfaces", index)
        target, normalised = _target(index, table, material, base_dir, parameters)
        if target.name in seen:
            table.expected("name", "a name no other surface has", target.name)
        seen.add(target.name)
        targets.append(target)
        tables.append(normalised)
    return tuple(targets), tables


def _target(
    index: int,
    t: Table,
    material: MaterialLaw,
    base_dir: Path,
    parameters: Mapping[str, float],
):
    allowed = {"name", "stimulus", "geometry"} | ({"start", "director"} if index else set())
    t.check_keys(allowed)
    name = check_name(t.get("name", f"surface{index}"), t.at("name"))
    stimulus = _vector(
        t, "stimulus", len(material.stimuli), f"one value per stimulus {list(material.stimuli)}"
    )
    table = t.table("geometry")
    surface = build_surface(name, table, base_dir)
    geometry = _absolute_files(dict(table.data), base_dir)
    normalised = {"name": name, "stimulus": stimulus.tolist(), "geometry": geometry}
    if index == 0:
        if surface.kind != "plane" or surface.bounds != UNBOUNDED:
            t.expected("geometry", 'kind = "plane" without a domain (the flat sheet)', geometry)
        check_unstretched(material, stimulus, t.at("stimulus"))
        return Target(name, surface, tuple(stimulus), np.zeros(2), np.array([1.0, 0.0])), normalised
    start, director = _placement(surface, t, parameters)
    normalised |= {key: _entries(t[key]) for key in ("start", "director")}
    return Target(name, surface, tuple(stimulus), start, director), normalised


def _entries(value: list) -> list:
    """A start or director as normalised: numbers as floats, expressions as their text."""
    return [v if isinstance(v, str) else float(v) for v in value]


def _placement(
    surface: Surface, t: Table, parameters: Mapping[str, float]
) -> tuple[np.ndarray, np.ndarray]:
    """A target's start point (chart) and director (unit in the metric) from its table."""
    start = _vector(t, "start", 2, "a chart point", parameters)
    direction = _vector(t, "director", 2, "chart components", parameters)
    _check_geometry_at_start(surface, start, t.at("geometry"))
    if not surface.contains(start[None])[0]:
        t.expected("start", f"a point inside the {surface.kind} chart", start.tolist())
    g = surface.metric(start)
    length_squared = direction @ g @ direction
    if not length_squared > 0:
        t.expected("director", "a non-zero vector", direction.tolist())
    return start, direction / np.sqrt(length_squared)


def _check_geometry_at_start(surface: Surface, start: np.ndarray, where: str) -> None:
    """Refuse a surface whose metric, Christoffel symbols or curvature are not finite at
    the start point, naming the expression (e.g. ``surfaces[2].geometry.z``) if it has one.

    Elsewhere a non-finite geometry is the edge of the surface: the solver stops there.
    """
    if all(np.all(np.isfinite(part)) for part in surface.geometry(start[None])):
        return
    at = ", ".join(f"{c} = {v:.6g}" for c, v in zip(surface.chart, start, strict=True))
    for key, expression in surface.expressions().items():
        parts = expression.jets(start[0], start[1], wrt=expression.names)
        if not all(np.all(np.isfinite(part)) for part in parts):
            raise FabkitError(
                f"{where}.{key}: not finite at the start point ({at}): "
                f"'{shorten(expression.text)}' or its first or second derivatives"
            )
    raise FabkitError(f"{where}: the metric or curvature is not finite at the start point ({at})")


def _absolute_files(geometry: dict[str, Any], base_dir: Path) -> dict[str, Any]:
    """Make a data file path absolute so the normalised spec stands on its own."""
    if isinstance(geometry.get("file"), str):
        geometry["file"] = str((base_dir / geometry["file"]).resolve())
    return geometry


def _check_material_at_start(
    material: MaterialLaw, initial: InitialData, targets: tuple[Target, ...], shown: str
) -> None:
    """lambda1, lambda2 and (where lambda > 0) their log-derivatives by eps must be finite
    at the start point's eps (the initial eps at t = 0) under every surface's stimulus."""
    eps = np.array([[e(0.0)] for e in initial.eps])  # (N, 1)
    material.check_domain(eps[:, 0], f"{shown}: initial.eps")
    for index, target in enumerate(targets):
        response = material.response(eps, np.array([target.stimulus]))
        for label, parts in (
            ("lambda1", (response.lambda1, response.l1_e, response.l1_ee)),
            ("lambda2", (response.lambda2, response.l2_e, response.l2_ee)),
        ):
            stretch, log_derivatives = parts[0], parts[1:]
            if np.isfinite(stretch).all() and (
                not (stretch > 0).all()  # lambda <= 0 is the solver's to report
                or all(np.isfinite(part).all() for part in log_derivatives)
            ):
                continue
            names = material.features + material.stimuli
            values = [*eps[:, 0], *target.stimulus]
            at = ", ".join(f"{n} = {v:.6g}" for n, v in zip(names, values, strict=True))
            raise FabkitError(
                f"{shown}: material.{label}: not finite at the start point, or its "
                f"log-derivatives by eps are not, at {at} (the initial eps under the stimulus "
                f"of surfaces[{index}] '{target.name}')"
            )


def describe_spec(spec: Spec) -> str:
    """A human summary: features and their class, stimuli, surfaces with K at their starts,
    and the initial data the problem needs."""
    material = spec.material
    lines = [
        f"material: {material.describe()}",
        f"stimuli: {', '.join(material.stimuli)}",
        "features:",
    ]
    for feature, kind in zip(material.features, spec.classes, strict=True):
        lines.append(f"  {feature}: acts {kind} the director")
    lines.append(f"surfaces ({len(spec.targets)}):")
    for index, target in enumerate(spec.targets):
        curvature = float(target.surface.curvature(target.start))
        stimulus = ", ".join(f"{s:g}" for s in target.stimulus)
        lines.append(
            f"  [{index}] {target.name}: {target.surface.describe()}, stimulus ({stimulus}), "
            f"start {np.round(target.start, 6).tolist()}, K = {curvature:.6g} at start"
        )
    lines.append("initial data needed:")
    for feature, kind, eps, slope in zip(
        material.features, spec.classes, spec.initial.eps, spec.initial.slope, strict=True
    ):
        if kind == ALONG:
            lines.append(f"  {feature} = {eps.text} and q = {slope.text} along the u-curve")
        else:
            lines.append(f"  {feature} = {eps.text} and p = {slope.text} along the v-curve")
    u, v = spec.initial.u_curve, spec.initial.v_curve
    lines.append(f"  u-curve ({u[0].text}, {u[1].text}), v-curve ({v[0].text}, {v[1].text})")
    solver = spec.solver
    lines.append(
        f"solver: step {solver.step:g}, {solver.diagonals} diagonals, "
        f"quadrants {[list(q) for q in solver.quadrants]}, max strain {solver.max_strain:g}"
    )
    return "\n".join(lines)
