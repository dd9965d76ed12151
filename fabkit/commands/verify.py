"""``fabkit verify DESIGN MACHINE_FILE``: read the machine file back and check it.

The verify stage (:mod:`fabkit.verify`) is imported when the command runs, so that
building the parser stays cheap for every other command.
"""

from __future__ import annotations

import argparse
import json

from fabkit import commands
from fabkit.commands.toolpath import part_arguments, part_request
from fabkit.mechanics.simulate import Settings
from fabkit.progress import ProgressBar, add_progress


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = commands.add_command(subparsers, "verify")
    parser.add_argument("design", help="design file (.npz) written by fabkit solve")
    parser.add_argument(
        "machine_file", help="sheet.gcode, sheet.dxf, or a laser pattern folder (laser/)"
    )
    commands.add_machine(
        parser,
        "machine profile (default: the one the file names in its header or manifest, else "
        "marlin_diw_pneumatic; the laser cutter for --baromorph)",
    )
    commands.add_process(parser, "TOML whose [process] replaces the machine's")
    parser.add_argument(
        "--baromorph",
        metavar="FILE",
        help="the channel settings of a baromorph drawing: read its channels (width and "
        "direction) instead of roads",
    )
    commands.add_scale(
        parser,
        "the part's longest side, as fabkit run --size (default: the file's scale)",
        "mm per design unit (default: file's)",
    )
    parser.add_argument(
        "--offset",
        type=commands.point_mm(2),
        metavar="X,Y",
        dest="offset_mm",
        help="sheet origin on the machine, mm (default: the file's record)",
    )
    commands.add_length(parser, "--cell", "grid cell (default: road width / 4, or the pixel)")
    commands.add_ignore_feature(parser, "a feature the file leaves out on purpose (repeatable)")
    simulation = parser.add_argument_group("simulation of the sheet as fabricated")
    simulation.add_argument(
        "--no-simulate",
        action="store_false",
        dest="simulate",
        help="compare the fields only, simulate nothing",
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
        default=Settings.max_iterations,
        help="Newton iterations per ramp step (default %(default)s)",
    )
    commands.add_length(
        simulation,
        "--smoothing",
        "average the read-back fields over a Gaussian of MM before simulating "
        "(default: the larger of the road width and the sheet's thickness; 0: raw)",
    )
    part_arguments(parser)
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    add_progress(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from fabkit.verify.machine_file import VerifyOptions, verify

    options = commands.call_with(
        VerifyOptions,
        args,
        part_request=part_request(args),
        process=commands.given_process(args),
        baromorph=commands.given_baromorph(args),
    )
    bar = ProgressBar("simulating the sheet as made", force=args.progress)
    try:
        result = verify(args.design, args.machine_file, options, bar)
    finally:
        bar.close()
    print(json.dumps(result.to_dict(), indent=2) if args.json else result.text())
    return 0
