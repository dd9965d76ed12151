"""Check a job against a machine profile before a single byte is sent.

:func:`check_job` follows the G-code's modal state (G90/G91, G92 offsets, G28, feed,
flow on/off, M82/M83) and refuses the job at the first problem with one line naming
the file line, the value and the limit: a position outside the envelope (arcs
included), a feed or axis speed above the profile's limits, a temperature above the
maximum, an unknown command for the flavour, a line the link cannot send.

Positions are machine coordinates: an axis is checked once it is known (homed with G28,
to 0 or the nearest envelope bound, or given absolutely). ``G92`` on an axis whose
machine position is unknown (a manual zero) makes that axis uncheckable; the summary
says so.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass

from fabkit.errors import FabkitError
from fabkit.link.gcode import Command, code_of, words
from fabkit.machines import GCODE_KEYS, MachineProfile

_TOL = 1e-6
_MOTION = {"G0", "G1", "G2", "G3"}
_COMMON = {"G0", "G1", "G2", "G3", "G4", "G21", "G28", "G90", "G91", "G92"}
_MARLIN = _COMMON | {
    "G29", "M0", "M1", "M17", "M18", "M82", "M83", "M84", "M104", "M105", "M106", "M107",
    "M109", "M110", "M114", "M115", "M117", "M118", "M140", "M190", "M201", "M203", "M204",
    "M205", "M220", "M221", "M300", "M400", "M410", "M42", "M3", "M4", "M5", "M7", "M8",
    "M9", "T0", "T1", "T2", "T3",
}  # fmt: skip
_GRBL = _COMMON | {
    "G10", "G17", "G18", "G19", "G28.1", "G30", "G30.1", "G38.2", "G38.3", "G38.4", "G38.5",
    "G40", "G43.1", "G49", "G53", "G54", "G55", "G56", "G57", "G58", "G59", "G61", "G80",
    "G91.1", "G92.1", "G93", "G94", "M0", "M1", "M2", "M30", "M3", "M4", "M5", "M7", "M8",
    "M9", "M56", "$H", "F", "S", "T", "X", "Y", "Z",
}  # fmt: skip
COMMANDS = {
    "marlin": _MARLIN,
    "klipper": _MARLIN,
    "reprap": _MARLIN | {"G10", "M116", "M568"},
    "hyrel": _MARLIN | {"M229", "M721", "M722", "M756"},
    "grbl": _GRBL,
}
"""Commands each flavour accepts (plus Klipper's extended commands, and every command the
profile's own snippets use)."""

MAX_MARLIN_CHARS = 80  # Marlin keeps 95 characters, of which "N<n> " and "*<xor>" take some
MAX_GRBL_CHARS = 79  # GRBL's line buffer is 80 bytes
_EXTENDED = re.compile(r"[A-Z][A-Z0-9]*_[A-Z0-9_]*$")
_G_WORD = re.compile(r"[Gg]\s*(\d+\.?\d*)")


@dataclass(frozen=True)
class JobCheck:
    """The outcome of a successful check (mm, s)."""

    source: str
    machine: str
    commands: int
    moves: int
    bounds_mm: tuple[tuple[float, float] | None, ...]
    motion_time_s: float
    unchecked_axes: tuple[str, ...]

    def summary(self) -> str:
        """A few lines for the user."""
        spans = "  ".join(
            f"{axis} {lo:.3f}..{hi:.3f}" if span else f"{axis} -"
            for axis, span in zip("XYZ", self.bounds_mm, strict=True)
            for lo, hi in [span or (0.0, 0.0)]
        )
        lines = [
            f"{self.source}: {self.commands} commands, {self.moves} moves fit machine "
            f"{self.machine}",
            f"positions (mm): {spans}",
            f"estimated motion time: {self.motion_time_s / 60:.1f} min",
        ]
        if self.unchecked_axes:
            axes = ", ".join(self.unchecked_axes)
            lines.append(f"note: {axes} zeroed with G92 at an unknown position: not checked")
        return "\n".join(lines)


def _normal(text: str) -> str:
    return " ".join(text.upper().split())


class _State:
    """Modal state while walking the job (machine coordinates, mm; feed mm/s)."""

    def __init__(self, machine: MachineProfile) -> None:
        self.machine = machine
        self.pos: list[float | None] = [None, None, None]
        self.offset: list[float | None] = [0.0, 0.0, 0.0]
        self.e_mm = 0.0
        self.absolute = True
        self.absolute_e = True
        self.feed_mm_s: float | None = None
        self.flow_on = False
        self.bounds: list[list[float] | None] = [None, None, None]
        self.moves = 0
        self.motion_time_s = 0.0
        self.unchecked: set[str] = set()
        self.motion = "G0"


class _Checker:
    def __init__(self, machine: MachineProfile, source: str) -> None:
        if machine.gcode is None or machine.serial is None:
            raise FabkitError(f"machine {machine.name} has flavour none and takes no G-code")
        self.machine = machine
        self.source = source
        self.grbl = machine.flavour == "grbl"
        snippets = [line for key in GCODE_KEYS for line in machine.render(key)]
        self.allowed = COMMANDS[machine.flavour] | {code_of(line) for line in snippets}
        self.flow_on = {_normal(line) for line in machine.render("flow_on_gcode")}
        self.flow_off = {_normal(line) for line in machine.render("flow_off_gcode")}
        self.state = _State(machine)
        self.line = 0

    def fail(self, message: str) -> None:
        raise FabkitError(f"{self.source}:{self.line}: {message}")

    def check(self, command: Command) -> None:
        self.line = command.file_line
        text = command.text
        self._check_text(text)
        code = code_of(text)
        self._check_known(text, code)
        values = words(text)
        normal = _normal(text)
        if normal in self.flow_on:
            self.state.flow_on = True
        elif normal in self.flow_off:
            self.state.flow_on = False
        self._modal(code, values, text)

    def _check_text(self, text: str) -> None:
        limit = MAX_GRBL_CHARS if self.grbl else MAX_MARLIN_CHARS
        if len(text) > limit:
            self.fail(f"command is {len(text)} characters long, the limit is {limit}")
        if any(ord(c) < 32 for c in text):
            self.fail("control character in command")
        forbidden = "?!~" if self.grbl else "*"
        for char in forbidden:
            if char in text:
                self.fail(f"'{char}' is not allowed in a command ({self.machine.flavour})")
        if re.match(r"N\d", text, re.IGNORECASE) and not self.grbl:
            self.fail("the line already carries a line number: remove N words and checksums")

    def _check_known(self, text: str, code: str) -> None:
        if code in ("G20", "G70"):
            self.fail("inch units (G20) are not supported: use millimetres (G21)")
        extended = self.machine.flavour == "klipper" and _EXTENDED.match(code)
        if code not in self.allowed and not extended:
            self.fail(f"unknown command {code} for flavour {self.machine.flavour}")
        if self.grbl:
            for letter, number in re.findall(r"([GMgm])\s*(\d+\.?\d*)", text):
                value = float(number)
                other = f"{letter.upper()}{int(value) if value.is_integer() else value}"
                if other not in self.allowed:
                    self.fail(f"unknown command {other} for flavour grbl")

    def _modal(self, code: str, values: dict[str, float], text: str) -> None:
        state = self.state
        gs = [float(n) for n in _G_WORD.findall(text)]
        if "F" in values:
            if values["F"] <= 0:
                self.fail(f"feed F{values['F']:g} must be positive")
            state.feed_mm_s = values["F"] / 60.0
        for g in gs:
            if g in (90, 91):
                state.absolute = g == 90
                state.absolute_e = state.absolute_e if self.grbl else g == 90
            elif g == 92:
                self._set_position(values)
            elif g == 28:
                self._home(values)
        if code in ("M82", "M83"):
            state.absolute_e = code == "M82"
        elif code in ("M104", "M109", "M140", "M190"):
            self._temperature(code, values)
        motion = self._motion(gs)
        if motion is not None and any(axis in values for axis in "XYZE"):
            self._move(motion, values, machine_coords=53 in gs)

    def _motion(self, gs: list[float]) -> str | None:
        """The motion of a line: its G0-G3 word, or (GRBL) the modal one for bare axes."""
        explicit = [g for g in gs if g in (0, 1, 2, 3)]
        if explicit:
            self.state.motion = f"G{int(explicit[-1])}"
            return self.state.motion
        if self.grbl and not any(g in (10, 28, 30, 92) for g in gs):
            return self.state.motion
        return None

    def _set_position(self, values: dict[str, float]) -> None:
        state = self.state
        for i, axis in enumerate("XYZ"):
            if axis in values:
                machine_pos = state.pos[i]
                if machine_pos is None:
                    state.offset[i] = None
                    state.unchecked.add(axis)
                else:
                    state.offset[i] = machine_pos - values[axis]
        if "E" in values:
            state.e_mm = values["E"]

    def _home(self, values: dict[str, float]) -> None:
        state = self.state
        named = [axis for axis in "XYZ" if axis in values]
        for axis in named or ["X", "Y", "Z"]:
            i = "XYZ".index(axis)
            lo, hi = self.machine.envelope.axis(axis.lower())
            state.pos[i] = min(max(0.0, lo), hi)
            state.offset[i] = 0.0
            state.unchecked.discard(axis)

    def _temperature(self, code: str, values: dict[str, float]) -> None:
        temps = self.machine.temperature
        nozzle = code in ("M104", "M109")
        limit = temps.nozzle_max_c if nozzle else temps.bed_max_c
        name = "nozzle_max_c" if nozzle else "bed_max_c"
        for letter in ("S", "R"):
            if letter in values and values[letter] > limit + _TOL:
                self.fail(
                    f"{code} {letter}{values[letter]:g}: {values[letter]:g} C exceeds "
                    f"[temperature] {name} = {limit:g} C of machine {self.machine.name}"
                )

    def _move(self, code: str, values: dict[str, float], *, machine_coords: bool) -> None:
        state = self.state
        start = list(state.pos)
        start_e = state.e_mm
        for i, axis in enumerate("XYZ"):
            if axis in values:
                self._axis_to(i, axis, values[axis], machine_coords)
        if "E" in values:
            state.e_mm = values["E"] if state.absolute_e else state.e_mm + values["E"]
        if code in ("G2", "G3"):
            self._check_arc(code, start, values)
        state.moves += 1
        self._check_speed(code, start, state.e_mm - start_e)

    def _axis_to(self, i: int, axis: str, value: float, machine_coords: bool) -> None:
        state = self.state
        current, offset = state.pos[i], 0.0 if machine_coords else state.offset[i]
        if offset is None:
            state.pos[i] = None
            return
        if state.absolute:
            state.pos[i] = value + offset
        elif current is not None:
            state.pos[i] = current + value
        if state.pos[i] is not None:
            self._check_inside(axis, state.pos[i])

    def _check_inside(self, axis: str, value: float) -> None:
        lo, hi = self.machine.envelope.axis(axis.lower())
        if not lo - _TOL <= value <= hi + _TOL:
            self.fail(
                f"{axis}={value:.3f} mm is outside the envelope {axis.lower()}_mm = "
                f"[{lo:g}, {hi:g}] of machine {self.machine.name}"
            )
        i = "XYZ".index(axis)
        span = self.state.bounds[i]
        if span is None:
            self.state.bounds[i] = [value, value]
        else:
            span[0], span[1] = min(span[0], value), max(span[1], value)

    def _check_arc(self, code: str, start: list[float | None], values: dict[str, float]) -> None:
        """The X/Y extremes an I/J arc passes (its bounding box) must be inside too."""
        end = self.state.pos
        if None in start[:2] or None in end[:2] or not ("I" in values or "J" in values):
            return
        cx, cy = start[0] + values.get("I", 0.0), start[1] + values.get("J", 0.0)
        radius = math.hypot(start[0] - cx, start[1] - cy)
        a0 = math.atan2(start[1] - cy, start[0] - cx)
        a1 = math.atan2(end[1] - cy, end[0] - cx)
        sweep = (a1 - a0) % (2 * math.pi) or 2 * math.pi
        if code == "G2":
            a0, sweep = a1, (2 * math.pi - sweep) % (2 * math.pi) or 2 * math.pi
        for k in range(4):
            angle = k * math.pi / 2
            if (angle - a0) % (2 * math.pi) <= sweep:
                self._check_inside("X", cx + radius * math.cos(angle))
                self._check_inside("Y", cy + radius * math.sin(angle))

    def _check_speed(self, code: str, start: list[float | None], de_mm: float) -> None:
        """The feed against travel/print limits; per-axis speeds once the move is known."""
        state, limits = self.state, self.machine.limits
        deltas = [
            (b - a) if a is not None and b is not None else 0.0
            for a, b in zip(start, state.pos, strict=True)
        ]
        length = math.hypot(*deltas) or abs(de_mm)
        if code == "G0" and self.grbl:  # rapid: at the machine's own maximum rates
            state.motion_time_s += length / limits.travel_mm_s
            return
        speed = state.feed_mm_s
        if speed is None:
            if self.grbl:
                self.fail(f"{code} before any feed rate (F) was set")
            return
        printing = de_mm > 0 or state.flow_on
        self._speed_limit("feed", speed, "print_mm_s" if printing else "travel_mm_s")
        if length <= 0:
            return
        components = [*(abs(d) for d in deltas), abs(de_mm)]
        for axis, delta in zip("xyze", components, strict=True):
            self._speed_limit(f"{axis.upper()} speed", speed * delta / length, f"{axis}_mm_s")
        state.motion_time_s += length / speed

    def _speed_limit(self, label: str, value: float, key: str) -> None:
        limit = getattr(self.machine.limits, key)
        if value > limit * (1 + 1e-9) + _TOL:
            self.fail(
                f"{label} {value:.3f} mm/s exceeds [limits] {key} = {limit:g} mm/s "
                f"of machine {self.machine.name}"
            )


def check_job(job: Sequence[Command], machine: MachineProfile, source: str = "job") -> JobCheck:
    """Walk ``job`` and refuse it (FabkitError) at the first line the machine must not get."""
    checker = _Checker(machine, source)
    for command in job:
        checker.check(command)
    state = checker.state
    return JobCheck(
        source=source,
        machine=machine.name,
        commands=len(job),
        moves=state.moves,
        bounds_mm=tuple(tuple(span) if span else None for span in state.bounds),
        motion_time_s=state.motion_time_s,
        unchecked_axes=tuple(sorted(state.unchecked)),
    )
