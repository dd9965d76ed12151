"""``fabkit run --refine``'s second round: the layers refined as printed, print by print.

A print does not make the design exactly: the print lines follow the director only as
closely as evenly spaced roads can (about a degree on average, several at the p95), and
the features are rounded to what a road carries. The verdict on the sheet as fabricated
runs every other start with that error turned over (:mod:`fabkit.mechanics.verdict`), so a
sheet formed as designed may still miss a target as printed (docs/layers.md: Fig. 1's
bump 0.28 % as designed, 2.71-3.70 % as fabricated).

:func:`refine_as_printed` prints the design in memory (the print lines planned and the
G-code written into a temporary folder, as the run does) and judges it as ``fabkit verify``
does: read back layer by layer and simulated from every start. While that print misses a
target, the layers are refined again with the error of every print so far added and
turned over (:func:`fabkit.mechanics.refine.refine_layering` with ``fabricated``), and the
refined design is printed and judged in turn, up to :data:`PRINTS` prints. One print's
error alone is not enough: a refined design prints with an error of its own, and on
Fig. 1 at 60 mm each round refined against the last print alone predicted the bump at
0.90 % and the next print made it 3.79 % and 3.74 % (stop 50); refined against both
prints' errors it predicted 1.01 % and the print made 1.36 %, formed. The run keeps the
design whose print formed the most targets (then the nearest), so the run's own print,
the same design through the same planner and writer, is judged as that print was. A
refinement is not printed when its sheet as designed forms fewer targets than the one
it refines.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from fabkit.design.design import Design
from fabkit.field.design_field import feature_names
from fabkit.mechanics.refine import Refined, refine_layering
from fabkit.mechanics.verdict import Verdict, design_verdict
from fabkit.run.fabricate import Run, print_in_memory
from fabkit.run.solve import Solved

PRINTS = 3
"""Most provisional prints judged: the refined design's, then up to two refined again with
the last print's error."""


@dataclass(frozen=True, eq=False)
class _Print:
    """A design printed in memory: its ``verdict`` as fabricated, the layers it read back
    (``fields``), the ``refinement`` that made the design and the verdict on its sheet as
    ``designed`` (both None: the first, the run's own)."""

    design: Design
    verdict: Verdict
    fields: list
    refinement: Refined | None = None
    designed: Verdict | None = None

    def rank(self) -> tuple[int, float]:
        """Its verdict's :meth:`~fabkit.mechanics.verdict.Verdict.rank`."""
        return self.verdict.rank()

    def to_dict(self) -> dict:
        """report.json's ``layers.prints`` item."""
        return {
            "headline": self.verdict.headline(),
            "formed": self.verdict.formed,
            "targets_formed": self.rank()[0],
            "rms_pct": [100 * s.rms for s in self.verdict.shapes],
        }


def refine_as_printed(run: Run) -> Solved:
    """``run.solved`` with its layers refined as printed (module docstring), or as it was
    when its print forms every target, a refinement forms fewer targets as designed, or a
    feature is left out of the file."""
    solved, options, say = run.solved, run.options, run.say
    if options.ignore_features:
        say("      not refined as printed: a feature is left out of the machine file")
        return solved
    say("      refining as printed (printed in memory, read back and judged from every start):")
    names = feature_names(solved.design)
    bounds = run.inputs.process.resolve(names, ()).bounds(names)
    least = sum(s.formed for s in solved.verdict.shapes) if solved.verdict else 0
    prints = [_printed(run, solved.design)]
    while len(prints) < PRINTS and not prints[-1].verdict.formed:
        say(f"        print {len(prints)}: {prints[-1].verdict.headline()}")
        made = [(p.design, p.fields) for p in prints]
        refined = refine_layering(prints[-1].design, bounds, solved.part, fabricated=made)
        say(f"        {refined.summary()}, the worst of {_errors(len(made))}")
        designed = design_verdict(
            refined.design,
            tolerance=options.form_tolerance,
            part=solved.part,
            mm_per_unit=solved.part.mm_per_unit,
        )
        if sum(s.formed for s in designed.shapes) < least:
            say(f"        not printed: as designed it forms fewer targets ({designed.headline()})")
            break
        prints.append(replace(_printed(run, refined.design), refinement=refined, designed=designed))
    say(f"        print {len(prints)}: {prints[-1].verdict.headline()}")
    number, best = max(enumerate(prints, 1), key=lambda item: item[1].rank())
    say(f"      kept print {number}'s design: its print forms the most targets, the nearest")
    layering = {
        **(solved.layering or {}),
        "printed_refinement": None if best.refinement is None else best.refinement.to_dict(),
        "prints": [p.to_dict() for p in prints],
    }
    if best.refinement is None:
        return replace(solved, layering=layering)
    best.design.save(run.out / "design.npz")
    return replace(solved, design=best.design, layering=layering, verdict=best.designed)


def _errors(count: int) -> str:
    """``the error and the error turned over`` (one print), ``2 prints' errors, each as
    printed and turned over``."""
    if count == 1:
        return "the error and the error turned over"
    return f"{count} prints' errors, each as printed and turned over"


def _printed(run: Run, design: Design) -> _Print:
    """``design`` printed in memory by the run's planner and writer, read back and judged
    as ``fabkit verify`` judges it (:func:`~fabkit.run.fabricate.print_in_memory`)."""
    verdict, fields = print_in_memory(run, design)
    return _Print(design, verdict, fields)
