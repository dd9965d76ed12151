"""``fabkit check design.npz``: isometry and curvature residuals of a design."""

from __future__ import annotations

import argparse
import json
import math

from fabkit.commands import add_command, add_strict, call_with
from fabkit.design.check import Tolerances, check_design
from fabkit.design.design import Design
from fabkit.errors import FabkitError
from fabkit.mechanics.verdict import FORM_TOLERANCE


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = add_command(subparsers, "check")
    parser.add_argument("design", help="design file (.npz) written by fabkit solve")
    parser.add_argument("--json", action="store_true", help="print the report as JSON")
    tolerance_arguments(parser)
    parser.add_argument(
        "--region", type=float, help="check only points with |u|, |v| <= REGION (design units)"
    )
    shapes = parser.add_argument_group("which shape the sheet takes (simulated from flat)")
    shapes.add_argument(
        "--no-simulate",
        action="store_false",
        dest="simulate",
        help="only the residuals: do not simulate the sheet under every target's stimulus",
    )
    verdict_arguments(shapes, "exit 1 also when a target is not formed")
    parser.set_defaults(func=run)


def verdict_arguments(group: argparse._ActionsContainer, strict_help: str) -> None:
    """``--form-tolerance`` and ``--strict``, the verdict's options (``fabkit check``,
    ``fabkit run``); ``strict_help`` says what exits 1."""
    group.add_argument(
        "--form-tolerance",
        type=float,
        default=100 * FORM_TOLERANCE,
        metavar="PCT",
        help="a target is formed when the simulated sheet ends within this RMS distance, "
        "%% of the patch diameter (default %(default)g)",
    )
    add_strict(group, strict_help)


TOLERANCE_HELP = {
    "isometry_median": "tolerance on the median isometry residual",
    "isometry_p95": "tolerance on the 95th percentile",
    "curvature_median": "tolerance on the median curvature residual",
}
"""The help of each field of :class:`Tolerances`, an option ``--isometry-median`` etc."""


def _option(field: str) -> str:
    return "--" + field.replace("_", "-")


def tolerance_arguments(parser: argparse.ArgumentParser) -> None:
    """The check's tolerances as options (``fabkit check``, ``fabkit optimise``)."""
    defaults = Tolerances()
    group = parser.add_argument_group("the check's tolerances")
    for field, text in TOLERANCE_HELP.items():
        group.add_argument(
            _option(field),
            type=float,
            default=getattr(defaults, field),
            help=f"{text} (default %(default)g)",
        )


def tolerances(args: argparse.Namespace) -> Tolerances:
    """The tolerances of :func:`tolerance_arguments`, each a positive finite number."""
    for field in TOLERANCE_HELP:
        _positive(_option(field), getattr(args, field))
    return call_with(Tolerances, args)


def _positive(option: str, value: float | None) -> None:
    if value is not None and not (math.isfinite(value) and value > 0):
        raise FabkitError(f"{option} {value:g}: expected a positive finite number")


def run(args: argparse.Namespace) -> int:
    _positive("--region", args.region)
    if not (math.isfinite(args.form_tolerance) and 0 < args.form_tolerance < 100):
        raise FabkitError(f"--form-tolerance {args.form_tolerance:g}: expected 0 to 100 (%)")
    design = Design.load(args.design)
    report = check_design(design, tolerances(args), region=args.region)
    verdict = None
    if args.simulate:
        from fabkit.field.part import simulation_part
        from fabkit.mechanics.verdict import design_verdict

        thickness = design.layering.thickness if design.layering else None
        part, thickness = simulation_part(design, thickness)  # design units: no scale
        verdict = design_verdict(design, thickness, tolerance=args.form_tolerance / 100, part=part)
    if args.json:
        data = report.to_dict()
        data["as designed"] = verdict.to_dict() if verdict else None
        print(json.dumps(data, indent=2))
    else:
        print(report.table())
        if verdict is not None:
            made = (
                f"{design.layers} layers, {thickness:.4g} design units thick"
                if design.layering
                else f"one layer, {thickness:.4g} design units thick (1 % of its diameter)"
            )
            print(f"{verdict.headline()} ({made}, simulated from flat on its part):")
            print("\n".join(f"  {line}" for line in verdict.lines()))
    formed = verdict is None or verdict.formed
    return 0 if report.passed and (formed or not args.strict) else 1
