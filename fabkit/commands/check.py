"""``fabkit check design.npz``: isometry and curvature residuals of a design."""

from __future__ import annotations

import argparse
import json
import math

from fabkit.commands import add_command
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


def tolerance_arguments(parser: argparse.ArgumentParser) -> None:
    """The check's tolerances as options (``fabkit check``, ``fabkit optimise``)."""
    defaults = Tolerances()
    group = parser.add_argument_group("the check's tolerances")
    group.add_argument(
        "--isometry-median",
        type=float,
        default=defaults.isometry_median,
        help="tolerance on the median isometry residual (default %(default)g)",
    )
    group.add_argument(
        "--isometry-p95",
        type=float,
        default=defaults.isometry_p95,
        help="tolerance on the 95th percentile (default %(default)g)",
    )
    group.add_argument(
        "--curvature-median",
        type=float,
        default=defaults.curvature_median,
        help="tolerance on the median curvature residual (default %(default)g)",
    )


def tolerances(args: argparse.Namespace) -> Tolerances:
    """The tolerances of :func:`tolerance_arguments`, each a positive finite number."""
    options = {
        "--isometry-median": args.isometry_median,
        "--isometry-p95": args.isometry_p95,
        "--curvature-median": args.curvature_median,
    }
    for option, value in options.items():
        _positive(option, value)
    return Tolerances(args.isometry_median, args.isometry_p95, args.curvature_median)


def _positive(option: str, value: float | None) -> None:
    if value is not None and not (math.isfinite(value) and value > 0):
        raise FabkitError(f"{option} {value:g}: expected a positive finite number")


def run(args: argparse.Namespace) -> int:
    _positive("--region", args.region)
    report = check_design(Design.load(args.design), tolerances(args), region=args.region)
    print(json.dumps(report.to_dict(), indent=2) if args.json else report.table())
    return 0 if report.passed else 1
