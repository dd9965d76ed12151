"""The summary and the header of a G-code job (:mod:`fabkit.writers.gcode`): its figures
(:class:`GcodeSummary`: lengths, volume, E, time, bounds) from the checked rows, and the
header comments slicer viewers read (Cura's and PrusaSlicer's keys), fabkit's own, the
profile's start G-code and the E mode.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fabkit.machines import MachineProfile
from fabkit.toolpath.model import Toolpath
from fabkit.version import __version__
from fabkit.writers.gcode_checks import Kinematics
from fabkit.writers.gcode_rows import Paths, Rows, column_bounds
from fabkit.writers.gcode_setup import Setup

_FLAVOUR_NAMES = {
    "marlin": "Marlin",
    "klipper": "Klipper",
    "reprap": "RepRap",
    "grbl": "GRBL",
    "hyrel": "Hyrel",
}


@dataclass(frozen=True)
class GcodeSummary:
    """What was written: counts, lengths (mm), volume (mm^3), E total, time (s), bounds.

    ``duration_s`` and ``motion_lines`` are the file's as :func:`fabkit.gcode.duration.estimate`
    plans and counts them (moves and dwells, as the machine's planner runs them; homing
    and heating not counted): the one figure the header, the report, ``export`` and
    ``send`` quote."""

    lines: int
    motion_lines: int
    print_length_mm: float
    travel_length_mm: float
    volume_mm3: float
    e_total: float
    duration_s: float
    low_mm: tuple[float, float, float]
    high_mm: tuple[float, float, float]
    offset_mm: tuple[float, float, float]
    e_mode: str
    e_units: str
    nominal_e: bool = False


def lines_bytes(lines: list[str]) -> bytes:
    """Lines as ASCII bytes, each ended by a newline."""
    return "".join(f"{line}\n" for line in lines).encode("ascii")


def job_summary(rows: Rows, kin: Kinematics, paths: Paths, setup: Setup) -> GcodeSummary:
    """The job's figures from its rows; its ``lines``, ``motion_lines`` and
    ``duration_s`` are those of the whole file, set once it is rendered."""
    printing = paths.printing[rows.move[kin.rows]]
    length = np.nan_to_num(kin.length)
    e = rows.e_delta[kin.rows]
    low, high = column_bounds(kin.position[_printed(kin.position, printing)])
    return GcodeSummary(
        lines=0,
        motion_lines=0,
        print_length_mm=float(length[printing].sum()),
        travel_length_mm=float(length[~printing].sum()),
        volume_mm3=float(rows.volume.sum()),
        e_total=float(e[printing].sum()),
        duration_s=0.0,
        low_mm=tuple(low.tolist()),
        high_mm=tuple(high.tolist()),
        offset_mm=tuple(paths.offset.tolist()),
        e_mode=setup.e_mode,
        e_units=setup.e_units,
        nominal_e=setup.nominal_e,
    )


def _printed(position: np.ndarray, printing: np.ndarray) -> np.ndarray:
    """(n,) the kinematic rows whose position (n, 3) a printed road starts or ends at: the
    header's MINX ... MAXZ are the print's extent, as Cura writes them (the travel lift
    above the sheet is no part of it); every known position when nothing prints."""
    known = np.isfinite(position).all(axis=1)
    starts = np.zeros_like(printing)
    starts[:-1] = printing[1:]  # a road starts where the row before it ends
    drawn = (printing | starts) & known
    return drawn if drawn.any() else known


def header_bytes(
    summary: GcodeSummary, toolpath: Toolpath, machine: MachineProfile, setup: Setup
) -> bytes:
    """Header comments (Cura and PrusaSlicer keys), start G-code and the E mode."""
    low, high = summary.low_mm, summary.high_mm
    heights = sorted({layer.height_mm for layer in toolpath.layers})
    lines = [
        f";FLAVOR:{_FLAVOUR_NAMES.get(machine.flavour, machine.flavour)}",
        f";Generated with fabkit {__version__} for machine {machine.name}",
        f";TIME:{round(summary.duration_s)}",
    ]
    if setup.e_units == "filament":
        lines.append(f";Filament used: {summary.e_total / 1000:.5f}m")
    lines += [
        f";Layer height: {heights[0]:g}",
        f";LAYER_COUNT:{len(toolpath.layers)}",
        *(
            f";{key}:{value:.3f}"
            for key, value in zip(
                ("MINX", "MINY", "MINZ", "MAXX", "MAXY", "MAXZ"), (*low, *high), strict=True
            )
        ),
        f"; estimated printing time (normal mode) = {_duration_text(summary.duration_s)}",
        f"; filament used [cm3] = {summary.volume_mm3 / 1000:.4f}",
    ]
    if setup.e_units == "filament":
        lines.append(f"; filament used [mm] = {summary.e_total:.2f}")
    lines += [
        f";fabkit printing path {summary.print_length_mm:.3f} mm, non-printing path "
        f"{summary.travel_length_mm:.3f} mm, volume {summary.volume_mm3:.4f} mm^3, "
        f"time {summary.duration_s:.1f} s",
        f";fabkit E mode {setup.e_mode}, E units {setup.e_units}, "
        f"{setup.e_per_mm3:.6g} E per mm^3, offset "
        + ",".join(f"{v:.3f}" for v in summary.offset_mm)
        + " mm",
        ";fabkit channels: "
        + (
            ", ".join(f"{name} ({features or '?'})" for name, features in toolpath.channels.items())
            or "none"
        ),
        *_scale_line(toolpath),
    ]
    if setup.nominal_e:
        lines.append(
            ";fabkit nominal E: for G-code viewers only; the firmware ignores it (no hot "
            "extruder) and the valve G-code switches the flow"
        )
    lines += machine.render("start_gcode")
    if setup.has_e or setup.nominal_e:
        lines += ["M82", "G92 E0"] if setup.e_mode == "absolute" else ["M83"]
    return lines_bytes(lines)


def _scale_line(toolpath: Toolpath) -> list[str]:
    """``;fabkit scale: S mm per design unit`` when the toolpath comes from a design."""
    scale = toolpath.meta.get("mm_per_unit")
    if not isinstance(scale, int | float) or isinstance(scale, bool):
        return []
    return [f";fabkit scale: {scale:.9g} mm per design unit"]


def _duration_text(seconds: float) -> str:
    """``1h 2m 3s`` (PrusaSlicer's style)."""
    total = round(seconds)
    hours, rest = divmod(total, 3600)
    minutes, secs = divmod(rest, 60)
    parts = [f"{hours}h"] if hours else []
    if hours or minutes:
        parts.append(f"{minutes}m")
    return " ".join([*parts, f"{secs}s"])
