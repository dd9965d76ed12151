"""``fabkit verify DESIGN MACHINE_FILE``: read the machine file back and check it.

The verify stage (:mod:`fabkit.verify`) is imported when the command runs, so that
building the parser stays cheap for every other command.
"""

from __future__ import annotations

import argparse
import json

from fabkit.commands import add_command
from fabkit.commands.toolpath import part_arguments, part_request
from fabkit.progress import ProgressBar, add_progress


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = add_command(subparsers, "verify")
    parser.add_argument("design", help="design file (.npz) written by fabkit solve")
    parser.add_argument(
        "machine_file", help="sheet.gcode, sheet.dxf, or a laser pattern folder (laser/)"
    )
    parser.add_argument(
        "--machine",
        metavar="NAME|FILE",
        help="machine profile (default: a laser folder's own, else marlin_diw_pneumatic)",
    )
    parser.add_argument(
        "--process", metavar="FILE", help="TOML whose [process] replaces the machine's"
    )
    parser.add_argument(
        "--baromorph",
        metavar="FILE",
        help="the channel settings of a baromorph drawing: read its channels (width and "
        "direction) instead of roads",
    )
    scale = parser.add_mutually_exclusive_group()
    scale.add_argument(
        "--size", type=float, metavar="MM", help="the sheet's longest side (default: the file's)"
    )
    scale.add_argument(
        "--scale", type=float, metavar="MM_PER_UNIT", help="mm per design unit (default: file's)"
    )
    parser.add_argument(
        "--offset",
        type=_numbers,
        metavar="X,Y",
        help="sheet origin on the machine, mm (default: the file's record)",
    )
    parser.add_argument(
        "--cell", type=float, metavar="MM", help="grid cell (default: road width / 4, or the pixel)"
    )
    parser.add_argument(
        "--ignore-feature",
        action="append",
        default=[],
        metavar="NAME",
        help="a feature the file leaves out on purpose (repeatable)",
    )
    simulation = parser.add_argument_group("simulation of the sheet as fabricated")
    simulation.add_argument(
        "--no-simulate", action="store_true", help="compare the fields only, simulate nothing"
    )
    simulation.add_argument(
        "--reference",
        action="store_true",
        help="also simulate the sheet as designed on the same mesh",
    )
    simulation.add_argument(
        "--stride",
        type=int,
        help="coarsen the design's grid by this for the simulations (default: about 800 triangles)",
    )
    simulation.add_argument(
        "--max-iterations",
        type=int,
        default=100,
        help="Newton iterations per ramp step (default %(default)s)",
    )
    simulation.add_argument(
        "--smoothing",
        type=float,
        metavar="MM",
        help="average the read-back fields over a Gaussian of MM before simulating "
        "(default: the larger of the road width and the sheet's thickness; 0: raw)",
    )
    part_arguments(parser)
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    add_progress(parser)
    parser.set_defaults(func=run)


def _numbers(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected X,Y in mm, got {text!r}") from None
    if len(values) != 2:
        raise argparse.ArgumentTypeError(f"expected X,Y in mm, got {text!r}")
    return values


def run(args: argparse.Namespace) -> int:
    from fabkit.verify.machine_file import VerifyOptions, verify

    options = VerifyOptions(
        machine=args.machine,
        process_file=args.process,
        size_mm=args.size,
        mm_per_unit=args.scale,
        offset_mm=args.offset,
        cell_mm=args.cell,
        ignore_features=tuple(args.ignore_feature),
        simulate=not args.no_simulate,
        reference=args.reference,
        stride=args.stride,
        max_iterations=args.max_iterations,
        smoothing_mm=args.smoothing,
        baromorph=args.baromorph,
        part_request=part_request(args),
    )
    bar = ProgressBar("simulating the sheet as made", force=args.progress)
    try:
        result = verify(args.design, args.machine_file, options, bar)
    finally:
        bar.close()
    print(json.dumps(result.to_dict(), indent=2) if args.json else result.table())
    return 0
