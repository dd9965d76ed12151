"""The emulated Marlin-protocol firmwares: line numbers, checksums, resends, ok, busy.

It follows Marlin's ``GCodeQueue``: lines are read from the receive ring into a command
queue of ``command_slots`` entries; a line that starts with ``N`` must carry the next
line number and a correct XOR checksum, else the firmware rejects it in its dialect's
words (:mod:`fabkit.link.emulator.dialects`: Marlin 2.1 answers ``Error:<reason>, Last Line:
<n>``, empties its receive ring, asks ``Resend: <n+1>`` and sends ``ok``; Repetier,
Smoothieware, RepRapFirmware and the other Marlin versions differ). A line without
``N`` is executed unchecked, as in Marlin. ``ok`` follows each executed command (M105
answers ``ok T:...`` instead; Repetier acknowledges ``ok <n>`` when it queues a line);
moves wait for room in the planner, M109/M190/M400/G4/G28 wait for their condition,
printing the dialect's busy line or temperature reports meanwhile.
"""

from __future__ import annotations

import re
from collections import deque
from dataclasses import dataclass, replace

from fabkit.gcode.read import code_of, marlin_checksum, words
from fabkit.link.emulator.dialects import DIALECTS, Dialect
from fabkit.link.emulator.firmware import (
    INF,
    EmulatorConfig,
    Faults,
    Firmware,
    Heater,
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
_ERR_NO_LINE_NO = "No Line Number with checksum, Last Line: "
REPETIER_SKIP_LINES = 14  # Repetier's waitingForResend after a resend request (gcode.cpp)
REPETIER_SEEN_LINES = 40  # a line number this close behind the last one is a repeat
_STRTOL = re.compile(r"\s*([-+]?\d+)")
_FRAMED = re.compile(rb"N([0-9]+) ([^*;\\\x08]*)\*([0-9]+)")
"""``N<n> <command>*<checksum>`` with nothing in it that :func:`clean_line` changes."""
_NUMBER = rb"[-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)"  # as fabkit.gcode.read.words reads one
_MOVE_LINE = re.compile(
    rb"^(?=[^\n]{0,%d}\n)(N([0-9]+) (G[01](?: [XYZEF]%s)*))\*([0-9]+)\n"
    % (MAX_CMD_SIZE - 1, _NUMBER),
    re.MULTILINE,
)
"""A whole line ``N<n> G0|G1 X.. Y.. F..*<checksum>``: :meth:`MarlinFirmware._framed` takes
it as it is (short enough, nothing :func:`clean_line` changes), its code is G0 or G1 and
:func:`~fabkit.gcode.read.words` reads its text as upper-case letters, each with the number
after it (groups: what is summed, the number, the text, the checksum)."""
_CODES: dict[str, str] = {}  # first word of a command -> its code (command_code)
_CODES_KEPT = 256

_MOVES = {"G0", "G1", "G2", "G3"}
_SYNC = {"M400", "G28", "G29", "M84", "M18"}
_NO_EFFECT = {
    "G21", "M17", "M106", "M107", "M42", "M3", "M4", "M5", "M7", "M8", "M9",
    "M117", "M118", "M201", "M203", "M204", "M205", "M220", "M221", "M300", "M999",
    "T0", "T1", "M110",
}  # fmt: skip
_ANSWERING = {"M112", "M105", "M109", "M190", "M114", "M115"}  # more than an ok
KNOWN = _MOVES | _SYNC | _NO_EFFECT | {
    "G4", "G90", "G91", "G92", "M82", "M83", "M104", "M105", "M109", "M112", "M114",
    "M115", "M140", "M190", "M410",
}  # fmt: skip


def strtol(text: str, start: int = 0) -> int:
    """C ``strtol(text + start, nullptr, 10)``: the leading integer, 0 if none."""
    match = _STRTOL.match(text, start)
    return int(match.group(1)) if match else 0


def strip_line_number(command: str) -> str:
    """The command without a leading ``N<digits>`` word (Marlin skips up to the first space)."""
    if len(command) > 1 and command[0] == "N" and (command[1].isdigit() or command[1] in "+-"):
        return command.split(" ", 1)[1].lstrip(" ") if " " in command else ""
    return command


def clean_line(raw: bytes) -> str:
    """Marlin's ``process_stream_char``: ``;`` comments, ``\\`` escapes, backspace, and
    characters past MAX_CMD_SIZE - 1 dropped."""
    if b";" not in raw and b"\\" not in raw and b"\x08" not in raw:
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


def command_code(text: str) -> str:
    """:func:`~fabkit.gcode.read.code_of`, remembered by the text's first word: the code
    depends on nothing else when neither of the text's first two characters is a blank
    (its pattern then matches inside the first word, and the words it splits are the
    same), so the few words a job starts its lines with are read once."""
    head = text.partition(" ")[0]
    code = _CODES.get(head)
    if code is None:
        code = code_of(text)
        blank = len(head) < 2 or head[0].isspace() or head[1].isspace()
        if not blank and len(_CODES) < _CODES_KEPT:
            _CODES[head] = code
    return code


def command_text(command: str) -> str:
    """The command as it runs: without line number and checksum."""
    return strip_line_number(command).split("*", 1)[0].rstrip()


@dataclass
class _Block:
    """The command at the head of the queue is waiting until ``wake`` (s)."""

    wake: float
    report_at: float
    temperature: bool


class MarlinFirmware(Firmware):
    """A Marlin-protocol firmware (:class:`Dialect`) on top of a :class:`Motion`."""

    noise_lines = NOISE_LINES

    @staticmethod
    def dialect_of(config: EmulatorConfig) -> Dialect:
        """The config's dialect with its overrides (``resend_ok``, ``drain``,
        ``ack_on_queue``, ``ack_numbered``) applied."""
        dialect = DIALECTS[config.dialect]
        changes = {
            key: getattr(config, key)
            for key in ("resend_ok", "drain", "ack_on_queue", "ack_numbered")
            if getattr(config, key) is not None
        }
        return replace(dialect, **changes) if changes else dialect

    @staticmethod
    def eol_for(config: EmulatorConfig) -> bytes:
        return MarlinFirmware.dialect_of(config).eol

    def _start(self) -> None:
        self.dialect = self.dialect_of(self.config)
        faults = self.config.faults
        self.counting = faults.disconnect_after is not None or faults.reset_after is not None
        """A fault counts the commands (``disconnect_after``, ``reset_after``)."""
        dialect = self.dialect
        self.direct = (
            faults == Faults()
            and dialect.line_error == "marlin"
            and not dialect.ack_on_queue
            and not dialect.idle_wait_s
            and self.config.command_slots >= 1
        )
        """:meth:`take_moves` may run move lines: no fault, Marlin's or Prusa's checks,
        ``ok`` after running, no idle ``wait``, a command queue."""
        self.ok_bytes = b"ok" + dialect.eol
        """The ``ok`` line as :meth:`take_moves` sends it."""
        self._reset_state()

    def _reset_state(self) -> None:
        config = self.config
        self.motion = config.motion()
        tau = config.heater_tau_s * config.time_scale
        self.hotend = Heater(tau)
        self.bed = Heater(tau)
        self.last_n = 0
        self.queue: deque[tuple[int | None, str, str]] = deque()
        """Queued commands: line number, command as received, its :func:`command_text`."""
        self.blocked: _Block | None = None
        self.waiting_for_resend = -1  # Repetier: lines still answered with "skip"
        self.acked = 0  # lines acknowledged when queued (Repetier)
        self.deaf = False  # the line is dead: nothing more is read
        self.wait_at = INF  # Repetier: when "wait" is due

    def boot(self, t: float) -> None:
        """Power-up (or reset) banner."""
        for text in self.dialect.banner:
            self.out.raw(text.encode() + self.out.eol, t)
        self._idle(t)

    @property
    def reading(self) -> bool:
        """True while the firmware takes lines as they arrive (not stuck in a command)."""
        return self.blocked is None and not self.halted

    def next_time(self) -> float:
        if self.halted:
            return INF
        if self.blocked is None:
            return self.wait_at
        return min(self.blocked.wake, self.blocked.report_at)

    def realtime(self, byte: int, t: float) -> None:
        """Marlin has no real-time bytes without EMERGENCY_PARSER: nothing to do."""

    def run(self, t: float) -> None:
        """The main loop at time ``t``: read lines, execute the queue head, repeat."""
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
                if not self.queue and self.blocked is None and t >= self.wait_at:
                    self.out.line("wait", t)  # Repetier: "the last ok may be lost"
                    self.wait_at = t + self.dialect.idle_wait_s
                return

    def _idle(self, t: float) -> None:
        """Input or work happened at ``t``: the next idle ``wait`` is due a while later."""
        self.wait_at = t + self.dialect.idle_wait_s if self.dialect.idle_wait_s else INF

    def _report(self, block: _Block, t: float) -> None:
        if block.temperature:
            self.out.line(" " + self._temperatures(t) + " W:?", t)
            block.report_at = t + 1.0
        else:
            if self.dialect.busy:
                self.out.line(self.dialect.busy, t)
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
        while len(self.queue) < self.config.command_slots and not self.deaf:
            raw = self.inp.take_line(t)
            if raw is None:
                return
            self._idle(t)
            for part in raw.split(b"\r"):
                if not self._accept(part, t):
                    return

    def _accept(self, raw: bytes, t: float) -> bool:
        """Check one line and queue it; False after a line error that drained the ring."""
        if self.dialect.line_error == "marlin" and self._accept_framed(raw, t):
            return True
        command = clean_line(raw).lstrip(" ")
        if not command:
            return True
        style = self.dialect.line_error
        if style == "silent":
            return self._accept_unsequenced(command)
        if style == "smoothie":
            return self._accept_smoothie(command, t)
        if not command.startswith("N"):
            if self.dialect.strict_star and "*" in command:
                return self._line_error(_ERR_NO_LINE_NO, t)
            if command.startswith("M410"):
                self.motion.clear(t)  # processed early, as Marlin does for unnumbered M410
            return self._queue(None, command, t)
        npos = 0
        m110 = "M110" in command
        if m110:
            second = command.find("N", 4)
            if second >= 0:
                npos = second
        gcode_n = strtol(command, npos + 1)
        star = command.rfind("*")
        if style == "repetier":
            return self._accept_repetier(command, gcode_n, star, m110, t)
        if gcode_n != self.last_n + 1 and not m110:
            return self._line_error(_ERR_LINE_NO, t)
        if star < 0:
            return self._line_error(_ERR_NO_CHECKSUM, t)
        if not _checksum_ok(command, star):
            return self._line_error(_ERR_CHECKSUM, t)
        self.last_n = gcode_n
        return self._queue(gcode_n, command, t)

    def _accept_framed(self, raw: bytes, t: float) -> bool:
        """The common line on Marlin and Prusa, checked and queued as :meth:`_accept`
        would, in fewer steps (:meth:`_framed`); False (nothing done) for any other line."""
        framed = self._framed(raw)
        if framed is None:
            return False
        self.last_n, text = framed
        return self._queue(self.last_n, raw.decode("latin-1"), t, text)

    def _framed(self, raw: bytes) -> tuple[int, str] | None:
        """The number and text of ``N<next> <command>*<checksum>``, short enough, that
        :func:`clean_line` leaves as it is, without ``M110`` and with the right number and
        checksum; None for any other line (:meth:`_accept` reads it, errors included)."""
        if len(raw) >= MAX_CMD_SIZE or b"M110" in raw:
            return None
        framed = _FRAMED.fullmatch(raw)
        if framed is None:
            return None
        n = int(framed[1])
        if n != self.last_n + 1 or int(framed[3]) != marlin_checksum(raw[: framed.start(3) - 1]):
            return None
        return n, framed[2].decode("latin-1").lstrip(" ").rstrip()

    def take_moves(self, data: bytes, t: float) -> bool:
        """Run the lines of ``data`` (whole lines only, each ending in a newline), which all
        arrived at ``t``, as :meth:`run` would, if every one is a framed move with the next
        number and the right checksum (:meth:`_moves`), the firmware is idle (reading,
        nothing queued) and the planner has room for them all: checked, queued, run and
        answered at once, the way :meth:`run` does it then, step for step (it reads up to
        ``command_slots`` of them ahead of the one it runs, but reading a good line says
        nothing, so the answers and the trace come out the same). False, with nothing
        done, otherwise. Only for :attr:`direct` firmwares: no fault, ``ok`` after
        running, no ``wait``."""
        if self.blocked is not None or self.halted or self.deaf or self.queue:
            return False
        moves = self._moves(data)
        motion = self.motion
        if moves is None or motion.blocks and motion.planned(t) + len(moves) > motion.depth:
            return False
        trace, n = self.trace, self.last_n
        for text, values in moves:
            n += 1
            motion.move(values, t, rapid=False, tag=len(trace))
            x, y, z, e = motion.pos
            trace.append(TraceEntry(n, text, x, y, z, e, t))
        self.last_n = n
        self.counters.executed += len(moves)
        self.out.raw(self.ok_bytes * len(moves), t)  # out.line("ok", ...) on a faultless output
        return True

    def _moves(self, data: bytes) -> list[tuple[str, dict[str, float]]] | None:
        """The text and :func:`~fabkit.gcode.read.words` of each line of ``data`` if every
        one is a :data:`_MOVE_LINE` that carries the next number after ``last_n`` (in
        order) and the right checksum; None otherwise."""
        lines = _MOVE_LINE.findall(data)
        if len(lines) != data.count(b"\n") or not data.endswith(b"\n"):
            return None
        n = self.last_n
        moves = []
        for summed, number, body, checksum in lines:
            n += 1
            if int(number) != n or int(checksum) != marlin_checksum(summed):
                return None
            text = body.decode("latin-1")
            moves.append((text, {word[0]: float(word[1:]) for word in text.split(" ")}))
        return moves

    def _queue(self, n: int | None, command: str, t: float, text: str | None = None) -> bool:
        """Queue ``command`` (``text``: :func:`command_text` of it, if known)."""
        self.queue.append((n, command, command_text(command) if text is None else text))
        if self.dialect.ack_on_queue:
            ok = f"ok {n}" if n is not None and self.dialect.ack_numbered else "ok"
            self.out.line(ok, t, n)
            self.acked += 1
            self._faults(t)
        return True

    def _line_error(self, message: str, t: float) -> bool:
        """Marlin and Prusa: ``Error:``, drain, ``Resend:`` and (by version) ``ok``."""
        self.counters.rejected_lines += 1
        self.out.line(f"Error:{message}{self.last_n}", t)
        if self.dialect.drain:
            self.inp.drain(t)
        self.out.line(f"Resend: {self.last_n + 1}", t)
        if self.dialect.resend_ok:
            self.out.line("ok", t)
        return False

    def _accept_repetier(self, command: str, n: int, star: int, m110: bool, t: float) -> bool:
        """Repetier's ``parseAscii`` (checksum) then ``checkAndPushCommand`` (sequence)."""
        if star >= 0 and not _checksum_ok(command, star):
            self.out.line("Error:Wrong checksum", t)
            return self._request_resend(t)
        if m110:
            self.last_n = n
            self.waiting_for_resend = -1
            self.out.line("ok", t)
            return True
        expected = self.last_n + 1
        if n % 65536 != expected % 65536:
            if (self.last_n - n) % 65536 < REPETIER_SEEN_LINES:
                return self._skip(n, t)
            if self.waiting_for_resend < 0:
                self.out.line(f"Error:expected line {expected} got {n}", t)
                return self._request_resend(t)
            self.waiting_for_resend -= 1
            return self._skip(n, t)
        self.last_n = n
        self.waiting_for_resend = -1
        return self._queue(n, command, t)

    def _skip(self, n: int, t: float) -> bool:
        self.counters.rejected_lines += 1
        self.out.line(f"skip {n}", t)
        self.out.line("ok", t)
        return True

    def _request_resend(self, t: float) -> bool:
        self.counters.rejected_lines += 1
        self.waiting_for_resend = REPETIER_SKIP_LINES
        self.out.line("", t)
        self.out.line(f"Resend:{self.last_n + 1}", t)
        self.out.line("ok", t)
        return False

    def _accept_smoothie(self, command: str, t: float) -> bool:
        """Smoothieware's ``on_console_line_received``: ``rs N<next>`` on any mismatch."""
        if not command.startswith(("G", "M", "T", "S", "N")):
            self.out.line("ok - ignored", t)
            return True
        if not command.startswith("N"):
            return self._queue(None, command, t)
        n = strtol(command, 1)
        if "M110" in command:
            self.last_n = n
            self.out.line("ok", t)
            return True
        star = command.find("*")
        if n != self.last_n + 1 or (star >= 0 and not _checksum_ok(command, star)):
            self.counters.rejected_lines += 1
            self.out.line(f"rs N{self.last_n + 1}", t)
            return True
        self.last_n = n
        return self._queue(n, command, t)

    def _accept_unsequenced(self, command: str) -> bool:
        """RepRapFirmware: a bad checksum drops the line without a word; numbers unchecked."""
        star = command.rfind("*")
        missing = star < 0 and self.dialect.checksum_required
        if missing or star >= 0 and not _checksum_ok(command, star):
            self.counters.rejected_lines += 1
            return True
        n = strtol(command, 1) if command.startswith("N") else None
        self.queue.append((n, command, command_text(command)))
        return True

    # -- executing -------------------------------------------------------------------------

    def _advance(self, t: float) -> bool:
        """Execute the queue head; False if it has to wait."""
        n, command, text = self.queue[0]
        code = command_code(text)
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
        self._execute(n, command, text, code, values, t)
        self._idle(t)
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
        self, n: int | None, command: str, text: str, code: str, values: dict[str, float], t: float
    ) -> None:
        motion = self.motion
        if code in _MOVES:
            arc = int(code[1]) if code in ("G2", "G3") else 0
            motion.move(values, t, rapid=False, arc=arc, tag=len(self.trace))
        elif code not in KNOWN:
            self._unknown(n, text, t)
            return
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
            motion.clear(t)
        elif code == "M110" and n is None and "N" in values:
            self.last_n = int(values["N"])
        self._record(n, command, text, t)
        self._respond(n, code, t)

    def _unknown(self, n: int | None, text: str, t: float) -> None:
        """A command the firmware does not know (line ``n``), in the dialect's words
        (nothing runs)."""
        self.counters.unknown_commands += 1
        style = self.dialect.line_error
        if style == "repetier":
            self.out.line(f"Unknown command:{text}", t)
        elif style == "silent":
            self.out.line(f"Error: Bad command: {text}", t)
            self.out.line("ok", t, n)
        elif style == "smoothie":
            self.out.line("ok", t, n)
        else:
            self.out.line(f'echo:Unknown command: "{text}"', t)
            self.out.line("ok", t, n)

    def _respond(self, n: int | None, code: str, t: float) -> None:
        """The answer to line ``n``, which ran ``code``."""
        out = self.out
        if code not in _ANSWERING:  # most commands: just the ok
            if not self.dialect.ack_on_queue:
                out.line("ok", t, n)
            self._faults(t)
            return
        if code == "M112":
            out.line("Error:Printer halted. kill() called!", t)
            self.halted = True
            return
        temperatures = self._temperatures(t) if code in ("M105", "M109", "M190") else ""
        if code == "M105" and not self.dialect.ack_on_queue:
            out.line("ok " + temperatures, t, n)
            self._faults(t)
            return
        if code == "M105":
            out.line(temperatures, t)
        elif code == "M114":
            x, y, z, e = self.motion.pos
            out.line(f"X:{x:.2f} Y:{y:.2f} Z:{z:.2f} E:{e:.2f} Count X:0 Y:0 Z:0", t)
        elif code == "M115":
            out.line(self.dialect.firmware_name, t)
            if self.dialect.name.startswith("marlin-2"):
                for cap in ("Cap:EEPROM:1", "Cap:AUTOREPORT_TEMP:1", "Cap:EMERGENCY_PARSER:0"):
                    out.line(cap, t)
        elif code in ("M109", "M190"):
            out.line(" " + temperatures + " W:0", t)
        if not self.dialect.ack_on_queue:
            out.line("ok", t, n)
        self._faults(t)

    def _record(self, n: int | None, command: str, text: str, t: float) -> None:
        x, y, z, e = self.motion.pos
        checked = n is None or "*" in command
        if not checked:
            self.counters.unchecked_lines += 1
        self.trace.append(TraceEntry(n, text, x, y, z, e, t, checked))
        self.counters.executed += 1

    def _faults(self, t: float) -> None:
        """``disconnect_after``: the line goes dead after that many acknowledged commands,
        and the machine runs exactly what it acknowledged (for a firmware that
        acknowledges when it queues, the queue is run first)."""
        if not self.counting:
            return
        faults = self.config.faults
        executed = self.counters.executed
        acked = self.acked if self.dialect.ack_on_queue else executed
        if faults.disconnect_after is not None and acked >= faults.disconnect_after:
            self.deaf = True
            if not self.queue or not self.dialect.ack_on_queue:
                self.halted = True
                self.on_disconnect(t)
        elif faults.reset_after is not None and executed == faults.reset_after:
            self.counters.resets += 1
            self._reset_state()
            self.inp.drain(t)
            self.boot(t)


def _checksum_ok(command: str, star: int) -> bool:
    """The XOR of the bytes before ``*`` equals the number after it."""
    return strtol(command, star + 1) == marlin_checksum(command[:star].encode("latin-1"))
