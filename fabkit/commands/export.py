"""``fabkit export INPUT --machine NAME --format gcode|dxf|laser -o OUT``.

The writers (ezdxf, PIL, the director fields) are imported when the command runs, so that
building the parser stays cheap for every other command.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from fabkit.commands import add_command, add_overwrite
from fabkit.commands.toolpath import part_arguments, part_request
from fabkit.machines import RELATIONS
from fabkit.writers.common import FORMATS, IMAGE_FORMATS
from fabkit.writers.gcode import E_MODES, E_UNITS, GcodeOptions


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = add_command(subparsers, "export")
    parser.add_argument("input", help="toolpath (.npz/.json), design.npz or director .toml")
    parser.add_argument("--machine", required=True, help="profile name or .toml path")
    parser.add_argument("--format", required=True, choices=FORMATS)
    parser.add_argument("-o", "--out", required=True, help="output file (laser: a directory)")
    add_overwrite(parser, "-o (laser: a directory)")
    parser.add_argument(
        "--offset",
        type=_numbers,
        help="X,Y[,Z]: sheet origin on the machine (mm); default: centred on the bed",
    )
    design = parser.add_argument_group("design input")
    design.add_argument("--size", type=float, help="longest side of the flat sheet (mm)")
    design.add_argument("--scale", type=float, help="mm per design unit")
    design.add_argument(
        "--ignore-feature",
        action="append",
        default=[],
        metavar="NAME",
        help="laser: leave feature NAME out on purpose (repeatable)",
    )
    design.add_argument(
        "--process", metavar="FILE", help="laser: TOML whose [process] replaces the machine's"
    )
    part_arguments(parser)
    gcode = parser.add_argument_group("gcode")
    gcode.add_argument("--e-mode", choices=E_MODES, help="default: the profile's start G-code")
    gcode.add_argument("--e-units", choices=E_UNITS, help="default: filament (hyrel: volume)")
    gcode.add_argument("--filament-diameter", type=float, help="mm (default 1.75)")
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
        default=GcodeOptions.retract_min_travel_mm,
        help="shorter travels neither lift nor retract (mm, default %(default)g)",
    )
    dxf = parser.add_argument_group("dxf")
    dxf.add_argument("--geometry", type=Path, help="GeoJSON with outline/channels/inlet layers")
    dxf.add_argument("--inlet-radius", type=float, default=0.5, help="mm (default %(default)g)")
    laser = parser.add_argument_group("laser")
    laser.add_argument("--pixel", type=float, help="pixel pitch (mm); default from the profile")
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


def _numbers(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected X,Y or X,Y,Z in mm, got {text!r}") from None
    if len(values) not in (2, 3):
        raise argparse.ArgumentTypeError(f"expected X,Y or X,Y,Z in mm, got {text!r}")
    return values


def run(args: argparse.Namespace) -> int:
    from fabkit.toolpath.process import load_process
    from fabkit.writers.export import ExportOptions, export

    options = ExportOptions(
        offset_mm=args.offset,
        size_mm=args.size,
        mm_per_unit=args.scale,
        process=load_process(args.process) if args.process else None,
        ignore_features=tuple(args.ignore_feature),
        part_request=part_request(args),
        gcode=GcodeOptions(
            e_mode=args.e_mode,
            e_units=args.e_units,
            filament_diameter_mm=args.filament_diameter,
            pulses_per_mm3=args.pulses_per_mm3,
            retract_min_travel_mm=args.min_travel,
            nominal_e=args.nominal_e,
        ),
        geometry=args.geometry,
        inlet_radius_mm=args.inlet_radius,
        pixel_mm=args.pixel,
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
    from fabkit.atomic import output_folder, record

    with output_folder(args.out, f"-o {args.out}", args.overwrite, whole=True):
        summary = export(args.input, args.machine, args.format, args.out, options)
        record(args.out)
    print(summary)
    return 0
