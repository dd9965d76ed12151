"""``fabkit optimise SPEC --out best.toml``: search the initial data for the most coverage."""

from __future__ import annotations

import argparse
import sys

from fabkit import commands
from fabkit.commands.check import tolerance_arguments, tolerances


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = commands.add_command(subparsers, "optimise")
    parser.add_argument("spec", help="spec file (TOML); [optimise.parameters] declares parameters")
    parser.add_argument("--out", default="best.toml", help="best spec to write (.toml)")
    parser.add_argument(
        "--vary",
        action="append",
        default=[],
        metavar="KEY=LO:HI",
        help="vary KEY between LO and HI (repeatable): a parameter, initial.eps[i], "
        "initial.slope[i], surfaces.NAME.start[k], surfaces.NAME.director[k]",
    )
    parser.add_argument(
        "--objective",
        choices=("flat", "smallest"),
        help="flat: area covered on the flat sheet; smallest: the smallest covered area "
        "over the targets (default: the spec's [optimise] objective, else flat)",
    )
    budget = parser.add_argument_group("budget")
    budget.add_argument("--generations", type=int, default=30, help="generations (default 30)")
    budget.add_argument(
        "--popsize", type=int, default=10, help="candidates per varied key (default 10)"
    )
    budget.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    budget.add_argument(
        "--batch", type=int, default=8, help="candidates solved together per task (default 8)"
    )
    pool = parser.add_argument_group("where it runs")
    pool.add_argument("--workers", type=int, help="worker processes (default: every core)")
    pool.add_argument(
        "--dask",
        metavar="ADDRESS",
        help="a Dask scheduler (tcp://host:8786), or 'local' for a LocalCluster of --workers",
    )
    pool.add_argument(
        "--checkpoint", metavar="FILE", help="checkpoint (default: OUT's stem + .checkpoint.json)"
    )
    process = parser.add_argument_group("count only what a process can make")
    commands.add_machine(process, "machine profile whose process")
    commands.add_process(process, "TOML with a [process] table")
    process.add_argument(
        "--scale", type=float, metavar="MM_PER_UNIT", help="mm per design unit (with a process)"
    )
    process.add_argument(
        "--min-width", type=float, metavar="MM", help="narrowest part (default: the road width)"
    )
    commands.add_ignore_feature(process, "a feature the process need not encode (repeatable)")
    tolerance_arguments(parser)  # a candidate counts only when its design passes them
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from fabkit.optimise.run import Job, optimise
    from fabkit.optimise.search import Budget

    for option in ("generations", "popsize", "batch", "workers"):
        value = getattr(args, option)
        if value is not None and value < 1:
            raise _error(f"--{option} {value}: expected a positive integer")
    job = Job(
        spec=args.spec,
        out=args.out,
        varies=tuple(args.vary),
        objective=args.objective,
        limits=_limits(args),
        budget=Budget(args.generations, args.popsize, args.seed, args.batch),
        workers=args.workers or 0,
        dask=args.dask,
        checkpoint=args.checkpoint,
        tolerances=tolerances(args),
    )
    outcome = optimise(job, report=lambda line: print(line, file=sys.stderr, flush=True))
    summary = outcome.summary
    again = summary["best_solved_again"]
    ratio = summary["ratio"]
    print(
        f"{summary['objective']} objective: spec as given {summary['start']['value']:.4g}, "
        f"best {summary['best']['value']:.4g}"
        + (f" ({ratio:.2f}x)" if ratio else "")
        + f"; {summary['computed']} evaluations computed, {summary['replayed']} from the "
        f"checkpoint, {summary['seconds']:.1f} s, {summary['evaluations_per_second']:.1f}/s "
        f"on {summary['pool']['workers']} worker(s)"
    )
    print(
        f"best solved again: {again['valid_points']} valid points, check "
        f"{'passed' if again['check']['passed'] else 'FAILED'}"
    )
    for path in outcome.files:
        print(f"wrote {path}")
    return 0


def _limits(args: argparse.Namespace):
    """The process's limits, or None without --machine / --process."""
    if not (args.machine or args.process_file):
        for option in ("scale", "min_width"):
            if getattr(args, option) is not None:
                name = option.replace("_", "-")
                raise _error(f"--{name} applies with --machine or --process only")
        return None
    from fabkit.optimise.objective import process_limits
    from fabkit.problem.spec import load_spec

    if args.scale is None or not 0 < args.scale < float("inf"):
        raise _error("--machine/--process: give --scale MM_PER_UNIT (> 0) to compare widths")
    if args.min_width is not None and not 0 <= args.min_width < float("inf"):
        raise _error(f"--min-width {args.min_width}: expected a width >= 0 (mm)")
    process = commands.chosen_process(args)
    features = load_spec(args.spec).material.features
    return process_limits(process, features, args.scale, args.min_width, args.ignore_features)


def _error(message: str):
    from fabkit.errors import FabkitError

    return FabkitError(message)
