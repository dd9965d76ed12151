"""The objective of a search: the area a candidate's design covers.

A candidate is the search's spec with other parameter values. Its design counts only if
it passes ``fabkit check`` (the default tolerances, or the objective's ``tolerances``:
:data:`ACCEPTANCE` asks residual medians <= 1e-3 of the curvature too); the solver has
already dropped every point beyond the strain limit (``solver.max_strain``) or its error
tolerance. The area a design covers on a surface is that of its **grid cells whose four
corners are counted points** (:func:`covered_areas`): each cell's area is h^2 times the
mean over its corners of alpha beta lambda1 lambda2, in design units squared. On the flat
sheet this is the area of the cells as drawn from r (within 0.5 % on Fig. 1 and Fig. 3).
The objective is that area on the flat sheet (``flat``), or the smallest of the targets'
(``smallest``).

The sum over points that ``design.json`` reports as realised area (every solved point
weighted by its own alpha beta lambda1 lambda2) is not used: a point at the edge of the
domain, next to a stop, can have a large alpha without any neighbour, and counts as a long
strip of sheet that is not there. A search finds such designs: one Fig. 1 candidate had
2.9 times the paper's realised flat area while its cells covered 0.8 times the paper's.

With a process (``--machine`` / ``--process``) a point counts only if the process can make
it (:class:`Limits`): every feature inside its channel's calibrated range (a joint channel:
the eps pair inside the region its measured grid covers), and inside the part that
:func:`fabkit.field.part.make_part` cuts from the counted points with the minimum width
(:func:`wide_enough`).

Candidates are evaluated in batches (:func:`evaluate_batch`), one call per batch in any
worker process: the spec is rebuilt there once and every batch is solved together
(:func:`fabkit.design.solver.solve_batch`), so a candidate's value is the same whichever
worker evaluates it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from fabkit.calibration import JointCalibration
from fabkit.design.check import Tolerances, check_design
from fabkit.design.design import Design
from fabkit.design.solver import solve_batch
from fabkit.errors import FabkitError
from fabkit.problem.spec import Spec, spec_from_json
from fabkit.process import Process

SPECS_KEPT = 4
"""Specs a worker process keeps built (a search sends the same one with every batch)."""
_specs: dict[str, Spec] = {}


@dataclass(frozen=True)
class Limits:
    """What a process can make. ``ranges``: (feature index, lowest, highest eps) of every
    single channel; ``regions``: (feature i, feature j, boundary (M, 2) of the eps pairs a
    joint channel's grid covers); ``min_width``: the narrowest part it can make, in design
    units (0: no limit)."""

    ranges: tuple[tuple[int, float, float], ...] = ()
    regions: tuple[tuple[int, int, np.ndarray], ...] = ()
    min_width: float = 0.0


ACCEPTANCE = Tolerances(isometry_median=1e-3, isometry_p95=1e-2, curvature_median=1e-3)
"""Issue 21's acceptance: "the check passing (residual medians <= 1e-3)", the curvature's
median included (the check's default allows it 1e-2)."""


@dataclass(frozen=True)
class Objective:
    """``kind``: ``flat`` or ``smallest`` (see the module docstring); ``limits``: a
    process's, or None to count every point the design solves; ``tolerances``: those of
    the check a candidate must pass to count."""

    kind: str = "flat"
    limits: Limits | None = None
    tolerances: Tolerances = Tolerances()


@dataclass(frozen=True)
class Evaluation:
    """A candidate's objective ``value`` (design units squared; 0 when it is refused or
    fails the check, ``note`` says why), the covered ``areas`` of its counted points by
    surface, its solved and counted ``points``, and whether it passed the check."""

    value: float
    areas: dict[str, float] = field(default_factory=dict)
    points: int = 0
    counted: int = 0
    passed: bool = False
    note: str = ""


def process_limits(
    process: Process,
    features: Sequence[str],
    mm_per_unit: float,
    min_width_mm: float | None = None,
    ignore: Sequence[str] = (),
) -> Limits:
    """The :class:`Limits` of ``process`` for a design with ``features``; the minimum width
    is ``min_width_mm`` (default: the process's road width), made design units by
    ``mm_per_unit``. A feature without a channel is refused (:meth:`Process.resolve`)."""
    resolution = process.resolve(tuple(features), tuple(ignore))
    ranges, regions = [], []
    for channel in resolution.channels:
        index = [list(features).index(name) for name in channel.features]
        table = channel.table
        if isinstance(table, JointCalibration):
            regions.append((index[0], index[1], _joint_boundary(table)))
        else:
            ranges.append((index[0], *table.eps_range))
    width = process.road_width_mm if min_width_mm is None else min_width_mm
    return Limits(tuple(ranges), tuple(regions), width / mm_per_unit)


def _joint_boundary(table: JointCalibration) -> np.ndarray:
    """The eps pairs (M, 2) along the edge of a joint table's grid, in order: its cells are
    bilinear, so their edges are straight and this ring bounds what the table can make."""
    eps = np.moveaxis(np.asarray(table.measured, dtype=float), 0, -1)
    return np.concatenate([eps[:, 0], eps[-1, 1:], eps[-2::-1, -1], eps[0, -2:0:-1]])


def evaluate_batch(
    spec_json: str, names: Sequence[str], points: Sequence[Sequence[float]], objective: Objective
) -> list[Evaluation]:
    """Evaluate the candidates at ``points`` of the space whose parameters are ``names``,
    the spec being ``spec_json`` (:meth:`Spec.to_json`); solved as one batch."""
    spec = _spec(spec_json)
    candidates: list[Spec | FabkitError] = []
    for point in points:
        try:
            candidates.append(spec.with_parameters(dict(zip(names, point, strict=True))))
        except FabkitError as exc:
            candidates.append(exc)
    specs = [c for c in candidates if isinstance(c, Spec)]
    solved = iter(solve_batch(specs, crop=True) if specs else [])
    results = []
    for candidate in candidates:
        outcome = next(solved) if isinstance(candidate, Spec) else candidate
        if isinstance(outcome, FabkitError):
            results.append(Evaluation(0.0, note=f"refused: {outcome}"))
        else:
            results.append(score(outcome.design, candidate, objective))
    return results


def _spec(text: str) -> Spec:
    """The spec of ``text``, built once per worker process."""
    if text not in _specs:
        if len(_specs) >= SPECS_KEPT:
            del _specs[next(iter(_specs))]
        _specs[text] = spec_from_json(text)
    return _specs[text]


def score(design: Design, spec: Spec, objective: Objective) -> Evaluation:
    """The objective of one solved design (``spec`` is its spec)."""
    points = int(design.valid.sum())
    check = check_design(design, objective.tolerances, spec=spec)
    if not check.passed:
        failed = ", ".join(s.name for s in check.surfaces if not s.passes(check.tolerances))
        return Evaluation(0.0, points=points, note=f"check failed on {failed}")
    counted = design.valid
    if objective.limits is not None:
        counted = counted & makeable(design, objective.limits)
        counted = wide_enough(design, counted, objective.limits.min_width)
    areas = covered_areas(design, counted, spec)
    if not any(areas.values()):
        return Evaluation(0.0, points=points, passed=True, note="no point the process can make")
    names = [t.name for t in spec.targets]
    value = areas[names[0]] if objective.kind == "flat" else min(areas[n] for n in names[1:])
    return Evaluation(value, areas, points, int(counted.sum()), True)


def covered_areas(design: Design, counted: np.ndarray, spec: Spec) -> dict[str, float]:
    """Area (design units squared) of the grid cells whose four corners are ``counted``
    (nu, nv), on every surface of ``spec``: h^2 times the mean over the corners of alpha
    beta lambda1 lambda2."""
    cells = counted[:-1, :-1] & counted[1:, :-1] & counted[:-1, 1:] & counted[1:, 1:]
    if not cells.any():
        return {target.name: 0.0 for target in spec.targets}
    eps = np.where(counted, design.eps, 0.0)
    response = spec.material.response(eps, design.stimuli)
    areas = {}
    for j, target in enumerate(spec.targets):
        density = design.alpha * design.beta * response.lambda1[j] * response.lambda2[j]
        density = np.where(counted, density, 0.0)
        corners = density[:-1, :-1] + density[1:, :-1] + density[:-1, 1:] + density[1:, 1:]
        areas[target.name] = float(np.sum(corners[cells]) / 4 * design.step**2)
    return areas


def makeable(design: Design, limits: Limits) -> np.ndarray:
    """Points (nu, nv) whose eps the process can make: inside every single channel's range
    and every joint channel's region (its boundary included)."""
    import shapely

    eps = np.where(design.valid, design.eps, 0.0)
    inside = design.valid.copy()
    for index, low, high in limits.ranges:
        inside &= (eps[index] >= low) & (eps[index] <= high)
    for first, second, boundary in limits.regions:
        region = shapely.Polygon(boundary)
        inside &= shapely.intersects_xy(region, eps[first], eps[second])
    return inside


def wide_enough(design: Design, counted: np.ndarray, width: float) -> np.ndarray:
    """The counted points (nu, nv) inside the part that fabkit cuts from them with a
    minimum width of ``width`` design units (:func:`fabkit.field.part.make_part`: the smooth
    margin outline inside the counted cells, then a closing and an opening with a disc of
    that diameter), i.e. the points that ``fabkit run`` would make with that width. 0 keeps
    every point; a part with nothing left keeps none."""
    if width <= 0 or not counted.any():
        return counted
    from fabkit.field.part import PartRules, make_part

    try:
        part = make_part(replace(design, valid=counted), PartRules(min_width=width))
    except FabkitError:  # nothing of the counted region is left
        return np.zeros_like(counted)
    kept = counted.copy()
    kept[counted] = part.contains(design.r[0][counted])
    return kept
