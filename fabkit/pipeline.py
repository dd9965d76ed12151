"""``fabkit run``: spec to machine files in one go, by calling each stage in turn.

spec -> solve -> check -> pictures -> toolpath -> export (-> send). Every stage writes
through :func:`fabkit.atomic.atomic_path`, so an interrupted run leaves no half-written
file under a final name, and re-running into the same folder replaces the files whole.

Files in the output folder:

================== ==============================================================
design.npz/.json   the design and its solve summary (``fabkit solve``)
pictures/          flat sheet, eps, actuated surfaces, residual maps (PNG)
patches/           each actuated patch as a mesh (PLY)
toolpath/          toolpath.npz, quality.json, preview.png/svg (``fabkit toolpath``)
sheet.gcode        machine file(s), one per ``--format`` (``fabkit export``)
sheet.dxf          (with ``--format dxf``)
laser/             (with ``--format laser`` on a laser-writer profile)
report.html        every picture and the key figures in one page
report.json        the key figures as data
================== ==============================================================
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from fabkit.atomic import atomic_path
from fabkit.design.patches import write_patch_mesh
from fabkit.design.report import solve_to_file
from fabkit.errors import FabkitError
from fabkit.machines import load_machine
from fabkit.plot import render_design
from fabkit.plot.report import html_report
from fabkit.spec import load_spec
from fabkit.toolpath.job import ChannelJob, ToolpathJob, run_channel_job, run_job
from fabkit.writers.dxf import layout_layers, write_dxf
from fabkit.writers.export import ExportOptions, export

FORMAT_FILES = {"gcode": "sheet.gcode", "dxf": "sheet.dxf", "laser": "laser"}
DEFAULT_MACHINE = "marlin_diw_pneumatic"
BAROMORPH_MACHINE = "laser_cutter"
DEFAULT_SIZE_MM = 60.0


@dataclass(frozen=True)
class RunOptions:
    """What ``fabkit run`` is asked to do; ``size_mm`` is the sheet's longest side in mm."""

    spec: str
    out: str
    machine: str = DEFAULT_MACHINE
    formats: tuple[str, ...] = ("gcode",)
    size_mm: float = DEFAULT_SIZE_MM
    send: str | None = None
    process_file: str | None = None
    baromorph: str | None = None


def run_pipeline(options: RunOptions, say: Callable[[str], None] = print) -> dict[str, Any]:
    """Run every stage; returns the key figures (also written to report.json)."""
    for fmt in options.formats:
        if fmt not in FORMAT_FILES:
            raise FabkitError(f"--format {fmt}: expected one of {', '.join(FORMAT_FILES)}")
    if options.send and "gcode" not in options.formats:
        raise FabkitError("--send needs --format gcode")
    out = Path(options.out)
    spec = load_spec(options.spec)
    load_machine(options.machine)  # a bad profile is refused before any work

    say(f"[1/6] solving {options.spec}")
    result = solve_to_file(spec, out / "design.npz", "      solving")
    solution, check, solved = result.solution, result.check, result.summary
    say(
        f"      {solved['valid_points']} valid points in {solved['solve_seconds']:.2f} s; "
        f"check {'passed' if check.passed else 'FAILED'}"
    )

    say("[2/6] drawing pictures and patch meshes")
    pictures = render_design(solution.design, out / "pictures")
    meshes = _patch_meshes(solution.design, spec, out / "patches")

    if options.baromorph:
        fabricated = _channels(options, out, say)
    else:
        fabricated = _print_lines(options, out, say)

    sent = None
    if options.send:
        say(f"[5/6] sending sheet.gcode to {options.send}")
        from fabkit.link.send import send_file

        sent = send_file(out / "sheet.gcode", options.send, machine=options.machine).summary()
    else:
        say("[5/6] not sending (no --send)")

    say("[6/6] writing report.html and report.json")
    figures = {
        "spec": str(options.spec),
        "machine": options.machine,
        "solve": {k: solved[k] for k in ("solve_seconds", "valid_points", "areas", "stop_counts")},
        "check": check.to_dict(),
        **fabricated.figures,
        "sent": sent,
        "meshes": meshes,
    }
    html_report(
        f"fabkit run {Path(options.spec).name}",
        figures,
        pictures + [fabricated.picture],
        out / "report.html",
    )
    with atomic_path(out / "report.json") as tmp:
        tmp.write_text(json.dumps(figures, indent=2) + "\n", encoding="utf-8")
    return figures


@dataclass(frozen=True)
class _Fabricated:
    """Key figures of the fabrication stages and their preview (caption, PNG)."""

    figures: dict[str, Any]
    picture: tuple[str, Path]


def _print_lines(options: RunOptions, out: Path, say: Callable[[str], None]) -> _Fabricated:
    """Print lines along the director, then the machine files."""
    say(f"[3/6] planning print lines for {options.machine} at {options.size_mm:g} mm")
    job = run_job(
        ToolpathJob(
            inputs=(str(out / "design.npz"),),
            machine=options.machine,
            process_file=options.process_file,
            size_mm=options.size_mm,
            out=str(out / "toolpath"),
        )
    )
    say(f"[4/6] writing {', '.join(options.formats)}")
    exports = {
        fmt: export(
            _export_source(fmt, out),
            options.machine,
            fmt,
            out / FORMAT_FILES[fmt],
            _export_options(fmt, options),
        )
        for fmt in options.formats
    }
    figures = {
        "toolpath quality": [q.to_dict() for q in job.plan.quality],
        "toolpath warnings": list(job.plan.warnings),
        "exports": exports,
    }
    caption = "Print lines coloured by the encoded parameter (travels thin)"
    return _Fabricated(figures, (caption, out / "toolpath" / "preview.png"))


def _channels(options: RunOptions, out: Path, say: Callable[[str], None]) -> _Fabricated:
    """Baromorph channels whose width encodes eps, their mould, and a DXF for a cutter."""
    if options.formats != ("dxf",):
        raise FabkitError("a baromorph run writes DXF only: use --format dxf (or no --format)")
    say(f"[3/6] laying out baromorph channels at {options.size_mm:g} mm")
    fields = ToolpathJob(inputs=(str(out / "design.npz"),), size_mm=options.size_mm)
    result = run_channel_job(
        ChannelJob(fields=fields, baromorph=options.baromorph, out=str(out / "channels"))
    )
    say("[4/6] writing channels.dxf")
    drawing = write_dxf(
        out / "channels.dxf", machine=load_machine(options.machine), **layout_layers(result.layout)
    )
    figures = {
        "channels": asdict(result.report),
        "mould": str(out / "channels" / "mould.stl"),
        "exports": {"dxf": f"wrote {out / 'channels.dxf'}: {drawing}"},
    }
    caption = "Baromorph channels coloured by width (walls grey), inlet red"
    return _Fabricated(figures, (caption, out / "channels" / "channels.png"))


def _patch_meshes(design, spec, folder: Path) -> list[str]:
    names = []
    for j, target in enumerate(spec.targets):
        if target.surface.embed(target.start[None]) is not None:
            path = folder / f"{j}_{target.name}.ply"
            write_patch_mesh(design, j, path)
            names.append(str(path))
    return names


def _export_source(fmt: str, out: Path) -> Path:
    """G-code and DXF are written from the toolpath, laser patterns from the design."""
    return out / ("design.npz" if fmt == "laser" else "toolpath/toolpath.npz")


def _export_options(fmt: str, options: RunOptions) -> ExportOptions:
    return ExportOptions(size_mm=options.size_mm) if fmt == "laser" else ExportOptions()
