"""The emulated GRBL 1.1 firmware: character counting, ok / error:N, ALARM, real-time bytes.

GRBL has no line numbers and no checksums. Each line (``\\n`` or ``\\r`` ends it, so
``\\r\\n`` is a line plus an empty line) gets exactly one ``ok`` or ``error:N`` once it
has been parsed and, for a move, put into the planner. ``?``, ``!``, ``~`` and Ctrl-X
are picked off the wire on arrival: status report, feed hold, resume, soft reset.

It fails where GRBL 1.1h fails (gnea/grbl, read from its source):

* **The receive ring drops what does not fit.** The serial interrupt (``serial.c``,
  ``ISR(SERIAL_RX)``) writes a byte into the ring only ``if (next_head !=
  serial_rx_buffer_tail)``: a byte arriving at a full ring is lost, and the halves of
  two lines merge into one. The main loop (``protocol.c``, ``protocol_main_loop``) empties
  the ring only between lines; while a line executes (the parser waits for planner room
  in ``mc_line``, a dwell or a buffer sync waits for the moves to end) bytes pile up.
  The emulated ring holds ``rx - 1`` bytes (127 by default, one fewer than 1.1h's 128:
  stricter than the firmware).
* **Status before parse.** ``?`` only sets a flag; it is answered at the next
  ``protocol_execute_realtime`` call: during every wait, and at the end of a line
  *before* that line is parsed (``protocol_main_loop``: the check point right after the
  EOL). A report can thus say ``Idle`` while lines wait in the ring unanswered.
* **Idle during a dwell.** ``G4`` (``mc_dwell``) first waits for the planned moves to
  end (``protocol_buffer_synchronize``: the state is ``Run``), then sleeps in
  ``delay_sec`` in steps of 50 ms (``DWELL_TIME_STEP``), answering status reports as
  ``Idle``, and only then answers ``ok``; the lines behind it wait in the ring.
* **Merged lines are read as one.** ``gc_execute_line`` (``gcode.c``, step 2) refuses a
  second motion or non-modal axis command (``error:24``), a second command of one modal
  group (``error:21``), a repeated value word (``error:25``), a negative ``F``/``N``/
  ``P``/``S``/``T`` (``error:4``); step 3 refuses words the block does not use
  (``error:36``): ``P`` without ``G4``/``G10``, ``L`` without ``G10``, ``I J K R``
  without an arc. A merge that passes these runs as a move nobody asked for.
"""

from __future__ import annotations

import math
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
DWELL_STEP_S = 0.05  # nuts_bolts.c delay_sec: a dwell sleeps in whole 50 ms steps
NOISE_LINES = ("[MSG:fabkit emulator noise]", "[echo:]", "\x00\x7f")

_WORD = re.compile(r"([A-Z])([-+]?(?:\d+\.?\d*|\.\d+))")
_G_GROUPS = {
    **dict.fromkeys((4, 10, 28, 30, 53, 92, 28.1, 30.1, 92.1), 0),
    **dict.fromkeys((0, 1, 2, 3, 38.2, 38.3, 38.4, 38.5, 80), 1),
    17: 2, 18: 2, 19: 2, 90: 3, 91: 3, 91.1: 4, 93: 5, 94: 5, 20: 6, 21: 6, 40: 7,
    43.1: 8, 49: 8, **dict.fromkeys((54, 55, 56, 57, 58, 59), 12), 61: 13,
}  # fmt: skip
"""Modal group of each G command GRBL 1.1h knows (gcode.c, step 2; gcode.h MODAL_GROUP_G*)."""
_G_INTEGER = {0, 1, 2, 3, 4, 10, 17, 18, 19, 20, 21, 40, 53, 54, 55, 56, 57, 58, 59, 80, 93, 94}
"""Commands GRBL reads by their integer part: a fraction of them is error:23."""
_AXIS_COMMANDS = {0, 1, 2, 3, 38.2, 38.3, 38.4, 38.5, 10, 28, 30, 92, 43.1, 49}
"""Commands that use the axis words: two in a block is error:24."""
_M_GROUPS = {0: 4, 1: 4, 2: 4, 30: 4, 3: 7, 4: 7, 5: 7, 7: 8, 8: 8, 9: 8, 56: 9}
_LETTERS = set("FGIJKLMNPRSTXYZ")
_NOT_NEGATIVE = set("FNPST")
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
    """One parsed block waiting to complete (s, mm). ``dwell_ends`` is set once the
    moves before a dwell have ended: the emulator time at which its sleep ends."""

    text: str
    g: list[float]
    m: list[int]
    values: dict[str, float]
    motion: float | None
    dwell_s: float
    dwell_ends: float | None = None


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
        return "Run" if self.motion.busy(t) else "Idle"  # Idle in a dwell's sleep

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
        """The block of ``line`` (cleaned), or the ``error:N`` GRBL answers it with."""
        words = _read_words(line)
        if isinstance(words, int):
            return None, words
        g, m, values = words
        motion = self._motion_of(g, values)
        if 4 in g and "P" not in values:
            return None, 28  # G4 without P: value word missing
        needs_feed = motion in (1, 2, 3) and "F" not in values and not self.motion.feed_mm_s
        if needs_feed:
            return None, 22
        if _unused_words(g, values, motion):
            return None, 36
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
        """When ``block`` can complete: a move once the planner has room, a synced command
        once the moves before it have ended, a dwell then its sleep later."""
        motion = self.motion
        moving = block.motion in (0, 1, 2, 3) and any(axis in block.values for axis in "XYZ")
        if moving and motion.full(t):
            return motion.free_time()
        synced = block.dwell_s > 0 or any(code in (28, 30) for code in block.g)
        if not (synced or any(code in _SYNC_M for code in block.m)):
            return t
        if block.dwell_ends is None:
            idle = motion.idle_time(t)
            if idle > t:
                return idle
            steps = math.ceil(block.dwell_s / DWELL_STEP_S - 1e-9)
            block.dwell_ends = t + steps * DWELL_STEP_S * self.config.time_scale
        return block.dwell_ends

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


def _read_words(line: str) -> tuple[list[float], list[int], dict[str, float]] | int:
    """The G and M commands and value words of a cleaned line, checked as
    ``gc_execute_line`` does in its step 2; or the number of its ``error:N``."""
    pos = 0
    g: list[float] = []
    m: list[int] = []
    values: dict[str, float] = {}
    groups: set[str] = set()
    axis_command = False
    for match in _WORD.finditer(line):
        if match.start() != pos:
            return 1 if not line[pos].isalpha() else 2
        letter, number = match.group(1), float(match.group(2))
        pos = match.end()
        if letter not in _LETTERS:
            return 20
        if letter == "G":
            code = round(number, 2)
            if code not in _G_GROUPS:
                return 23 if int(number) in _G_INTEGER else 20
            if code in _AXIS_COMMANDS:
                if axis_command:
                    return 24
                axis_command = True
            group = f"G{_G_GROUPS[code]}"
            g.append(int(code) if code == int(code) else code)
        elif letter == "M":
            if number != int(number):
                return 23
            if int(number) not in _M_GROUPS:
                return 20
            group = f"M{_M_GROUPS[int(number)]}"
            m.append(int(number))
        else:
            if letter in values:
                return 25
            if letter in _NOT_NEGATIVE and number < 0:
                return 4
            values[letter] = number
            continue
        if group in groups:
            return 21
        groups.add(group)
    if pos != len(line):
        return 1 if not line[pos].isalpha() else 2
    return g, m, values


def _unused_words(g: list[float], values: dict[str, float], motion: float | None) -> bool:
    """Whether a value word is left that no command of the block uses (``error:36``,
    ``gc_execute_line`` step 3): ``P`` without ``G4``/``G10``, ``L`` without ``G10``,
    ``I J K R`` without an arc."""
    used = set("FNSTXYZ")
    if 4 in g or 10 in g:
        used |= {"P", "L"} if 10 in g else {"P"}
    if motion in (2, 3):
        used |= set("IJKR")
    return any(letter not in used for letter in values)
