"""``fabkit run``: spec to machine files in one go, by calling each stage in turn.

spec -> solve -> check -> part -> pictures -> toolpath -> export -> verify (-> send).
With no ``--layers`` on a printer, a print that misses a target as verified hands over to
the next layer count whose sheet as designed forms every target, from the layering on,
and when none of their prints forms every target the nearest is refined as printed
(:func:`_printed`); nothing is sent before the print kept is known. The
part of the flat sheet that is made (:mod:`fabkit.field.part`: a smooth outline inside the
solved cells, trimmed of regions too narrow to take their shape, no narrower than the
minimum width, within ``--outline``) is cut once, right after the solve, and every later
stage takes it: the pictures, the print lines, channels or laser patterns, and the
verification. Every
feature of the design goes to the machine through its own channel of the process (a
feature the process does not encode is refused before any work, unless it is named with
``--ignore-feature``, which the report then says on its first line); the machine file is
then read back and checked (``fabkit verify``, skipped with ``--no-verify``). Every stage
writes
through :func:`fabkit.files.atomic.atomic_path`, so an interrupted run leaves no half-written
file under a final name. The output folder is claimed first
(:func:`fabkit.files.atomic.output_folder`): a folder holding an earlier run's files is refused
unless ``--overwrite``, which removes exactly the files that run wrote (listed in the
folder's ``.fabkit-files``); a folder holding files fabkit did not write is refused.

This module holds :func:`run_pipeline`, the order of the stages and the report; the
stages are :mod:`fabkit.run.inputs` (the options, their defaults and the checks before
any work), :mod:`fabkit.run.solve` (solve, check, the part, the layers, the verdict as
designed) and :mod:`fabkit.run.fabricate` (the machine files, verify, the shapes the
sheet takes, send).

Files in the output folder:

================== ==============================================================
design.npz/.json   the design and its solve summary (``fabkit solve``)
pictures/          flat sheet, eps, actuated surfaces, residual maps (PNG; none with
                   ``--no-pictures``, nor the toolpath preview nor as_fabricated/'s PNG)
patches/           each actuated patch as a mesh (PLY, or ``--mesh-format``)
toolpath/          toolpath.npz, quality.json, preview.png/svg (``fabkit toolpath``)
sheet.gcode        machine file(s), one per ``--format`` (``fabkit export``)
sheet.dxf          (with ``--format dxf``)
laser/             (with ``--format laser`` on a laser-writer profile)
as_fabricated/     per target, the sheet as fabricated beside it (PNG), as a mesh (PLY, mm)
                   and the target's mesh where the sheet is placed (NAME_target.ply);
                   ``as_designed/`` when the machine file is not simulated
report.html        the verdict first, then every picture and figure in words (one page)
report.json        the key figures as data (``docs/report.schema.json``)
================== ==============================================================
"""

from __future__ import annotations

import json
from collections.abc import Callable
from contextlib import nullcontext, suppress
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any

from fabkit.background import worker
from fabkit.design.patches import write_patch_meshes
from fabkit.errors import FabkitError
from fabkit.files.atomic import atomic_path, output_folder
from fabkit.machines import load_machine
from fabkit.mechanics.verdict import Verdict
from fabkit.plot import DESIGN_PICTURES, write_pictures
from fabkit.plot.html import html_report
from fabkit.plot.page_sections import run_page
from fabkit.plot.scene import scene
from fabkit.plot.view3d import shapes_3d
from fabkit.run.fabricate import Drawings, Made, Run, fabricate, send_stage
from fabkit.run.inputs import (
    RunInputs,
    RunOptions,
    check_inputs,
    ignored_notice,
    layers_notice,
    machine_name,
    with_defaults,
)
from fabkit.run.printed import refine_as_printed
from fabkit.run.solve import NOT_JUDGED_LAYERS, NOT_SIMULATED, Solved, layers_solved, solve_stage

WORKER_MODULES = ("fabkit.plot.design", "fabkit.toolpath.preview", "fabkit.plot.shapes")
"""What the worker imports while the run solves: the drawings it will be given."""


def run_pipeline(options: RunOptions, say: Callable[[str], None] = print) -> dict[str, Any]:
    """Run every stage; returns the key figures (also written to report.json).

    Every input (spec, options, machine, process and channel files, the output folder) is
    checked before any work, so bad input is refused without writing anything. The
    pictures are drawn in a spawned worker process (:mod:`fabkit.background`), which
    imports the calling script again: a script that calls this keeps its top level under
    ``if __name__ == "__main__":``, as for any spawned process.
    """
    machine = load_machine(machine_name(options))
    options = with_defaults(options, machine)
    inputs = check_inputs(options, machine)
    with output_folder(options.out, f"--out {options.out}", options.overwrite):
        return _stages(options, inputs, say)


def _stages(options: RunOptions, inputs: RunInputs, say: Callable[[str], None]) -> dict[str, Any]:
    """Every stage in turn, into the claimed output folder; returns the key figures.

    The design pictures, the toolpath preview and the pictures of the shapes the sheet
    takes are drawn in a second process (:mod:`fabkit.background`) while the later stages
    run, and written at the report (also when a later stage fails).
    """
    out = Path(options.out)
    notices = (ignored_notice(options), _not_simulated(options), layers_notice(options, inputs))
    notice = "; ".join(n for n in notices if n)
    if notice:
        say(f"      {notice}")
    with worker(warm=WORKER_MODULES) if options.pictures else nullcontext() as background:
        drawings = Drawings(background)
        if background is not None and options.simulate:
            # the shell's kernels compiled beside the solve: a first run after an install
            # would compile them at its first simulation (fabkit.mechanics.simulate)
            background.start("fabkit.mechanics.simulate:warm_kernels")
        solved = solve_stage(options, inputs, say)
        if options.refine and solved.design.layering is not None:
            solved = refine_as_printed(Run(options, inputs, solved, drawings, say))
        try:
            solved, made, meshes = _printed(Run(options, inputs, solved, drawings, say))
            sent = send_stage(Run(options, inputs, solved, drawings, say))
        except FabkitError:
            with suppress(Exception):  # the run fails with its own error; keep what it drew
                drawings.write()
            raise
        drawings.write()
    drawn = DESIGN_PICTURES if options.pictures else ()
    pictures = [(caption, out / "pictures" / name) for name, caption in drawn]

    say("[7/7] writing report.html and report.json")
    verification = made.verification.to_dict() if made.verification is not None else None
    figures = {
        **({"notice": notice} if notice else {}),
        "spec": str(options.spec),
        "machine": options.machine,
        "size_mm": options.size_mm,
        "solve": {
            k: solved.summary[k]
            for k in ("solve_seconds", "valid_points", "area_design_units2", "stop_counts")
        },
        "check": solved.check.to_dict(),
        "part": solved.part.to_dict(),
        **({"layers": solved.layering} if solved.layering else {}),
        "as designed": solved.verdict.to_dict() if solved.verdict is not None else None,
        **made.fabricated.figures,
        "machine file": made.machine_file,
        "verify": verification,
        **({"prints": made.prints} if made.prints else {}),
        "sent": sent,
        "meshes": meshes,
        "shapes": made.shapes,
    }
    verdicts = [solved.verdict] if solved.verdict is not None else []
    if made.final is not None and made.final is not solved.verdict:
        verdicts.append(made.final)
    figures["verdicts"] = [verdict.to_dict() for verdict in verdicts]
    figures["verdict"] = _verdict(made.final, figures["verdicts"])
    shapes = shapes_3d(made.final) if made.final is not None else ()
    page = run_page(figures, pictures, made.fabricated.picture, out, shapes)
    html_report(page, out / "report.html")
    with atomic_path(out / "report.json") as tmp:
        tmp.write_text(json.dumps(figures, indent=2) + "\n", encoding="utf-8")
    return figures


def _printed(run: Run) -> tuple[Solved, Made, list[str]]:
    """The design's pictures, patch meshes and machine files, verified (:func:`_made`);
    while the print misses a target and the run chose its layers, the next layer count
    whose sheet as designed forms every target (:attr:`Solved.fallbacks`) is layered and
    made in its place. The print that forms the most targets, nearest, is the one left in
    the folder (made again if a later one was not better); if it still misses a target,
    its layers are refined as printed (:func:`_refined_print`). Returns the print kept: the
    solved design, what was made and the patch meshes' paths."""
    options, inputs, say = run.options, run.inputs, run.say
    solved = run.solved
    made, meshes = _made(run)
    tries = [(solved, made, meshes)]
    while solved.fallbacks and _misses(made):
        choice = solved.fallbacks[0]
        say(
            f"      the print of {solved.design.layers} layers {made.final.outcome()}: printing "
            f"{choice.layers} layers, the next count whose sheet as designed forms every "
            "target (--layers K prints K)"
        )
        tried = (solved.layering or {}).get("layers_tried")
        remaining = replace(solved, fallbacks=solved.fallbacks[1:])
        solved = layers_solved(remaining, choice, options, inputs, say, tried)
        made, meshes = _made(replace(run, solved=solved))
        tries.append((solved, made, meshes))
    if len(tries) > 1:
        printed = {str(t[0].design.layers): t[1].final.outcome() for t in tries}
        best = max(tries, key=lambda t: t[1].final.rank())
        if best is not tries[-1]:
            solved = best[0]
            say(
                f"      no count's print forms every target: making {solved.design.layers} "
                "layers again, the print that formed the most, nearest"
            )
            solved.design.save(run.out / "design.npz")
            made, meshes = _made(replace(run, solved=solved))
        solved = replace(solved, layering={**(solved.layering or {}), "counts_printed": printed})
    # a run that judged several counts (a part too small for more than two gets two, as
    # they come: tests/test_auto_layers.py) refines the nearest; --refine did already
    chose = bool((solved.layering or {}).get("layers_tried")) and not options.refine
    if chose and _misses(made):
        return _refined_print(replace(run, solved=solved), made, meshes)
    return solved, made, meshes


def _refined_print(run: Run, made: Made, meshes: list[str]) -> tuple[Solved, Made, list[str]]:
    """The layers of the print kept refined as printed (:func:`~fabkit.run.printed.
    refine_as_printed`, ``--refine``'s second round) when no layer count's print formed
    every target; the refined design made in its place when a refinement is kept."""
    solved = run.solved
    run.say(
        f"      the print of {solved.design.layers} layers {made.final.outcome()}: refining "
        "its layers as printed (--refine's second round; minutes; --layers K prints K "
        "without it)"
    )
    refined = refine_as_printed(run)
    if refined.design is solved.design:  # no refinement printed better: the print stands
        return refined, made, meshes
    made, meshes = _made(replace(run, solved=refined))
    return refined, made, meshes


def _made(run: Run) -> tuple[Made, list[str]]:
    """The design's pictures and patch meshes, then its machine files, verified
    (:func:`~fabkit.run.fabricate.fabricate`); the patch meshes' paths."""
    drawing = "drawing pictures and" if run.options.pictures else "no pictures (--no-pictures);"
    run.say(f"[2/7] {drawing} patch meshes")
    design = run.solved.design
    run.drawings.draw(
        "fabkit.plot:draw_design",
        (scene(design, run.solved.part, run.solved.maps),),
        partial(write_pictures, folder=run.out / "pictures"),
    )
    folder = run.out / "patches"
    meshes = [str(path) for path in write_patch_meshes(design, folder, run.options.mesh_format)]
    return fabricate(run), meshes


def _misses(made: Made) -> bool:
    """Whether the machine file was read back and simulated and misses a target."""
    verified = made.verification is not None and made.final is not None
    return verified and not made.final.formed


def _not_simulated(options: RunOptions) -> str:
    if options.simulate:
        return ""
    return NOT_SIMULATED + (f"; {NOT_JUDGED_LAYERS}" if options.layers > 1 else "")


def _verdict(final: Verdict | None, verdicts: list[dict[str, Any]]) -> dict[str, Any]:
    """report.json's ``verdict``: the ``final`` verdict's headline and lines, formed when
    every one of ``verdicts`` is (None when nothing was simulated)."""
    if final is None:
        return {"what": "not simulated", "headline": NOT_SIMULATED, "formed": None, "lines": []}
    return {
        "what": final.what,
        "headline": final.headline(),
        "formed": all(v["formed"] for v in verdicts),
        "lines": final.lines(),
    }
