"""``fabkit compare SCAN RUN_DIR --target NAME``: a scan of the printed sheet against its
target, in the words of ``run``'s verdict (docs/compare.md).

The stage (:mod:`fabkit.scan`) and the picture are imported when the command runs, so
that building the parser stays cheap for every other command.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING

from fabkit import commands
from fabkit.errors import FabkitError

if TYPE_CHECKING:
    from fabkit.scan.compare import Compared
    from fabkit.scan.targets import Target

ALIGNED = "scan_aligned.ply"
PICTURE = "compare.png"
FIGURES = "compare.json"
"""The files written into --out."""


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = commands.add_command(subparsers, "compare")
    parser.add_argument("scan", help="the scan: a mesh or point cloud (PLY, STL, OBJ, OFF or GLB)")
    parser.add_argument(
        "run_dir", nargs="?", metavar="RUN_DIR", help="the --out folder of a fabkit run"
    )
    parser.add_argument("--target", metavar="NAME", help="the target (default: the only one)")
    parser.add_argument(
        "--design",
        metavar="FILE",
        help="a design (.npz) instead of a run: its target at the part's size --size",
    )
    commands.add_length(
        parser, "--size", "with --design: the part's longest side (default 60, as fabkit run)"
    )
    commands.add_machine(
        parser,
        "with --design: the machine it was made on, whose road width and layer height cut "
        "the part as fabkit run cuts it (default marlin_diw_pneumatic)",
    )
    commands.add_process(parser, "with --design: a TOML whose [process] replaces the machine's")
    parser.add_argument(
        "--units",
        choices=("mm", "cm", "m", "in"),
        default="mm",
        help="the scan's length unit (default %(default)s)",
    )
    parser.add_argument("--out", required=True, metavar="DIR", help="output folder")
    commands.add_overwrite(parser)
    parser.add_argument(
        "--form-tolerance",
        type=float,
        metavar="PCT",
        help="the scan forms the target within this RMS distance, %% of the patch diameter "
        "(default: the run's limit, else 3, as fabkit run)",
    )
    commands.add_strict(parser, "exit 1 when the scan does not form the target")
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    parser.set_defaults(func=run)


@commands.in_out_folder
def run(args: argparse.Namespace) -> int:
    from fabkit.scan.compare import compare_scan
    from fabkit.scan.read import check_extent, read_scan

    target, source = _target(args)
    scan = read_scan(args.scan, args.units)
    check_extent(scan, target.extent_mm, target.name, args.units)
    compared = compare_scan(scan, target, _tolerance(args.form_tolerance, target))
    verdict = compared.verdict
    picture = _picture(compared, target)
    figures = {
        "scan": str(args.scan),
        "source": source,
        "verdict": verdict.to_dict(),
        "motion": {
            "mirrored": compared.motion.mirrored,
            "rotation": compared.motion.rotation.tolist(),
            "translation_mm": compared.motion.translation.tolist(),
        },
        "files": {"aligned_scan": ALIGNED, "picture": PICTURE},
    }
    _write(Path(args.out), compared, picture, figures)
    if args.json:
        print(json.dumps(figures, indent=2))
    else:
        lines = verdict.lines()
        print("\n".join(lines[:-1]))
        print(f"wrote {PICTURE}, {ALIGNED} and {FIGURES} into {args.out}")
        print(lines[-1])  # the verdict, last
    return 1 if args.strict and not verdict.formed else 0


def _target(args: argparse.Namespace) -> tuple[Target, dict]:
    """The target compared with, and where it came from (compare.json's ``source``)."""
    from fabkit.field.part import DEFAULT_SIZE_MM
    from fabkit.scan.targets import design_target, run_target

    if (args.run_dir is None) == (args.design is None):
        raise FabkitError("give a run's folder (RUN_DIR) or --design design.npz, one of them")
    if args.design is None:
        given = [flag for flag, value in _DESIGN_ONLY if getattr(args, value) is not None]
        if given:
            raise FabkitError(f"{given[0]} goes with --design: a run's folder sets the part")
        return run_target(args.run_dir, args.target), {"run": str(args.run_dir)}
    size = DEFAULT_SIZE_MM if args.size_mm is None else args.size_mm
    process = commands.chosen_process(args)
    target = design_target(
        args.design, args.target, size, process.road_width_mm, process.layer_height_mm
    )
    return target, {"design": args.design, "size_mm": size}


_DESIGN_ONLY = (("--size", "size_mm"), ("--machine", "machine"), ("--process", "process_file"))
"""The options that only a design alone takes, and their destinations."""


def _tolerance(percent: float | None, target: Target) -> float:
    """The limit (a share of the patch diameter): ``--form-tolerance``, else the run's."""
    from fabkit.mechanics.verdict import FORM_TOLERANCE

    if percent is None:
        return FORM_TOLERANCE if target.tolerance is None else target.tolerance
    if not (0 < percent < 100):
        raise FabkitError(f"--form-tolerance {percent:g}: expected a percentage above 0, below 100")
    return percent / 100


def _picture(compared: Compared, target: Target) -> bytes:
    """The picture of the scan beside its target (:func:`fabkit.plot.scan.scan_picture`)."""
    from fabkit.plot.scan import scan_picture

    verdict = compared.verdict
    mirror = ", mirrored to fit" if verdict.mirrored else ""
    return scan_picture(
        target.mesh.vertices_mm,
        target.mesh.triangles,
        compared.points_mm,
        compared.point_distance_mm,
        verdict.rms_mm,
        verdict.limit_mm,
        f"{target.name}: the scan {verdict.scan} beside the target, coloured by its distance "
        f"to it (patch diameter {verdict.diameter_mm:.3g} mm)",
        f"the scan{mirror}: {verdict.status()}",
    )


def _write(out: Path, compared: Compared, picture: bytes, figures: dict) -> None:
    """The outputs, each atomically; the figures last (they name the others)."""
    from fabkit.files.atomic import atomic_path, inside
    from fabkit.mechanics.mesh import save_mesh

    values = {"distance_mm": compared.distance_mm}
    if compared.sheet_distance_mm is not None:
        values["sheet_distance_mm"] = compared.sheet_distance_mm
    save_mesh(inside(out, ALIGNED), compared.aligned_mm, compared.faces, values)
    with atomic_path(inside(out, PICTURE)) as tmp:
        tmp.write_bytes(picture)
    with atomic_path(inside(out, FIGURES)) as tmp:
        tmp.write_text(json.dumps(figures, indent=2) + "\n", encoding="utf-8")
