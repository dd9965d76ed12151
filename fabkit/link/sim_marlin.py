"""The emulated Marlin 2.x firmware: line numbers, checksums, resends, ok, busy, heaters.

It follows Marlin's ``GCodeQueue``: lines are read from the receive ring into a command
queue of ``command_slots`` entries; a line that starts with ``N`` must carry the next
line number and a correct XOR checksum, else Marlin answers
``Error:<reason>, Last Line: <n>``, empties its receive ring (2.x), asks
``Resend: <n+1>`` and (2.1.x, 1.1.x) sends ``ok``. A line without ``N`` is executed
unchecked, as in Marlin. ``ok`` follows each executed command (M105 answers
``ok T:...`` instead); moves wait for room in the planner, M109/M190/M400/G4/G28 wait
for their condition, printing ``busy: processing`` or temperature reports meanwhile.
"""

from __future__ import annotations

import random
import re
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from fabkit.link.gcode import code_of, marlin_checksum, words
from fabkit.link.sim_machine import (
    INF,
    Counters,
    EmulatorConfig,
    Heater,
    Input,
    Motion,
    Output,
    TraceEntry,
)

MAX_CMD_SIZE = 96
NOISE_LINES = (
    "echo:SD card ok",
    "// action:notification fabkit emulator",
    "wait",
    "echo:Active Extruder: 0",
    "\x00\x7f\x1b[0m",
)
_ERR_LINE_NO = "Line Number is not Last Line Number+1, Last Line: "
_ERR_CHECKSUM = "checksum mismatch, Last Line: "
_ERR_NO_CHECKSUM = "No Checksum with line number, Last Line: "
_STRTOL = re.compile(r"\s*([-+]?\d+)")

_MOVES = {"G0", "G1", "G2", "G3"}
_SYNC = {"M400", "G28", "G29", "M84", "M18"}
_NO_EFFECT = {
    "G21", "M17", "M106", "M107", "M42", "M3", "M4", "M5", "M7", "M8", "M9",
    "M117", "M118", "M201", "M203", "M204", "M205", "M220", "M221", "M300", "M999",
    "T0", "T1", "M110",
}  # fmt: skip
KNOWN = _MOVES | _SYNC | _NO_EFFECT | {
    "G4", "G90", "G91", "G92", "M82", "M83", "M104", "M105", "M109", "M112", "M114",
    "M115", "M140", "M190", "M410",
}  # fmt: skip


def strtol(text: str) -> int:
    """C ``strtol(text, nullptr, 10)``: the leading integer, 0 if none."""
    match = _STRTOL.match(text)
    return int(match.group(1)) if match else 0


def strip_line_number(command: str) -> str:
    """The command without a leading ``N<digits>`` word (Marlin skips up to the first space)."""
    if len(command) > 1 and command[0] == "N" and (command[1].isdigit() or command[1] in "+-"):
        return command.split(" ", 1)[1].lstrip(" ") if " " in command else ""
    return command


def clean_line(raw: bytes) -> str:
    """Marlin's ``process_stream_char``: ``;`` comments, ``\\`` escapes, backspace, and
    characters past MAX_CMD_SIZE - 1 dropped."""
    if not any(c in raw for c in b";\\\x08"):
        return raw[: MAX_CMD_SIZE - 1].decode("latin-1")
    out: list[str] = []
    escaped = False
    for c in raw.decode("latin-1"):
        if escaped:
            escaped = False
        elif c == "\\":
            escaped = True
            continue
        elif c == ";":
            break
        if c == "\x08":
            if out:
                out.pop()
        else:
            out.append(c)
            if len(out) >= MAX_CMD_SIZE - 1:
                break
    return "".join(out)


@dataclass
class _Block:
    """The command at the head of the queue is waiting until ``wake`` (s)."""

    wake: float
    report_at: float
    temperature: bool


class MarlinFirmware:
    """Marlin's serial protocol and command execution on top of a :class:`Motion`."""

    eol = b"\n"
    noise_lines = NOISE_LINES

    def __init__(
        self,
        config: EmulatorConfig,
        inp: Input,
        out: Output,
        trace: list[TraceEntry],
        counters: Counters,
        rng: random.Random,
        on_disconnect: Callable[[float], None],
    ) -> None:
        self.config = config
        self.inp = inp
        self.out = out
        self.trace = trace
        self.counters = counters
        self.rng = rng
        self.on_disconnect = on_disconnect
        self.halted = False
        self._reset_state()

    def _reset_state(self) -> None:
        config = self.config
        self.motion = Motion(config.planner_depth, config.time_scale, config.rapid_mm_s)
        tau = config.heater_tau_s * config.time_scale
        self.hotend = Heater(tau)
        self.bed = Heater(tau)
        self.last_n = 0
        self.queue: deque[tuple[int | None, str]] = deque()
        self.blocked: _Block | None = None

    def boot(self, t: float) -> None:
        """Power-up (or reset) banner."""
        for text in ("start", "echo:Marlin 2.1.2.1 (fabkit emulator)", "echo:Free Memory: 4096"):
            self.out.raw(text.encode() + self.eol, t)

    @property
    def reading(self) -> bool:
        """True while the firmware takes lines as they arrive (not stuck in a command)."""
        return self.blocked is None and not self.halted

    def next_time(self) -> float:
        if self.blocked is None or self.halted:
            return INF
        return min(self.blocked.wake, self.blocked.report_at)

    def realtime(self, byte: int, t: float) -> None:
        """Marlin has no real-time bytes without EMERGENCY_PARSER: nothing to do."""

    def run(self, t: float) -> None:
        """Marlin's main loop at time ``t``: read lines, execute the queue head, repeat."""
        while not self.halted:
            block = self.blocked
            if block is not None:
                if t >= block.report_at:
                    self._report(block, t)
                if t < block.wake:
                    return
            else:
                self._get_serial_commands(t)
            if not self.queue or not self._advance(t):
                return

    def _report(self, block: _Block, t: float) -> None:
        if block.temperature:
            self.out.line(" " + self._temperatures(t) + " W:?", t)
            block.report_at = t + 1.0
        else:
            self.out.line("busy: processing", t)
            block.report_at = t + self.config.keepalive_s

    def _temperatures(self, t: float) -> str:
        self.hotend.update(t)
        self.bed.update(t)
        return (
            f"T:{self.hotend.temp_c:.2f} /{self.hotend.target_c:.2f} "
            f"B:{self.bed.temp_c:.2f} /{self.bed.target_c:.2f} @:0 B@:0"
        )

    # -- reading ---------------------------------------------------------------------------

    def _get_serial_commands(self, t: float) -> None:
        while len(self.queue) < self.config.command_slots:
            raw = self.inp.take_line(t)
            if raw is None:
                return
            for part in raw.split(b"\r"):
                if not self._accept(part, t):
                    return

    def _accept(self, raw: bytes, t: float) -> bool:
        """Check one line and queue it; False after a line error (the ring was drained)."""
        command = clean_line(raw).lstrip(" ")
        if not command:
            return True
        n = None
        if command.startswith("N"):
            npos = command
            m110 = "M110" in command
            if m110:
                second = command.find("N", 4)
                if second >= 0:
                    npos = command[second:]
            gcode_n = strtol(npos[1:])
            if gcode_n != self.last_n + 1 and not m110:
                return self._line_error(_ERR_LINE_NO, t)
            star = command.rfind("*")
            if star < 0:
                return self._line_error(_ERR_NO_CHECKSUM, t)
            if strtol(command[star + 1 :]) != marlin_checksum(command[:star].encode("latin-1")):
                return self._line_error(_ERR_CHECKSUM, t)
            self.last_n = gcode_n
            n = gcode_n
        elif command.startswith("M410"):
            self.motion.clear()  # processed early, as Marlin does for unnumbered M410
        self.queue.append((n, command))
        return True

    def _line_error(self, message: str, t: float) -> bool:
        self.counters.rejected_lines += 1
        self.out.line(f"Error:{message}{self.last_n}", t)
        if self.config.drain:
            self.inp.drain(t)
        self.out.line(f"Resend: {self.last_n + 1}", t)
        if self.config.resend_ok:
            self.out.line("ok", t)
        return False

    # -- executing -------------------------------------------------------------------------

    def _advance(self, t: float) -> bool:
        """Execute the queue head; False if it has to wait."""
        n, command = self.queue[0]
        text = strip_line_number(command).split("*", 1)[0].rstrip()
        code = code_of(text)
        values = words(text)
        wake = self._wake_time(code, values, t)
        if wake > t:
            if self.blocked is None:
                heating = code in ("M109", "M190")
                report_at = t if heating else t + self.config.keepalive_s
                self.blocked = _Block(wake, report_at, heating)
            self.blocked.wake = wake
            return False
        self.blocked = None
        self.queue.popleft()
        self._execute(n, text, code, values, t)
        return True

    def _wake_time(self, code: str, values: dict[str, float], t: float) -> float:
        """When the command can complete (``t`` or earlier: now)."""
        motion = self.motion
        if code in _MOVES:
            return motion.free_time() if motion.full(t) else t
        if code in _SYNC:
            return motion.idle_time(t)
        if code == "G4":
            if self.blocked is not None:
                return self.blocked.wake
            dwell_s = values.get("P", 0.0) / 1000.0 + values.get("S", 0.0)
            return motion.idle_time(t) + dwell_s * self.config.time_scale
        if code in ("M109", "M190"):
            heater = self.hotend if code == "M109" else self.bed
            if self.blocked is None:
                heater.set_target(values.get("S", values.get("R", heater.target_c)), t)
            return heater.reach_time(t)
        return t

    def _execute(
        self, n: int | None, text: str, code: str, values: dict[str, float], t: float
    ) -> None:
        motion = self.motion
        if code not in KNOWN:
            self.counters.unknown_commands += 1
            self.out.line(f'echo:Unknown command: "{text}"', t)
            self.out.line("ok", t)
            return
        if code in _MOVES:
            motion.move(values, t, rapid=False, arc=int(code[1]) if code in ("G2", "G3") else 0)
        elif code in ("G90", "G91"):
            motion.absolute = motion.absolute_e = code == "G90"
        elif code in ("M82", "M83"):
            motion.absolute_e = code == "M82"
        elif code == "G92":
            motion.set_position(values)
        elif code == "G28":
            motion.home(values)
        elif code in ("M104", "M140"):
            heater = self.hotend if code == "M104" else self.bed
            heater.set_target(values.get("S", heater.target_c), t)
        elif code == "M410":
            motion.clear()
        elif code == "M110" and n is None and "N" in values:
            self.last_n = int(values["N"])
        self._record(n, text, t)
        self._respond(code, t)

    def _respond(self, code: str, t: float) -> None:
        if code == "M112":
            self.out.line("Error:Printer halted. kill() called!", t)
            self.halted = True
            return
        if code == "M105":
            self.out.line("ok " + self._temperatures(t), t)
        elif code == "M114":
            x, y, z, e = self.motion.pos
            self.out.line(f"X:{x:.2f} Y:{y:.2f} Z:{z:.2f} E:{e:.2f} Count X:0 Y:0 Z:0", t)
        elif code == "M115":
            self.out.line("FIRMWARE_NAME:Marlin 2.1.2.1 (fabkit emulator) PROTOCOL_VERSION:1.0", t)
        elif code in ("M109", "M190"):
            self.out.line(" " + self._temperatures(t) + " W:0", t)
        if code != "M105":
            self.out.line("ok", t)
        self._faults(t)

    def _record(self, n: int | None, text: str, t: float) -> None:
        x, y, z, e = self.motion.pos
        self.trace.append(TraceEntry(n, text, x, y, z, e, t))
        self.counters.executed += 1

    def _faults(self, t: float) -> None:
        faults = self.config.faults
        executed = self.counters.executed
        if faults.disconnect_after is not None and executed == faults.disconnect_after:
            self.halted = True
            self.on_disconnect(t)
        elif faults.reset_after is not None and executed == faults.reset_after:
            self.counters.resets += 1
            self._reset_state()
            self.inp.drain(t)
            self.boot(t)
