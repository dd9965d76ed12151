"""The Marlin protocol (Marlin, Prusa, Repetier, Smoothieware, RepRapFirmware, Klipper).

Stream
    ``N0 M110 N0`` resets the line number, ``N1 M115`` asks the firmware who it is and
    ``N2 M105`` confirms: its answer, ``ok T:...`` (or ``ok 2`` where oks name their
    line), is the only answer that names its command. Job lines follow as
    ``N<n> <command>*<xor>``. The firmware accepts only line last+1 and each line
    number, once sent, keeps its text (see Resends for the one exception), so nothing
    is executed twice or out of order. The answers' wording differs between firmwares:
    :mod:`fabkit.link.dialects` reads them all.

Window
    Every transmission stays in ``inflight`` until it is known gone. Lines leave the
    firmware's receive buffer in order and every ``ok``, resend request or ``skip``
    (Repetier) answers a distinct one, so *k* answers prove the first *k* transmissions
    gone. Exceptions, counted as nothing (which only errs on the safe side): the ``ok``
    that follows a resend request (Marlin 2.1 and 1.1, Prusa, Repetier) or a ``skip``,
    an ``ok`` after an unknown-command echo that is not a line in flight (a fragment of
    a line split by a corrupted byte) and Smoothieware's ``ok - ignored``. Where the
    firmware does not say whether an ``ok`` follows a resend request (Marlin 2.0.x,
    unknown firmwares), that ``ok`` is not counted and a probe is sent at once. An
    ``ok T:`` or an ``ok <n>`` re-bases the count: every answer owed by lines sent
    before that line has arrived by then. The unanswered bytes stay within the
    receive buffer (``rx_buffer_bytes - 1``, lowered when a line error shows the
    buffer overflowed), their count within the planner depth; job lines leave room
    for two M105 probes.

    Marlin and Prusa empty their receive buffer when they reject a line. If a later
    line has only partly arrived then, its rest arrives without ``N<n>`` and runs
    unchecked. That needs three unanswered lines at once (the command the firmware is
    stuck in, the rejected line, the partial one), so on draining firmwares at most two
    job lines are unanswered (a probe may be a third: its fragment is a harmless
    M105). Lost ``ok`` lines and drained lines only make the window more cautious until
    the next re-base; so that they cannot fill both slots, a probe follows every
    ``SYNC_EVERY`` job lines there (fewer after a loss). RepRapFirmware checks no line
    numbers and drops a line with a bad checksum without a word: one line at a time,
    and a silence is resolved by ``M114``: the position says whether the line ran.

Resends
    ``Resend: X`` (also ``Resend:X``, ``rs NX``, ``rs X``) rewinds to line X. The lines
    sent after the rejected one each trigger the same request again, a ``skip`` or
    nothing (drained): that many repeats are ignored, as is a request for a line already
    certainly executed or not yet sent. During the recovery (``sync``) ``ok`` lines are
    not counted as executed lines; the answer to a numbered M105 ends it with an exact
    count. After a checksum error on the only copy of line X in flight, that M105
    becomes line X and the unaccepted lines move up by one: nothing sent earlier can be
    accepted before it (the firmware waits for X), so it goes first and its answer
    clears the lines the firmware drained from the window. Otherwise the M105 follows
    the resent lines. An ``Error:`` line with other wording is fatal unless a resend
    request follows within ``ERROR_GRACE_S``.

Silence
    With lines in flight and no answer for a while (adapting to the recent pace), a
    numbered M105 probes the machine. After ``assume_idle_s`` of silence, or
    ``probe_max_s`` of answered probes but no job line done (lost answers can leave the
    probes' answers unplaced), the ring is assumed empty; no answer at all for ``dead_s``
    (``wait_dead_s`` while a heat-up, homing or dwell is in flight) is a lost
    connection. ``busy:`` and temperature reports count as answers
    (a firmware that sends ``busy:`` is probed only after a silence of 1.5 of its
    ``busy:`` intervals); ``wait`` (an idle firmware whose ``ok`` may be lost) triggers a
    probe.
"""

from __future__ import annotations

import time
from collections import deque

from fabkit.errors import FabkitError
from fabkit.link import dialects
from fabkit.link.dialects import Answer, classify
from fabkit.link.duration import STOPS, estimate
from fabkit.link.gcode import code_of, frame_marlin
from fabkit.link.host.session import SendReport, Session

WAIT_CODES = frozenset(
    {"M109", "M190", "G28", "G29", "G4", "M400", "M0", "M1", "M600", "M226", "M303"}
)
WAIT_PROBE_S = 2.5  # longer than Marlin's default busy: interval
ERROR_GRACE_S = 0.5  # an unknown Error: is fatal unless a resend request follows by then
_PROBE = "M105"
_WHERE = "M114"
_HANDSHAKE = ("M110 N0", "M115", _PROBE)
PROBE_LINE, SAFE_STOP, HOUSEKEEPING, DROPPED = -1, -2, -3, -4  # job_index of other lines
DRAINING_MAX_LINES = 2
SYNC_EVERY = 200  # most job lines between probes on draining firmwares at first
SYNC_EVERY_MAX = 800  # ... after probes that found no lost answer (each costs a line)
SYNC_EVERY_MIN = 10  # ... after probes that did
REGROW_LINES = 500  # clean lines before a byte window shrunk by an overflow grows again


class MarlinProtocol(Session):
    """Streams a job to a Marlin-protocol firmware (see the module docstring)."""

    protocol = "marlin"

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.firmware = dialects.identify("", self.machine.flavour)
        self.rx_usable = self.serial.rx_buffer_bytes - 1
        biggest_n = 10 ** len(str(2 * len(self.job) + 1000)) - 1
        longest = max((len(c.text) for c in self.job), default=0)
        self.longest_frame = len(frame_marlin(biggest_n, "x" * longest))
        self.probe_frame = len(frame_marlin(biggest_n, _PROBE))
        self.job_window = self.rx_usable - 2 * self.probe_frame
        if self.job_window < self.longest_frame:
            raise FabkitError(
                f"a {longest}-character command does not fit in the "
                f"{self.serial.rx_buffer_bytes}-byte receive buffer of {self.machine.name}"
            )
        self.byte_cap = self.job_window
        self.regrow_after = REGROW_LINES
        self.clean_lines = 0
        self.next_cap: int | None = None  # the byte window after the current recovery
        self.max_lines = self.options.window_lines or self.serial.planner_depth
        self.texts: list[str] = list(_HANDSHAKE)
        self.job_index: list[int] = [HOUSEKEEPING, HOUSEKEEPING, PROBE_LINE]
        self.cursor = len(_HANDSHAKE)
        # (n, bytes, transmission, text, unanswered bytes once it was sent)
        self.inflight: deque[tuple[int, int, int, str, int]] = deque()
        self.inflight_bytes = 0
        self.last_tx_of: dict[int, int] = {}
        self.first_tx: dict[int, int] = {}  # line number -> its first transmission
        self.copies: dict[int, list[int]] = {}  # line number -> its transmissions
        self.rejected_until: dict[int, int] = {}  # copies of a line up to this were refused
        self.answers = 0  # answers counted: that many first transmissions are gone
        self.since_probe = 0
        self.sync_every = SYNC_EVERY
        self.highest_sent = len(_HANDSHAKE) - 1
        self.e_count = self.highest_sent  # lines executed, counted from oks (not in sync)
        self.e_cert = self.highest_sent  # lines certainly executed (ok T:, ok <n>)
        self.sync = False
        self.sync_probe: int | None = None
        self.m105_scan = self.cursor
        self.resend_x: int | None = None
        self.resend_budget = 0
        self.unknown_echo: str | None = None
        self.checksum_error = False
        self.pair_ok = False  # the next ok belongs to a resend request or a skip
        self.pair_unsure = False  # ... perhaps (the firmware did not say): probe
        self.resend_tx = 0
        self.pending_error: tuple[str, float] | None = None
        self.job_next = 0
        self.tail: list[str] = []
        self.ok_gap_s = 0.05
        self.last_ok_s = time.monotonic()
        self.last_probe_s = 0.0
        self.last_busy_s = -1e9
        self.busy_gap_s: float | None = None  # the firmware's busy: interval, once seen
        self.heating_note = ""
        self.stop_point: tuple[float, float, float] | None = None
        self.last_done = 0
        self.last_progress_s = time.monotonic()

    # -- public ----------------------------------------------------------------------------

    def run(self) -> SendReport:
        """Handshake, stream the whole job, return the report (FabkitError on failure)."""
        self._handshake()
        finished = self._stream() if self.firmware.sequenced else OneByOne(self).run()
        self.show(self.done_lines, force=True)
        if self.aborting:
            stopped = "safe-stop sent" if finished else "safe-stop not confirmed"
            sent = [i for n, i in enumerate(self.job_index) if i >= 0 and n <= self.highest_sent]
            raise self.stopped_error(stopped, self.stop_point, max(sent, default=-1))
        return self.report()

    def _stream(self) -> bool:
        """Send the job ahead within the window (see the module docstring); False if an
        abort's safe stop was not confirmed in time."""
        deadline = None
        while not self._done():
            if self.control.aborted and not self.aborting:
                self._begin_abort()
                deadline = time.monotonic() + self.options.finish_s
            if deadline is not None and time.monotonic() > deadline:
                break
            self._check_pending_error()
            if b"\n" not in self.rx and self.pending_error is None:
                self._fill()  # answer everything received before sending more
            line = self.read_line()
            if line is None:
                self._on_silence()
            else:
                self._on_line(line)
        return self._done()

    @property
    def executed(self) -> int:
        """Line number up to which everything is known to be executed."""
        return max(self.e_count, self.e_cert)

    @property
    def done_lines(self) -> int:
        """Job lines known to be executed."""
        for n in range(min(self.executed, len(self.texts) - 1), 0, -1):
            if self.job_index[n] >= 0:
                return self.job_index[n] + 1
        return 0

    # -- handshake -------------------------------------------------------------------------

    def _handshake(self) -> None:
        """``N0 M110 N0``, ``N1 M115``, ``N2 M105`` until line 2 is answered (a board that
        resets when the port opens loses the first try); after a retry, wait for the line
        to fall quiet so that no answer to an earlier try is mistaken for a job line's."""
        deadline = time.monotonic() + self.options.handshake_s
        self.discard_input()
        frames = b"".join(frame_marlin(n, text) for n, text in enumerate(_HANDSHAKE))
        attempts = 0
        while time.monotonic() < deadline:
            self.write(frames)
            attempts += 1
            report: list[str] = []
            retry_at = min(time.monotonic() + 2.0, deadline)
            while time.monotonic() < retry_at:
                line = self.read_line()
                if line is None:
                    continue
                answer = classify(line)
                if answer.kind == dialects.INFO and line.startswith("FIRMWARE_NAME"):
                    report.append(line)
                last = len(_HANDSHAKE) - 1
                if answer.kind == dialects.OK and (
                    answer.temperatures or (answer.number or 0) >= last
                ):
                    if not answer.temperatures:  # acknowledged when queued: let them run
                        report += self._read_until(dialects.TEMPERATURES, 1.0)
                    if attempts > 1:
                        self._settle()
                    self._configure(" ".join(report))
                    return
                if answer.kind == dialects.RESEND:
                    break
        raise FabkitError(
            f"no answer from {self.port_name} at {self.serial.baud} baud: is it a "
            "Marlin-protocol machine and the baud rate right?"
        )

    def _configure(self, report: str) -> None:
        """What the firmware said about itself decides the window (module docstring)."""
        self.firmware = dialects.identify(report, self.machine.flavour)
        if self.firmware.drains:
            self.max_lines = min(self.max_lines, DRAINING_MAX_LINES)
        if not self.firmware.sequenced:
            self.max_lines = 1

    def _read_until(self, kind: str, limit_s: float) -> list[str]:
        """The ``FIRMWARE_NAME`` lines read until an answer of ``kind`` (or ``limit_s``)."""
        stop = time.monotonic() + limit_s
        report = []
        while time.monotonic() < stop:
            line = self.read_line()
            if line is None:
                continue
            if line.startswith("FIRMWARE_NAME"):
                report.append(line)
            if classify(line).kind == kind:
                break
        return report

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
            probe = self.job_index[n] in (PROBE_LINE, HOUSEKEEPING)
            if len(self.inflight) >= self.max_lines + (2 if probe else 0):
                break
            frame = frame_marlin(n, text)
            if self.inflight_bytes + len(frame) > (self.rx_usable if probe else self.byte_cap):
                break
            self.inflight_bytes += len(frame)
            self.inflight.append((n, len(frame), self.transmissions, text, self.inflight_bytes))
            self.last_tx_of[n] = self.transmissions
            self.first_tx.setdefault(n, self.transmissions)
            self.copies.setdefault(n, []).append(self.transmissions)
            self.transmissions += 1
            self.highest_sent = max(self.highest_sent, n)
            self.cursor += 1
            frames.append(frame)
        if frames:
            self.write(b"".join(frames))

    def _append(self) -> bool:
        """Number the next line: a job line (or, now and then, a probe) or a safe-stop line."""
        periodic = self.firmware.drains and self.firmware.sequenced
        if self.job_next < len(self.job) and not self.aborting:
            if periodic and self.since_probe >= self.sync_every:
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
        while last >= len(_HANDSHAKE) and self.job_index[last] in (PROBE_LINE, DROPPED):
            last -= 1
        return self.executed >= last

    def _begin_abort(self) -> None:
        """The safe-stop snippet follows the lines in flight, with an ``M114`` after its
        ``M410`` (which drops the planned moves): where the tool stopped says which line
        to resume from."""
        self.aborting = True
        self.tail = self.machine.render("safe_stop_gcode")
        at = next((i + 1 for i, text in enumerate(self.tail) if code_of(text) == "M410"), 0)
        self.tail.insert(at, _WHERE)
        self.warnings.append("aborted by the user: safe-stop snippet sent")

    # -- answers ---------------------------------------------------------------------------

    def _on_line(self, line: str) -> None:
        answer = classify(line)
        kind = answer.kind
        if kind == dialects.OK:
            self._on_ok(answer)
        elif kind == dialects.RESEND:
            self.pending_error = None  # the error before it was a line error
            self._on_resend_request(answer.number)
        elif kind == dialects.SKIP:
            self._on_skip()
        else:
            self._on_other(answer, line)

    def _on_other(self, answer: Answer, line: str) -> None:
        """Everything but acknowledgements and resend requests (both protocols' loops)."""
        kind = answer.kind
        if kind == dialects.LINE_ERROR:
            self.checksum_error = "checksum" in line.lower()
            self._enter_sync()
        elif kind == dialects.ERROR:
            self.pending_error = (line, time.monotonic() + ERROR_GRACE_S)
        elif kind == dialects.FATAL:
            raise self._reported(line)
        elif kind == dialects.OVERFLOW:
            self._on_overflow(answer)
        elif kind == dialects.START:
            raise self.lost(self.done_lines, "the machine reset during the job")
        elif kind == dialects.UNKNOWN_COMMAND:
            self.unknown_echo = answer.text
        elif kind == dialects.WAIT and self.inflight and self.cursor > self.highest_sent:
            self._queue_probe()
        elif kind == dialects.TEMPERATURES:
            if " W:" in line or any(code_of(e[3]) in ("M109", "M190") for e in self.inflight):
                self.heating_note = "heating " + line.strip().split(" W:")[0]
                self.show(self.done_lines, self.heating_note)
        elif kind == dialects.BUSY:  # its pace: a silence shorter than that is a busy command
            now = time.monotonic()
            gap = now - self.last_busy_s
            if gap < 10.0:
                self.busy_gap_s = gap if self.busy_gap_s is None else min(self.busy_gap_s, gap)
            self.last_busy_s = now
        elif kind == dialects.POSITION and self.aborting and self.stop_point is None:
            where = dialects.position(line)
            if all(axis in where for axis in "XYZ"):
                self.stop_point = (where["X"], where["Y"], where["Z"])
        elif kind == dialects.OTHER and self.inflight:
            self.probes += 1  # perhaps a garbled answer: find out now, before another
            self._queue_probe()

    def _reported(self, line: str) -> FabkitError:
        return FabkitError(
            f"{self.port_name} reported '{line}' after file line "
            f"{self.file_line_after(self.done_lines)}"
        )

    def _check_pending_error(self) -> None:
        if self.pending_error is not None and time.monotonic() > self.pending_error[1]:
            raise self._reported(self.pending_error[0])

    def _on_overflow(self, answer: Answer) -> None:
        """Marlin's RX_BUFFER_MONITOR: the buffer holds at most ``answer.number`` bytes."""
        size = answer.number or self.rx_usable
        if size < self.rx_usable:
            self.warnings.append(
                f"the machine's receive buffer overflowed ({size} bytes): the profile's "
                f"rx_buffer_bytes = {self.serial.rx_buffer_bytes} is too large"
            )
            self.rx_usable = size - 1
            self.byte_cap = max(
                self.longest_frame, min(self.byte_cap, size - 1 - 2 * self.probe_frame)
            )

    def _on_ok(self, answer: Answer) -> None:
        now = time.monotonic()
        gap = now - max(self.last_ok_s, self.last_tx_s)  # the machine's pace, not our waits
        self.ok_gap_s = 0.8 * self.ok_gap_s + 0.2 * gap
        self.last_ok_s = now
        echo, self.unknown_echo = self.unknown_echo, None
        # an echo of a line in flight (perhaps with a garbled N word) answers it; any other
        # echo is a fragment of a line split by a corrupted byte, answered already
        garbage = answer.ignored or (
            echo is not None
            and not any(
                echo == entry[3] or echo.endswith(" " + entry[3]) for entry in self.inflight
            )
        )
        if garbage:
            pass
        elif answer.temperatures or answer.number is not None or not self.pair_ok:
            self.answers += 1
        else:
            self.pair_ok = False
            if self.pair_unsure:  # perhaps no resend's ok at all (Marlin 2.0.x): re-base now
                self.pair_unsure = False
                self._queue_probe()
        certain = self._certain_line(answer)
        if certain is not None:
            self._rebase(certain)
        self._retire()
        if certain is not None:
            self.e_cert = max(self.e_cert, certain)
            if self.sync and self.sync_probe is not None and certain >= self.sync_probe:
                self._leave_sync()
        elif not self.sync and not garbage:
            self._count_ok(echo)
        if not self.sync:
            self.e_count = max(self.e_count, self.e_cert)
            if not garbage:
                self._grow()
        self._progress()
        self.show(self.done_lines, self.heating_note)

    def _certain_line(self, answer: Answer) -> int | None:
        """The line an ``ok T:`` (M105) or ``ok <n>`` proves accepted, if any."""
        if answer.number is not None and answer.number in self.first_tx:
            return answer.number
        if answer.temperatures:
            probe = self._answered_m105()
            if probe is not None and probe in self.first_tx:
                return probe
        return None

    def _count_ok(self, echo: str | None) -> None:
        n = self.e_count + 1
        if n > self.highest_sent:
            return
        if echo is not None and echo != self.texts[n]:
            self._enter_sync()  # an ok for a garbled line: recover exactly
            self._queue_probe()
            return
        if echo is not None:
            self.warnings.append(f"the machine did not know '{self.texts[n]}'")
        self.e_count = n

    def _idle_for_long(self, now: float) -> bool:
        """Silent for ``assume_idle_s``; or answering probes (lost answers can leave
        them unplaced) but no job line done, with no ``busy:``, for ``probe_max_s``: a
        firmware busy with a line answers no probe behind it."""
        if now - self.last_rx_s > self.options.assume_idle_s:
            return True
        busy = self.busy_gap_s is not None and now - self.last_busy_s < 1.5 * self.busy_gap_s
        return not busy and now - self.last_progress_s > self.options.probe_max_s

    def _grow(self) -> None:
        """A clean job line: after enough of them a shrunk byte window grows again."""
        self.clean_lines += 1
        if self.byte_cap < self.job_window and self.clean_lines >= self.regrow_after:
            self.byte_cap = min(self.job_window, self.byte_cap + max(8, self.longest_frame // 2))
            self.clean_lines = 0

    def _progress(self) -> None:
        done = self.done_lines
        if done != self.last_done:
            self.last_done = done
            self.last_progress_s = time.monotonic()

    def _retire(self) -> None:
        """Drop the transmissions known gone from the window (see Window above)."""
        while self.inflight and self.inflight[0][2] < self.answers:
            self.inflight_bytes -= self.inflight.popleft()[1]

    def _rebase(self, line: int) -> None:
        """An ``ok T:`` or ``ok <n>`` for ``line``: every transmission up to the line's is
        gone, and every answer they owe has arrived (earlier lines execute first;
        rejected ones are answered when parsed), so later answers count on from there.
        A resend request proves the copies of its line sent before the transmission it
        answers refused; of several copies left, which one was accepted is unknown: the
        first one's predecessors are the safe bound."""
        first = self.first_tx[line]
        refused = self.rejected_until.get(line, -1)
        left = [tx for tx in self.copies.get(line, [first]) if tx > refused]
        bound = left[0] + 1 if len(left) == 1 else left[0] if left else first
        # answers were lost: probe more often (on draining firmwares), else less often
        lost = bound > self.answers
        self.sync_every = (
            max(SYNC_EVERY_MIN, self.sync_every // 2)
            if lost
            else min(SYNC_EVERY_MAX, 2 * self.sync_every)
        )
        self.answers = max(self.answers, bound)
        # a line sent after the last resend request: that request's ok (if any) came already
        if first >= self.resend_tx:
            self.pair_ok = self.pair_unsure = False

    def _answered_m105(self) -> int | None:
        """The line number of the M105 an ``ok T:`` answers, as low as it can be.

        M105 lines execute in order, after every line counted by an ``ok`` (a count that
        recovery only lowers): it bounds the number from below as well."""
        start = max(self.m105_scan, self.e_count + 1)
        for n in range(start, len(self.texts)):
            if self.texts[n] == _PROBE and self.job_index[n] in (PROBE_LINE, HOUSEKEEPING):
                self.m105_scan = n + 1
                return n
        return None

    def _enter_sync(self) -> None:
        if not self.sync:
            self.sync = True
            self.sync_probe = None

    def _queue_probe(self, text: str = _PROBE) -> int:
        """Make the first never-sent line an M105 (inserted there); its line number."""
        at = max(self.cursor, self.highest_sent + 1)
        if at == len(self.texts) or self.texts[at] != text:
            self.texts.insert(at, text)
            self.job_index.insert(at, PROBE_LINE)
        if self.sync and self.sync_probe is None and text == _PROBE:
            self.sync_probe = at
        return at

    def _leave_sync(self) -> None:
        self.sync = False
        if self.next_cap is not None:
            self.byte_cap, self.next_cap = min(self.byte_cap, self.next_cap), None
        self.e_count = self.e_cert
        self.resend_x = None
        self.resend_budget = 0

    def _on_resend_request(self, x: int | None) -> None:
        if x is not None:  # it answers transmission number `answers`: x was refused so far
            self.rejected_until[x] = max(self.rejected_until.get(x, -1), self.answers)
        self._on_resend(x)
        self.answers += 1
        self._retire()
        if self.firmware.resend_ok is not False:
            self.pair_ok = True
            self.pair_unsure = self.firmware.resend_ok is None
        self.resend_tx = self.transmissions

    def _on_skip(self) -> None:
        """Repetier's answer to a line after a rejected one (``skip N`` then ``ok``)."""
        self._enter_sync()
        if self.resend_budget > 0:
            self.resend_budget -= 1
        if self.resend_x is not None:
            self.rejected_until[self.resend_x] = self.answers
        self.answers += 1
        self._retire()
        self.pair_ok = True

    def _on_resend(self, x: int | None) -> None:
        self._enter_sync()
        if x is None or x <= self.e_cert or x > self.highest_sent + 1:
            return  # stale or garbled: the firmware never asks for an executed line
        if x == self.resend_x and self.resend_budget > 0:
            self.resend_budget -= 1
            return
        self._suspect_overflow(x)
        self.e_count = min(self.e_count, x - 1)
        self.resends += 1
        self.resend_x = x
        last = self.last_tx_of.get(x)
        self.resend_budget = self.transmissions - last - 1 if last is not None else 0
        self.cursor = x
        if x < len(self.texts) and self.texts[x] == _PROBE:
            self.sync_probe = x
        elif self._no_copy_pending(x):
            self.texts.insert(x, _PROBE)
            self.job_index.insert(x, PROBE_LINE)
            for n in range(x, self.highest_sent + 1):  # these numbers get other lines now
                for table in (self.first_tx, self.copies, self.rejected_until):
                    table.pop(n, None)
            self.highest_sent = x - 1
            self.sync_probe = x
        else:
            later = [n for n in range(x, len(self.texts)) if self.texts[n] == _PROBE]
            self.sync_probe = later[0] if later else self._queue_probe()
        self.checksum_error = False

    def _no_copy_pending(self, x: int) -> bool:
        """No copy of line ``x`` in flight can still be accepted: none is, or the one that is
        was received and rejected (a checksum error names the line it rejects; otherwise
        the request answers the oldest unanswered transmission)."""
        copies = [entry for entry in self.inflight if entry[0] == x]
        if not copies:
            return True
        return len(copies) == 1 and (self.checksum_error or self.inflight[0][0] == x)

    def _suspect_overflow(self, x: int) -> None:
        """A line rejected while others were unanswered before it: the receive buffer may
        be smaller than the profile says (bytes that do not fit are lost, the line
        garbled), so the byte window shrinks below what was unanswered then. It grows
        back after ``regrow_after`` clean lines, which doubles each time it shrinks: a
        buffer that really is smaller costs a few resends, a corrupted byte little. The
        window shrinks once the recovery is over (lost answers may hold some of it now)."""
        entry = next((e for e in reversed(self.inflight) if e[0] == x), None)
        if entry is None or entry[4] <= entry[1]:
            return
        self.next_cap = max(self.longest_frame, min(self.byte_cap, entry[4] * 3 // 4))
        self.regrow_after = min(16 * REGROW_LINES, 2 * self.regrow_after)
        self.clean_lines = 0

    # -- silence ---------------------------------------------------------------------------

    def _on_silence(self) -> None:
        if not self.inflight and (self.control.paused or self.executed >= self.highest_sent):
            return
        now = time.monotonic()
        options = self.options
        probe_after = min(max(8 * self.ok_gap_s, options.probe_min_s), options.probe_max_s)
        quiet = now - max(self.last_rx_s, self.last_tx_s)
        if quiet < probe_after and now - self.last_rx_s <= options.dead_s:
            return  # the common case, decided cheaply
        waiting = any(code_of(entry[3]) in WAIT_CODES for entry in self.inflight)
        limit = options.wait_dead_s if waiting else options.dead_s
        if self.inflight and now - self.last_rx_s > limit:
            raise self.lost(self.done_lines, f"no answer for {limit:g} s")
        if waiting:  # heat-ups report every 1 s, busy: comes every 2 s
            probe_after = max(probe_after, WAIT_PROBE_S)
        if self.busy_gap_s is not None:  # a firmware that says busy: would have said so
            probe_after = max(probe_after, 1.5 * self.busy_gap_s)
        if quiet < probe_after or now - self.last_probe_s < probe_after:
            return
        self.last_probe_s = now
        if self.inflight and not waiting and self._idle_for_long(now):
            self.recoveries += 1  # nothing can be left in the ring
            self.answers = self.transmissions
            self._retire()
        if self.cursor > self.highest_sent:
            self.probes += 1
            self._queue_probe()


# --- one line at a time (RepRapFirmware) ----------------------------------------
# Streaming to a firmware that checks no line numbers: one line at a time, by position.
#
# RepRapFirmware 3 drops a line with a bad checksum without a word and does not check line
# numbers (src/GCodes/GCodeBuffer/StringParser.cpp ``LineFinished``), so a resend cannot
# be asked for and lines sent ahead would run out of order after a dropped one. The link
# therefore keeps one line unanswered. When a line stays unanswered (dropped, or its
# ``ok`` lost), ``M114`` asks where the machine is: the firmware runs it after the line,
# so the position says whether the line ran (the position after it, or the one before);
# once a probe is out, an ``ok`` no longer counts for the line (it may be the probe's,
# with its position garbled).
# A line that moves nothing (a mode, a set point, an output) is sent again: such commands
# can run twice. Every position answer is followed by the ``M114``'s own ``ok``, which is
# not counted; no new line goes out while a probe is unanswered, so an answer is never
# taken for a later line's.

POSITION_TOL_MM = 0.02  # the firmware reports positions to 0.01 mm or better


class OneByOne:
    """Runs the job of ``proto`` (after its handshake) one line at a time."""

    def __init__(self, proto: MarlinProtocol) -> None:
        self.proto = proto
        self.positions = estimate(proto.job, proto.machine).positions
        self.current: int | None = None  # the line number in flight
        self.sent_s = 0.0
        self.probes: list[int] = []  # line numbers of unanswered M114 probes (oldest first)
        self.probe_s = 0.0
        self.absorb = 0  # oks still owed by answered probes
        self.next_job = 0

    def run(self) -> bool:
        """Stream the job; False if an abort's safe stop was not confirmed in time."""
        proto = self.proto
        deadline = None
        while not self._done():
            if proto.control.aborted and not proto.aborting:
                proto._begin_abort()
                deadline = time.monotonic() + proto.options.finish_s
            if deadline is not None and time.monotonic() > deadline:
                break
            proto._check_pending_error()
            if self.current is None and not self.probes and proto.pending_error is None:
                self._send_next()
            line = proto.read_line()
            if line is None:
                self._on_silence()
            else:
                self._on_line(line)
        return self._done()

    # -- sending ---------------------------------------------------------------------------

    def _done(self) -> bool:
        proto = self.proto
        finished = self.next_job == len(proto.job) or proto.aborting
        return finished and not proto.tail and self.current is None and not self.probes

    def _send_next(self) -> None:
        proto = self.proto
        if proto.control.paused and not proto.aborting:
            return
        if self.next_job < len(proto.job) and not proto.aborting:
            text, index = proto.job[self.next_job].text, self.next_job
            self.next_job += 1
        elif proto.tail:
            text, index = proto.tail.pop(0), -2
        else:
            return
        self.current = self._send(text, index)

    def _send(self, text: str, index: int) -> int:
        proto = self.proto
        n = len(proto.texts)
        proto.texts.append(text)
        proto.job_index.append(index)
        proto.transmissions += 1
        proto.highest_sent = n
        proto.write(frame_marlin(n, text))
        self.sent_s = time.monotonic()
        return n

    # -- answers ---------------------------------------------------------------------------

    def _on_line(self, line: str) -> None:
        proto = self.proto
        answer = classify(line)
        if answer.kind == dialects.OK:
            self._on_ok()
        elif answer.kind == dialects.POSITION:
            seen = dialects.position(line)
            if proto.aborting and not self.probes and all(axis in seen for axis in "XYZ"):
                proto.stop_point = (seen["X"], seen["Y"], seen["Z"])
            self._on_position(seen)
        elif answer.kind == dialects.RESEND and self.current is not None:
            proto.pending_error = None
            self._finish(ran=False)  # RepRapFirmware 2: "rs" instead of an ok
        else:
            proto._on_other(answer, line)

    def _on_ok(self) -> None:
        proto = self.proto
        now = time.monotonic()
        proto.ok_gap_s = 0.8 * proto.ok_gap_s + 0.2 * (now - max(proto.last_ok_s, self.sent_s))
        proto.last_ok_s = now
        if self.absorb:
            self.absorb -= 1
        elif self.current is not None and not self.probes:
            self._finish(ran=True)  # once a probe is out, only its position decides

    def _on_position(self, seen: dict[str, float]) -> None:
        """A probe's answer: it ran after the line in flight, which ran or was dropped."""
        self.absorb += 1
        if not self.probes:
            return  # a probe given up for lost after all: it says nothing about this line
        self.probes.pop(0)
        if self.current is not None:
            ran = self._ran(self.current, seen)
            if ran is not None:  # else a garbled answer: the next probe decides
                self._finish(ran=ran)

    def _finish(self, *, ran: bool) -> None:
        proto = self.proto
        n, self.current = self.current, None
        index = proto.job_index[n]
        if ran:
            proto.e_count = proto.e_cert = n
        else:
            proto.resends += 1
            proto.job_index[n] = -4  # DROPPED: not a job line any more
            proto.e_count = proto.e_cert = n
            if index >= 0:
                self.next_job = index
            else:
                proto.tail.insert(0, proto.texts[n])
        proto.show(proto.done_lines, proto.heating_note)

    def _ran(self, n: int, seen: dict[str, float]) -> bool | None:
        """Whether line ``n`` ran, judged by the reported position ``seen``: the position
        after it (True) or before it (False); None if it is neither (a garbled answer)."""
        proto = self.proto
        index = proto.job_index[n]
        if index < 0:
            return False
        after = self.positions[index]
        before = self.positions[index - 1] if index > 0 else (None,) * 4
        moved = [
            (axis, a, b)
            for axis, a, b in zip("XYZE", after, before, strict=True)
            if a is not None and b is not None and abs(a - b) > POSITION_TOL_MM and axis in seen
        ]
        if not moved:
            proto.warnings.append(
                f"sent '{proto.job[index].text}' again: the machine did not answer it and it "
                "moves nothing, so whether it ran is unknown"
            )
            return False
        if all(abs(seen[axis] - a) <= POSITION_TOL_MM for axis, a, _ in moved):
            return True
        if all(abs(seen[axis] - b) <= POSITION_TOL_MM for axis, _, b in moved):
            return False
        return None

    # -- silence ---------------------------------------------------------------------------

    def _on_silence(self) -> None:
        proto = self.proto
        if self.current is None and not self.probes:
            return
        now = time.monotonic()
        waiting = self.current is not None and (code_of(proto.texts[self.current]) in STOPS)
        limit = proto.options.wait_dead_s if waiting else proto.options.dead_s
        if now - proto.last_rx_s > limit:
            raise proto.lost(proto.done_lines, f"no answer for {limit:g} s")
        options = proto.options
        probe_after = min(max(8 * proto.ok_gap_s, options.probe_min_s), options.probe_max_s)
        if waiting:
            probe_after = max(probe_after, 10.0)
        quiet = now - max(proto.last_rx_s, proto.last_tx_s)
        if quiet < probe_after:
            return
        if self.probes:
            # a probe with nothing but probes before it unanswered this long: dropped
            if now - self.probe_s >= probe_after and self.current is None:
                self.probes.clear()
            elif now - self.probe_s < probe_after:
                return
        if self.current is not None:
            proto.probes += 1
            self.probes.append(self._send("M114", -1))
            self.probe_s = now
