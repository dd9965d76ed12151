"""The Marlin protocol (also Klipper, RepRapFirmware, Hyrel): numbered, checksummed lines.

Stream
    ``N0 M110 N0`` resets the line number and ``N1 M105`` confirms: its answer,
    ``ok T:...``, is the only ``ok`` that names its command. Job lines follow as
    ``N<n> <command>*<xor>``. The firmware accepts only line last+1 and each line
    number, once sent, keeps its text (see Resends for the one exception), so nothing
    is executed twice or out of order.

Window
    Every transmission stays in ``inflight`` until it is known gone. Lines leave the
    firmware's receive ring in order and every ``ok`` or ``Resend:`` answers a distinct
    one, so *k* answers prove the first *k* transmissions gone. Exceptions, counted as
    nothing (which only errs on the safe side): the ``ok`` that 2.1.x and 1.1.x send
    right after ``Resend:`` (it answers the same line; 2.0.x sends none), and an ``ok``
    after an unknown-command echo that is not a line in flight (a fragment of a line
    split by a corrupted byte). An ``ok T:`` re-bases the count: every answer owed by
    lines sent before its M105 has arrived by then. The unanswered bytes stay within
    the ring (``rx_buffer_bytes - 1``), their count within the planner depth; job lines
    leave room for two M105 probes.

    Marlin 2.x empties its ring when it rejects a line. If a later line has only partly
    arrived then, its rest arrives without ``N<n>`` and Marlin executes it unchecked (a
    line run twice, out of order). That needs three unanswered lines at once: the
    command Marlin is stuck in, the rejected line behind it and the partial one. So
    for Marlin at most two lines are unanswered (two 45-byte lines fill the usual
    window anyway); Klipper, RepRapFirmware and Hyrel do not drain. Lost ``ok`` lines
    and lines the firmware drained only make the window more cautious until the next
    ``ok T:``; so that they cannot fill both slots, Marlin gets an M105 every 20 job
    lines (5 after a loss) and after any line the sender does not recognise.

Resends
    ``Resend: X`` (also ``Resend:X``, ``rs X``) rewinds to line X. The lines sent after
    the rejected one each trigger the same request again (or were drained): that many
    repeats are ignored, as is a request for a line already certainly executed or not
    yet sent. Whether ``ok`` follows a resend request differs between versions, so
    during the recovery (``sync``) ``ok`` lines are not counted as executed lines; the
    answer to a numbered M105 ends the recovery with an exact count. After a checksum
    error on the only copy of line X in flight, that M105 becomes line X and the
    unaccepted lines move up by one: nothing sent earlier can be accepted before it (the
    firmware waits for X), so it goes first and its answer clears the lines the firmware
    drained from the window. Otherwise the M105 follows the resent lines.

Silence
    With lines in flight and no answer for a while (adapting to the recent pace), a
    numbered M105 probes the machine; it may exceed the two-line cap only after 2.5 s
    without answers (Marlin says ``busy:`` every 2 s while it holds a line). After
    ``assume_idle_s`` the ring is assumed empty; no answer at all for ``dead_s``
    (``wait_dead_s`` while a heat-up, homing or dwell is in flight) is a lost
    connection.
"""

from __future__ import annotations

import re
import time
from collections import deque

from fabkit.errors import FabkitError
from fabkit.link.gcode import code_of, frame_marlin
from fabkit.link.session import SendReport, Session

WAIT_CODES = frozenset({"M109", "M190", "G28", "G29", "G4", "M400", "M0", "M1", "M600"})
WAIT_PROBE_S = 2.5  # longer than Marlin's default busy: interval
_RESEND = re.compile(r"(?:resend|rs)\s*:?\s*n?:?\s*(\d+)", re.IGNORECASE)
_ADVANCED_OK = re.compile(r"ok\s+N(\d+)")
_UNKNOWN = re.compile(r'echo:\s*Unknown command:\s*"(.*)"')
_PROBE = "M105"
_KNOWN_LINES = ("echo:", "busy:", "//", "wait", "X:", "FIRMWARE_NAME", "Cap:")
PROBE_LINE, SAFE_STOP = -1, -2  # job_index of lines that are not job lines
DRAINING_FLAVOURS = frozenset({"marlin"})  # firmwares that empty the ring on a line error
DRAINING_MAX_LINES = 2
SYNC_EVERY = 20  # most job lines between probes on draining firmwares (clears lost answers)


class MarlinProtocol(Session):
    """Streams a job to a Marlin-protocol firmware (see the module docstring)."""

    protocol = "marlin"

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.rx_usable = self.serial.rx_buffer_bytes - 1
        self.max_lines = self.options.window_lines or self.serial.planner_depth
        if self.machine.flavour in DRAINING_FLAVOURS:
            self.max_lines = min(self.max_lines, DRAINING_MAX_LINES)
        biggest_n = 10 ** len(str(2 * len(self.job) + 1000)) - 1
        longest = max((len(c.text) for c in self.job), default=0)
        longest_frame = len(frame_marlin(biggest_n, "x" * longest))
        self.job_window = self.rx_usable - 2 * len(frame_marlin(biggest_n, _PROBE))
        if self.job_window < longest_frame:
            raise FabkitError(
                f"a {longest}-character command does not fit in the "
                f"{self.serial.rx_buffer_bytes}-byte receive buffer of {self.machine.name}"
            )
        self.texts: list[str] = ["M110 N0", _PROBE]
        self.job_index: list[int] = [PROBE_LINE, PROBE_LINE]
        self.cursor = 2
        self.inflight: deque[tuple[int, int, int, str]] = deque()  # (n, bytes, tx, text)
        self.inflight_bytes = 0
        self.last_tx_of: dict[int, int] = {}
        self.first_tx: dict[int, int] = {}  # line number -> its first transmission
        self.answers = 0  # answers counted: that many first transmissions are gone
        self.stalled = False
        self.since_probe = 0
        self.sync_every = SYNC_EVERY
        self.highest_sent = 1
        self.e_count = 1  # lines executed, counted from oks (frozen during sync)
        self.e_cert = 1  # lines certainly executed (from ok T: and ok N<n>)
        self.sync = False
        self.sync_probe: int | None = None
        self.m105_scan = 2
        self.resend_x: int | None = None
        self.resend_budget = 0
        self.unknown_echo: str | None = None
        self.checksum_error = False
        self.after_resend = False
        self.resend_tx = 0
        self.job_next = 0
        self.tail: list[str] = []
        self.ok_gap_s = 0.05
        self.last_ok_s = time.monotonic()
        self.last_probe_s = 0.0
        self.heating_note = ""

    # -- public ----------------------------------------------------------------------------

    def run(self) -> SendReport:
        """Handshake, stream the whole job, return the report (FabkitError on failure)."""
        self._handshake()
        deadline = None
        while not self._done():
            if self.control.aborted and not self.aborting:
                self._begin_abort()
                deadline = time.monotonic() + self.options.finish_s
            if deadline is not None and time.monotonic() > deadline:
                break
            if b"\n" not in self.rx:  # answer everything received before sending more
                self._fill()
            line = self.read_line()
            if line is None:
                self._on_silence()
            else:
                self._on_line(line)
        self.show(self.done_lines, force=True)
        if self.aborting:
            stopped = "safe-stop sent" if self._done() else "safe-stop not confirmed"
            raise self.aborted_error(self.done_lines, stopped)
        return self.report()

    @property
    def executed(self) -> int:
        """Line number up to which everything is known to be executed."""
        return max(self.e_count, self.e_cert)

    @property
    def done_lines(self) -> int:
        """Job lines known to be executed."""
        for n in range(min(self.executed, len(self.texts) - 1), 1, -1):
            if self.job_index[n] >= 0:
                return self.job_index[n] + 1
        return 0

    # -- handshake -------------------------------------------------------------------------

    def _handshake(self) -> None:
        """``N0 M110 N0`` + ``N1 M105`` until ``ok T:`` answers (a board that resets when the
        port opens loses the first try); after a retry, wait for the line to fall quiet
        so that no answer to an earlier try is mistaken for a job line's."""
        deadline = time.monotonic() + self.options.handshake_s
        self.discard_input()
        attempts = 0
        while time.monotonic() < deadline:
            self.write(frame_marlin(0, "M110 N0") + frame_marlin(1, _PROBE))
            attempts += 1
            retry_at = min(time.monotonic() + 2.0, deadline)
            while time.monotonic() < retry_at:
                line = self.read_line()
                if line is not None and line.startswith("ok") and "T:" in line:
                    if attempts > 1:
                        self._settle()
                    return
                if line is not None and _RESEND.match(line):
                    break
        raise FabkitError(
            f"no answer from {self.port_name} at {self.serial.baud} baud: is it a "
            "Marlin-protocol machine and the baud rate right?"
        )

    def _settle(self, quiet_s: float = 0.3, limit_s: float = 3.0) -> None:
        """Read and drop lines until none came for ``quiet_s`` (at most ``limit_s``)."""
        stop = time.monotonic() + limit_s
        while time.monotonic() < stop and time.monotonic() - self.last_rx_s < quiet_s:
            self.read_line()

    # -- sending ---------------------------------------------------------------------------

    def _fill(self) -> None:
        frames = []
        while not self.control.paused or self.aborting:
            n = self.cursor
            if n == len(self.texts) and not self._append():
                break
            text = self.texts[n]
            frame = frame_marlin(n, text)
            limit = self.job_window if self.job_index[n] >= 0 else self.rx_usable
            probe = self.job_index[n] == PROBE_LINE
            cap = self.max_lines + (1 if probe and self.stalled else 0)
            if self.inflight_bytes + len(frame) > limit or len(self.inflight) >= cap:
                break
            self.inflight.append((n, len(frame), self.transmissions, text))
            self.last_tx_of[n] = self.transmissions
            self.first_tx.setdefault(n, self.transmissions)
            self.transmissions += 1
            self.inflight_bytes += len(frame)
            self.highest_sent = max(self.highest_sent, n)
            self.cursor += 1
            frames.append(frame)
        if frames:
            self.write(b"".join(frames))

    def _append(self) -> bool:
        """Number the next line: a job line (or, now and then, a probe) or a safe-stop line."""
        draining = self.machine.flavour in DRAINING_FLAVOURS
        if self.job_next < len(self.job) and not self.aborting:
            if draining and self.since_probe >= self.sync_every:
                self.since_probe = 0
                self.probes += 1
                text, index = _PROBE, PROBE_LINE
            else:
                text, index = self.job[self.job_next].text, self.job_next
                self.job_next += 1
                self.since_probe += 1
        elif self.tail:
            text, index = self.tail.pop(0), SAFE_STOP
        else:
            return False
        self.texts.append(text)
        self.job_index.append(index)
        return True

    def _done(self) -> bool:
        """Every job (or safe-stop) line executed; probes after the last one do not count."""
        if not (self.job_next == len(self.job) or self.aborting) or self.tail:
            return False
        last = len(self.texts) - 1
        while last > 1 and self.job_index[last] == PROBE_LINE:
            last -= 1
        return self.executed >= last

    def _begin_abort(self) -> None:
        self.aborting = True
        self.tail = self.machine.render("safe_stop_gcode")
        self.warnings.append("aborted by the user: safe-stop snippet sent")

    # -- answers ---------------------------------------------------------------------------

    def _on_line(self, line: str) -> None:
        self.stalled = False
        if line.startswith("ok"):
            self._on_ok(line)
            return
        resend = _RESEND.match(line)
        if resend:
            self._on_resend(int(resend.group(1)))
            self.answers += 1
            self._retire()
            self.after_resend = True
            self.resend_tx = self.transmissions
        elif line.startswith(("Error:", "!!")):
            lowered = line.lower()
            if "last line" in lowered or "checksum" in lowered or "line number" in lowered:
                self.checksum_error = "checksum" in lowered
                self.sync = True
            else:
                raise FabkitError(
                    f"{self.port_name} reported '{line}' after file line "
                    f"{self.file_line_after(self.done_lines)}"
                )
        elif line.startswith("start"):
            raise self.lost(self.done_lines, "the machine reset during the job")
        elif line.startswith("echo:") and _UNKNOWN.match(line):
            self.unknown_echo = _UNKNOWN.match(line).group(1)
        elif line == "wait" and self.inflight and self.cursor > self.highest_sent:
            self._queue_probe()
        elif line.startswith("T:") or " T:" in line:
            self.heating_note = "heating " + line.split(" W:")[0]
            self.show(self.done_lines, self.heating_note)
        elif self.inflight and not line.startswith(_KNOWN_LINES):
            self.probes += 1  # perhaps a garbled answer: find out now, before another
            self._queue_probe()

    def _on_ok(self, line: str) -> None:
        now = time.monotonic()
        gap = now - max(self.last_ok_s, self.last_tx_s)  # the machine's pace, not our waits
        self.ok_gap_s = 0.8 * self.ok_gap_s + 0.2 * gap
        self.last_ok_s = now
        temperature = "T:" in line
        # an echo of a line in flight (perhaps with a garbled N word) answers it; any other
        # echo is a fragment of a line split by a corrupted byte, answered already
        echo = self.unknown_echo
        garbage = echo is not None and not any(
            echo == entry[3] or echo.endswith(" " + entry[3]) for entry in self.inflight
        )
        if garbage:
            pass
        elif temperature or not self.after_resend:
            self.answers += 1
        else:
            self.after_resend = False
            self._queue_probe()  # if that was no resend's ok (2.0.x), re-base soon
        advanced = _ADVANCED_OK.match(line)
        if advanced:
            self.e_cert = max(self.e_cert, int(advanced.group(1)))
        probe = self._answered_m105() if temperature else None
        if probe is not None and probe in self.first_tx:
            self._rebase(probe)
        self._retire()
        if probe is not None:
            self.e_cert = max(self.e_cert, probe)
            if self.sync and self.sync_probe is not None and probe >= self.sync_probe:
                self._leave_sync()
        elif not self.sync:
            self._count_ok()
        if not self.sync:
            self.e_count = max(self.e_count, self.e_cert)
        self.unknown_echo = None
        self.show(self.done_lines, self.heating_note)

    def _count_ok(self) -> None:
        n = self.e_count + 1
        if n > self.highest_sent:
            return
        if self.unknown_echo is not None and self.unknown_echo != self.texts[n]:
            self._enter_sync()  # an ok for a garbled line: recover exactly
            self._queue_probe()
            return
        if self.unknown_echo is not None:
            self.warnings.append(f"the machine did not know '{self.texts[n]}'")
        self.e_count = n

    def _retire(self) -> None:
        """Drop the transmissions known gone from the window (see Window above)."""
        while self.inflight and self.inflight[0][2] < self.answers:
            self.inflight_bytes -= self.inflight.popleft()[1]

    def _rebase(self, probe: int) -> None:
        """An ``ok T:`` for line ``probe`` (or a later M105): every transmission up to the
        probe's is gone, and every answer they owe has arrived (earlier lines execute
        first; rejected ones are answered when parsed), so later answers count on from
        there. With several copies of the line, which one ran is unknown: the first
        copy's predecessors are the safe bound."""
        first = self.first_tx[probe]
        once = self.last_tx_of.get(probe) == first
        bound = first + 1 if once else first
        # answers were lost: probe more often (on draining firmwares), else less often
        lost = bound > self.answers
        self.sync_every = (
            max(5, self.sync_every // 2) if lost else min(SYNC_EVERY, 2 * self.sync_every)
        )
        self.answers = max(self.answers, bound)
        # a probe sent after the last Resend: that request's ok (if any) came already
        self.after_resend = self.after_resend and first < self.resend_tx

    def _answered_m105(self) -> int | None:
        """The line number of the M105 an ``ok T:`` answers, as low as it can be.

        M105 lines execute in order, after every line counted by an ``ok``: outside
        recovery that count bounds it from below as well."""
        start = self.m105_scan if self.sync else max(self.m105_scan, self.e_count + 1)
        for n in range(start, len(self.texts)):
            if self.texts[n] == _PROBE:
                self.m105_scan = n + 1
                return n
        return None

    def _enter_sync(self) -> None:
        if not self.sync:
            self.sync = True
            self.sync_probe = None

    def _queue_probe(self) -> int:
        """Make the first never-sent line an M105 (inserted there); its line number."""
        at = max(self.cursor, self.highest_sent + 1)
        if at == len(self.texts) or self.texts[at] != _PROBE:
            self.texts.insert(at, _PROBE)
            self.job_index.insert(at, PROBE_LINE)
        if self.sync and self.sync_probe is None:
            self.sync_probe = at
        return at

    def _leave_sync(self) -> None:
        self.sync = False
        self.e_count = self.e_cert
        self.resend_x = None
        self.resend_budget = 0

    def _on_resend(self, x: int) -> None:
        self._enter_sync()
        if x <= self.e_cert or x > self.highest_sent + 1:
            return  # stale or garbled: the firmware never asks for an executed line
        if x == self.resend_x and self.resend_budget > 0:
            self.resend_budget -= 1
            return
        self.e_count = min(self.e_count, x - 1)
        self.resends += 1
        self.resend_x = x
        last = self.last_tx_of.get(x)
        self.resend_budget = self.transmissions - last - 1 if last is not None else 0
        self.cursor = x
        copies = sum(1 for entry in self.inflight if entry[0] == x)
        if x < len(self.texts) and self.texts[x] == _PROBE:
            self.sync_probe = x
        elif copies == (1 if self.checksum_error else 0):
            self.texts.insert(x, _PROBE)
            self.job_index.insert(x, PROBE_LINE)
            self.highest_sent = x - 1
            self.first_tx = {n: tx for n, tx in self.first_tx.items() if n < x}
            self.sync_probe = x
        else:
            later = [n for n in range(x, len(self.texts)) if self.texts[n] == _PROBE]
            self.sync_probe = later[0] if later else self._queue_probe()
        self.checksum_error = False

    # -- silence ---------------------------------------------------------------------------

    def _on_silence(self) -> None:
        if not self.inflight and (self.control.paused or self.executed >= self.highest_sent):
            return
        now = time.monotonic()
        waiting = any(code_of(entry[3]) in WAIT_CODES for entry in self.inflight)
        limit = self.options.wait_dead_s if waiting else self.options.dead_s
        if self.inflight and now - self.last_rx_s > limit:
            raise self.lost(self.done_lines, f"no answer for {limit:g} s")
        options = self.options
        probe_after = min(max(8 * self.ok_gap_s, options.probe_min_s), options.probe_max_s)
        if waiting:  # heat-ups report every 1 s, busy: comes every 2 s
            probe_after = max(probe_after, WAIT_PROBE_S)
        quiet = now - max(self.last_rx_s, self.last_tx_s)
        # silent longer than Marlin's busy: interval: no line is really held, so a probe
        # may go beyond the line cap
        self.stalled = now - self.last_rx_s >= WAIT_PROBE_S
        if quiet < probe_after or now - self.last_probe_s < probe_after:
            return
        self.last_probe_s = now
        if self.inflight and now - self.last_rx_s > options.assume_idle_s and not waiting:
            self.recoveries += 1  # silent for long: nothing can be left in the ring
            self.answers = self.transmissions
            self._retire()
        if self.cursor > self.highest_sent:
            self.probes += 1
            self._queue_probe()
