"""``fabkit plot design.npz --out DIR``: pictures, patch meshes and an HTML report."""

from __future__ import annotations

import argparse
from pathlib import Path

from fabkit.commands import add_command, add_overwrite, in_out_folder
from fabkit.design.patches import MESH_TYPES


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = add_command(subparsers, "plot")
    parser.add_argument("design", help="design file (.npz) written by fabkit solve")
    parser.add_argument("--out", default="plots", help="output folder (default %(default)s)")
    parser.add_argument(
        "--mesh-format",
        default="ply",
        choices=list(MESH_TYPES),
        help="format of the patch meshes (default %(default)s)",
    )
    add_overwrite(parser)
    parser.set_defaults(func=run)


@in_out_folder
def run(args: argparse.Namespace) -> int:
    from fabkit.design.check import check_design
    from fabkit.design.design import Design
    from fabkit.design.patches import write_patch_meshes
    from fabkit.plot import render_design
    from fabkit.plot.html import html_report
    from fabkit.plot.page_sections import design_page

    design = Design.load(args.design)
    out = Path(args.out)
    pictures = render_design(design, out / "pictures")  # where fabkit run writes them
    patches = write_patch_meshes(design, out / "patches", args.mesh_format)
    meshes = [path.relative_to(out).as_posix() for path in patches]
    report = check_design(design)
    figures = {
        "valid points": int(design.valid.sum()),
        "grid step": design.step,
        "check passed": report.passed,
        "check": report.to_dict(),
        "meshes": meshes,
    }
    page = design_page(Path(args.design).name, figures, pictures, meshes, out)
    html_report(page, out / "report.html")
    for _, path in pictures:
        print(f"wrote {path}")
    print(f"wrote {', '.join(meshes)} and {out / 'report.html'}")
    return 0
