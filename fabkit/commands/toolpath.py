"""``fabkit toolpath``: print lines along the director, encoded, layered, with a quality report."""

from __future__ import annotations

import argparse
import sys

from fabkit import commands
from fabkit.field.part import PartRequest
from fabkit.process import Process
from fabkit.toolpath.job import ChannelJob, ToolpathJob, run_channel_job, run_job
from fabkit.toolpath.plan import PATTERNS


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = commands.add_command(subparsers, "toolpath")
    _field_arguments(parser, "design.npz or director .toml; several stack (bottom layer first)")
    process = parser.add_argument_group("process")
    commands.add_machine(process, "machine profile (default: marlin_diw_pneumatic)")
    commands.add_process(process, "TOML whose [process] replaces it")
    commands.add_length(process, "--road-width", "override road width w")
    commands.add_length(process, "--layer-height", "override layer height")
    process.add_argument(
        "--no-encode",
        action="store_false",
        dest="encode",
        help="encode no feature (each one left out)",
    )
    commands.add_ignore_feature(
        process,
        "leave feature NAME out of the encoding on purpose (repeatable); without it a "
        "feature the process does not encode is an error",
    )
    process.add_argument("--clip-eps", action="store_true", help="clip eps to the calibration")
    parser.add_argument(
        "--end-inset",
        type=float,
        default=0.45,
        metavar="FRACTION",
        help="line ends stop this fraction of w inside the outline (default 0.45; 0.5: "
        "roads strictly inside)",
    )
    parser.add_argument(
        "--layers",
        type=int,
        help="number of layers (default: a layered design's own, else one per input)",
    )
    parser.add_argument("--pattern", choices=PATTERNS, default="same", help="layer pattern")
    parser.add_argument("--out", required=True, metavar="DIR", help="output folder")
    parser.add_argument("--json", action="store_true", help="also write toolpath.json")
    commands.add_overwrite(parser)
    parser.set_defaults(func=run)

    channels = commands.add_command(subparsers, "channels")
    _field_arguments(channels, "design.npz or director .toml (one)")
    channels.add_argument(
        "--baromorph", required=True, metavar="FILE", help="TOML with a [baromorph] table"
    )
    channels.add_argument("--out", required=True, metavar="DIR", help="output folder")
    commands.add_overwrite(channels)
    channels.set_defaults(func=run_channels)


def _field_arguments(parser: argparse.ArgumentParser, inputs_help: str) -> None:
    parser.add_argument("inputs", nargs="*", metavar="INPUT", help=inputs_help)
    source = parser.add_argument_group("director field without a design")
    source.add_argument("--director", metavar="EXPR", help='theta(x, y), rad: "arctan2(y, x)"')
    source.add_argument(
        "--shape", metavar="SHAPE", help="disc:R, square:S, rect:W,H, annulus:R1,R2, ellipse:A,B"
    )
    source.add_argument("--eps", metavar="EXPR", help='eps(x, y), e.g. "0.2 + 0.01*r"')
    commands.add_scale(
        parser.add_argument_group("design scale"),
        "longest side of the part that is printed, mm (default 60, as fabkit run)",
        "mm per design unit",
    )
    part_arguments(parser)


def part_arguments(parser: argparse.ArgumentParser) -> None:
    """The options that cut a design's part (docs/part.md), shared by every command that
    makes one from a design (their defaults, None, are fabkit.field.part's: a test checks that
    the help states them)."""
    part = parser.add_argument_group("the part of a design that is made (docs/part.md)")
    part.add_argument(
        "--outline",
        metavar="SHAPE|FILE",
        help="intersect the part with a shape (disc:R, ...) or the closed paths of a "
        ".dxf, .svg, .geojson or .csv file (mm, sheet frame); clips a director field too",
    )
    commands.add_length(
        part,
        "--min-width",
        "remove parts narrower than this (default 4 road widths, channels 2 pitches; 0: keep them)",
    )
    part.add_argument(
        "--trim",
        type=float,
        metavar="N",
        help="remove regions narrower than N bending lengths sqrt(h R), too narrow to "
        "take their shape (h: the layers' height; default 4; 0: keep them)",
    )


def part_request(args: argparse.Namespace) -> PartRequest:
    """The part options of :func:`part_arguments`, as one value."""
    return commands.call_with(PartRequest, args)


def _job(args: argparse.Namespace, process: Process | None = None) -> ToolpathJob:
    """The job the options ask for, printed with ``process`` (``channels``: its field
    options alone)."""
    return commands.call_with(ToolpathJob, args, part_request=part_request(args), process=process)


@commands.in_out_folder
def run_channels(args: argparse.Namespace) -> int:
    settings = commands.given_baromorph(args)
    result = run_channel_job(ChannelJob(_job(args), settings, args.out))
    if result.part is not None:
        print(result.part.summary())
    print(result.report.summary())
    for path in result.files:
        print(f"wrote {path}")
    return 0


@commands.in_out_folder
def run(args: argparse.Namespace) -> int:
    result = run_job(_job(args, commands.chosen_process(args)))
    for warning in result.plan.warnings:
        print(f"fabkit: warning: {warning}", file=sys.stderr)
    for part in result.parts:
        print(part.summary())
    for index, quality in enumerate(result.plan.quality):
        print(f"layer {index + 1}: {quality.summary()}")
    for path in result.files:
        print(f"wrote {path}")
    return 0
