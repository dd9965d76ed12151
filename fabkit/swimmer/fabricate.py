"""Make the swimmer: both layers' print lines (bottom first) and the machine file.

The ``[fabrication]`` table of the swimmer spec picks the machine profile and optional
process overrides; each layer of the spec becomes an equal block of printed layers whose
lines follow that layer's director (the toolpath stage, :mod:`fabkit.toolpath.plan`),
and the toolpath is written as G-code for the machine (:mod:`fabkit.writers.export`).
The number of printed layers is the sheet thickness over the layer height, rounded to a
multiple of the number of spec layers.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from fabkit.field.flat import field_from_expression
from fabkit.field.outlines import parse_shape
from fabkit.files.tomlfile import Table
from fabkit.machines import DEFAULT_MACHINE
from fabkit.swimmer.spec import SwimmerSpec
from fabkit.toolpath.model import save_toolpath
from fabkit.toolpath.plan import PATTERNS, PlanSettings, plan_toolpath
from fabkit.toolpath.process_file import machine_process
from fabkit.writers.export import export


@dataclass(frozen=True)
class Fabrication:
    """``machine`` profile name or path; ``road_width_mm`` and ``layer_height_mm``
    override the profile's process (None: keep it); ``pattern`` "same" or "alternate"."""

    machine: str = DEFAULT_MACHINE
    road_width_mm: float | None = None
    layer_height_mm: float | None = None
    pattern: str = "alternate"


@dataclass(frozen=True)
class Made:
    """Files written and one line per fact worth printing."""

    files: tuple[Path, ...]
    lines: tuple[str, ...]


def fabrication_settings(t: Table) -> Fabrication:
    """Validate the ``[fabrication]`` table (all keys optional)."""
    t.check_keys({"machine", "road_width_mm", "layer_height_mm", "pattern"})
    machine = t.get("machine", DEFAULT_MACHINE)
    if not isinstance(machine, str):
        t.expected("machine", "a profile name or path", machine)
    pattern = t.text("pattern", PATTERNS, default="alternate")
    overrides = {
        key: t.number(key, positive=True)
        for key in ("road_width_mm", "layer_height_mm")
        if key in t
    }
    return Fabrication(machine=machine, pattern=pattern, **overrides)


def fabricate(spec: SwimmerSpec, out: Path) -> Made:
    """Plan both layers' lines and write ``toolpath.npz``, ``preview.png`` and G-code."""
    settings = fabrication_settings(spec.fabrication)
    process = machine_process(settings.machine).with_overrides(
        road_width_mm=settings.road_width_mm, layer_height_mm=settings.layer_height_mm
    )
    outline = parse_shape(f"disc:{spec.radius:.12g}", "sheet.radius")
    fields = [
        field_from_expression(layer.director, outline, where=f"layer '{layer.name}'")
        for layer in spec.layers
    ]
    count = len(spec.layers)
    per_layer = max(1, round(spec.thickness / (count * process.layer_height_mm)))
    plan = plan_toolpath(fields, process, PlanSettings(count * per_layer, settings.pattern))
    toolpath_file, preview_file = out / "toolpath.npz", out / "preview.png"
    gcode_file = out / "swimmer.gcode"
    save_toolpath(plan.toolpath, toolpath_file)
    from fabkit.toolpath.preview import save_preview  # matplotlib: only when drawing

    save_preview(plan.toolpath, [f.outline for f in fields], [preview_file])
    written = export(toolpath_file, settings.machine, "gcode", gcode_file).summary
    printed = count * per_layer * process.layer_height_mm
    lines = [
        f"toolpath: {count * per_layer} printed layers ({per_layer} per sheet layer, bottom "
        f"first), road width {process.road_width_mm:g} mm, printed thickness {printed:g} mm "
        f"(spec {spec.thickness:g} mm)",
        *(f"warning: {w}" for w in plan.warnings),
        written,
    ]
    return Made((toolpath_file, preview_file, gcode_file), tuple(lines))
