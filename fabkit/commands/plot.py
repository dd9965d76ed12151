"""``fabkit plot design.npz --out DIR``: pictures, patch meshes and an HTML report."""

from __future__ import annotations

import argparse
from pathlib import Path

from fabkit.design.check import check_design
from fabkit.design.design import Design
from fabkit.design.patches import write_patch_mesh
from fabkit.plot import render_design
from fabkit.plot.report import html_report
from fabkit.spec import spec_from_json


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "plot", help="draw a design: pictures, actuated patches as meshes, HTML report"
    )
    parser.add_argument("design", help="design file (.npz) written by fabkit solve")
    parser.add_argument("--out", default="plots", help="output folder (default %(default)s)")
    parser.add_argument("--mesh-format", default="ply", choices=["ply", "stl", "glb", "obj"])
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    design = Design.load(args.design)
    out = Path(args.out)
    pictures = render_design(design, out)
    spec = spec_from_json(design.spec)
    meshes = []
    for j, target in enumerate(spec.targets):
        if target.surface.embed(target.start[None]) is not None:
            path = out / f"patch_{j}_{target.name}.{args.mesh_format}"
            write_patch_mesh(design, j, path)
            meshes.append(path.name)
    report = check_design(design)
    figures = {
        "valid points": int(design.valid.sum()),
        "grid step": design.step,
        "check passed": str(report.passed),
        "residuals (median / p95)": report.table(),
        "meshes": ", ".join(meshes),
    }
    html_report(f"fabkit design {Path(args.design).name}", figures, pictures, out / "report.html")
    for _, path in pictures:
        print(f"wrote {path}")
    print(f"wrote {', '.join(meshes)} and {out / 'report.html'}")
    return 0
