"""``fabkit check design.npz``: isometry and curvature residuals of a design."""

from __future__ import annotations

import argparse
import json
import math

from fabkit.commands import add_command, call_with
from fabkit.design.check import Tolerances, check_design
from fabkit.design.design import Design
from fabkit.errors import FabkitError


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = add_command(subparsers, "check")
    parser.add_argument("design", help="design file (.npz) written by fabkit solve")
    parser.add_argument("--json", action="store_true", help="print the report as JSON")
    tolerance_arguments(parser)
    parser.add_argument(
        "--region", type=float, help="check only points with |u|, |v| <= REGION (design units)"
    )
    parser.set_defaults(func=run)


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
    report = check_design(Design.load(args.design), tolerances(args), region=args.region)
    print(json.dumps(report.to_dict(), indent=2) if args.json else report.table())
    return 0 if report.passed else 1
