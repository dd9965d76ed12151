"""The GRBL 1.1 protocol: character counting, ``ok`` / ``error:N``, real-time bytes.

GRBL answers every line with exactly one ``ok`` or ``error:N``, in order, and keeps the
lines it has not parsed in a receive ring (``RX_BUFFER_SIZE``, 128 bytes in 1.1h; the
profile's ``rx_buffer_bytes``, of which one byte is left spare). The sender counts the
bytes of the unanswered lines and sends a line only if it fits (character counting).
Real-time bytes skip the buffer: ``?`` asks for a status report, ``!`` holds the feed,
``~`` resumes, Ctrl-X resets.

Before the job, ``$I`` asks the machine for its buffers: its build info ends in
``[OPT:<options>,<planner blocks>,<rx bytes>]`` (grbl/report.c ``report_build_info``);
without it, the ``Bf:<free blocks>,<free rx bytes>`` of an idle status report gives them
(``report_realtime_status``; ``serial_get_rx_buffer_available`` is RX_BUFFER_SIZE when
empty). A machine whose buffer is smaller than the profile's ``rx_buffer_bytes`` is
refused (streaming would overflow it and GRBL would run truncated lines); a larger one
is used.

**Character counting, right by construction** (docs/link.md, "GRBL"): the bytes of a
line stay counted until *its own* answer, ``ok`` or ``error:``, has arrived (answers
come in order, one per line). Nothing else frees space: GRBL answers ``?`` before it
parses the lines waiting in its ring (``protocol.c``, ``protocol_main_loop``: the
real-time check point right after a line's end) and reports ``Idle`` while it sleeps in
a dwell (``mc_dwell``), so a status report says nothing about the ring.

An answer lost on the wire would keep its line counted for ever. So after a quiet spell
with lines in flight a *barrier* is sent, the system command ``$G`` (3 bytes, counted
like a line; room for two is kept free): GRBL runs the lines of its ring in order, and
its ``[GC:...]`` report proves that every line sent before it was parsed and answered.
The lines still unanswered then had their answer lost: they are retired, named in the
report as lines that may not have run (an ``ok`` or an ``error:`` was lost), and
counted as recoveries. A report is taken for the oldest barrier in flight whose report
has not come, which never retires a line too early (a report can only come from that
barrier or a later one); when a report itself is lost, the next quiet spell sends the
second barrier, whose report settles the lines before the first.

``error:N`` means that line did not run and the job cannot continue as written; the
lines behind it are already in GRBL's buffer and run regardless. So nothing more is
sent, those lines are let run to the end (their answers are read, the machine waited for
``Idle``), the profile's safe-stop snippet follows, and the message names the rejected
line and the first line that never reached the machine: ``--resume-from`` there runs no
line twice. ``ALARM:N`` and Ctrl-C stop at once: the feed is held, the position read,
the machine soft-reset (which drops the planned moves) and the safe-stop snippet sent;
the position says in which line the machine stopped.
"""

from __future__ import annotations

import re
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace

from fabkit.errors import FabkitError
from fabkit.link.host.session import ANSWER_LOST, SendReport, Session, UnrunLine

HOLD, RESUME, STATUS, RESET = b"!", b"~", b"?", b"\x18"
STATUS_MIN_S = 0.2  # at most 5 status queries a second while the machine moves
ERRORS = {
    1: "expected a command letter",
    2: "bad number format",
    3: "invalid $ statement",
    4: "negative value",
    9: "G-code locked out during alarm",
    11: "line too long",
    20: "unsupported command",
    21: "two commands of one modal group",
    22: "feed rate not set",
    23: "command value not an integer",
    24: "two commands that both use the axis words",
    25: "repeated word",
    26: "no axis words",
    28: "value word missing",
    32: "no axis words in the arc's plane",
    33: "invalid motion target",
    34: "arc radius error",
    36: "unused words",
}
"""The texts of GRBL 1.1's error codes a job line can get (report.h STATUS_*, the wiki)."""
ALARMS = {
    1: "hard limit",
    2: "soft limit",
    3: "reset while in motion",
    4: "probe fail",
    6: "homing fail (reset)",
    8: "homing fail (pull-off)",
    9: "homing fail (switch not found)",
}


BARRIER = b"$G\n"  # answered [GC:...] then ok, in turn with the lines before it
BARRIERS = 2
"""Barriers in flight at most: with room for two kept free, one whose report was lost
never blocks the next (module docstring)."""


@dataclass(slots=True)
class _Sent:
    """A line written and not yet answered: its bytes and its job index (-1: a barrier;
    ``reported``: its ``[GC:`` has arrived)."""

    size: int
    index: int
    reported: bool = False


class GrblProtocol(Session):
    """Streams a job to GRBL (see the module docstring)."""

    protocol = "grbl"

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.rx_usable = self.serial.rx_buffer_bytes - 1
        self.max_lines = self.options.window_lines or self.serial.planner_depth
        longest = max((len(c.text) + 1 for c in self.job), default=0)
        if longest > self.rx_usable - BARRIERS * len(BARRIER):
            raise FabkitError(
                f"a {longest - 1}-character command does not fit in the "
                f"{self.serial.rx_buffer_bytes}-byte receive buffer of {self.machine.name}"
            )
        self.inflight: deque[_Sent] = deque()  # oldest first
        self.inflight_bytes = 0
        self.sent = 0
        self.acked = 0  # job lines answered (or proven parsed by a barrier), in order
        self.rejected: list[tuple[int, str]] = []  # job index, error line
        self.unanswered: list[int] = []  # job indices whose answer was lost
        self.last_query_s = 0.0
        self.last_answer_s = self.last_barrier_s = time.monotonic()
        self.held = False
        self.ok_gap_s = 0.05
        self.last_status = ""
        self.planner_free = 0  # free planner blocks of an empty planner ($I, else Bf: seen)

    def run(self) -> SendReport:
        """Handshake, stream the whole job, return the report (FabkitError on failure)."""
        self._handshake()
        self._ask_buffers()
        while self.acked < len(self.job):
            if self.control.aborted:
                self._abort("safe-stop sent")
            self._hold(self.control.paused)
            if b"\n" not in self.rx and not self.rejected:  # answer everything first
                self._fill()
            line = self.read_line()
            if line is None:
                self._on_silence()
            else:
                self._on_line(line)
            if self.rejected and not self._job_in_flight():
                self._after_error()
        self._settle_barriers()
        self.show(self.acked, force=True)
        return self.report()

    def report(self) -> SendReport:
        lost = (self.job[i] for i in self.unanswered)
        unrun = tuple(UnrunLine(c.file_line, c.text, ANSWER_LOST) for c in lost)
        return replace(super().report(), may_not_have_run=unrun)

    # -- handshake and sending -------------------------------------------------------------

    def _handshake(self) -> None:
        deadline = time.monotonic() + self.options.handshake_s
        while time.monotonic() < deadline:
            self.write(STATUS)
            retry_at = time.monotonic() + 0.5
            while time.monotonic() < min(retry_at, deadline):
                line = self.read_line()
                if line is None:
                    continue
                if line.startswith("<Alarm"):
                    raise FabkitError(
                        f"{self.port_name} is in ALARM state: home ($H) or unlock ($X) it first"
                    )
                if line.startswith("<"):
                    self.last_status = line
                    return
                if line.startswith("Grbl"):
                    break
        raise FabkitError(
            f"no answer from {self.port_name} at {self.serial.baud} baud: is it a GRBL "
            "machine and the baud rate right?"
        )

    def _ask_buffers(self) -> None:
        """Learn the receive buffer from ``$I`` (or an idle ``Bf:``); refuse a profile that
        claims more than the machine has (see the module docstring)."""
        self.write(b"$I\n")
        lines = self._wait_for(("ok", "error:"), b"", 2.0)
        sizes = next((_opt_sizes(line) for line in lines if line.startswith("[OPT:")), None)
        source = next((line for line in lines if line.startswith("[OPT:")), "")
        if sizes is None:
            bf = re.search(r"Bf:(\d+),(\d+)", self.last_status)
            if bf and self.last_status.startswith("<Idle"):
                sizes, source = (
                    (int(bf.group(1)), int(bf.group(2))),
                    f"Bf:{bf.group(1)},{bf.group(2)}",
                )
        if sizes is None:
            self.warnings.append(
                "the machine did not report its receive buffer ($I, Bf:): trusted the "
                f"profile's rx_buffer_bytes = {self.serial.rx_buffer_bytes}"
            )
            return
        blocks, rx = sizes
        if rx < self.serial.rx_buffer_bytes:
            raise FabkitError(
                f"{self.port_name} reports a {rx}-byte receive buffer ({source}) but machine "
                f"{self.machine.name} has [serial] rx_buffer_bytes = "
                f"{self.serial.rx_buffer_bytes}: set it to {rx} in {self.machine.path}"
            )
        self.rx_usable = rx - 1
        self.planner_free = blocks
        if not self.options.window_lines:
            self.max_lines = max(self.max_lines, blocks)

    def _fill(self) -> None:
        frames = []
        room = self.rx_usable - BARRIERS * len(BARRIER)  # barriers always fit beside them
        while self.sent < len(self.job) and not self.held:
            frame = self.job[self.sent].text.encode("ascii") + b"\n"
            full = self.inflight_bytes + len(frame) > room
            if full or self._job_in_flight() >= self.max_lines:
                break
            self._push(_Sent(len(frame), self.sent))
            self.sent += 1
            self.transmissions += 1
            frames.append(frame)
        if frames:
            self.write(b"".join(frames))

    def _push(self, sent: _Sent) -> None:
        self.inflight.append(sent)
        self.inflight_bytes += sent.size

    def _job_in_flight(self) -> int:
        """Job lines written and not yet answered."""
        return self.sent - self.acked

    def _hold(self, paused: bool) -> None:
        if paused != self.held:
            self.held = paused
            self.write(HOLD if paused else RESUME)
            self.show(self.acked, "paused (feed hold)" if paused else "", force=True)

    # -- answers ---------------------------------------------------------------------------

    def _on_line(self, line: str) -> None:
        if line == "ok" or line.startswith("error:"):
            now = time.monotonic()
            gap = now - max(self.last_answer_s, self.last_tx_s)  # the machine's pace
            self.ok_gap_s = 0.8 * self.ok_gap_s + 0.2 * gap
            self.last_answer_s = now
            answered = self._pop()
            if line != "ok" and answered is not None and answered.index >= 0:
                self.rejected.append((answered.index, line))
            self.show(self.acked)
        elif line.startswith("[GC:"):
            self._on_barrier()
        elif line.startswith("ALARM:"):
            self._abort(f"{self.port_name} raised {line} {ALARMS.get(_code(line), '')}".rstrip())
        elif line.startswith("<"):
            self.last_status = line
        elif line.startswith("Grbl"):
            drops = "GRBL's planned moves and its receive buffer"
            raise self.reset_error(self.acked, self.sent, self.serial.planner_depth, drops)

    def _pop(self) -> _Sent | None:
        """Retire the oldest line in flight (None if there is none)."""
        if not self.inflight:
            return None
        sent = self.inflight.popleft()
        self.inflight_bytes -= sent.size
        if sent.index >= 0:
            self.acked += 1
        return sent

    def _on_barrier(self) -> None:
        """A ``[GC:`` report: every line sent before the oldest barrier in flight has been
        parsed; those still unanswered lost their answer (module docstring)."""
        self.last_answer_s = time.monotonic()
        barrier = next((s for s in self.inflight if s.index < 0 and not s.reported), None)
        if barrier is None:
            return
        while self.inflight[0] is not barrier:
            lost = self._pop()
            if lost is not None and lost.index >= 0:
                self.unanswered.append(lost.index)
                self.recoveries += 1
        barrier.reported = True

    def _on_silence(self) -> None:
        if not self.inflight:
            return
        now = time.monotonic()
        options = self.options
        if now - self.last_rx_s > options.dead_s:
            raise self.lost(self.acked, f"no answer for {options.dead_s:g} s", self.sent)
        if now - self.last_answer_s > options.wait_dead_s:  # status reports, but no ok
            reason = f"no ok nor error: for {options.wait_dead_s:g} s"
            raise self.lost(self.acked, reason, self.sent)
        probe_after = min(max(8 * self.ok_gap_s, options.probe_min_s), options.probe_max_s)
        quiet = now - max(self.last_rx_s, self.last_tx_s)
        if quiet >= probe_after and now - self.last_query_s >= max(probe_after, STATUS_MIN_S):
            self.last_query_s = now
            self.probes += 1
            self.write(STATUS)  # keeps the link alive and the state known; frees nothing
        if self._barrier_wanted(now, probe_after):
            self.last_barrier_s = now
            self._push(_Sent(len(BARRIER), -1))
            self.write(BARRIER)

    def _barrier_wanted(self, now: float, quiet_s: float) -> bool:
        """No answer nor barrier for ``quiet_s``, fewer than :data:`BARRIERS` barriers in
        flight (their room is kept free), and a job line waiting for its answer."""
        if now - max(self.last_answer_s, self.last_barrier_s) < quiet_s:
            return False
        barriers = sum(1 for sent in self.inflight if sent.index < 0)
        return barriers < BARRIERS and self._job_in_flight() > 0

    def _settle_barriers(self, limit_s: float = 1.0) -> None:
        """Read the answers of the barriers still in flight once every job line is
        answered (they come right after), so that none is left for the next command."""
        deadline = time.monotonic() + limit_s
        while self.inflight and time.monotonic() < deadline:
            line = self.read_line()
            if line is not None:
                self._on_line(line)

    # -- stopping --------------------------------------------------------------------------

    def _after_error(self) -> None:
        """Every job line sent is answered after a rejected one: let the machine finish
        what it holds, stop safely, and name the line to resume from (module docstring)."""
        self._settle_barriers()
        self._wait_until(self._drained, STATUS, self.options.finish_s)
        self._safe_stop()
        index, error = self.rejected[0]
        failed = self.job[index]
        text = f"{self.port_name} rejected file line {failed.file_line} ('{failed.text}'): "
        text += f"{error} {ERRORS.get(_code(error), '')}".rstrip()
        if len(self.rejected) > 1:
            text += f" (and {len(self.rejected) - 1} more lines)"
        later = self.job[index + 1 : self.sent]
        if not later:
            text += f"; safe-stop sent; fix it and continue with --resume-from {failed.file_line}"
            raise FabkitError(text)
        lines = f"file line {later[0].file_line}"
        if len(later) > 1:
            lines = f"file lines {later[0].file_line}-{later[-1].file_line}"
        text += f"; {lines} behind it, already in its buffer, {self._fate(index)}; safe-stop sent"
        if self.sent < len(self.job):
            resume = self.job[self.sent].file_line
            text += f"; continue with --resume-from {resume} (no line runs twice)"
        raise FabkitError(text)

    def _fate(self, index: int) -> str:
        """What became of the job lines sent after job line ``index``: ran (answered
        ``ok``), or how many were refused too or lost their answer."""
        refused = len(self.rejected) - 1
        lost = sum(1 for i in self.unanswered if i > index)
        if not refused and not lost:
            return "ran"
        parts = [f"{refused} refused too"] if refused else []
        parts += [f"{lost} unconfirmed (answer lost)"] if lost else []
        return "ran but " + " and ".join(parts)

    def _abort(self, detail: str) -> None:
        """Hold, read where the tool stopped, reset, send the safe-stop snippet; raise
        FabkitError with ``detail`` and the line to resume from."""
        last = self.sent - 1
        self.write(HOLD)
        stopped = self._wait_for(("<Hold:0", "<Idle", "<Alarm"), STATUS, 2.0)
        point = _position(stopped[-1]) if stopped and stopped[-1].startswith("<") else None
        self.write(RESET)
        after_reset = self._wait_for(("Grbl",), b"", 3.0) + self._wait_for(("[MSG:",), b"", 0.2)
        if any(line.startswith("ALARM") or "'$X' to unlock" in line for line in after_reset):
            detail += "; the machine is in ALARM after the reset (unlock with $X)"
        else:
            self._safe_stop()
        raise self.stopped_error(detail, point, last)

    def _safe_stop(self) -> None:
        for text in self.machine.render("safe_stop_gcode"):
            self.write(text.encode("ascii") + b"\n")
            self._wait_for(("ok", "error:"), b"", 5.0)

    def _drained(self, line: str) -> bool:
        """``line`` is a status report of a machine that has run every planned move: in
        ALARM, or Idle with an empty planner. An Idle report alone is not enough: GRBL
        reports Idle with blocks planned until its auto cycle start (``protocol.c``,
        ``protocol_auto_cycle_start``) begins them (a real GRBL 1.1h answered
        ``<Idle|...|Bf:2,128|...>`` with 13 moves waiting)."""
        if line.startswith("<Alarm"):
            return True
        if not line.startswith("<Idle"):
            return False
        free = re.search(r"Bf:(\d+),", line)
        if free is None:
            return True
        self.planner_free = max(self.planner_free, int(free.group(1)))
        return int(free.group(1)) >= self.planner_free

    def _wait_for(self, prefixes: tuple[str, ...], query: bytes, timeout_s: float) -> list[str]:
        """The lines read until one starts with one of ``prefixes`` or ``timeout_s`` passed,
        sending ``query`` every 0.1 s if given."""
        return self._wait_until(lambda line: line.startswith(prefixes), query, timeout_s)

    def _wait_until(self, done: Callable[[str], bool], query: bytes, timeout_s: float) -> list[str]:
        """The lines read until ``done`` holds for one or ``timeout_s`` passed, sending
        ``query`` every 0.1 s if given."""
        seen: list[str] = []
        deadline = time.monotonic() + timeout_s
        next_query = 0.0
        while time.monotonic() < deadline:
            if query and time.monotonic() >= next_query:
                self.write(query)
                next_query = time.monotonic() + 0.1
            line = self.read_line()
            if line is None:
                continue
            seen.append(line)
            if done(line):
                break
        return seen


def _opt_sizes(line: str) -> tuple[int, int] | None:
    """Planner blocks and receive-buffer bytes of ``[OPT:V,15,128]`` (None if absent)."""
    parts = line.strip("[]").split(":", 1)[-1].split(",")
    if len(parts) >= 3 and parts[1].isdigit() and parts[2].isdigit():
        return int(parts[1]), int(parts[2])
    return None


def _position(status: str) -> tuple[float, float, float] | None:
    """The work position of a status report (``WPos``, or ``MPos`` less ``WCO``)."""
    found = {key: value for key, value in re.findall(r"(WPos|MPos|WCO):([-\d.,]+)", status)}
    for key in ("WPos", "MPos"):
        if key in found:
            x, y, z = (float(v) for v in found[key].split(",")[:3])
            if key == "MPos" and "WCO" in found:
                ox, oy, oz = (float(v) for v in found["WCO"].split(",")[:3])
                x, y, z = x - ox, y - oy, z - oz
            return x, y, z
    return None


def _code(line: str) -> int:
    """The number of ``error:N`` / ``ALARM:N`` (0 if none)."""
    digits = line.split(":", 1)[1].strip()
    return int(digits) if digits.isdigit() else 0
