"""``fabkit run``'s solve stage: the spec solved and checked, the part cut, the layers.

:func:`solve_stage` solves and checks the spec into design.npz, cuts the part of the
flat sheet that is made (:func:`design_part`, or a baromorph's), programs the layers of
a layered sheet (:func:`layer_design`, also ``fabkit solve --layers``; with no
``--layers`` on a printer, of the layer counts :func:`layer_choices` allows the one
:func:`chosen_layers` picks, the others that form every target as designed kept for the
run to print in turn while a print misses one: :func:`fallback_layers`) and gives the
verdict on the sheet as designed (:class:`Solved`). Called by
:func:`fabkit.run.pipeline.run_pipeline` (:func:`layers_solved` again for another count).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from fabkit.design.check import CheckReport, ResidualMaps
from fabkit.design.design import Design
from fabkit.design.layers import layered, layering_report
from fabkit.design.summary import checked_points, solve_to_file
from fabkit.field.design_field import feature_names as design_features
from fabkit.field.part import (
    MIN_WIDTH_PITCHES,
    MIN_WIDTH_ROADS,
    Part,
    PartRequest,
    part_of_size,
    solved_region,
)
from fabkit.figures import AREA_UNIT
from fabkit.mechanics.refine import refine_layering
from fabkit.mechanics.simulate import STARTS
from fabkit.mechanics.verdict import FORM_TOLERANCE, Shape, Verdict, design_verdict
from fabkit.process import Process
from fabkit.run.inputs import MIN_SIZE_PER_THICKNESS, RunInputs, RunOptions, layer_choices

NOT_SIMULATED = (
    "NOT SIMULATED (--no-simulate): no verdict on the shapes the sheet takes; the design's "
    "residuals and the machine file are checked"
)
"""What a run without simulations says first and last, where the verdict would be."""
NOT_JUDGED_LAYERS = (
    "the layers carry every target's curvature, the whole first-order layering, not judged "
    "(its share is chosen by simulations)"
)
"""What a layered run without simulations says of its layers, first and where it layers."""


@dataclass(frozen=True)
class LayerChoice:
    """A layer count a run may print: ``layers``, and the shares of its first-order
    layering whose sheet already missed a target while the run chose it (share, verdict:
    :attr:`LayerRequest.missed`, not judged again)."""

    layers: int
    missed: tuple[tuple[float, Verdict], ...] = ()


@dataclass(frozen=True)
class Solved:
    """The solve stage's results: the ``design`` (layered when asked), its check
    (``check``, the residual ``maps``), the solver's ``summary``, the ``part`` that is
    made, how well the layers program the curvature (``layering``, None for one layer)
    and the ``verdict`` on the sheet as designed (None: not simulated, --no-simulate)."""

    design: Design
    check: CheckReport
    maps: tuple[ResidualMaps, ...]
    summary: dict[str, Any]
    part: Part
    layering: dict[str, Any] | None
    verdict: Verdict | None
    unlayered: Design | None = None
    """The design before it was layered (another layer count starts from it)."""
    fallbacks: tuple[LayerChoice, ...] = ()
    """The layer counts a run printing ``design`` tries next, in turn, when its print
    misses a target (:func:`choose_layers`; none when ``--layers`` was given)."""


def solve_stage(options: RunOptions, inputs: RunInputs, say: Callable[[str], None]) -> Solved:
    """Solve and check the spec into design.npz; cut the part that is made."""
    say(f"[1/7] solving {options.spec}")
    result = solve_to_file(inputs.spec, Path(options.out) / "design.npz", "      solving")
    check, solved = result.check, result.summary
    say(
        f"      {solved['valid_points']} valid points in {solved['solve_seconds']:.2f} s; "
        f"check {'passed' if check.passed else 'FAILED'}"
    )
    say(f"      {checked_points(solved['check'])}")
    say(
        f"      area over the solved cells ({AREA_UNIT}): "
        + ", ".join(f"{k} {v:.4g}" for k, v in solved["area_design_units2"].items())
    )
    design = result.solution.design
    choices, tried = (LayerChoice(options.layers),), {}
    if options.layers_chosen and options.layers > 1 and options.simulate:
        choices, tried = choose_layers(design, options, inputs, say)
    fallbacks = () if options.refine else choices[1:]  # --refine reprints its own design
    unlayered = Solved(design, check, result.maps, solved, None, None, None, design, fallbacks)
    return layers_solved(unlayered, choices[0], options, inputs, say, tried)


def layers_solved(
    solved: Solved,
    choice: LayerChoice,
    options: RunOptions,
    inputs: RunInputs,
    say: Callable[[str], None],
    tried: dict[str, str] | None = None,
) -> Solved:
    """``solved``'s unlayered design (:attr:`Solved.unlayered`) made of ``choice.layers``
    layers: the part cut for that thickness, the layers programmed (:func:`layer_design`)
    and the sheet as designed judged; the design saved as design.npz. ``tried``: the
    counts judged while choosing (report.json's ``layers.layers_tried``)."""
    design, layers = solved.unlayered, choice.layers
    part = _part(options, inputs, design, layers)
    say(f"      {part.summary()}")
    thickness_mm = layers * inputs.process.layer_height_mm if inputs.process else None
    layering, verdict = None, None
    if layers > 1:
        request = LayerRequest(
            layers,
            inputs.process,
            part,
            options.ignore_features,
            options.form_tolerance,
            options.refine,
            missed=choice.missed,
        )
        made = layer_design(design, request, say, simulate=options.simulate)
        design, verdict = made.design, made.as_designed
        layering = {**made.figures, "layers_tried": tried or {}}
        design.save(Path(options.out) / "design.npz")
    if not options.simulate:
        say(f"      {NOT_SIMULATED}")
        return replace(solved, design=design, part=part, layering=layering, verdict=None)
    verdict = verdict or design_verdict(
        design,
        None if thickness_mm is None else thickness_mm / part.mm_per_unit,
        tolerance=options.form_tolerance,
        part=part,
        mm_per_unit=part.mm_per_unit,
    )
    say(f"      {verdict.headline()}:")
    for line in verdict.lines():
        say(f"        {line}")
    return replace(solved, design=design, part=part, layering=layering, verdict=verdict)


CHOOSING_STARTS = ("dome", "dome-down")
"""The starts a run judges each layer count from while it chooses (a side not programmed
shows between these two); the count chosen is judged from every start."""
COUNTS_PRINTED = 3
"""The most layer counts a run with no ``--layers`` prints while their prints miss a
target (each a whole print verified: 20-40 s at 60 mm): the count chosen and the next two
of :func:`fallback_layers`."""
PRINT_MARGIN = 0.01
"""How far inside each target's limit (a share of the patch diameter) a sheet as designed
must end for a run to choose it for its thickness: the print's error took the examples'
sheets 0.3 to 1.3 % farther from their targets (docs/layers.md)."""


def _nearest(verdict: Verdict) -> Shape:
    """The target the sheet ends nearest its limit (or farthest outside it)."""
    return min(verdict.shapes, key=lambda s: s.tolerance - s.rms)


def _room(verdict: Verdict) -> float:
    """How far inside its limit the sheet ends from the target nearest its limit (a share
    of the patch diameter; negative: outside)."""
    nearest = _nearest(verdict)
    return nearest.tolerance - nearest.rms


def chosen_layers(verdicts: dict[int, Verdict]) -> tuple[int, str]:
    """Of the sheets as designed in several layer counts (count -> verdict), the count a
    run prints and why: the thickest that forms every target :data:`PRINT_MARGIN` inside
    its limit; else, of those that form every target, the one nearest its targets; else
    the one that forms the most of them, nearest."""

    def room(k: int) -> float:
        return _room(verdicts[k])

    formed = [k for k, v in verdicts.items() if v.formed]
    clear = [k for k in formed if room(k) >= PRINT_MARGIN]
    if clear:
        why = (
            f"the thickest sheet that forms every target {100 * PRINT_MARGIN:g} % inside its limit"
        )
        return max(clear), why
    if formed:
        why = f"none forms every target {100 * PRINT_MARGIN:g} % inside its limit: the nearest"
        return max(formed, key=room), why
    best = max(verdicts, key=lambda k: (sum(s.formed for s in verdicts[k].shapes), room(k)))
    return best, "none forms every target as designed: the one that forms the most, nearest"


def fallback_layers(verdicts: dict[int, Verdict], chosen: int) -> tuple[int, ...]:
    """The counts a run prints in turn after ``chosen`` while a print misses a target: the
    others whose sheet as designed forms every target, farthest inside its limits first."""
    formed = [k for k, v in verdicts.items() if v.formed and k != chosen]
    return tuple(sorted(formed, key=lambda k: -_room(verdicts[k])))


def choose_layers(
    design: Design, options: RunOptions, inputs: RunInputs, say: Callable[[str], None]
) -> tuple[tuple[LayerChoice, ...], dict[str, str]]:
    """The layer counts a printed run with no ``--layers`` may print, the one it prints
    first, and what each count judged did (count -> one line): every count of
    :func:`layer_choices` layered and judged as designed from :data:`CHOOSING_STARTS`, each
    on its own part (the trim follows the thickness); :func:`chosen_layers` picks the first;
    the others whose sheet forms every target follow, farthest inside its limits first
    (the run prints them in turn while a print misses a target)."""
    height = inputs.process.layer_height_mm
    choices = layer_choices(options.size_mm, height)
    if len(choices) == 1:
        return (LayerChoice(choices[0]),), {}
    say(
        f"      layers judged as designed: {choices[0]} to {choices[-1]} of {height:g} mm "
        f"(no --layers; the sheet at most 1/{MIN_SIZE_PER_THICKNESS:g} of its size thick)"
    )
    verdicts, tried, missed = {}, {}, {}
    for k in choices:
        part = _part(options, inputs, design, k)
        request = LayerRequest(
            k, inputs.process, part, options.ignore_features, options.form_tolerance,
            starts=CHOOSING_STARTS,
        )  # fmt: skip
        made = layer_design(design, request, lambda line: None)
        verdicts[k] = verdict = made.as_designed
        missed[k] = made.missed
        nearest = _nearest(verdict)
        tried[str(k)] = (
            f"forms every target, nearest its limit {nearest.target} {100 * nearest.rms:.2f} % "
            f"(limit {100 * nearest.tolerance:g} %)"
            if verdict.formed
            else verdict.outcome()
        )
        say(f"        {k} layers ({k * height:.2g} mm): {tried[str(k)]}")
    chosen, why = chosen_layers(verdicts)
    say(f"      chosen: {chosen} layers, {why}")
    counts = (chosen, *fallback_layers(verdicts, chosen))[:COUNTS_PRINTED]
    return tuple(LayerChoice(k, missed[k]) for k in counts), tried


@dataclass(frozen=True)
class LayerRequest:
    """A layered sheet asked for: ``layers`` of the ``process``'s layer height on the
    ``part`` (its scale sets the thickness in design units), features within the ranges
    their channels encode (``ignore_features`` left out), targets held to ``tolerance``;
    ``refine``: the first-order layering refined against the simulation first
    (:mod:`fabkit.mechanics.refine`, ``--refine``); ``starts``: those each share is judged
    from; ``missed``: (share, verdict) of shares already judged from fewer starts that miss
    a target (a miss from some starts is a miss from all), not judged again."""

    layers: int
    process: Process
    part: Part
    ignore_features: tuple[str, ...] = ()
    tolerance: float = FORM_TOLERANCE
    refine: bool = False
    starts: tuple[str, ...] = STARTS
    missed: tuple[tuple[float, Verdict], ...] = ()


SHARES = (1.0, 0.1)
"""The shares of the first-order layering (:func:`~fabkit.design.layers.layered`) that
a layered run tries, largest first. The whole layering programs Fig. 3 (every target
formed from every start, as designed); on Fig. 1 it bends the bump's flank too far
(5.17 %), a tenth of it forms both targets. A larger share holds the side against more
of the print's error."""


@dataclass(frozen=True)
class Layered:
    """A layered design, the figures of its layering (report.json's ``layers``) and the
    verdict on the layered sheet as designed (None: not simulated)."""

    design: Design
    figures: dict[str, Any]
    as_designed: Verdict | None
    missed: tuple[tuple[float, Verdict], ...] = ()
    """(share, verdict) of the shares whose sheet missed a target."""


def layer_design(
    design: Design,
    request: LayerRequest,
    say: Callable[[str], None] = print,
    *,
    simulate: bool = True,
) -> Layered:
    """The design made of ``request.layers`` layers programmed with every target's
    curvature (``fabkit run --layers``, ``fabkit solve --layers``): the first-order
    layering scaled by the largest of :data:`SHARES` whose sheet as designed forms every
    target from every start (simulated at the layers' thickness; else the share that
    forms the most), and the figures of how well. The sheet programmed by its metric
    alone is no longer simulated (stop 46: the layering no longer depends on it; its
    figures are in docs/layers.md). Without ``simulate`` (``run --no-simulate``) nothing
    is simulated: the whole layering, not judged, and the run says so."""
    process, part = request.process, request.part
    thickness = request.layers * process.layer_height_mm / part.mm_per_unit
    names = design_features(design)
    bounds = process.resolve(names, request.ignore_features).bounds(names)

    def judged(sheet: Design) -> Verdict:
        return design_verdict(
            sheet,
            thickness,
            tolerance=request.tolerance,
            part=part,
            mm_per_unit=part.mm_per_unit,
            starts=request.starts,
        )

    if not simulate:
        unjudged, report = layered(design, request.layers, thickness, bounds)
        say(f"      {request.layers} layers of {process.layer_height_mm:g} mm: {NOT_JUDGED_LAYERS}")
        figures = {
            "metric alone": None,
            "share": 1.0,
            "refined": False,
            "refinement": None,
            "printed_refinement": None,
            "prints": [],
            "shares_tried": {},
            "layers_tried": {},
            "counts_printed": {},
            **report.to_dict(),
        }
        return Layered(unjudged, figures, None)
    how = (
        "the first-order layering refined against the simulation"
        if request.refine
        else "a share of the first-order layering"
    )
    say(
        f"      {request.layers} layers of {process.layer_height_mm:g} mm, programmed with "
        f"every target's curvature ({how}; docs/layers.md):"
    )
    tried, refinement, known = [], None, dict(request.missed)
    if request.refine:
        whole, _ = layered(design, request.layers, thickness, bounds)
        refinement = refine_layering(whole, bounds, part)
        say(f"        {refinement.summary()}")
        verdict = judged(refinement.design)
        say(f"        refined: {verdict.headline()}")
        report = layering_report(design, refinement.design, bounds)
        tried.append(("refined", 1.0, refinement.design, report, verdict))
    for share in () if tried and tried[0][4].formed else SHARES:
        candidate, report = layered(design, request.layers, thickness, bounds, share=share)
        verdict = known.get(share) or judged(candidate)
        tried.append((f"{share:g}", share, candidate, report, verdict))
        judged_from = ""
        if share in known:
            judged_from = f" (from {', '.join(end.start for end in verdict.shapes[0].starts)})"
        say(
            f"        {share:.0%}{', not refined' if request.refine else ''}: "
            f"{verdict.headline()}{judged_from}"
        )
        if verdict.formed:
            break
    label, share, chosen, report, verdict = max(
        tried, key=lambda t: (sum(s.formed for s in t[4].shapes), t[0] == "refined", t[1])
    )
    if label != "refined" and share in known:
        verdict = judged(chosen)  # the sheet printed is judged from every start
    say(f"      chosen: {'refined' if label == 'refined' else f'{share:.0%} of the layering'}")
    if label == "refined":
        say(
            "        what the refined layers program, by the first-order measures (the "
            "refinement aims at the simulated shapes, not at them):"
        )
    for line in report.lines():
        say(f"        {line}")
    figures = {
        "metric alone": None,
        "share": share,
        "refined": label == "refined",
        "refinement": None if refinement is None else refinement.to_dict(),
        "printed_refinement": None,
        "prints": [],
        "shares_tried": {t[0]: t[4].headline() for t in tried},
        "layers_tried": {},
        "counts_printed": {},
        **report.to_dict(),
    }
    missed = tuple((t[1], t[4]) for t in tried if t[0] != "refined" and not t[4].formed)
    return Layered(chosen, figures, verdict, missed)


def design_part(
    design: Design,
    size_mm: float,
    process: Process,
    layers: int = 1,
    request: PartRequest | None = None,
    thickness_mm: float | None = None,
) -> Part:
    """The part of a printed sheet (``fabkit run``): at ``size_mm`` (its longest side), for
    the process's road width and a sheet of ``layers`` of its layer height (or
    ``thickness_mm`` thick, when given)."""
    solved = solved_region(design)
    thickness_mm = layers * process.layer_height_mm if thickness_mm is None else thickness_mm
    options = (request or PartRequest()).for_process(
        process.road_width_mm, thickness_mm, MIN_WIDTH_ROADS
    )
    return part_of_size(design, size_mm, options, solved)


def _part(options: RunOptions, inputs: RunInputs, design: Design, layers: int) -> Part:
    """The part of the flat sheet that is made, at the run's size, for its process: the
    road width (a baromorph's: two channel pitches) and the sheet's thickness (``layers``
    of its layer height; a baromorph's part thickness) set the default minimum width and
    the trim."""
    if not options.baromorph:
        return design_part(design, options.size_mm, inputs.process, layers, options.part_request)
    settings = inputs.baromorph
    solved = solved_region(design)
    return part_of_size(
        design,
        options.size_mm,
        options.part_request.for_process(
            settings.pitch_mm, settings.part_thickness_mm, MIN_WIDTH_PITCHES
        ),
        solved,
    )
