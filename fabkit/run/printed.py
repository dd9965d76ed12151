"""``fabkit run --refine``'s second round: the layers refined as printed.

A print does not make the design exactly: the print lines follow the director only as
closely as evenly spaced roads can (about a degree on average, several at the p95), and
the features are rounded to what a road carries. The verdict on the sheet as fabricated
runs every other start with that error turned over (:mod:`fabkit.mechanics.verdict`), so a
sheet formed as designed may still miss a target as printed (docs/layers.md: Fig. 1's
bump 0.28 % as designed, 2.71-3.70 % as fabricated).

:func:`refine_as_printed` prints the refined design in memory (the print lines planned and
the G-code written into a temporary folder, as the run does), reads every layer back as
``fabkit verify`` does, and refines the layers again with the print's error added and
turned over (:func:`fabkit.mechanics.refine.refine_layering` with ``fabricated``): the
error is taken to stay what it was when the design changes a little, which the sheet then
printed for real is judged on. The refined sheet is kept when its sheet as designed forms
as many targets as the one it refines.
"""

from __future__ import annotations

import tempfile
from dataclasses import replace
from pathlib import Path

from fabkit.field.design_field import feature_names
from fabkit.mechanics.refine import refine_layering
from fabkit.mechanics.verdict import design_verdict
from fabkit.run.fabricate import Drawings, Run, plan_print
from fabkit.run.solve import Solved
from fabkit.verify.machine_file import VerifyOptions, read_back
from fabkit.writers.export import write_machine_file


def refine_as_printed(run: Run) -> Solved:
    """``run.solved`` with its layers refined as printed (module docstring), or as it was
    when that forms fewer targets as designed or a feature is left out of the file."""
    solved, options, inputs, say = run.solved, run.options, run.inputs, run.say
    if options.ignore_features:
        say("      not refined as printed: a feature is left out of the machine file")
        return solved
    say("      refining as printed (the sheet printed, read back, its error in the loop):")
    design, process = solved.design, inputs.process
    with tempfile.TemporaryDirectory(prefix="fabkit-printed-") as folder:
        out = Path(folder)
        quiet = replace(run, options=replace(options, out=folder), drawings=Drawings(None))
        job = plan_print(quiet, out)
        write_machine_file(job.plan.toolpath, inputs.machine, "gcode", out / "sheet.gcode")
        check = VerifyOptions(
            machine=inputs.machine, process=process, part=solved.part, simulate=False
        )
        fields = read_back(out / "design.npz", out / "sheet.gcode", check, design).fields(check)
    names = feature_names(design)
    bounds = process.resolve(names, ()).bounds(names)
    refined = refine_layering(design, bounds, solved.part, fabricated=fields)
    say(f"        {refined.summary()}, the worse of the error and the error turned over")
    verdict = design_verdict(
        refined.design,
        tolerance=options.form_tolerance,
        part=solved.part,
        mm_per_unit=solved.part.mm_per_unit,
    )
    say(f"        refined as printed: {verdict.headline()}")
    before = sum(s.formed for s in solved.verdict.shapes) if solved.verdict else 0
    if sum(s.formed for s in verdict.shapes) < before:
        say("      kept the layers refined as designed: they form more targets as designed")
        return solved
    refined.design.save(run.out / "design.npz")
    layering = {**(solved.layering or {}), "printed_refinement": refined.to_dict()}
    return replace(solved, design=refined.design, layering=layering, verdict=verdict)
