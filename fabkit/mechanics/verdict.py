"""Which shape the sheet takes: every target simulated from several starts, and a verdict.

The sheet (a design as designed, or a sheet as fabricated) is ramped from its flat state
to every embedded target's stimulus (:func:`~fabkit.mechanics.fabricated.simulate_sheet`)
and compared with that target (:func:`~fabkit.mechanics.compare.compare`). The flat
sheet is a symmetric state that a simulation must leave by some perturbation, and a real
sheet picks its side by its own noise; so every target is simulated from each of the
:data:`~fabkit.mechanics.simulate.STARTS` (a dome up and down, a saddle and the same
turned, two random bumps). A target is **formed** when *every* start converged, none
ended as the mirror image and each ended within ``tolerance`` RMS of the target (a share
of the patch's diameter). Otherwise the verdict says which starts went where ("its side
is not programmed: 3 of 6 starts end as its mirror image"); its figures are those of
the worst start, with the spread of the RMS over all of them.

The simulations follow the stimulus slowly (:func:`~fabkit.mechanics.simulate.ramp`), as
a lab actuates a sheet: a sheet with any natural curvature then buckles to the side that
curvature favours, whatever its start. A printed sheet's natural curvature is the one its
layers were programmed with plus the print's errors, so a side can be chosen by the
errors alone: Fig. 1 as fabricated, with nothing programmed, forms its sphere from all
six starts. The verdict on a sheet as fabricated therefore runs every other start
(dome-down, saddle-down, random-2) on the same sheet with the print's error turned over
(:func:`~fabkit.mechanics.fabricated.turned_over`: another print whose every error is
this one's negated). A side the design programs holds on both; a side the error chose
flips, and the verdict says so.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from fabkit.background import parallel_map
from fabkit.design.design import Design
from fabkit.field.part import Part
from fabkit.mechanics import cache
from fabkit.mechanics.compare import (
    Comparison,
    FormedShape,
    compare,
    formed_shape,
    proper_rotation,
)
from fabkit.mechanics.fabricated import (
    SheetFields,
    SheetProblem,
    design_fields,
    sheet_problems,
    turned_over,
)
from fabkit.mechanics.metric import face_edges
from fabkit.mechanics.simulate import (
    MIRRORED,
    STARTS,
    Settings,
    Simulation,
    curved,
    default_thickness,
    mirrored,
    ramp,
)

FORM_TOLERANCE = 0.03
"""Largest RMS distance to a target, as a share of its patch's diameter, of a sheet that
forms it."""
TARGET_TRIANGLES = 800
"""About how many triangles a verdict's simulation uses (the design's grid coarsened)."""


@dataclass(frozen=True)
class StartEnd:
    """Where the simulation from one start (:data:`~fabkit.mechanics.simulate.STARTS`)
    ended: its RMS and max distance to the target (shares of the patch diameter),
    whether that is the mirror image and whether it converged; ``turned`` whether it ran
    on the sheet with the print's error turned over (module docstring)."""

    start: str
    rms: float
    max: float
    mirrored: bool
    converged: bool
    turned: bool = False

    @classmethod
    def of(cls, start: str, distance: Comparison, turned: bool = False) -> StartEnd:
        """Where ``start`` ended, from its comparison with the target."""
        return cls(start, distance.rms, distance.max, distance.mirrored, distance.converged, turned)

    def formed(self, tolerance: float) -> bool:
        return self.converged and not self.mirrored and self.rms <= tolerance

    def to_dict(self, tolerance: float) -> dict:
        return {
            "start": self.start,
            "formed": self.formed(tolerance),
            "rms_pct": 100 * self.rms,
            "max_pct": 100 * self.max,
            "mirror_image": self.mirrored,
            "converged": self.converged,
            "error_turned_over": self.turned,
        }


def distance_words(percent: float, mm: float | None, spec: str = ".2f") -> str:
    """A distance as the verdicts write it: ``1.28 % (0.946 mm)``, a percentage of the
    patch diameter and its length in mm (none where unknown)."""
    text = f"{percent:{spec}} %"
    return text if mm is None else f"{text} ({mm:.3g} mm)"


@dataclass(frozen=True)
class Shape:
    """What the sheet does under one target's stimulus: its RMS and max distance to the
    target (shares of the patch diameter), whether that is the mirror image, whether the
    simulation converged (all those of the worst start, :func:`worst`), the
    ``tolerance`` it is held to, and the wall time (s). ``starts`` holds where every
    start ended. ``diameter_mm`` is the patch diameter in mm and ``mesh`` the sheet from
    the worst start beside its target (:class:`~fabkit.mechanics.compare.FormedShape`),
    both None where the sheet's scale is unknown."""

    target: str
    rms: float
    max: float
    mirrored: bool
    converged: bool
    tolerance: float
    seconds: float = 0.0
    diameter_mm: float | None = None
    mesh: FormedShape | None = field(default=None, repr=False, compare=False)
    starts: tuple[StartEnd, ...] = ()

    @property
    def formed(self) -> bool:
        """Formed from every start (the worst start's figures are the shape's)."""
        return self.converged and not self.mirrored and self.rms <= self.tolerance

    def line(self) -> str:
        """One line with every figure of the verdict on this target, e.g. ``sphere: formed
        from all 6 starts, 0.79 % RMS (0.41 mm), max 2.87 % (1.49 mm) of the patch diameter
        (52 mm) at worst (RMS 0.77-0.79 % over the starts); limit 3 % RMS (1.56 mm);
        converged; not a mirror image`` (no mm where the scale is unknown). Not formed,
        it says first which starts went where."""
        diameter = f" ({self.diameter_mm:.3g} mm)" if self.diameter_mm is not None else ""
        mirror = "the target's mirror image" if self.mirrored else "not a mirror image"
        figures = f"{self._pct(self.rms)} RMS, max {self._pct(self.max)} of the patch diameter"
        figures += diameter
        if len(self.starts) > 1:
            rms = [end.rms for end in self.starts]
            spread = f"RMS {100 * min(rms):.2f}-{100 * max(rms):.2f} % over the starts"
            if self.formed:
                status = f"formed from all {len(self.starts)} starts, {figures} at worst ({spread})"
            else:
                start = worst(self.starts, self.tolerance).start
                status = f"NOT formed: {self.why()}; worst: {figures}, from the {start} start"
                status += f" ({spread})"
        else:
            status = f"{'formed' if self.formed else 'NOT formed'}, {figures}"
        return (
            f"{self.target}: {status}; limit {self._pct(self.tolerance, '.3g')} RMS; "
            f"{'converged' if self.converged else 'NOT converged'}; {mirror}"
        )

    def why(self) -> str:
        """Which starts went where, for a target not formed: ``its side is not programmed:
        3 of 6 starts end as its mirror image (dome-down, saddle, random-2)`` (``its side is
        the print's error's, not the design's: ...`` when every such start ran with the
        print's error turned over); starts that did not converge, or ended farther than
        the limit, likewise."""
        count = len(self.starts)
        mirrored = [end for end in self.starts if _mirror(end)]
        erred = bool(mirrored) and all(end.turned for end in mirrored)
        side = "the print's error's, not the design's" if erred else "not programmed"
        parts = []
        groups = (  # the verb for several starts, then for one
            (
                f"its side is {side}: {{}} of {{}} starts {{}} as its mirror image",
                "end",
                "ends",
                _mirror,
            ),
            ("{} of {} starts {} not converge", "do", "does", _unconverged),
            ("{} of {} starts {} farther than the limit", "end", "ends", _far(self.tolerance)),
        )
        for text, several, one, holds in groups:
            ends = [end.start for end in self.starts if holds(end)]
            if ends:
                verb = one if len(ends) == 1 else several
                parts.append(text.format(len(ends), count, verb) + f" ({', '.join(ends)})")
        if erred:
            parts[0] += ", each on the sheet with the print's error turned over"
        return "; ".join(parts)

    @classmethod
    def of(
        cls,
        target: str,
        ends: Sequence[StartEnd],
        tolerance: float,
        seconds: float = 0.0,
        diameter_mm: float | None = None,
        mesh: FormedShape | None = None,
    ) -> Shape:
        """The shape from where every start ended: the worst start's figures (:func:`worst`;
        ``mesh``, when given, is that start's sheet)."""
        bad = worst(ends, tolerance)
        return cls(
            target,
            bad.rms,
            bad.max,
            bad.mirrored,
            bad.converged,
            tolerance,
            seconds,
            diameter_mm,
            mesh,
            tuple(ends),
        )

    def mm(self, share: float) -> float | None:
        """A share of the patch diameter in mm (None where the scale is unknown)."""
        return None if self.diameter_mm is None else share * self.diameter_mm

    def _pct(self, share: float, spec: str = ".2f") -> str:
        """A share of the patch diameter as a percentage, and in mm when known."""
        return distance_words(100 * share, self.mm(share), spec)

    def miss(self) -> str:
        """A missed target in a few words: ``wavy (5.36 % RMS, mirror image from 3 of 6
        starts)``."""
        return f"{self.target} ({', '.join([f'{100 * self.rms:.2f} % RMS', *self._reasons()])})"

    def _reasons(self) -> list[str]:
        if len(self.starts) < 2:
            reasons = [("mirror image", self.mirrored), ("not converged", not self.converged)]
            return [reason for reason, holds in reasons if holds]
        count = len(self.starts)
        out = []
        for text, holds in (("mirror image", _mirror), ("not converged", _unconverged)):
            ends = sum(1 for end in self.starts if holds(end))
            if ends:
                out.append(f"{text} from {ends} of {count} starts")
        return out

    def to_dict(self) -> dict:
        """The figures; the ``_mm`` ones None where the scale is unknown."""
        mm = self.mm
        rms = [end.rms for end in self.starts] or [self.rms]
        return {
            "target": self.target,
            "formed": self.formed,
            "rms_pct": 100 * self.rms,
            "max_pct": 100 * self.max,
            "mirror_image": self.mirrored,
            "converged": self.converged,
            "limit_pct": 100 * self.tolerance,
            "seconds": self.seconds,
            "patch_diameter_mm": self.diameter_mm,
            "rms_mm": mm(self.rms),
            "max_mm": mm(self.max),
            "limit_mm": mm(self.tolerance),
            "formed_starts": sum(end.formed(self.tolerance) for end in self.starts),
            "rms_pct_over_starts": [100 * min(rms), 100 * max(rms)],
            "starts": [end.to_dict(self.tolerance) for end in self.starts],
            "line": self.line(),
        }


TIE = 1e-6
"""RMS distances (shares of the patch diameter) closer than this are one figure: ends in
one state differ by 1e-9 to 1e-7 (Fig. 3's face from the two random starts, and the
same sheet simulated by ``run`` and by ``verify``)."""


def _mirror(end: StartEnd) -> bool:
    return end.mirrored


def _unconverged(end: StartEnd) -> bool:
    return not end.converged and not end.mirrored


def _far(tolerance: float) -> Callable[[StartEnd], bool]:
    return lambda end: end.converged and not end.mirrored and end.rms > tolerance


def worst(ends: Sequence[StartEnd], tolerance: float) -> StartEnd:
    """The start whose end is worst: one that did not form the target, if any, then the
    largest RMS; of the starts within :data:`TIE` of the largest (ends in one state,
    whose RMS differ by the solver's tolerance: a start and its mirror image, two random
    starts), the first in the order of :data:`~fabkit.mechanics.simulate.STARTS`, so that
    ``run`` and ``verify`` name the same start."""
    missed = [end for end in ends if not end.formed(tolerance)] or list(ends)
    largest = max(end.rms for end in missed)
    tied = [end for end in missed if end.rms >= largest - TIE]
    return min(tied, key=lambda end: STARTS.index(end.start) if end.start in STARTS else 0)


@dataclass(frozen=True)
class Verdict:
    """The shapes a sheet takes (``what``: "as designed" or "as fabricated"), ``layers``
    and ``thickness_mm`` (None where the scale is unknown) of the sheet simulated."""

    what: str
    shapes: tuple[Shape, ...]
    layers: int
    thickness_mm: float | None = None

    @property
    def formed(self) -> bool:
        """Every target formed."""
        return all(shape.formed for shape in self.shapes)

    def headline(self) -> str:
        """One line for the end of a run: which targets the sheet forms."""
        return f"the sheet {self.what} {self.outcome()}"

    def rank(self) -> tuple[int, float]:
        """Targets formed, then the worst RMS, negated: of two sheets' verdicts, the larger
        is the better."""
        return sum(s.formed for s in self.shapes), -max(s.rms for s in self.shapes)

    def outcome(self) -> str:
        """What the sheet does, without naming the sheet: ``forms every target (sphere,
        bump)`` or ``does NOT form saddle (4.14 % RMS); trough (3.95 % RMS)``."""
        missed = [s for s in self.shapes if not s.formed]
        if not missed:
            return f"forms every target ({', '.join(s.target for s in self.shapes)})"
        return "does NOT form " + "; ".join(s.miss() for s in missed)

    def lines(self) -> list[str]:
        return [shape.line() for shape in self.shapes]

    def to_dict(self) -> dict:
        return {
            "what": self.what,
            "headline": self.headline(),
            "formed": self.formed,
            "layers": self.layers,
            "thickness_mm": self.thickness_mm,
            "targets": [shape.to_dict() for shape in self.shapes],
        }


def worst_of(verdicts: Sequence[Verdict]) -> Verdict:
    """The verdict of several prints (or sheets) of one design, target by target the worst
    of them: a target not formed by one of them if any (the farthest), else the farthest
    formed one. So a target is formed only where every one of ``verdicts`` forms it."""
    first = verdicts[0]
    names = [shape.target for shape in first.shapes]
    if any([shape.target for shape in v.shapes] != names for v in verdicts):
        raise ValueError("worst_of: the verdicts judge different targets")
    shapes = tuple(
        min((v.shapes[i] for v in verdicts), key=lambda shape: (shape.formed, -shape.rms))
        for i in range(len(names))
    )
    return replace(first, shapes=shapes)


def embedded_targets(design: Design) -> list[int]:
    """The surfaces (indices > 0) embedded in 3D: the ones a shape can be compared with."""
    targets = design.problem.targets
    return [
        s for s in range(1, len(targets)) if targets[s].surface.embed(np.zeros((1, 2))) is not None
    ]


def sheet_verdict(
    design: Design,
    layers: Sequence[SheetFields],
    thickness: float,
    what: str,
    *,
    tolerance: float = FORM_TOLERANCE,
    part: Part | None = None,
    stride: int | None = None,
    settings: Settings | None = None,
    mm_per_unit: float | None = None,
    starts: Sequence[str] = STARTS,
    progress: Callable[[int, int], None] | None = None,
) -> Verdict:
    """Simulate the sheet of ``layers`` (bottom first), ``thickness`` thick (design
    units), from every one of ``starts`` to every embedded target's stimulus; the verdict
    on each (module docstring)."""
    shapes = target_shapes(
        design,
        layers,
        embedded_targets(design),
        thickness,
        tolerance=tolerance,
        part=part,
        stride=stride,
        settings=settings,
        mm_per_unit=mm_per_unit,
        starts=starts,
        progress=progress,
    )
    thickness_mm = thickness * mm_per_unit if mm_per_unit is not None else None
    return Verdict(what, tuple(shapes), len(layers), thickness_mm)


def target_shapes(
    design: Design,
    layers: Sequence[SheetFields],
    surfaces: Sequence[int],
    thickness: float,
    *,
    tolerance: float = FORM_TOLERANCE,
    part: Part | None = None,
    stride: int | None = None,
    settings: Settings | None = None,
    mm_per_unit: float | None = None,
    starts: Sequence[str] = STARTS,
    progress: Callable[[int, int], None] | None = None,
    designed: Sequence[SheetFields] | None = None,
) -> list[Shape]:
    """The sheet of ``layers`` under each of the ``surfaces``' stimuli from every one of
    ``starts``: per surface a :class:`Shape` with the worst start's figures and mesh
    (``mm_per_unit`` given) and where every start ended. ``designed`` (the layers as
    designed, one per layer; a sheet as fabricated) runs every other start on the sheet
    with the print's error turned over (module docstring), where the sheet has a natural
    curvature (layers that differ): one layer's error bends it to no side. The simulations
    are spread over the cores (:func:`fabkit.background.parallel_map`);
    ``progress(done, total)`` counts them as they finish."""
    stride = stride or grid_stride(design)
    settings = settings or Settings()
    problems = sheet_problems(design, list(layers), surfaces, thickness, part=part, stride=stride)
    runs, turned = [], turned_starts(starts)
    for problem in problems:
        if designed is None or _symmetric(problem.metrics):  # no natural curvature to turn
            runs.append([problem] * len(starts))
        else:
            other = turned_over(problem, designed)
            runs.append([other if s in turned else problem for s in starts])
    calls = [
        (p.mesh.points, p.mesh.triangles, p.metrics, p.thickness, p.poisson,
         replace(settings, seed=start), None, p.start_metrics)
        for run in runs
        for p, start in zip(run, starts, strict=True)
    ]  # fmt: skip
    results = _simulations(calls, progress)
    count = len(starts)
    return [
        _shape(run, starts, results[k * count : (k + 1) * count], tolerance, mm_per_unit)
        for k, run in enumerate(runs)
    ]


def turned_starts(starts: Sequence[str] = STARTS) -> tuple[str, ...]:
    """The starts that a verdict on a sheet as fabricated runs with the print's error
    turned over: every other one (dome-down, saddle-down, random-2)."""
    return tuple(starts[1::2])


WARM = ("fabkit.mechanics.simulate",)
"""What a worker imports before its first simulation."""


def _simulations(
    calls: list[tuple], progress: Callable[[int, int], None] | None
) -> list[Simulation]:
    """The results of :func:`~fabkit.mechanics.simulate.simulate` on each of ``calls``:
    those kept in the cache (:mod:`fabkit.mechanics.cache`) read; a start that mirrors
    another of the same sheet, where the sheet has no natural curvature, reflected from
    it (:func:`~fabkit.mechanics.simulate.mirrored`: exact, the energy is symmetric); the
    others computed over the cores (:func:`_computed`: starts that relax alike share the
    rest of their ramp) and kept."""
    names = [cache.simulation_key(*call[:6], call[7]) for call in calls]
    results = [cache.load(name) for name in names]
    mirrors = _mirror_sources(calls)
    missing = [k for k, r in enumerate(results) if r is None and k not in mirrors]
    done = len(calls) - len(missing)

    def advance(finished: int, _total: int) -> None:
        if progress is not None:
            progress(done + finished, len(calls))

    if done:
        advance(0, len(missing))  # those read or reflected count as done
    computed = _computed([calls[k] for k in missing], advance)
    for k, result in zip(missing, computed, strict=True):
        cache.store(names[k], result)
        results[k] = result
    for k, source in mirrors.items():
        results[k] = results[k] or mirrored(results[source])
    return results


RAMP_PART = "fabkit.mechanics.simulate:ramp_part"
MERGE = 0.01
"""Starts of one sheet with a natural curvature whose states after the first ramp step
lie within this share of the mean flat edge of each other (after the best proper rigid
motion) share the rest of the ramp: from the same state the same steps give the same
result. On such a sheet every start relaxes to near flat at the first small share of the
stimulus (module docstring of :mod:`fabkit.mechanics.simulate`), which takes a tenth of
a simulation; the rest of the ramp, where the sheet buckles, is then run once, not six
times."""


def _computed(calls: list[tuple], advance: Callable[[int, int], None]) -> list[Simulation]:
    """:func:`~fabkit.mechanics.simulate.simulate` on each of ``calls`` over the cores.
    A start of a sheet with a natural curvature runs its first ramp step alone; the rest
    of the ramp runs once for every group of its sheet's starts that reached the same state
    (:data:`MERGE`), and each start of a group gets its result (its own first step's
    iterations added). ``advance(done, total)`` counts the calls whose result is known."""
    split = [_rampable(call) for call in calls]
    first = [(*call, 0, 1 if part else None) for call, part in zip(calls, split, strict=True)]
    whole_done = np.cumsum([not part for part in split])

    def first_progress(finished: int, _total: int) -> None:
        advance(int(whole_done[finished - 1]), len(calls))

    starts = parallel_map(RAMP_PART, first, WARM, first_progress)
    groups = _groups(calls, starts, split)
    rest = [(*calls[lead][:6], starts[lead].positions, calls[lead][7], 1, None) for lead in groups]
    settled = int(whole_done[-1]) if len(calls) else 0
    sizes = np.cumsum([len(members) for members in groups.values()])

    def rest_progress(finished: int, _total: int) -> None:
        advance(settled + int(sizes[finished - 1]), len(calls))

    ends = parallel_map(RAMP_PART, rest, WARM, rest_progress)
    results = [start if not part else None for start, part in zip(starts, split, strict=True)]
    for end, members in zip(ends, groups.values(), strict=True):
        for k in members:
            results[k] = Simulation(
                end.positions,
                end.energy,
                starts[k].iterations + end.iterations,
                end.converged,
                starts[k].seconds + end.seconds,
            )
    return results


def _rampable(call: tuple) -> bool:
    """Whether a call is a ramp of several steps from a seeded start on a sheet with a
    natural curvature (its first step is run alone, :func:`_computed`)."""
    natural = curved(np.asarray(call[2]))
    settings, initial = call[5], call[6]
    return natural and initial is None and len(ramp(settings, natural)) > 1


def _groups(
    calls: list[tuple], starts: list[Simulation], split: list[bool]
) -> dict[int, list[int]]:
    """The calls ramped in parts grouped by sheet and by the state their first step
    reached (:data:`MERGE`): the first call of each group (its lead) -> its members."""
    groups: dict[int, list[int]] = {}
    for k, call in enumerate(calls):
        if not split[k]:
            continue
        edge = float(np.mean(np.linalg.norm(face_edges(call[0], call[1])[1], axis=-1)))
        for lead, members in groups.items():
            other = calls[lead]
            same_sheet = other[2] is call[2] and other[7] is call[7] and other[0] is call[0]
            if same_sheet and _apart(starts[k].positions, starts[lead].positions) <= MERGE * edge:
                members.append(k)
                break
        else:
            groups[k] = [k]
    return groups


def _apart(a: np.ndarray, b: np.ndarray) -> float:
    """The largest distance between corresponding points of ``a`` and ``b`` (V, 3) after
    the proper rigid motion that best fits ``a`` to ``b``."""
    moved = (a - a.mean(0)) @ proper_rotation(a, b) + b.mean(0)
    return float(np.max(np.linalg.norm(moved - b, axis=1)))


def _mirror_sources(calls: list[tuple]) -> dict[int, int]:
    """For each call whose start mirrors another call's start on the same sheet without
    natural curvature, the index of that other call."""
    where = {(id(call[2]), call[5].seed): k for k, call in enumerate(calls)}
    sources = {}
    for k, call in enumerate(calls):
        partner = MIRRORED.get(call[5].seed)
        source = where.get((id(call[2]), partner))
        if source is not None and _symmetric(call[2]) and _symmetric(call[7]):
            sources[k] = source
    return sources


def _symmetric(metrics: np.ndarray | None) -> bool:
    """Metrics of one layer, or of layers all equal: no natural curvature."""
    return metrics is None or not curved(metrics)


def _shape(
    problems: Sequence[SheetProblem],
    starts: Sequence[str],
    results: Sequence[Simulation],
    tolerance: float,
    mm_per_unit: float | None,
) -> Shape:
    """The :class:`Shape` of one target from the simulations of its ``problems`` (one per
    start: the sheet, or the sheet with the print's error turned over) from each of
    ``starts``."""
    ends, found = [], {}
    problem = problems[0]
    for sheet, start, result in zip(problems, starts, results, strict=True):
        simulation = sheet.simulation(result)
        distance = compare(sheet.coarse, simulation, sheet.patch_size)
        ends.append(StartEnd.of(start, distance, sheet is not problem))
        found[start] = (simulation, distance)
    simulation, distance = found[worst(ends, tolerance).start]
    if mm_per_unit is None:
        diameter_mm, mesh = None, None
    else:
        diameter_mm = distance.size * mm_per_unit
        mesh = formed_shape(
            problem.coarse, simulation, mm_per_unit, problem.patch_size, problem.outline
        )
    seconds = sum(result.seconds for result in results)
    return Shape.of(distance.name, ends, tolerance, seconds, diameter_mm, mesh)


def share_progress(
    progress: Callable[[int, int], None] | None, k: int, count: int
) -> Callable[[int, int], None] | None:
    """The progress of the k-th of ``count`` simulations as a share of them all."""
    if progress is None:
        return None
    return lambda done, total: progress(k * total + done, count * total)


def design_verdict(
    design: Design,
    thickness: float | None = None,
    *,
    tolerance: float = FORM_TOLERANCE,
    part: Part | None = None,
    stride: int | None = None,
    mm_per_unit: float | None = None,
    starts: Sequence[str] = STARTS,
    progress: Callable[[int, int], None] | None = None,
) -> Verdict:
    """The verdict on the sheet as designed: every layer's own director and features (one
    layer without a layering); ``thickness`` defaults to the layering's, else 1 % of the
    flat domain's diameter (as ``fabkit simulate``)."""
    if design.layering is not None:
        layers = [design_fields(design.layer(k)) for k in range(design.layers)]
        thickness = design.layering.thickness if thickness is None else thickness
    else:
        layers = [design_fields(design)]
    if thickness is None:
        thickness = default_thickness(design)
    return sheet_verdict(
        design,
        layers,
        thickness,
        "as designed",
        tolerance=tolerance,
        part=part,
        stride=stride,
        mm_per_unit=mm_per_unit,
        starts=starts,
        progress=progress,
    )


def grid_stride(design: Design) -> int:
    """The grid coarsening that leaves about :data:`TARGET_TRIANGLES` triangles."""
    valid = design.valid
    cells = int((valid[:-1, :-1] & valid[1:, :-1] & valid[:-1, 1:] & valid[1:, 1:]).sum())
    return max(1, round(math.sqrt(2 * cells / TARGET_TRIANGLES)))
