"""``fabkit export INPUT --machine NAME --format gcode|dxf|laser -o OUT``.

The writers (ezdxf, PIL, the director fields) are imported when the command runs, so that
building the parser stays cheap for every other command.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from fabkit import commands
from fabkit.commands.toolpath import part_arguments, part_request
from fabkit.machines import RELATIONS
from fabkit.writers.common import FORMATS, IMAGE_FORMATS
from fabkit.writers.gcode_setup import E_MODES, E_UNITS, GcodeOptions


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = commands.add_command(subparsers, "export")
    parser.add_argument("input", help="toolpath (.npz/.json), design.npz or director .toml")
    parser.add_argument("--machine", required=True, help="profile name or .toml path")
    parser.add_argument("--format", required=True, choices=FORMATS)
    parser.add_argument("-o", "--out", required=True, help="output file (laser: a directory)")
    commands.add_overwrite(parser, "-o (laser: a directory)")
    parser.add_argument(
        "--offset",
        type=commands.point_mm(2, 3),
        metavar="OFFSET",
        dest="offset_mm",
        help="X,Y[,Z]: sheet origin on the machine (mm); default: centred on the bed",
    )
    design = parser.add_argument_group("design input")
    commands.add_length(
        design, "--size", "longest side of the part that is made (mm; default 60, as fabkit run)"
    )
    design.add_argument(
        "--scale", type=float, metavar="MM_PER_UNIT", dest="mm_per_unit", help="mm per design unit"
    )
    commands.add_ignore_feature(design, "laser: leave feature NAME out on purpose (repeatable)")
    commands.add_process(design, "laser: TOML whose [process] replaces the machine's")
    part_arguments(parser)
    gcode = parser.add_argument_group("gcode")
    gcode.add_argument("--e-mode", choices=E_MODES, help="default: the profile's start G-code")
    gcode.add_argument("--e-units", choices=E_UNITS, help="default: filament (hyrel: volume)")
    commands.add_length(gcode, "--filament-diameter", "mm (default 1.75)")
    gcode.add_argument("--pulses-per-mm3", type=float, help="pulse extruder calibration")
    gcode.add_argument(
        "--nominal-e",
        action="store_true",
        default=None,
        help="a Marlin valve machine: also write E (the roads' volume as filament) that the "
        "firmware ignores, so that slicer viewers show the roads as extrusions (default: "
        "the profile's [tool] nominal_e)",
    )
    gcode.add_argument(
        "--min-travel",
        type=float,
        metavar="MM",
        dest="retract_min_travel_mm",
        default=GcodeOptions.retract_min_travel_mm,
        help="shorter travels neither lift nor retract (mm, default %(default)g)",
    )
    dxf = parser.add_argument_group("dxf")
    dxf.add_argument("--geometry", type=Path, help="GeoJSON with outline/channels/inlet layers")
    commands.add_length(dxf, "--inlet-radius", "mm (default %(default)g)", default=0.5)
    laser = parser.add_argument_group("laser")
    commands.add_length(laser, "--pixel", "pixel pitch (mm); default from the profile")
    laser.add_argument("--bins", type=int, help="director angle bins (default 18)")
    laser.add_argument("--dose-levels", type=int, help="dose levels (default 4)")
    laser.add_argument("--dose", type=float, help="constant dose (mJ/cm^2)")
    laser.add_argument("--relation", choices=RELATIONS, help="director vs polarisation")
    laser.add_argument("--polarisation", type=float, help="input polarisation angle (deg)")
    laser.add_argument("--intensity", type=float, help="mW/cm^2, for exposure times")
    laser.add_argument("--scan-speed", type=float, help="mm/s (scanning writers)")
    laser.add_argument("--max-power", type=float, help="mW (scanning writers)")
    laser.add_argument("--image-format", choices=IMAGE_FORMATS, help="png (default) or tiff")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from fabkit.writers.export import ExportOptions, export

    options = commands.call_with(
        ExportOptions,
        args,
        process=commands.given_process(args),
        part_request=part_request(args),
        gcode=commands.call_with(GcodeOptions, args),
        laser={
            "bins": args.bins,
            "dose_levels": args.dose_levels,
            "dose": args.dose,
            "relation": args.relation,
            "input_polarisation_deg": args.polarisation,
            "intensity_mw_cm2": args.intensity,
            "scan_speed_mm_s": args.scan_speed,
            "max_power_mw": args.max_power,
            "image_format": args.image_format,
        },
    )
    if args.format != "laser":
        print(export(args.input, args.machine, args.format, args.out, options))
        return 0
    from fabkit.files.atomic import output_folder, record

    with output_folder(args.out, f"-o {args.out}", args.overwrite, whole=True):
        summary = export(args.input, args.machine, args.format, args.out, options)
        record(args.out)
    print(summary)
    return 0
