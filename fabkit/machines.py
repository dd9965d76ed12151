"""Machine profiles: what a printer, dispenser, light writer or cutter can do, as plain data.

A profile is a TOML file in the repository's ``machines/`` folder (documented key by key
in ``docs/machines.md``). :func:`load_machine` reads one into a frozen
:class:`MachineProfile`; every problem (unknown or missing key, wrong type, negative
limit, unknown machine) is a :class:`~fabkit.errors.FabkitError` whose one-line message
names the file and the key.

Units: millimetres, seconds, mm/s, degrees Celsius. G-code feeds (``F``) are mm/min and
are only ever produced by the template placeholders that say so (``*_feed_mm_min``).
"""

from __future__ import annotations

import string
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fabkit.errors import FabkitError
from fabkit.files.shipped import PROFILES_DIR
from fabkit.files.tomlfile import Table, read_toml
from fabkit.limits import MAGNITUDE, TEMPLATE_CHARS, TEMPLATE_LINE_CHARS
from fabkit.process import Process, parse_process

MACHINES_DIR = PROFILES_DIR
"""The shipped profiles (see :mod:`fabkit.files.shipped`)."""

DEFAULT_MACHINE = "marlin_diw_pneumatic"
"""The profile used when no machine is given (a pneumatic DIW printer with two inks; see
``machines/marlin_diw_pneumatic.toml``)."""
KINDS = ("extrusion_printer", "pneumatic_diw", "laser_writer", "cutter_plotter")
FLAVOURS = ("marlin", "klipper", "reprap", "grbl", "hyrel", "none")
PROTOCOLS = ("marlin", "grbl")
E_MODES = ("absolute", "relative")
E_UNITS = ("filament", "volume", "pulses")
"""What the E axis counts: mm of filament, mm^3 (= uL) of material, or extruder pulses."""
RELATIONS = ("perpendicular", "parallel")
"""How a photoalignment layer's director lies with respect to the light's polarisation."""
DEFAULT_RELATION = "perpendicular"
"""Azo dyes such as SD1 align the director perpendicular to the polarisation."""
INK_METHODS = ("alternate", "mixing")
"""How a machine makes a share of a second ink: alternating the two inks along every road
(valves or tools switched by ``ink2_on_gcode`` / ``ink2_off_gcode``), or a mixing
extruder's ratio (Marlin ``M163`` / ``M164``)."""

GCODE_KEYS = (
    "start_gcode",
    "end_gcode",
    "flow_on_gcode",
    "flow_off_gcode",
    "safe_stop_gcode",
    "ink2_on_gcode",
    "ink2_off_gcode",
)
OPTIONAL_GCODE_KEYS = ("ink2_on_gcode", "ink2_off_gcode")
"""Template keys a profile may leave out (empty): the second ink's switch."""
PLACEHOLDERS = (
    "nozzle_c",
    "bed_c",
    "travel_lift_mm",
    "travel_feed_mm_min",
    "print_feed_mm_min",
    "z_feed_mm_min",
    "retract_mm",
    "retract_feed_mm_min",
)
"""Names a G-code template may use as ``{name}``."""


@dataclass(frozen=True)
class Envelope:
    """Soft limits of the work volume in machine coordinates (mm), each ``(min, max)``."""

    x_mm: tuple[float, float]
    y_mm: tuple[float, float]
    z_mm: tuple[float, float]

    def axis(self, axis: str) -> tuple[float, float]:
        """The ``(min, max)`` of ``axis`` ("x", "y" or "z"), mm."""
        return getattr(self, f"{axis}_mm")

    def size_text(self) -> str:
        """Like ``220x220x250 mm``."""
        spans = (hi - lo for lo, hi in (self.x_mm, self.y_mm, self.z_mm))
        return "x".join(_num(span) for span in spans) + " mm"


@dataclass(frozen=True)
class Limits:
    """Maximum speeds, mm/s: per axis, and for travel and printing moves; the planner's
    accelerations (mm/s^2: X and Y, Z, E) and junction deviation (mm), which only the
    duration estimate uses (optional keys, typical Marlin values by default)."""

    x_mm_s: float
    y_mm_s: float
    z_mm_s: float
    e_mm_s: float
    travel_mm_s: float
    print_mm_s: float
    acceleration_mm_s2: float = 1000.0
    z_acceleration_mm_s2: float = 100.0
    e_acceleration_mm_s2: float = 1000.0
    junction_deviation_mm: float = 0.013

    def axis_mm_s(self, axis: str) -> float:
        """The limit of ``axis`` ("x", "y", "z" or "e"), mm/s."""
        return getattr(self, f"{axis}_mm_s")


@dataclass(frozen=True)
class Tool:
    """The nozzle (or beam / blade) and the moves around printing, mm and mm/s.

    The E axis (machines whose flow follows E): ``e_mode`` "absolute" (M82) or
    "relative" (M83), None = what the start G-code selects; ``e_units`` one of E_UNITS,
    None = "volume" for flavour hyrel, else "filament"; ``filament_diameter_mm`` converts
    volume to filament length; ``pulses_per_mm3`` converts it to pulses (None = unknown).
    ``nominal_e``: a machine without an E axis (valve or pressure dispenser, Marlin) also
    writes E words, the road's volume as filament, for slicer G-code viewers; its
    firmware ignores them (no extruder, or a cold one) and the valve still switches the flow.
    """

    nozzle_diameter_mm: float
    travel_lift_mm: float
    retract_mm: float
    retract_speed_mm_s: float
    e_mode: str | None = None
    e_units: str | None = None
    filament_diameter_mm: float = 1.75
    pulses_per_mm3: float | None = None
    nominal_e: bool = False


@dataclass(frozen=True)
class Temperatures:
    """Default and maximum set points, degrees C (0 = no heater)."""

    nozzle_c: float
    bed_c: float
    nozzle_max_c: float
    bed_max_c: float


@dataclass(frozen=True)
class GcodeTemplates:
    """G-code snippets (newline-separated lines, ``{placeholder}`` fields, see PLACEHOLDERS).

    ``flow_on_gcode`` / ``flow_off_gcode`` start and stop the material (valve, dispenser,
    beam); empty when the flow follows the E axis. ``safe_stop_gcode`` is sent on abort.
    ``ink2_on_gcode`` / ``ink2_off_gcode`` (optional) start and stop the second ink of a
    two-ink machine (its valve, or a tool change such as ``T1`` / ``T0``).
    """

    start_gcode: str
    end_gcode: str
    flow_on_gcode: str
    flow_off_gcode: str
    safe_stop_gcode: str
    ink2_on_gcode: str = ""
    ink2_off_gcode: str = ""


@dataclass(frozen=True)
class PressureOutput:
    """How a pneumatic machine sets its dispense pressure (the optional ``[pressure]``).

    ``command`` is written with ``S<n>``, n = round(pressure / ``full_scale_kpa`` x
    ``s_max``) (an electronic regulator on a PWM output: Marlin ``M106 P1``, 0..255);
    ``max_kpa`` is the highest pressure the machine may be asked for.
    """

    command: str
    s_max: int
    full_scale_kpa: float
    max_kpa: float

    def s_value(self, kpa: Any) -> Any:
        """The S word (whole steps, halves up) for pressures in kPa (numbers or arrays)."""
        return np.floor(np.asarray(kpa, dtype=float) / self.full_scale_kpa * self.s_max + 0.5)

    def kpa(self, s: Any) -> Any:
        """The pressure, kPa, that S words set."""
        return np.asarray(s, dtype=float) * self.full_scale_kpa / self.s_max


@dataclass(frozen=True)
class Inks:
    """A machine with a second ink (the optional ``[inks]`` table).

    ``method`` one of INK_METHODS. ``alternate``: every road switches between the two
    inks (``flow_on_gcode`` / ``flow_off_gcode`` for the first, ``ink2_on_gcode`` /
    ``ink2_off_gcode`` for the second) in runs of about ``piece_mm`` (mm, never shorter
    than half of it), so that the share of the second ink over a few road widths is the
    encoded fraction. ``mixing``:
    a mixing extruder (E axis, Marlin-like) takes the ratio per move from ``M163 S0 P..``,
    ``M163 S1 P..`` and ``M164 S0``.
    """

    method: str
    piece_mm: float = 0.5


@dataclass(frozen=True)
class SerialSettings:
    """How to talk to the controller: baud rate, protocol and its buffer sizes.

    ``rx_buffer_bytes`` is the firmware's serial receive buffer (Marlin and GRBL: 128;
    one byte of the ring stays empty, so 127 are usable); ``planner_depth`` is the number
    of moves the planner holds, which also caps the lines the sender keeps in flight.
    """

    baud: int
    protocol: str
    rx_buffer_bytes: int
    planner_depth: int


@dataclass(frozen=True)
class LaserOptics:
    """The light of a photoalignment writer (the optional ``[laser]`` table).

    ``pixel_pitch_mm``: projected pixel (DMD) or scan line pitch, None = the process road
    width; ``relation``: the aligned director lies perpendicular (azo dyes such as SD1) or
    parallel to the polarisation; ``input_polarisation_deg``: the polarisation entering
    the half-wave plate, degrees from +x in [0, 180); ``intensity_mw_cm2`` (exposure
    times) and ``max_power_mw`` (scan power limit), None = unknown; ``dose_levels`` and
    ``bins``: dose levels and director angle bins of the exposures (None = the writer's
    defaults).
    """

    pixel_pitch_mm: float | None = None
    relation: str = DEFAULT_RELATION
    input_polarisation_deg: float = 0.0
    intensity_mw_cm2: float | None = None
    max_power_mw: float | None = None
    dose_levels: int | None = None
    bins: int | None = None


@dataclass(frozen=True)
class MachineProfile:
    """One machine: what it is, where it can go, how fast, and how to talk to it.

    ``gcode`` and ``serial`` are None exactly when ``flavour == "none"`` (a machine that
    takes no G-code, e.g. a projector-based writer driven by images); ``laser`` is set
    only for kind ``laser_writer`` (defaults when its profile has no ``[laser]`` table);
    ``pressure`` and ``inks`` when the profile says how it sets a dispense pressure and
    makes a second ink. ``process`` is the default :class:`~fabkit.process.Process`.
    """

    name: str
    kind: str
    flavour: str
    description: str
    envelope: Envelope
    limits: Limits
    tool: Tool
    temperature: Temperatures
    gcode: GcodeTemplates | None
    serial: SerialSettings | None
    process: Process
    laser: LaserOptics | None
    path: Path
    pressure: PressureOutput | None = None
    inks: Inks | None = None

    def placeholders(self) -> dict[str, str]:
        """Values of the template placeholders for this machine, formatted for G-code."""
        values = {
            "nozzle_c": self.temperature.nozzle_c,
            "bed_c": self.temperature.bed_c,
            "travel_lift_mm": self.tool.travel_lift_mm,
            "travel_feed_mm_min": self.process.travel_speed_mm_s * 60.0,
            "print_feed_mm_min": self.process.print_speed_mm_s * 60.0,
            "z_feed_mm_min": self.limits.z_mm_s * 60.0,
            "retract_mm": self.tool.retract_mm,
            "retract_feed_mm_min": self.tool.retract_speed_mm_s * 60.0,
        }
        return {key: _num(value) for key, value in values.items()}

    def render(self, key: str) -> list[str]:
        """The G-code lines of template ``key`` (one of GCODE_KEYS), placeholders filled in."""
        if self.gcode is None:
            raise FabkitError(f"machine {self.name} has flavour none and takes no G-code")
        text = getattr(self.gcode, key).format_map(self.placeholders())
        return [line.strip() for line in text.splitlines() if line.strip()]


def load_machine(name_or_path: str | Path) -> MachineProfile:
    """Load a profile by name (from ``machines/``) or from a ``.toml`` path."""
    path = _resolve(str(name_or_path))
    return _parse(read_toml(path, "machine", shown=_display(path)), path)


def list_machines() -> list[MachineProfile]:
    """Every shipped profile, sorted by name."""
    return [load_machine(path) for path in sorted(_machines_dir().glob("*.toml"))]


def machine_table(profiles: list[MachineProfile]) -> str:
    """A plain-text table: name, kind, flavour, envelope, protocol (one row per machine)."""
    header = ("NAME", "KIND", "FLAVOUR", "ENVELOPE", "PROTOCOL")
    rows = [header] + [
        (
            p.name,
            p.kind,
            p.flavour,
            p.envelope.size_text(),
            p.serial.protocol if p.serial else "-",
        )
        for p in profiles
    ]
    widths = [max(len(row[i]) for row in rows) for i in range(len(header))]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)) for row in rows]
    return "\n".join(line.rstrip() for line in lines)


def _machines_dir() -> Path:
    if not MACHINES_DIR.is_dir():
        raise FabkitError(
            f"the machine profiles folder {MACHINES_DIR} is missing: reinstall fabkit "
            "(pip install .) or pass a profile path"
        )
    return MACHINES_DIR


def _resolve(name_or_path: str) -> Path:
    looks_like_path = name_or_path.endswith(".toml") or "/" in name_or_path or "\\" in name_or_path
    if looks_like_path:
        path = Path(name_or_path)
        if not path.is_file():
            raise FabkitError(f"machine profile {name_or_path} does not exist")
        return path
    path = _machines_dir() / f"{name_or_path}.toml"
    if not path.is_file():
        known = ", ".join(sorted(p.stem for p in _machines_dir().glob("*.toml")))
        raise FabkitError(f"unknown machine '{name_or_path}'; known machines: {known}")
    return path


def _display(path: Path) -> str:
    try:
        return str(path.resolve().relative_to(MACHINES_DIR.parent))
    except ValueError:
        return str(path)


def _num(value: float) -> str:
    """A number as G-code likes it: no exponent, no trailing zeros (``9000``, ``0.4``)."""
    return f"{value:.4f}".rstrip("0").rstrip(".")


def _parse(data: dict[str, Any], path: Path) -> MachineProfile:
    top = Table(data, _display(path))
    flavour = top.text("flavour", FLAVOURS)
    kind = top.text("kind", KINDS)
    streamable = flavour != "none"
    for key in ("gcode", "serial"):
        if not streamable and top.has(key):
            top.expected(key, "no table for flavour none (the machine takes no G-code)", top[key])
    if kind != "laser_writer" and top.has("laser"):
        top.expected("laser", f"no table for kind {kind} (only for laser_writer)", top["laser"])
    laser = None
    if kind == "laser_writer":
        laser = top.optional("laser", lambda key: _laser(top.table(key)), LaserOptics())
    name = top.text("name")
    profile = MachineProfile(
        name=name,
        kind=kind,
        flavour=flavour,
        description=top.text("description"),
        envelope=_envelope(top.table("envelope")),
        limits=_limits(top.table("limits")),
        tool=_tool(top.table("tool")),
        temperature=_temperatures(top.table("temperature")),
        gcode=_gcode(top.table("gcode")) if streamable else None,
        serial=_serial(top.table("serial")) if streamable else None,
        process=parse_process(
            top.table("process"), light=kind == "laser_writer", source=f"machine {name}"
        ),
        laser=laser,
        path=path,
        pressure=top.optional("pressure", lambda key: _pressure(top.table(key)), None),
        inks=top.optional("inks", lambda key: _inks(top.table(key)), None),
    )
    top.finish()
    if profile.gcode is not None:
        _check_placeholders(profile.gcode, path)
        _check_rendered(profile)
    _check_outputs(profile, top)
    return profile


def _envelope(t: Table) -> Envelope:
    out = Envelope(**{key: t.span(key, bound=MAGNITUDE) for key in ("x_mm", "y_mm", "z_mm")})
    t.finish()
    return out


_SPEED_KEYS = ("x_mm_s", "y_mm_s", "z_mm_s", "e_mm_s", "travel_mm_s", "print_mm_s")
_MOTION_KEYS = (
    "acceleration_mm_s2",
    "z_acceleration_mm_s2",
    "e_acceleration_mm_s2",
    "junction_deviation_mm",
)


def _limits(t: Table) -> Limits:
    speeds = {key: _positive(t)(key) for key in _SPEED_KEYS}
    motion = {
        key: t.optional(key, _positive(t), Limits.__dataclass_fields__[key].default)
        for key in _MOTION_KEYS
    }
    out = Limits(**speeds, **motion)
    t.finish()
    return out


def _tool(t: Table) -> Tool:
    out = Tool(
        nozzle_diameter_mm=_positive(t)("nozzle_diameter_mm"),
        travel_lift_mm=_size(t)("travel_lift_mm"),
        retract_mm=_size(t)("retract_mm"),
        retract_speed_mm_s=_size(t)("retract_speed_mm_s"),
        e_mode=t.optional("e_mode", lambda key: t.text(key, E_MODES), None),
        e_units=t.optional("e_units", lambda key: t.text(key, E_UNITS), None),
        filament_diameter_mm=t.optional("filament_diameter_mm", _positive(t), 1.75),
        pulses_per_mm3=t.optional("pulses_per_mm3", _positive(t), None),
        nominal_e=t.optional("nominal_e", t.flag, False),
    )
    t.finish()
    return out


def _positive(t: Table) -> Callable[[str], float]:
    """A reader of positive numbers within MAGNITUDE."""
    return lambda key: t.number(key, positive=True, bound=MAGNITUDE)


def _size(t: Table) -> Callable[[str], float]:
    """A reader of numbers >= 0 within MAGNITUDE."""
    return lambda key: t.number(key, nonnegative=True, bound=MAGNITUDE)


def _temperatures(t: Table) -> Temperatures:
    out = Temperatures(**{key: _size(t)(key) for key in Temperatures.__dataclass_fields__})
    t.finish()
    for key, limit in (("nozzle_c", "nozzle_max_c"), ("bed_c", "bed_max_c")):
        if getattr(out, key) > getattr(out, limit):
            t.expected(key, f"at most {limit} = {getattr(out, limit):g}", t[key])
    return out


def _gcode(t: Table) -> GcodeTemplates:
    out = GcodeTemplates(
        **{
            key: t.optional(key, t.text, "") if key in OPTIONAL_GCODE_KEYS else t.text(key)
            for key in GCODE_KEYS
        }
    )
    t.finish()
    return out


def _pressure(t: Table) -> PressureOutput:
    out = PressureOutput(
        command=t.text("command"),
        s_max=t.integer("s_max"),
        full_scale_kpa=_positive(t)("full_scale_kpa"),
        max_kpa=_positive(t)("max_kpa"),
    )
    t.finish()
    if (
        not out.command.strip()
        or any(c in out.command for c in ";(\n")
        or len(out.command) > TEMPLATE_LINE_CHARS
    ):
        t.expected("command", "one G-code command", out.command)
    if out.max_kpa > out.full_scale_kpa:
        t.expected("max_kpa", f"at most full_scale_kpa = {out.full_scale_kpa:g}", t["max_kpa"])
    return out


def _inks(t: Table) -> Inks:
    out = Inks(
        method=t.text("method", INK_METHODS),
        piece_mm=t.optional("piece_mm", _positive(t), Inks.piece_mm),
    )
    t.finish()
    return out


def _check_outputs(profile: MachineProfile, top: Table) -> None:
    """The [pressure] and [inks] tables need G-code, and [inks] what its method uses."""
    gcode = profile.gcode
    for key, table in (("pressure", profile.pressure), ("inks", profile.inks)):
        if table is not None and gcode is None:
            top.expected(key, "no table for flavour none (it needs G-code)", top[key])
    if profile.inks is None or gcode is None:
        return
    if profile.inks.method == "alternate" and not gcode.ink2_on_gcode.strip():
        top.expected(
            "gcode.ink2_on_gcode",
            "G-code switching to ink 2 (inks.method alternate needs it)",
            gcode.ink2_on_gcode,
        )
    marlin_like = profile.flavour in ("marlin", "klipper", "reprap")
    if profile.inks.method == "mixing" and (gcode.flow_on_gcode.strip() or not marlin_like):
        top.expected(
            "inks.method",
            "alternate (mixing needs a Marlin-like mixing extruder with an E axis)",
            profile.inks.method,
        )


def _serial(t: Table) -> SerialSettings:
    out = SerialSettings(
        baud=t.integer("baud"),
        protocol=t.text("protocol", PROTOCOLS),
        rx_buffer_bytes=t.integer("rx_buffer_bytes"),
        planner_depth=t.integer("planner_depth"),
    )
    t.finish()
    if out.rx_buffer_bytes < 32:
        t.expected("rx_buffer_bytes", "an integer >= 32", out.rx_buffer_bytes)
    return out


def _laser(t: Table) -> LaserOptics:
    out = LaserOptics(
        pixel_pitch_mm=t.optional("pixel_pitch_mm", _positive(t), None),
        relation=t.optional("relation", lambda key: t.text(key, RELATIONS), DEFAULT_RELATION),
        input_polarisation_deg=t.optional("input_polarisation_deg", _size(t), 0.0),
        intensity_mw_cm2=t.optional("intensity_mw_cm2", _positive(t), None),
        max_power_mw=t.optional("max_power_mw", _positive(t), None),
        dose_levels=t.optional("dose_levels", t.integer, None),
        bins=t.optional("bins", t.integer, None),
    )
    t.finish()
    if not out.input_polarisation_deg < 180:
        t.expected("input_polarisation_deg", "an angle in [0, 180)", t["input_polarisation_deg"])
    return out


def _check_placeholders(gcode: GcodeTemplates, path: Path) -> None:
    """Every template at most TEMPLATE_CHARS long, its fields plain known placeholders
    (``{bed_c}``: a format spec such as ``{bed_c:>100000000}`` or a conversion such as
    ``{bed_c!r}`` could make a line of any length)."""
    for key in GCODE_KEYS:
        template = getattr(gcode, key)
        if len(template) > TEMPLATE_CHARS:
            raise FabkitError(
                f"{_display(path)}: gcode.{key}: expected at most {TEMPLATE_CHARS} characters, "
                f"got {len(template)}"
            )
        try:
            fields = list(string.Formatter().parse(template))
        except ValueError as exc:
            raise FabkitError(
                f"{_display(path)}: gcode.{key}: expected a G-code template, got {exc}"
            ) from None
        for _, name, spec, conversion in fields:
            if name is not None and name not in PLACEHOLDERS:
                raise FabkitError(
                    f"{_display(path)}: gcode.{key}: expected placeholders among "
                    f"{', '.join(PLACEHOLDERS)}, got {{{name}}}"
                )
            if name is not None and (spec or conversion):
                raise FabkitError(
                    f"{_display(path)}: gcode.{key}: expected plain {{{name}}}, got a format "
                    "spec or conversion"
                )


def _check_rendered(profile: MachineProfile) -> None:
    """Every template, rendered, at most TEMPLATE_CHARS long in lines of at most
    TEMPLATE_LINE_CHARS."""
    for key in GCODE_KEYS:
        lines = profile.render(key)
        size = sum(len(line) + 1 for line in lines)
        longest = max((len(line) for line in lines), default=0)
        if size > TEMPLATE_CHARS or longest > TEMPLATE_LINE_CHARS:
            raise FabkitError(
                f"{_display(profile.path)}: gcode.{key}: expected at most {TEMPLATE_CHARS} "
                f"characters in lines of {TEMPLATE_LINE_CHARS} once rendered, got {size} with "
                f"a line of {longest}"
            )
