"""``fabkit run SPEC --out DIR``: solve, check, draw, plan, export (and send) in one go."""

from __future__ import annotations

import argparse

from fabkit import commands
from fabkit.commands.check import verdict_arguments
from fabkit.commands.toolpath import part_arguments, part_request
from fabkit.design.patches import MESH_TYPES
from fabkit.field.part import DEFAULT_SIZE_MM
from fabkit.machines import DEFAULT_MACHINE
from fabkit.run.inputs import BAROMORPH_MACHINE, FORMAT_FILES, RunOptions
from fabkit.run.pipeline import run_pipeline

NOT_REFINED = (
    "what would change it: --refine refines the layers against the simulation, as designed "
    "and as printed, the print's error in the loop (minutes; docs/layers.md)"
)
"""What a layered run whose sheet misses a target says before its verdict's lines,
unrefined (the last lines are the verdict's)."""


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = commands.add_command(subparsers, "run")
    parser.add_argument("spec", help="spec file (TOML), e.g. examples/two_shapes.toml")
    parser.add_argument("--out", required=True, metavar="DIR", help="output folder")
    commands.add_machine(
        parser,
        f"machine profile (default {DEFAULT_MACHINE}, or {BAROMORPH_MACHINE} with "
        "--baromorph; see fabkit machines)",
    )
    parser.add_argument(
        "--format",
        action="append",
        choices=list(FORMAT_FILES),
        dest="formats",
        help="machine file format, repeatable (default: dxf with --baromorph, laser on a "
        "laser writer, else gcode)",
    )
    commands.add_length(
        parser,
        "--size",
        "longest side of the part that is printed, mm (default %(default)g)",
        default=DEFAULT_SIZE_MM,
    )
    commands.add_process(
        parser, "TOML whose [process] table replaces the machine's (eps calibration)"
    )
    parser.add_argument(
        "--baromorph",
        metavar="FILE",
        help="lay out baromorph channels with these settings instead of print lines "
        "(writes channels/ and channels.dxf; default machine laser_cutter)",
    )
    parser.add_argument(
        "--step", type=float, help="solver grid step in u and v (default: the spec's)"
    )
    parser.add_argument(
        "--diagonals", type=int, help="solver diagonals per quadrant (default: the spec's)"
    )
    parser.add_argument(
        "--mesh-format",
        default="ply",
        choices=list(MESH_TYPES),
        help="format of the patch meshes in patches/ (default %(default)s)",
    )
    commands.add_ignore_feature(
        parser,
        "leave feature NAME out of the machine file on purpose (repeatable); without "
        "it a feature the process does not encode is an error",
    )
    parser.add_argument(
        "--no-verify",
        action="store_false",
        dest="verify",
        help="do not read the machine file back and check it (fabkit verify)",
    )
    parser.add_argument(
        "--no-pictures",
        action="store_false",
        dest="pictures",
        help="draw no pictures (pictures/, the toolpath preview, each target's picture of the "
        "shape the sheet takes): every file and figure else, sooner, for sweeps and scripts",
    )
    parser.add_argument(
        "--no-simulate",
        action="store_false",
        dest="simulate",
        help="do not simulate the sheet (as designed nor as fabricated): no verdict on the "
        "shapes it takes, as the run's first and last lines say; the residuals and the "
        "machine file are still checked",
    )
    parser.add_argument(
        "--send",
        metavar="PORT|URL",
        help="stream the G-code to a port or pyserial URL, e.g. sim://marlin, or print it "
        "through a printer host, e.g. octoprint+http://HOST:PORT (see fabkit send --host)",
    )
    parser.add_argument(
        "--layers",
        type=int,
        default=None,
        help="print the sheet in this many layers, their differences programmed with each "
        "target's curvature so that the sheet takes the target, not a mirror image or a "
        "neighbour; 1 prints one layer, which programs no target's side (default on a "
        "printer: 2 to 5 judged as designed, at most 1/30 of --size thick, and the "
        "thickest that forms every target 1 %% inside its limit printed, the next "
        "while its print misses a target (at most 3), then the nearest refined as "
        "printed as --refine does (minutes), as the run's first line says; 1 for laser "
        "writers and baromorphs)",
    )
    parser.add_argument(
        "--refine",
        action="store_true",
        help="refine the layers against the simulation (adjoint gradients, every target), "
        "as designed, then as printed: printed in memory, read back and judged from every "
        "start, refined again with every print's error while a print misses a target (up "
        "to 3 prints), the best print's design kept; minutes more (docs/layers.md)",
    )
    parser.add_argument(
        "--prints",
        type=int,
        default=1,
        metavar="K",
        help="judge K prints of the design as fabricated: the machine file's and K - 1 made "
        "in memory with the print lines shifted k/K of their spacing (equally good prints, "
        "their errors elsewhere); a target is formed only when every print forms it "
        "(default 1: the verdict is the machine file's print's; docs/layers.md)",
    )
    verdict_arguments(
        parser, "exit 1 when the sheet (as designed or as fabricated) does not form every target"
    )
    commands.add_api_key(parser)
    commands.add_overwrite(parser)
    part_arguments(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    options = commands.call_with(
        RunOptions,
        args,
        part_request=part_request(args),
        form_tolerance=args.form_tolerance / 100,
    )
    figures = run_pipeline(options)
    check = (
        "the design's check passed" if figures["check"]["passed"] else "the design's check FAILED"
    )
    verdict = figures["verdict"]
    missed = not all(v["formed"] for v in figures["verdicts"])
    layers = figures.get("layers")
    if missed and layers and not layers["refined"] and figures["verdicts"]:
        print(f"      {NOT_REFINED}")
    if verdict["lines"]:
        print(f"      the sheet {verdict['what']}:")
    for line in verdict["lines"]:
        print(f"        {line}")
    left_out = ""
    if args.ignore_features:  # the machine file cannot make the designed sheet: say so first
        names = ", ".join(args.ignore_features)
        left_out = f"NOT ENCODED in the machine file (--ignore-feature): {names}; "
    print(f"done: {left_out}{verdict['headline']}; {check}; see {args.out}/report.html")
    return 1 if args.strict and (missed or not figures["check"]["passed"]) else 0
