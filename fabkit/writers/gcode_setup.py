"""The settings of one G-code job (:mod:`fabkit.writers.gcode`): the writer's options
(:class:`GcodeOptions`) and the machine profile resolved once into a :class:`Setup` (the E
axis, its mode and units, lifts, retraction, feeds, the flow, ink and pressure G-code),
and the channels a G-code file can carry (:data:`SUPPORTED`, :func:`check_channels`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from fabkit.errors import FabkitError
from fabkit.machines import MachineProfile
from fabkit.toolpath.model import Toolpath

E_MODES = ("absolute", "relative")
E_UNITS = ("filament", "volume", "pulses")
DEFAULT_RETRACT_MIN_TRAVEL_MM = 1.0
"""Travels shorter than this (mm) neither lift nor retract (slicers' "minimum travel")."""


SUPPORTED = {
    "print_speed_mm_s": "the feed F",
    "extrusion_multiplier": "the E volume (or the feed without an E axis)",
    "line_spacing_mm": "the road positions",
    "temperature_c": "M104 S",
    "pressure_kpa": "the [pressure] command",
    "ink_fraction": "alternating inks ([inks] alternate) or M163/M164 ([inks] mixing)",
}
"""The channels a G-code file can carry, and how (some need the profile's support)."""


@dataclass(frozen=True)
class GcodeOptions:
    """Choices the profile does not fix; None means "from the profile, else the default".

    ``e_mode``: "absolute" (M82) or "relative" (M83); default: what the profile's start
    G-code selects, else relative. ``e_units``: "filament" (mm of filament), "volume"
    (mm^3 = uL) or "pulses"; default "volume" for flavour hyrel, else "filament".
    ``offset_mm``: sheet-to-machine offset (x, y[, z]); default: centred on the bed.
    ``nominal_e``: write nominal E on a Marlin machine without an E axis
    (:mod:`fabkit.writers.gcode`); default: the profile's ``[tool] nominal_e``.
    """

    e_mode: str | None = None
    e_units: str | None = None
    filament_diameter_mm: float | None = None
    pulses_per_mm3: float | None = None
    offset_mm: tuple[float, ...] | None = None
    retract_min_travel_mm: float = DEFAULT_RETRACT_MIN_TRAVEL_MM
    nominal_e: bool | None = None


@dataclass(frozen=True)
class Setup:
    """The resolved settings of one job."""

    has_e: bool
    e_mode: str
    e_units: str
    e_per_mm3: float
    lift_mm: float
    retract: float
    retract_feed: float
    z_feed: float
    travel_feed: float
    min_travel_mm: float
    flow_on: str
    flow_off: str
    ink2_on: str = ""
    ink2_off: str = ""
    pressure: str = ""
    inks: str = ""
    piece_mm: float = 0.0
    s_per_kpa: float = 0.0
    nominal_e: bool = False


def job_setup(machine: MachineProfile, options: GcodeOptions) -> Setup:
    if machine.gcode is None:
        raise FabkitError(
            f"machine {machine.name} takes no G-code (flavour none); use --format laser"
        )
    has_e = not machine.gcode.flow_on_gcode.strip()
    nominal = _nominal_e(machine, options, has_e)
    e_mode = options.e_mode or _profile_e_mode(machine)
    if e_mode not in E_MODES:
        raise FabkitError(f"E mode '{e_mode}' is not one of {', '.join(E_MODES)}")
    units = (
        "filament"
        if nominal
        else (
            options.e_units
            or machine.tool.e_units
            or ("volume" if machine.flavour == "hyrel" else "filament")
        )
    )
    if units not in E_UNITS:
        raise FabkitError(f"E units '{units}' is not one of {', '.join(E_UNITS)}")
    tool, limits = machine.tool, machine.limits
    return Setup(
        has_e=has_e,
        e_mode=e_mode if has_e or nominal else "none",
        e_units=units if has_e or nominal else "none",
        e_per_mm3=_e_per_mm3(machine, options, units) if has_e or nominal else 0.0,
        lift_mm=tool.travel_lift_mm,
        retract=tool.retract_mm if has_e else 0.0,
        retract_feed=tool.retract_speed_mm_s * 60.0,
        z_feed=limits.z_mm_s * 60.0,
        travel_feed=machine.process.travel_speed_mm_s * 60.0,
        min_travel_mm=options.retract_min_travel_mm,
        flow_on=_snippet(machine, "flow_on_gcode"),
        flow_off=_snippet(machine, "flow_off_gcode"),
        ink2_on=_snippet(machine, "ink2_on_gcode"),
        ink2_off=_snippet(machine, "ink2_off_gcode"),
        pressure=machine.pressure.command if machine.pressure else "",
        inks=machine.inks.method if machine.inks else "",
        piece_mm=machine.inks.piece_mm if machine.inks else 0.0,
        s_per_kpa=(
            machine.pressure.s_max / machine.pressure.full_scale_kpa if machine.pressure else 0.0
        ),
        nominal_e=nominal,
    )


def _nominal_e(machine: MachineProfile, options: GcodeOptions, has_e: bool) -> bool:
    """Whether to write nominal E (:mod:`fabkit.writers.gcode`); refuses it where it is not safe."""
    nominal = machine.tool.nominal_e if options.nominal_e is None else options.nominal_e
    if nominal and has_e:
        raise FabkitError(
            f"nominal E is for machines without an E axis; the flow of {machine.name} "
            "follows E already (its flow_on_gcode is empty)"
        )
    if nominal and machine.flavour != "marlin":
        raise FabkitError(
            f"nominal E needs flavour marlin (whose firmware ignores E without a hot "
            f"extruder); {machine.name} is flavour {machine.flavour}, which may refuse E words"
        )
    return nominal


def check_channels(toolpath: Toolpath, machine: MachineProfile) -> None:
    """Refuse, naming it, a channel of ``toolpath`` that ``machine``'s G-code cannot carry."""
    for name in toolpath.channels:
        reason = _unsupported(name, toolpath, machine)
        if reason:
            raise FabkitError(
                f"machine {machine.name} cannot carry the {name} channel "
                f"({toolpath.channels[name] or 'a feature'}) in G-code: {reason}"
            )


def _unsupported(name: str, toolpath: Toolpath, machine: MachineProfile) -> str:
    """Why the G-code for ``machine`` cannot carry channel ``name`` ("" if it can)."""
    gcode = machine.gcode
    has_e = gcode is not None and not gcode.flow_on_gcode.strip()
    if name not in SUPPORTED:
        return (
            "it is written by the laser writer (--format laser)"
            if "dose" in name
            else ("no G-code command sets it")
        )
    if name == "extrusion_multiplier" and not has_e and "print_speed_mm_s" in toolpath.channels:
        return (
            "without an E axis the multiplier is written as the feed (speed / multiplier), "
            "which the print_speed_mm_s channel already sets; encode the flow as pressure_kpa"
        )
    if name == "temperature_c":
        if machine.flavour == "grbl":
            return "GRBL has no temperature command"
        if machine.temperature.nozzle_max_c <= 0:
            return "it has no nozzle heater ([temperature] nozzle_max_c = 0)"
    if name == "pressure_kpa" and machine.pressure is None:
        return "its profile has no [pressure] table (the command that sets the pressure)"
    if name == "ink_fraction" and machine.inks is None:
        return "its profile has no [inks] table (a second ink: alternating, or a mixing extruder)"
    return ""


def _profile_e_mode(machine: MachineProfile) -> str:
    """The E mode the profile prefers: the last M82/M83 its start G-code names, else
    relative (a preference, not a reading of the machine's state: the file then selects
    its mode itself, M83 or M82 with G92 E0, after the start G-code)."""
    mode = "relative"
    for line in machine.render("start_gcode"):
        word = line.split(";")[0].split()
        if word and word[0].upper() in ("M82", "M83"):
            mode = "absolute" if word[0].upper() == "M82" else "relative"
    return machine.tool.e_mode or mode


def _e_per_mm3(machine: MachineProfile, options: GcodeOptions, units: str) -> float:
    if units == "volume":
        return 1.0
    if units == "pulses":
        pulses = options.pulses_per_mm3 or machine.tool.pulses_per_mm3
        if not pulses or pulses <= 0:
            raise FabkitError("E units 'pulses' need pulses per mm^3 (--pulses-per-mm3)")
        return float(pulses)
    diameter = options.filament_diameter_mm or machine.tool.filament_diameter_mm
    if diameter <= 0:
        raise FabkitError(f"filament diameter must be > 0 mm, got {diameter}")
    return 4.0 / (math.pi * diameter**2)


def _snippet(machine: MachineProfile, key: str) -> str:
    return "\n".join(machine.render(key))
