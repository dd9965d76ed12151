"""G-code writer: a :class:`~fabkit.toolpath.model.Toolpath` as a machine's G-code file.

The toolpath (sheet frame, mm, mm/s) is placed on the machine (see
:mod:`fabkit.writers.common`) and turned into one table of rows, built with numpy for
all moves at once and formatted by :func:`fabkit.writers.line_table.render`:

* travels: retraction (E-axis machines), lift to ``max z + travel_lift_mm``, ``G0`` along
  the travel polyline, lowering, un-retraction. Travels shorter than
  ``retract_min_travel_mm`` neither lift nor retract. A print move that does not start
  where the previous move ended gets such a travel inserted.
* prints: ``G1`` to every vertex with ``F`` = speed x 60 (mm/min) and, on E-axis
  machines, E from the deposited volume ``length x width x layer height x flow`` (mm^3):
  E = volume x 4 / (pi d^2) for filament of diameter d, E = volume for ``volume`` units,
  E = volume x pulses per mm^3 for a pulse extruder. Absolute (M82) or relative (M83) E;
  relative values are differences of the rounded running total, so they add up exactly.
* machines without an E axis (pneumatic dispensers, beams: the profile's
  ``flow_on_gcode`` is not empty) get ``flow_on_gcode`` before and ``flow_off_gcode``
  after every print move; at constant pressure the volume per mm goes as 1 / speed, so
  the flow multiplier is written as feed = speed / flow. With *nominal E* (``[tool]
  nominal_e``, ``fabkit export --nominal-e``; Marlin only) such a machine's print moves
  also carry E, the road's volume as filament of ``filament_diameter_mm`` (M83 or M82),
  so that slicer G-code viewers draw the roads as extrusions of their width; the
  firmware ignores it (no extruder, or a cold one) and the valve still switches the flow.
  Its rate is checked against ``[limits] e_mm_s`` all the same (as the link's check
  does), so that a firmware with a working E axis could never slow a road for it.
* channels (one per feature, :attr:`Toolpath.channels`): ``print_speed_mm_s`` is the
  feed ``F``; ``extrusion_multiplier`` the E volume (or the feed on a machine without an
  E axis, when speed is not a channel too); ``line_spacing_mm`` is in the road positions;
  ``temperature_c`` is ``M104 S<C>``, ``pressure_kpa`` the profile's ``[pressure]``
  command ``S<n>``, and a mixing extruder's ``ink_fraction`` ``M163 S0 P<1-f>``,
  ``M163 S1 P<f>``, ``M164 S0``, each written before the first vertex where its written
  value (whole degrees, whole S steps, hundredths) changes. On a machine that alternates
  two inks, every road is cut into runs of one ink no shorter than ``[inks] piece_mm``
  (two-dimensional error diffusion, :mod:`fabkit.writers.inks`), each run bracketed by
  its ink's on and off G-code. A channel the machine cannot emit is refused, naming it.

Comments that slicer viewers read (Cura's ``plugins/GCodeReader/FlavorParser.py``,
PrusaSlicer's ``GCodeProcessor``): a header with ``;FLAVOR:``, ``;TIME:`` (s),
``;Filament used:`` (m), ``;LAYER_COUNT:``, the bounds, PrusaSlicer's estimated time and
filament lines; then at every layer ``;LAYER:n`` (n from 0), ``;TYPE:FILL`` (Cura's name
for infill: every road of a sheet is fill) and ``;HEIGHT:h`` (mm), and ``;WIDTH:w`` (mm,
to the micrometre) before the first print segment and wherever the road width changes.
Viewers tell extrusions from travels by E, hence nominal E above. X, Y, Z are written
only when they change, F when it changes or the motion word changes (G0 and G1 keep
separate feeds on some firmware).

Every row is checked before anything is written: positions inside the envelope (with
the lift), feeds within the print, travel and per-axis limits, E rate within the E limit,
temperature within the nozzle maximum; the first violation is a one-line
:class:`~fabkit.errors.FabkitError` naming the layer, move and vertex.

The writer's stages, one module each: :mod:`fabkit.writers.gcode_setup` (the options and
the profile resolved once), :mod:`fabkit.writers.gcode_rows` (the row table),
:mod:`fabkit.writers.gcode_checks` (the kinematics and the checks) and
:mod:`fabkit.writers.gcode_header` (the summary and the header).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from fabkit.files.atomic import atomic_path
from fabkit.gcode.duration import estimate
from fabkit.gcode.read import commands_from_lines
from fabkit.machines import MachineProfile
from fabkit.toolpath.model import Toolpath
from fabkit.writers.gcode_checks import Kinematics, check_rows, slow_travels
from fabkit.writers.gcode_header import GcodeSummary, header_bytes, job_summary, lines_bytes
from fabkit.writers.gcode_rows import WORDS, Paths, build_rows, row_prefixes
from fabkit.writers.gcode_setup import GcodeOptions, check_channels, job_setup
from fabkit.writers.line_table import render


def write_gcode(
    toolpath: Toolpath,
    machine: MachineProfile,
    path: str | Path,
    options: GcodeOptions | None = None,
) -> GcodeSummary:
    """Check and write ``toolpath`` as G-code for ``machine`` at ``path`` (atomically)."""
    text, summary = gcode_bytes(toolpath, machine, options)
    with atomic_path(path) as tmp:
        tmp.write_bytes(text)
    return summary


def gcode_bytes(
    toolpath: Toolpath, machine: MachineProfile, options: GcodeOptions | None = None
) -> tuple[bytes, GcodeSummary]:
    """The whole G-code file as ASCII bytes, and its summary; raises before any output."""
    options = options or GcodeOptions()
    setup = job_setup(machine, options)
    check_channels(toolpath, machine)
    paths = Paths.gather(toolpath, machine, options.offset_mm, setup)
    rows = build_rows(paths, setup, toolpath)
    rows = slow_travels(rows, machine)
    kinematics = Kinematics.of(rows)
    check_rows(rows, kinematics, paths, machine, toolpath, setup.nominal_e)
    summary = job_summary(rows, kinematics, paths, setup)
    rows = rows.modal(setup)
    body = render(rows.prefix, row_prefixes(setup), rows.values, rows.present, WORDS)
    end = lines_bytes(machine.render("end_gcode"))
    body = _without_repeat(body, end)
    draft = header_bytes(summary, toolpath, machine, setup) + body + end
    # the file as the machine plans it (the header's time is a comment, which it skips)
    planned = estimate(commands_from_lines(draft.decode("ascii").splitlines()), machine)
    summary = replace(summary, duration_s=planned.total_s, motion_lines=planned.moves)
    text = header_bytes(summary, toolpath, machine, setup) + body + end
    return text, replace(summary, lines=text.count(b"\n"))


def _without_repeat(body: bytes, end: bytes) -> bytes:
    """``body`` without its last line when the end G-code starts with the same command
    (the last road's valve closed, then the end G-code closing it again: ``M42 P4 S0``
    twice)."""
    first = end.split(b"\n", 1)[0]
    if first and body.endswith(b"\n" + first + b"\n"):
        return body[: -len(first) - 1]
    return body
