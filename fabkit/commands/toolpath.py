"""``fabkit toolpath``: print lines along the director, encoded, layered, with a quality report."""

from __future__ import annotations

import argparse
import sys

from fabkit.toolpath.job import ToolpathJob, run_job
from fabkit.toolpath.plan import PATTERNS


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "toolpath",
        help="print lines along the director of a design or director field (see docs/toolpath.md)",
        description="Evenly spaced print lines along the director, ordered, layered and "
        "encoded; writes toolpath.npz, quality.json and preview.png/svg into --out.",
    )
    parser.add_argument(
        "inputs",
        nargs="*",
        metavar="INPUT",
        help="design.npz or director .toml; several inputs stack (bottom layer first)",
    )
    source = parser.add_argument_group("director field without a design")
    source.add_argument(
        "--director", metavar="EXPR", help='theta(x, y) in rad, e.g. "arctan2(y, x)"'
    )
    source.add_argument(
        "--shape",
        metavar="SHAPE",
        help="disc:R, square:S, rect:W,H, annulus:R1,R2, ellipse:A,B (mm)",
    )
    source.add_argument("--eps", metavar="EXPR", help='eps(x, y) to encode, e.g. "0.2 + 0.01*r"')
    scale = parser.add_argument_group("design scale").add_mutually_exclusive_group()
    scale.add_argument("--size", type=float, metavar="MM", help="longest side of the sheet, mm")
    scale.add_argument("--scale", type=float, metavar="MM_PER_UNIT", help="mm per design unit")
    parser.add_argument(
        "--feature", type=int, default=0, help="eps feature of the design to encode (default 0)"
    )
    parser.add_argument("--clip", metavar="SHAPE", help="clip every outline by this shape (mm)")
    process = parser.add_argument_group("process")
    process.add_argument(
        "--machine", metavar="NAME|FILE", help="machine profile (default: marlin_diw_pneumatic)"
    )
    process.add_argument(
        "--process", metavar="FILE", help="TOML whose [process] replaces the machine's"
    )
    process.add_argument("--road-width", type=float, metavar="MM", help="override the road width w")
    process.add_argument(
        "--layer-height", type=float, metavar="MM", help="override the layer height"
    )
    process.add_argument("--no-encode", action="store_true", help="do not encode eps")
    process.add_argument(
        "--clip-eps", action="store_true", help="clip eps to the calibration table"
    )
    parser.add_argument("--layers", type=int, default=1, help="number of layers (default 1)")
    parser.add_argument("--pattern", choices=PATTERNS, default="same", help="layer pattern")
    parser.add_argument("--out", required=True, metavar="DIR", help="output folder")
    parser.add_argument("--json", action="store_true", help="also write toolpath.json")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    job = ToolpathJob(
        inputs=tuple(args.inputs),
        director=args.director,
        shape=args.shape,
        eps=args.eps,
        size_mm=args.size,
        mm_per_unit=args.scale,
        feature=args.feature,
        clip=args.clip,
        machine=args.machine,
        process_file=args.process,
        road_width_mm=args.road_width,
        layer_height_mm=args.layer_height,
        layers=args.layers,
        pattern=args.pattern,
        encode=not args.no_encode,
        clip_eps=args.clip_eps,
        out=args.out,
        json=args.json,
    )
    result = run_job(job)
    for warning in result.plan.warnings:
        print(f"fabkit: warning: {warning}", file=sys.stderr)
    for index, quality in enumerate(result.plan.quality):
        print(f"layer {index + 1}: {quality.summary()}")
    for path in result.files:
        print(f"wrote {path}")
    return 0
