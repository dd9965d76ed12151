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

import math
import string
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fabkit.errors import FabkitError
from fabkit.limits import MAGNITUDE, TEMPLATE_CHARS, TEMPLATE_LINE_CHARS
from fabkit.shipped import PROFILES_DIR
from fabkit.tomlfile import read_toml

MACHINES_DIR = PROFILES_DIR
"""The shipped profiles (see :mod:`fabkit.shipped`)."""

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
PRINT_PARAMETERS = (
    "print_speed_mm_s",
    "extrusion_multiplier",
    "temperature_c",
    "line_spacing_mm",
)
"""Print-line parameters an eps calibration may map to (same names as the toolpath's)."""
LIGHT_PARAMETERS = ("dose_mj_cm2",)
"""Exposure parameters an eps calibration of a laser writer may map to."""
CALIBRATION_PARAMETERS = PRINT_PARAMETERS + LIGHT_PARAMETERS

GCODE_KEYS = ("start_gcode", "end_gcode", "flow_on_gcode", "flow_off_gcode", "safe_stop_gcode")
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
    """

    nozzle_diameter_mm: float
    travel_lift_mm: float
    retract_mm: float
    retract_speed_mm_s: float
    e_mode: str | None = None
    e_units: str | None = None
    filament_diameter_mm: float = 1.75
    pulses_per_mm3: float | None = None


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
    """

    start_gcode: str
    end_gcode: str
    flow_on_gcode: str
    flow_off_gcode: str
    safe_stop_gcode: str


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
class Calibration:
    """Measured eps (programmed strain) against one process parameter.

    ``eps`` strictly increasing, ``value`` positive and strictly monotone; ``clip``: eps
    outside the table is clipped to it (with a warning) instead of being an error. The
    stage that uses the table interpolates it (the toolpath: monotone PCHIP).
    """

    parameter: str
    eps: tuple[float, ...]
    value: tuple[float, ...]
    clip: bool = False


@dataclass(frozen=True)
class ProcessProfile:
    """Default process settings the toolpath reads (mm, mm/s), and the eps calibration."""

    road_width_mm: float
    layer_height_mm: float
    print_speed_mm_s: float
    travel_speed_mm_s: float
    calibration: Calibration | None


@dataclass(frozen=True)
class LaserOptics:
    """The light of a photoalignment writer (the optional ``[laser]`` table).

    ``pixel_pitch_mm``: projected pixel (DMD) or scan line pitch, None = the process road
    width; ``relation``: the aligned director lies perpendicular (azo dyes such as SD1) or
    parallel to the polarisation; ``input_polarisation_deg``: the polarisation entering
    the half-wave plate, degrees from +x in [0, 180); ``intensity_mw_cm2`` (exposure
    times) and ``max_power_mw`` (scan power limit), None = unknown.
    """

    pixel_pitch_mm: float | None = None
    relation: str = DEFAULT_RELATION
    input_polarisation_deg: float = 0.0
    intensity_mw_cm2: float | None = None
    max_power_mw: float | None = None


@dataclass(frozen=True)
class MachineProfile:
    """One machine: what it is, where it can go, how fast, and how to talk to it.

    ``gcode`` and ``serial`` are None exactly when ``flavour == "none"`` (a machine that
    takes no G-code, e.g. a projector-based writer driven by images); ``laser`` is set
    only for kind ``laser_writer`` (defaults when its profile has no ``[laser]`` table).
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
    process: ProcessProfile
    laser: LaserOptics | None
    path: Path

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


class _Table:
    """Typed access to one TOML table; every error names the file, table and key."""

    def __init__(self, data: Any, where: str, path: Path) -> None:
        self.where = where
        self.path = path
        if not isinstance(data, Mapping):
            self.fail(f"{where} must be a table")
        self.data = dict(data)
        self.seen: set[str] = set()

    def fail(self, message: str) -> None:
        raise FabkitError(f"{_display(self.path)}: {message}")

    def _raw(self, key: str) -> Any:
        self.seen.add(key)
        if key not in self.data:
            self.fail(f"{self._name(key)} is missing")
        return self.data[key]

    def optional(self, key: str, read: Callable[[str], Any], default: Any) -> Any:
        """``read(key)`` (one of the typed getters) if the table has ``key``, else ``default``."""
        self.seen.add(key)
        return read(key) if key in self.data else default

    def _name(self, key: str) -> str:
        return f"{self.where} {key}" if self.where else key

    def has(self, key: str) -> bool:
        return key in self.data

    def text(self, key: str, choices: tuple[str, ...] | None = None) -> str:
        value = self._raw(key)
        if not isinstance(value, str):
            self.fail(f"{self._name(key)} must be a string, got {_type(value)}")
        if choices is not None and value not in choices:
            self.fail(f"{self._name(key)} = '{value}' is not one of {', '.join(choices)}")
        return value

    def number(self, key: str, *, positive: bool = False) -> float:
        value = self._raw(key)
        return self._check_number(key, value, positive)

    def _check_number(self, key: str, value: Any, positive: bool) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            self.fail(f"{self._name(key)} must be a number, got {_type(value)}")
        if not math.isfinite(value):
            self.fail(f"{self._name(key)} must be finite, got {value}")
        if positive and value <= 0:
            self.fail(f"{self._name(key)} must be > 0, got {value}")
        if value < 0:
            self.fail(f"{self._name(key)} must not be negative, got {value}")
        if value > MAGNITUDE:
            self.fail(f"{self._name(key)} = {value:g} is beyond the plausible {MAGNITUDE:g}")
        return float(value)

    def flag(self, key: str) -> bool:
        value = self._raw(key)
        if not isinstance(value, bool):
            self.fail(f"{self._name(key)} must be true or false, got {_type(value)}")
        return value

    def integer(self, key: str) -> int:
        value = self._raw(key)
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(f"{self._name(key)} must be an integer, got {_type(value)}")
        if value <= 0:
            self.fail(f"{self._name(key)} must be > 0, got {value}")
        return value

    def numbers(self, key: str) -> tuple[float, ...]:
        value = self._raw(key)
        if not isinstance(value, list):
            self.fail(f"{self._name(key)} must be an array of numbers, got {_type(value)}")
        out = []
        for item in value:
            if isinstance(item, bool) or not isinstance(item, int | float):
                self.fail(f"{self._name(key)} must hold numbers only, got {_type(item)}")
            if not math.isfinite(item):
                self.fail(f"{self._name(key)} must hold finite numbers, got {item}")
            if abs(item) > MAGNITUDE:
                self.fail(f"{self._name(key)} holds {item:g}, beyond the plausible +-{MAGNITUDE:g}")
            out.append(float(item))
        return tuple(out)

    def span(self, key: str) -> tuple[float, float]:
        value = self.numbers(key)
        if len(value) != 2 or not value[0] < value[1]:
            self.fail(f"{self._name(key)} must be [min, max] with min < max, got {list(value)}")
        return value[0], value[1]

    def table(self, key: str) -> _Table:
        return _Table(self._raw(key), f"[{self._qualified(key)}]", self.path)

    def _qualified(self, key: str) -> str:
        return f"{self.where.strip('[]')}.{key}" if self.where else key

    def finish(self) -> None:
        unknown = sorted(set(self.data) - self.seen)
        if unknown:
            where = f" in {self.where}" if self.where else ""
            self.fail(f"unknown key '{unknown[0]}'{where}")


def _type(value: Any) -> str:
    return {str: "a string", bool: "a boolean", list: "an array", dict: "a table"}.get(
        type(value), type(value).__name__
    )


def _parse(data: dict[str, Any], path: Path) -> MachineProfile:
    top = _Table(data, "", path)
    flavour = top.text("flavour", FLAVOURS)
    kind = top.text("kind", KINDS)
    streamable = flavour != "none"
    for key in ("gcode", "serial"):
        if not streamable and top.has(key):
            top.fail(f"[{key}] must be absent for flavour none (the machine takes no G-code)")
    if kind != "laser_writer" and top.has("laser"):
        top.fail(f"[laser] is only for kind laser_writer, not {kind}")
    laser = None
    if kind == "laser_writer":
        laser = top.optional("laser", lambda key: _laser(top.table(key)), LaserOptics())
    profile = MachineProfile(
        name=top.text("name"),
        kind=kind,
        flavour=flavour,
        description=top.text("description"),
        envelope=_envelope(top.table("envelope")),
        limits=_limits(top.table("limits")),
        tool=_tool(top.table("tool")),
        temperature=_temperatures(top.table("temperature")),
        gcode=_gcode(top.table("gcode")) if streamable else None,
        serial=_serial(top.table("serial")) if streamable else None,
        process=_process(top.table("process"), light=kind == "laser_writer"),
        laser=laser,
        path=path,
    )
    top.finish()
    if profile.gcode is not None:
        _check_placeholders(profile.gcode, path)
        _check_rendered(profile)
    return profile


def _envelope(t: _Table) -> Envelope:
    out = Envelope(x_mm=t.span("x_mm"), y_mm=t.span("y_mm"), z_mm=t.span("z_mm"))
    t.finish()
    return out


_SPEED_KEYS = ("x_mm_s", "y_mm_s", "z_mm_s", "e_mm_s", "travel_mm_s", "print_mm_s")
_MOTION_KEYS = (
    "acceleration_mm_s2",
    "z_acceleration_mm_s2",
    "e_acceleration_mm_s2",
    "junction_deviation_mm",
)


def _limits(t: _Table) -> Limits:
    speeds = {key: t.number(key, positive=True) for key in _SPEED_KEYS}
    motion = {
        key: t.optional(key, _positive(t), Limits.__dataclass_fields__[key].default)
        for key in _MOTION_KEYS
    }
    out = Limits(**speeds, **motion)
    t.finish()
    return out


def _tool(t: _Table) -> Tool:
    out = Tool(
        nozzle_diameter_mm=t.number("nozzle_diameter_mm", positive=True),
        travel_lift_mm=t.number("travel_lift_mm"),
        retract_mm=t.number("retract_mm"),
        retract_speed_mm_s=t.number("retract_speed_mm_s"),
        e_mode=t.optional("e_mode", lambda key: t.text(key, E_MODES), None),
        e_units=t.optional("e_units", lambda key: t.text(key, E_UNITS), None),
        filament_diameter_mm=t.optional("filament_diameter_mm", _positive(t), 1.75),
        pulses_per_mm3=t.optional("pulses_per_mm3", _positive(t), None),
    )
    t.finish()
    return out


def _positive(t: _Table) -> Callable[[str], float]:
    return lambda key: t.number(key, positive=True)


def _temperatures(t: _Table) -> Temperatures:
    out = Temperatures(**{key: t.number(key) for key in Temperatures.__dataclass_fields__})
    t.finish()
    for key, limit in (("nozzle_c", "nozzle_max_c"), ("bed_c", "bed_max_c")):
        if getattr(out, key) > getattr(out, limit):
            t.fail(f"[temperature] {key} = {getattr(out, key):g} exceeds {limit}")
    return out


def _gcode(t: _Table) -> GcodeTemplates:
    out = GcodeTemplates(**{key: t.text(key) for key in GCODE_KEYS})
    t.finish()
    return out


def _serial(t: _Table) -> SerialSettings:
    out = SerialSettings(
        baud=t.integer("baud"),
        protocol=t.text("protocol", PROTOCOLS),
        rx_buffer_bytes=t.integer("rx_buffer_bytes"),
        planner_depth=t.integer("planner_depth"),
    )
    t.finish()
    if out.rx_buffer_bytes < 32:
        t.fail(f"[serial] rx_buffer_bytes must be >= 32, got {out.rx_buffer_bytes}")
    return out


def parse_process(data: Mapping[str, Any], path: Path, *, light: bool = False) -> ProcessProfile:
    """A ``[process]`` table (with its optional calibration) read from the file ``path``.

    ``light``: the machine is a laser writer, whose calibration may also map eps to an
    exposure (LIGHT_PARAMETERS). Errors are one line naming the file and the key.
    """
    return _process(_Table(data, "[process]", path), light=light)


def _process(t: _Table, *, light: bool) -> ProcessProfile:
    values = {
        key: t.number(key, positive=True)
        for key in ("road_width_mm", "layer_height_mm", "print_speed_mm_s", "travel_speed_mm_s")
    }
    calibration = t.optional("calibration", lambda key: _calibration(t.table(key), light), None)
    t.finish()
    return ProcessProfile(**values, calibration=calibration)


def _calibration(t: _Table, light: bool) -> Calibration:
    parameters = CALIBRATION_PARAMETERS if light else PRINT_PARAMETERS
    out = Calibration(
        parameter=t.text("parameter", parameters),
        eps=t.numbers("eps"),
        value=t.numbers("value"),
        clip=t.optional("clip", t.flag, False),
    )
    t.finish()
    if len(out.eps) < 2 or len(out.eps) != len(out.value):
        t.fail("[process.calibration] eps and value must have the same length, at least 2")
    if any(b <= a for a, b in zip(out.eps, out.eps[1:], strict=False)):
        t.fail("[process.calibration] eps must be strictly increasing")
    if any(v <= 0 for v in out.value):
        t.fail("[process.calibration] value must hold positive numbers only")
    steps = np.diff(out.value)
    if not (np.all(steps > 0) or np.all(steps < 0)):
        t.fail("[process.calibration] value must be strictly increasing or decreasing in eps")
    return out


def _laser(t: _Table) -> LaserOptics:
    out = LaserOptics(
        pixel_pitch_mm=t.optional("pixel_pitch_mm", _positive(t), None),
        relation=t.optional("relation", lambda key: t.text(key, RELATIONS), DEFAULT_RELATION),
        input_polarisation_deg=t.optional("input_polarisation_deg", t.number, 0.0),
        intensity_mw_cm2=t.optional("intensity_mw_cm2", _positive(t), None),
        max_power_mw=t.optional("max_power_mw", _positive(t), None),
    )
    t.finish()
    if not out.input_polarisation_deg < 180:
        angle = out.input_polarisation_deg
        t.fail(f"[laser] input_polarisation_deg must be in [0, 180), got {angle:g}")
    return out


def _check_placeholders(gcode: GcodeTemplates, path: Path) -> None:
    """Every template at most TEMPLATE_CHARS long, its fields plain known placeholders
    (``{bed_c}``: a format spec such as ``{bed_c:>100000000}`` or a conversion such as
    ``{bed_c!r}`` could make a line of any length)."""
    for key in GCODE_KEYS:
        template = getattr(gcode, key)
        if len(template) > TEMPLATE_CHARS:
            raise FabkitError(
                f"{_display(path)}: [gcode] {key} is {len(template)} characters, more than the "
                f"limit of {TEMPLATE_CHARS}"
            )
        try:
            fields = list(string.Formatter().parse(template))
        except ValueError as exc:
            raise FabkitError(f"{_display(path)}: [gcode] {key}: {exc}") from None
        for _, name, spec, conversion in fields:
            if name is not None and name not in PLACEHOLDERS:
                raise FabkitError(
                    f"{_display(path)}: [gcode] {key} uses unknown placeholder {{{name}}}; "
                    f"known: {', '.join(PLACEHOLDERS)}"
                )
            if name is not None and (spec or conversion):
                raise FabkitError(
                    f"{_display(path)}: [gcode] {key}: placeholder {{{name}}} carries a format "
                    f"spec or conversion; write plain {{{name}}}"
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
                f"{_display(profile.path)}: [gcode] {key} renders {size} characters with a "
                f"line of {longest}, more than the limit of {TEMPLATE_CHARS} characters in lines "
                f"of {TEMPLATE_LINE_CHARS}"
            )
