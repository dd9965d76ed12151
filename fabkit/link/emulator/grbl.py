"""The emulated GRBL 1.1 firmware: character counting, ok / error:N, ALARM, real-time bytes.

GRBL has no line numbers and no checksums. Each line (``\\n`` or ``\\r`` ends it, so
``\\r\\n`` is a line plus an empty line) gets exactly one ``ok`` or ``error:N`` once it
has been parsed and, for a move, put into the planner (the parser waits while the
planner is full, and the receive ring fills meanwhile). ``?``, ``!``, ``~`` and Ctrl-X
are picked off the wire on arrival: status report, feed hold, resume, soft reset.
"""

from __future__ import annotations

import re
from collections import deque
from dataclasses import dataclass

from fabkit.link.emulator.firmware import (
    INF,
    Firmware,
    TraceEntry,
)

REALTIME = b"?!~\x18"
BANNER = b"\r\nGrbl 1.1h ['$' for help]\r\n"
LINE_BUFFER_SIZE = 80
NOISE_LINES = ("[MSG:fabkit emulator noise]", "[echo:]", "\x00\x7f")

_WORD = re.compile(r"([A-Z])([-+]?(?:\d+\.?\d*|\.\d+))")
_G_SUPPORTED = {
    0, 1, 2, 3, 4, 10, 17, 18, 19, 20, 21, 28, 28.1, 30, 30.1, 38.2, 38.3, 38.4, 38.5,
    40, 43.1, 49, 53, 54, 55, 56, 57, 58, 59, 61, 80, 90, 91, 91.1, 92, 92.1, 93, 94,
}  # fmt: skip
_M_SUPPORTED = {0, 1, 2, 30, 3, 4, 5, 7, 8, 9, 56}
_LETTERS = set("FGIJKLMNPRSTXYZ")
_SYNC_M = {0, 1, 2, 30, 3, 4, 5, 7, 8, 9}
_MOTION_G = {0, 1, 2, 3, 38.2, 38.3, 38.4, 38.5, 80}


def grbl_clean(raw: bytes) -> tuple[str, bool]:
    """GRBL's line filter: no blanks or control characters, no ``( )`` / ``;`` comments,
    upper case. Returns the line and whether it overflowed the line buffer."""
    out: list[str] = []
    in_paren = False
    for c in raw.decode("latin-1"):
        if in_paren:
            in_paren = c != ")"
        elif c == "(":
            in_paren = True
        elif c == ";":
            break
        elif c > " " and c != "/":
            out.append(c.upper())
    return "".join(out[: LINE_BUFFER_SIZE - 1]), len(out) >= LINE_BUFFER_SIZE


@dataclass
class _Parsed:
    """One parsed block waiting to complete (s, mm)."""

    text: str
    g: list[float]
    m: list[int]
    values: dict[str, float]
    motion: float | None
    dwell_s: float


class GrblFirmware(Firmware):
    """GRBL's protocol loop and a subset of its G-code interpreter on a :class:`Motion`."""

    eol = b"\r\n"
    noise_lines = NOISE_LINES

    def _start(self) -> None:
        self.alarm = False
        self._reset_state()

    def _reset_state(self) -> None:
        config = self.config
        self.motion = config.motion(config.planner_depth - 1)  # a ring keeps one block free
        self.motion_mode: float = 0
        self.head: _Parsed | None = None
        self.wake = INF
        self.parts: deque[bytes] = deque()
        self.spindle = 0.0

    def boot(self, t: float) -> None:
        self.out.raw(BANNER, t)

    @property
    def reading(self) -> bool:
        return self.head is None and not self.parts and not self.halted

    def next_time(self) -> float:
        return INF if self.halted or self.head is None else self.wake

    def state(self, t: float) -> str:
        if self.alarm:
            return "Alarm"
        if self.motion.held_since is not None:
            return "Hold:0"
        return "Run" if self.head is not None or self.motion.busy(t) else "Idle"

    # -- real-time bytes -------------------------------------------------------------------

    def realtime(self, byte: int, t: float) -> None:
        if self.halted:
            return
        if byte == ord("?"):
            self._status(t)
        elif byte == ord("!") and not self.alarm:
            self.motion.hold(t)
            self._refresh_wake(t)
        elif byte == ord("~"):
            self.motion.resume(t)
            self._refresh_wake(t)
        elif byte == 0x18:
            self._soft_reset(t)

    def _status(self, t: float) -> None:
        """``<State|MPos:x,y,z|Bf:planner,rx|FS:feed,speed>`` (grbl/report.c): MPos where the
        tool really is, Bf the free planner blocks and receive-buffer bytes (as
        ``serial_get_rx_buffer_available``: RX_BUFFER_SIZE when empty), when ``$10``
        asks for it (``bf``)."""
        x, y, z, _ = self.motion.position_at(t)
        if not self.reading:
            self.inp.fill(t)
        planner_free = self.motion.depth - self.motion.planned(t)
        rx_free = self.inp.capacity + 1 - len(self.inp.pending)
        feed = (self.motion.feed_mm_s or 0.0) * 60.0
        buffer = f"|Bf:{planner_free},{rx_free}" if self.config.grbl_bf else ""
        self.out.line(
            f"<{self.state(t)}|MPos:{x:.3f},{y:.3f},{z:.3f}{buffer}"
            f"|FS:{feed:.0f},{self.spindle:.0f}>",
            t,
        )

    def _soft_reset(self, t: float) -> None:
        moving = self.motion.held_since is None and self.motion.busy(t)
        self.counters.resets += 1
        self._reset_state()
        self.inp.drain(t)
        if moving:
            self.alarm = True
            self.out.line("ALARM:3", t)
        self.boot(t)
        if self.alarm:
            self.out.line("[MSG:'$H'|'$X' to unlock]", t)

    def _refresh_wake(self, t: float) -> None:
        if self.head is not None:
            self.wake = self._wake_time(self.head, t)

    # -- the protocol loop -----------------------------------------------------------------

    def run(self, t: float) -> None:
        while not self.halted:
            if self.head is not None:
                self.wake = self._wake_time(self.head, t)
                if self.wake > t:
                    return
                head, self.head = self.head, None
                self._complete(head, t)
            if not self.parts:
                raw = self.inp.take_line(t)
                if raw is None:
                    return
                self.parts.extend(raw.split(b"\r"))
            self._line(self.parts.popleft(), t)

    def _line(self, raw: bytes, t: float) -> None:
        line, overflow = grbl_clean(raw)
        text = raw.decode("latin-1").strip()
        if overflow:
            self.out.line("error:11", t)
        elif not line:
            self.out.line("ok", t)
        elif line.startswith("$"):
            self._system(line, t)
        elif self.alarm:
            self.out.line("error:9", t)
        else:
            parsed, error = self._parse(line, text)
            if error:
                self.out.line(f"error:{error}", t)
                return
            self.head = parsed
            self.wake = t

    def _parse(self, line: str, text: str) -> tuple[_Parsed | None, int]:
        pos = 0
        g: list[float] = []
        m: list[int] = []
        values: dict[str, float] = {}
        for match in _WORD.finditer(line):
            if match.start() != pos:
                return None, 1 if not line[pos].isalpha() else 2
            letter, number = match.group(1), float(match.group(2))
            if letter not in _LETTERS:
                return None, 20
            if letter == "G":
                g.append(number)
            elif letter == "M":
                m.append(int(number))
            elif letter in values:
                return None, 25
            else:
                values[letter] = number
            pos = match.end()
        if pos != len(line):
            return None, 1 if not line[pos].isalpha() else 2
        if any(code not in _G_SUPPORTED for code in g) or any(c not in _M_SUPPORTED for c in m):
            return None, 20
        motion = self._motion_of(g, values)
        needs_feed = motion in (1, 2, 3) and "F" not in values and not self.motion.feed_mm_s
        if needs_feed:
            return None, 22
        dwell_s = values.get("P", 0.0) if 4 in g else 0.0
        return _Parsed(text, g, m, values, motion, dwell_s), 0

    def _motion_of(self, g: list[float], values: dict[str, float]) -> float | None:
        """The motion of the block: a motion G word, or the modal one for axis words."""
        explicit = [code for code in g if code in _MOTION_G]
        if explicit:
            return explicit[-1]
        axes = any(axis in values for axis in "XYZ")
        if axes and not any(code in (10, 28, 30, 92) for code in g):
            return self.motion_mode
        return None

    def _wake_time(self, block: _Parsed, t: float) -> float:
        motion = self.motion
        moving = block.motion in (0, 1, 2, 3) and any(axis in block.values for axis in "XYZ")
        if moving and motion.full(t):
            return motion.free_time()
        synced = block.dwell_s > 0 or any(code in (28, 30) for code in block.g)
        if synced or any(code in _SYNC_M for code in block.m):
            return motion.idle_time(t) + block.dwell_s * self.config.time_scale
        return t

    def _complete(self, block: _Parsed, t: float) -> None:
        motion, values = self.motion, block.values
        for code in block.g:
            if code in (20, 21):
                motion.unit_mm = 25.4 if code == 20 else 1.0
            elif code in (90, 91):
                motion.absolute = motion.absolute_e = code == 90
            elif code == 92:
                motion.set_position(values)
            elif code in (28, 30):
                motion.home({})
        if "F" in values:
            motion.feed_mm_s = values["F"] * motion.unit_mm / 60.0
        if "S" in values:
            self.spindle = values["S"]
        if block.motion is not None:
            self.motion_mode = block.motion
            if block.motion in (0, 1, 2, 3) and any(axis in values for axis in "XYZ"):
                arc = int(block.motion) if block.motion in (2, 3) else 0
                motion.move(values, t, rapid=block.motion == 0, arc=arc, tag=len(self.trace))
        if 0 in block.m or 1 in block.m:
            motion.hold(t)
        x, y, z, e = motion.pos
        self.trace.append(TraceEntry(None, block.text, x, y, z, e, t))
        self.counters.executed += 1
        if 2 in block.m or 30 in block.m:
            self.out.line("[MSG:Pgm End]", t)
        self.out.line("ok", t)
        self._faults(t)

    def _system(self, line: str, t: float) -> None:
        if line == "$X":
            if self.alarm:
                self.alarm = False
                self.out.line("[MSG:Caution: Unlocked]", t)
        elif line == "$H":
            self.alarm = False
            self.motion.home({})
        elif line == "$I":
            self.out.line("[VER:1.1h.20190830:fabkit emulator]", t)  # grbl/report.c build info
            sizes = f",{self.motion.depth},{self.inp.capacity + 1}" if self.config.grbl_opt else ""
            self.out.line(f"[OPT:V{sizes}]", t)
        elif line == "$G":
            mode = "G90" if self.motion.absolute else "G91"
            self.out.line(f"[GC:G{self.motion_mode:g} G54 G17 G21 {mode} G94 M5 M9 T0 F0 S0]", t)
        elif line == "$$":
            for setting in ("$0=10", "$10=3", "$32=0", "$110=3000.000", "$120=100.000"):
                self.out.line(setting, t)
        else:
            self.out.line("error:3", t)
            return
        self.out.line("ok", t)

    def _faults(self, t: float) -> None:
        faults = self.config.faults
        executed = self.counters.executed
        if faults.disconnect_after is not None and executed == faults.disconnect_after:
            self.halted = True
            self.on_disconnect(t)
        elif faults.reset_after is not None and executed == faults.reset_after:
            self._soft_reset(t)
