"""The design problem as a researcher writes it: a TOML spec, validated into a :class:`Spec`.

See ``docs/spec.md`` for every key. Every problem a user can make in a spec is a
:class:`FabkitError` with one line naming the file, the key path and what to fix, read
with :class:`fabkit.tomlfile.Table` (whose module documents the wording).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from fabkit.atomic import check_name
from fabkit.errors import FabkitError
from fabkit.problem.expr import RESERVED, Expression, parse, shorten
from fabkit.problem.material import ALONG, Material, check_unstretched
from fabkit.problem.surfaces import Surface, build_surface
from fabkit.problem.surfaces.base import UNBOUNDED
from fabkit.shipped import user_or_example
from fabkit.tomlfile import Table, read_toml, real

ALL_QUADRANTS = ((1, 1), (-1, 1), (-1, -1), (1, -1))
PERPENDICULAR_TOLERANCE = 1e-6
"""Largest |cos| between the initial curves' tangents at t = 0 accepted as perpendicular."""
MAX_SOLVER_BYTES = 4 * 2**30
"""Largest memory the solver's grid may need (bytes, see :func:`solver_memory`)."""
MIN_STEP = 1e-6
"""Smallest grid step (design units): below, rounding dominates the cross derivatives."""
MAX_REACH = 1e6
"""Largest step x diagonals (design units): the grid's reach |u| + |v|."""


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


@dataclass(frozen=True)
class InitialData:
    """The Goursat data: curves on the flat sheet (parameter t) and eps with its slope.

    ``eps[i]`` and ``slope[i]`` are functions of t along the u-curve for a feature acting
    along the director (slope = q) and along the v-curve for one acting across (slope = p).
    """

    u_curve: tuple[Expression, Expression]
    v_curve: tuple[Expression, Expression]
    eps: tuple[Expression, ...]
    slope: tuple[Expression, ...]


@dataclass(frozen=True)
class SolverSettings:
    """Grid step (design units), diagonals per quadrant, quadrants (sign of u, sign of v).

    ``tolerance``: largest accepted error estimate of a solved point (dimensionless, the
    relative Richardson difference of its designed lengths; see docs/solver.md).
    """

    step: float = 0.05
    diagonals: int = 200
    quadrants: tuple[tuple[int, int], ...] = ALL_QUADRANTS
    max_strain: float = 3.0
    extrapolate: bool = True
    tolerance: float = 1e-2


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

    material: Material
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
        solver, normalised = _solver(
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
        initial, _ = _initial(table.table("initial"), self.material, self.classes, optimise.values)
        targets = _with_flat_start(tuple(targets), initial, table.at("initial"))
        _check_material_at_start(self.material, initial, targets, table.shown)
        normalised = {**self.normalised, "optimise": _optimise_table(optimise)}
        return replace(
            self, targets=targets, initial=initial, optimise=optimise, normalised=normalised
        )


def load_spec(path: str | Path) -> Spec:
    """Read and validate a TOML spec file (or a shipped example, see
    :func:`fabkit.shipped.user_or_example`)."""
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
    material, material_table = _material(top.table("material"))
    targets, surface_tables = _targets(top, material, base_dir, optimise.values)
    stimuli = np.array([t.stimulus for t in targets])
    classes = material.classify(stimuli[1:])
    initial, initial_table = _initial(top.table("initial"), material, classes, optimise.values)
    targets = _with_flat_start(targets, initial, top.at("initial"))
    _check_material_at_start(material, initial, targets, shown)
    solver, solver_table = _solver(top.table("solver", default={}), len(material.features))
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
    u_start, director = _check_curves(initial, where)
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


def _material(t: Table) -> tuple[Material, dict[str, Any]]:
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


def _targets(top: Table, material: Material, base_dir: Path, parameters: Mapping[str, float]):
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
    material: Material,
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


def _initial(
    t: Table,
    material: Material,
    classes: tuple[str, ...],
    parameters: Mapping[str, float],
):
    t.check_keys({"u_curve", "v_curve", "eps", "slope"})
    count = len(material.features)
    curves = []
    for key in ("u_curve", "v_curve"):
        what = 'two expressions in t, like ["t", "0"]'
        value = t.array(key, what)
        if len(value) != 2:
            t.expected(key, what, value)
        curves.append(tuple(parse(v, ("t",), t.at(key), parameters) for v in value))
    series = []
    for key in ("eps", "slope"):
        what = f"{count} expression(s) in t, one per feature {list(material.features)}"
        value = t.array(key, what)
        if len(value) != count:
            t.expected(key, what, value)
        series.append(
            tuple(parse(v, ("t",), t.at(f"{key}[{i}]"), parameters) for i, v in enumerate(value))
        )
    initial = InitialData(curves[0], curves[1], series[0], series[1])
    normalised = {
        "u_curve": [e.text for e in initial.u_curve],
        "v_curve": [e.text for e in initial.v_curve],
        "eps": [e.text for e in initial.eps],
        "slope": [e.text for e in initial.slope],
    }
    _check_finite_initial(initial, classes, t)
    return initial, normalised


def _check_finite_initial(initial: InitialData, classes: tuple[str, ...], t: Table) -> None:
    """eps, its derivative along its curve and the slope must be finite at t = 0."""
    for i, kind in enumerate(classes):
        carrier = "u_curve" if kind == ALONG else "v_curve"
        checks = (("eps", initial.eps[i], 1), ("slope", initial.slope[i], 0))
        for label, expression, order in checks:
            value, grad, _ = expression.jets(0.0, wrt=("t",), order=order)
            if not np.isfinite(value) or (order and not np.isfinite(grad[0])):
                what = "it or its derivative is" if order else "it is"
                t.fail(
                    f"not finite at t = 0 on the {carrier} ({what} not finite: "
                    f"'{shorten(expression.text)}')",
                    f"{label}[{i}]",
                )


def _check_material_at_start(
    material: Material, initial: InitialData, targets: tuple[Target, ...], shown: str
) -> None:
    """lambda1, lambda2 and (where lambda > 0) their log-derivatives by eps must be finite
    at the start point's eps (the initial eps at t = 0) under every surface's stimulus."""
    eps = np.array([[e(0.0)] for e in initial.eps])  # (N, 1)
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


def _check_curves(initial: InitialData, where: str) -> tuple[np.ndarray, np.ndarray]:
    """The common start point and the flat-sheet director (unit u-curve tangent) at t = 0;
    ``where`` is the ``[initial]`` table (``FILE: initial``)."""
    for key in ("u_curve", "v_curve"):
        for expression in getattr(initial, key):
            if not all(np.all(np.isfinite(p)) for p in expression.jets(0.0, wrt=("t",))):
                raise FabkitError(
                    f"{where}.{key}: not finite at t = 0: '{shorten(expression.text)}' or its "
                    "first or second derivative (the curve, its tangent or its curvature)"
                )
    u_point = np.array([c(0.0) for c in initial.u_curve])
    v_point = np.array([c(0.0) for c in initial.v_curve])
    u_tangent = np.array([c.diff("t")(0.0) for c in initial.u_curve])
    v_tangent = np.array([c.diff("t")(0.0) for c in initial.v_curve])
    if np.linalg.norm(u_point - v_point) > 1e-9 * (1 + np.linalg.norm(u_point)):
        raise FabkitError(
            f"{where}: the u-curve starts at {u_point.tolist()} but the v-curve at "
            f"{v_point.tolist()}; they must meet at t = 0"
        )
    u_speed, v_speed = np.linalg.norm(u_tangent), np.linalg.norm(v_tangent)
    if not (u_speed > 0 and v_speed > 0):
        raise FabkitError(f"{where}: the u- and v-curves need non-zero tangents at t = 0")
    cosine = float(u_tangent @ v_tangent) / (u_speed * v_speed)
    if abs(cosine) > PERPENDICULAR_TOLERANCE:
        raise FabkitError(
            f"{where}: the u- and v-curves must be perpendicular at t = 0 (cos = {cosine:.3g})"
        )
    cross = u_tangent[0] * v_tangent[1] - u_tangent[1] * v_tangent[0]
    if cross < 0:
        raise FabkitError(
            f"{where}: the v-curve must leave the start point 90 degrees counter-clockwise from "
            "the u-curve (reverse the v-curve's parameter)"
        )
    return u_point, u_tangent / u_speed


def _solver(
    t: Table, features: int, labels: Mapping[str, str] = MappingProxyType({})
) -> tuple[SolverSettings, dict[str, Any]]:
    """Solver settings for ``features`` designable features; ``labels`` name the
    command-line options that gave some keys (``{"step": "--step"}``) in the grid's
    bounds (:func:`_check_grid`)."""
    t.check_keys({"step", "diagonals", "quadrants", "max_strain", "extrapolate", "tolerance"})
    defaults = SolverSettings()
    step = t.number("step", positive=True, default=defaults.step)
    diagonals = t.integer("diagonals", default=defaults.diagonals)
    quadrants = _quadrants(t)
    max_strain = t.number("max_strain", positive=True, default=defaults.max_strain)
    extrapolate = t.flag("extrapolate", default=defaults.extrapolate)
    tolerance = t.number("tolerance", positive=True, default=defaults.tolerance)
    settings = SolverSettings(step, diagonals, quadrants, max_strain, extrapolate, tolerance)
    _check_grid(settings, features, {"step": t.at("step"), "diagonals": t.at("diagonals")} | labels)
    normalised = {
        "step": step,
        "diagonals": diagonals,
        "quadrants": [list(q) for q in quadrants],
        "max_strain": max_strain,
        "extrapolate": extrapolate,
        "tolerance": tolerance,
    }
    return settings, normalised


def solver_memory(settings: SolverSettings, features: int) -> int:
    """Bytes the solver needs at most for ``settings`` and N = ``features`` (S = N + 2
    surfaces), estimated before anything is allocated.

    Every point of every diagonal marched is kept until the design is assembled: alpha,
    beta, b, s, eps, p, q (N each), r and n (2 per surface), 12 + 7N floats, with its
    valid flag and failure code (9 bytes). A march of M diagonals holds Q (M + 1)(M + 2) / 2
    points over Q quadrants; the march at h (M = D) and the one at h/2 (M = 2D) always run
    together (their difference is the error estimate). Three designs of (2D + 1)^2 nodes
    (2 + N + 4S floats and a flag each) are budgeted at the end, and assembling a design
    needs the stored r (2S floats per point) twice more. The total, plus 20 % for
    temporaries, was 1.07 to 1.35 times the peak traced by tracemalloc for Fig. 1 and
    Fig. 3 grids of 40 to 160 diagonals whose points are all solved (the worst case; the
    march keeps only the design's variables at solved points, so this errs on the safe
    side).
    """
    n, surfaces, d = features, features + 2, settings.diagonals
    points = len(settings.quadrants) * sum((m + 1) * (m + 2) // 2 for m in (d, 2 * d))
    nodes = (2 * d + 1) ** 2
    stored = points * (8 * (12 + 7 * n) + 9)
    designs = 3 * nodes * (8 * (2 + n + 4 * surfaces) + 1)
    assembling = 8 * 2 * surfaces * (points + 2 * nodes)
    return int(1.2 * (stored + designs + assembling))


def _check_grid(settings: SolverSettings, features: int, labels: Mapping[str, str]) -> None:
    """Refuse a grid the solver cannot march: too fine a step, too long a reach, or more
    memory than :data:`MAX_SOLVER_BYTES` (estimated before anything is allocated)."""
    if settings.step < MIN_STEP:
        raise FabkitError(
            f"{labels['step']} {settings.step:g}: below {MIN_STEP:g}, rounding error swamps "
            "the cross derivatives; give a larger step (design units)"
        )
    if settings.step * settings.diagonals > MAX_REACH:
        raise FabkitError(
            f"{labels['step']} {settings.step:g} x {labels['diagonals']} {settings.diagonals}: "
            f"the grid would reach {settings.step * settings.diagonals:.3g} design units, more "
            f"than {MAX_REACH:g}; give a smaller step or fewer diagonals"
        )
    needed = solver_memory(settings, features)
    if needed > MAX_SOLVER_BYTES:
        most = settings.diagonals
        while most > 1 and solver_memory(replace(settings, diagonals=most), features) > (
            MAX_SOLVER_BYTES
        ):
            most = int(most * 0.95)
        raise FabkitError(
            f"{labels['diagonals']} {settings.diagonals}: the solver would need about "
            f"{needed / 2**30:,.0f} GiB ({len(settings.quadrants)} quadrants, {features} "
            f"feature(s), a second march at half the step), more than the "
            f"{MAX_SOLVER_BYTES / 2**30:g} GiB limit; use at most about {most} diagonals "
            "(and a larger step for the same reach)"
        )


def _quadrants(t: Table) -> tuple[tuple[int, int], ...]:
    value = t.get("quadrants", "all")
    if value == "all":
        return ALL_QUADRANTS
    what = '"all" or a list of distinct quadrants like [[1, 1], [-1, 1]]'
    if not isinstance(value, list) or not value:
        t.expected("quadrants", what, value)
    quadrants = []
    for item in value:
        if (
            not isinstance(item, list)
            or len(item) != 2
            or any(isinstance(s, bool) or s not in (1, -1) for s in item)
        ):
            t.expected("quadrants", what, value)
        quadrants.append((int(item[0]), int(item[1])))
    if len(set(quadrants)) != len(quadrants):
        t.expected("quadrants", what, value)
    return tuple(quadrants)


def describe_spec(spec: Spec) -> str:
    """A human summary: features and their class, stimuli, surfaces with K at their starts,
    and the initial data the problem needs."""
    material = spec.material
    lines = [
        f"material: lambda1 = {material.lambda1.text}, lambda2 = {material.lambda2.text}",
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
