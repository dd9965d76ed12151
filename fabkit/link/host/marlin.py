"""The Marlin line protocol (Marlin, Prusa, Repetier, Smoothieware, Klipper, RepRapFirmware).

Numbering
    ``N0 M110 N0`` resets the firmware's line counter, ``N1 M115`` asks who it is and
    ``N2 M105`` confirms. Its answer names it: a temperature report on the ``ok`` line
    (``ok T:...``, Klipper's ``ok B:... T0:...``), ``ok 2`` where oks name their line, or,
    where the firmware acknowledges a line before running it, three ``ok`` and a report
    on a line of its own (:func:`~fabkit.link.answers.m105_answer` has the sources; the
    third ``ok`` alone may be the pair of a refusal). Every later line goes out as
    ``N<n> <command>*<xor>``. A number, once sent, keeps its text to the end of the job:
    a job line is never renumbered and never replaced by anything; a probe (``M105``)
    takes the next number after every line already sent.
    No ``M110`` follows the handshake. The answers' wording differs between firmwares:
    :mod:`fabkit.link.answers` reads them all.

Why every line runs exactly once, in order
    A sequenced firmware accepts a numbered line only when its number is the last
    accepted one + 1 and its checksum matches (Marlin/src/gcode/queue.cpp
    ``get_serial_commands``, Prusa-Firmware cmdqueue.cpp, Repetier gcode.cpp
    ``checkAndPushCommand``, Smoothieware GcodeDispatch.cpp). The accepted numbers are
    therefore 1, 2, 3, ..., each once, and with one text per number the lines that run
    are the numbered texts in order, each once, *whatever* the host sends again, however
    often and whenever. Sending a line again is always safe; everything below decides
    only *when* to send it again (so that the job goes on) and how much may be
    unanswered (so that the receive buffer never overflows). Two things are outside
    this argument: Marlin and Prusa empty their receive buffer when they refuse a line,
    and a later line that has only partly arrived then runs its rest without ``N``
    (see Window); Klipper checks neither numbers nor checksums, which its pseudo-
    terminal makes unnecessary (it never asks for a line again).

Which answer belongs to which transmission
    The firmware reads the lines in the order they were sent and answers each one it
    reads, in that order: ``ok`` (Repetier: ``ok <n>`` once queued) for an accepted
    line; for a refused one ``Error:...`` and ``Resend: X`` (also ``Resend:X``, ``rs N X``)
    followed by an ``ok`` that pairs with the refusal (Marlin 2.1 and 1.1, Prusa,
    Repetier; not Marlin 2.0.x or Smoothieware), or Repetier's ``skip <n>`` + ``ok``.
    A line Marlin drains, and an answer lost on the way back, leave no answer at all.
    So counting answers against the transmissions in flight, oldest first, gives each
    answer its own transmission or an earlier one, never a later one: a loss makes
    lines look unanswered for longer, which only makes the window more cautious.

The prediction
    For each transmission in flight the sender keeps the line the firmware will expect
    when it reads it (``expect``); the transmission is predicted *accepted* when its
    number is that line, else *refused* with ``Resend: expect``. ``cursor`` is the line
    the firmware will expect once everything in flight is read, and the next line sent
    is always ``cursor``: predicted accepted.

    * An answer that matches the prediction of its transmission changes nothing. This
      is why several identical ``Resend: X`` for one discarded window mean one resend
      from X: every line sent after the refused one was predicted refused with exactly
      that request.
    * An answer that does not match (a refusal where an acceptance was predicted, a
      request for another line than predicted) is what the firmware says it expects
      now: the transmissions after the answered one are predicted again in order (a
      copy of X accepted, X+1 after it, ...; anything else refused), and ``cursor``
      becomes the first line that no transmission in flight will deliver. Exactly the
      lines the firmware discarded are sent again; a line still on its way is not. A
      request the firmware garbled is corrected by the next answer in the same way.
    * An ``ok`` never belongs to a transmission predicted refused: those ahead of the
      oldest predicted acceptance are dropped from the window (drained, or their
      refusal was lost) and the ``ok`` goes to that acceptance.
    * An ``ok`` after an ``Error:`` line whose ``Resend`` was lost pairs with that refusal
      (Marlin prints the three together); an ``ok`` whose pairing the firmware does not
      declare (Marlin 2.0 releases before 2.0.8, unknown firmwares) is taken as the
      pair, and a probe is sent to find out. Both err on the side of fewer answers.

Anchors
    ``ok T:`` (or any temperature report on an ``ok`` line: an M105 answer) and
    ``ok <n>`` name their transmission: the oldest M105 predicted accepted in flight,
    the oldest copy of line n predicted accepted. Everything sent before it is gone
    from the firmware's buffer, so the window is emptied up to it. The job is complete
    when the M105 sent after its last line is answered: the firmware accepts in order,
    so every line before it has run.

    A firmware that answered the handshake's M105 with the report on a line of its own
    (Repetier without ``ACK_WITH_LINENUMBER``, VirtualPrinter's ``okBeforeCommandOutput``)
    reports each M105 once, in the order of their numbers: a report names the oldest
    M105 not yet reported, and, if a copy is in flight predicted accepted, the window is
    emptied up to it (through it where its ``ok`` came before the report, as there; up
    to it where the ``ok`` comes after). Reports that no M105 asked for (heat-ups print
    them every second, Marlin/src/module/temperature.cpp ``wait_for_hotend``; ``M155``
    turns on ``AutoReportTemp``) would name the wrong M105, so from the first line of
    ``REPORTING_CODES`` in the job, or a report with no M105 waiting, reports are no
    anchors; the oks are counted as ever.

Window
    Unanswered lines predicted accepted stay within the planner depth, unanswered
    bytes within the receive buffer (``rx_buffer_bytes - 1``, lowered when a refusal
    suggests an overflow or Marlin's ``RX BUF overflow`` says so); job lines leave room
    for two M105 probes. On draining firmwares (Marlin, Prusa) at most
    ``DRAINING_MAX_LINES`` job lines are unanswered: a line that has only partly
    arrived when the firmware drains needs three unanswered lines at once (the one the
    firmware is busy with, the refused one and the partial one); a probe may be a third,
    its fragment a harmless M105. Lost answers and drained lines only hold the window
    until the next anchor, so on draining firmwares an M105 follows every ``sync_every``
    job lines (fewer after a probe found lost answers). Each line is written to the
    port by its own ``write`` call, as a person typing would send it.

Silence
    With lines in flight and no answer for a while (adapting to the recent pace), an
    M105 probes the machine. After ``assume_idle_s`` of silence, or ``probe_max_s`` of
    answered probes but no job line done, the window is assumed empty; no answer at all
    for ``dead_s`` (``wait_dead_s`` while a heat-up, homing or dwell is in flight) is a
    lost connection. ``busy:`` and temperature reports count as answers (a firmware that
    sends ``busy:`` is probed only after 1.5 of its ``busy:`` intervals of silence);
    ``wait`` (an idle firmware whose ``ok`` may be lost) triggers a probe. An ``Error:``
    with other wording is fatal unless a resend request follows within
    ``ERROR_GRACE_S``; Klipper's ``!!`` errors and ``// Klipper state: Shutdown`` are fatal.

Lines a firmware may not have run
    A firmware that asks for line X has no line from X on, so of each such line it can
    take only the copies in flight then and those sent after. An error line that names
    the refused line N and the expected one, after it (VirtualPrinter and Repetier:
    ``expected line 106 got 105``), says the firmware has N. When that refused copy was
    the last of those it could have taken, it took none, and N may not have run: it is
    reported (:attr:`SendReport.may_not_have_run`), and sending goes on (no sender can
    make the firmware take it). VirtualPrinter's ``105:resend_with_timeout`` does this:
    ``Resend:105``, then it swallows the next line and counts 105 as received. Lines
    acknowledged already are never reset (a request for one is garbled), and a refusal
    that does not name its line is never counted: an answer counted against the wrong
    transmission cannot report a line that ran.

    Every line a firmware accepts is answered by one ``ok`` (Marlin/src/gcode/queue.cpp
    ``RingBuffer::ok_to_send``, called once per command processed; a refusal's own
    ``ok`` aside), in order. So when an anchor (or the job's end) shows the firmware
    past line n, the lines after the last point where the count was complete
    (``tallied``) up to n owe one ``ok`` each, and the oks counted since (``oks``) pay
    for them; each missing one is a line received and never answered: its ``ok`` lost on
    the wire (it ran) or the line dropped (VirtualPrinter's ``105:resend_with_timeout``
    swallowing the copy it asked for): it may not have run, and is reported. Oks are not
    tagged: when the missing ones are as many as those lines, each is named
    (:data:`~fabkit.link.host.session.OK_LOST`); else each of them is named as one of a
    run of which some lost their ``ok`` (:func:`~fabkit.link.host.session.oks_lost`).
    The count is complete, and starts afresh, wherever it pays for every line sent, or
    for the lines before a resend request for the line predicted (the firmware has them;
    their oks may still be on their way, so a shortfall there names nothing). The line
    an anchor names got its ``ok``; a line the firmware claimed as a refused copy
    (above) owes none. Whatever takes lines out of the window (an anchor, silence, a
    ``wait`` and its probe) leaves their count to this rule. Errors lean one way: more
    oks than lines (a fragment's, an anchor credited to an older M105 whose answer was
    lost) cannot be placed and keep the count open until it balances, so they can hide
    or move a loss but name no line when every ok came; an ``ok`` taken as a refusal's
    pair counts as a line's too until the firmware has sent one that no line in flight
    can have sent (whatever it says of itself, it may not pair its refusals:
    VirtualPrinter's ``brokenResend``), and then the earlier ones are taken back.

RepRapFirmware checks no line numbers: one line at a time there
(:class:`~fabkit.link.host.one_by_one.OneByOne`); a line whose ``ok`` is lost is placed by
the position an M114 then reports (sent again if it did not run), so none is named.

This module is over 600 lines: one class, :class:`MarlinProtocol`, whose methods
(handshake, sending, answers, silence) all read and change the one window's state, and
the description of the protocol above.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable

from fabkit.errors import FabkitError
from fabkit.gcode.read import code_of, frame_marlin, frame_summed, job_texts, text_checksums
from fabkit.link import answers
from fabkit.link.answers import Answer, classify
from fabkit.link.host.one_by_one import OneByOne
from fabkit.link.host.session import OK_LOST, REFUSED_COPY, SendReport, Session, oks_lost

WAIT_CODES = frozenset(
    {"M109", "M190", "G28", "G29", "G4", "M400", "M0", "M1", "M600", "M226", "M303"}
)
REPORTING_CODES = frozenset({"M109", "M190", "M191", "M116", "M155", "M303"})  # report unasked
WAIT_PROBE_S = 2.5  # longer than Marlin's default busy: interval
ERROR_GRACE_S = 0.5  # an unknown Error: is fatal unless a resend request follows by then
PROBE = "M105"
WHERE = "M114"
HANDSHAKE = ("M110 N0", "M115", PROBE)
PROBE_LINE, SAFE_STOP, HOUSEKEEPING = -1, -2, -3  # origin of non-job lines; -4: one_by_one.DROPPED
DRAINING_MAX_LINES = 2
SYNC_EVERY = 200  # most job lines between probes on draining firmwares at first
SYNC_EVERY_MAX = 800  # ... after probes that found no lost answer (each costs a line)
SYNC_EVERY_MIN = 10  # ... after probes that did
REGROW_LINES = 500  # clean lines before a byte window shrunk by an overflow grows again
QUEUED_COMMANDS = 4
"""Acknowledged commands a firmware may hold besides its planned moves: Marlin's command
queue (``BUFSIZE``, 4 by default in Configuration_adv.h); Repetier acknowledges a line as
it queues it. A reset drops them with the planner."""
BACKWARD_LIMIT = 3  # requests in a row for a line proven accepted that mean a reset


class Transmission:
    """One line written to the port and not yet answered.

    ``n``: its line number; ``size``: its bytes; ``expect``: the line the firmware is
    predicted to expect when it reads it (accepted if ``n == expect``); ``backlog``: the
    unanswered bytes, itself included, when it was sent; ``accepted``: predicted accepted
    (change ``expect`` only through :meth:`predict`, which keeps it)."""

    __slots__ = ("n", "size", "expect", "backlog", "accepted")

    def __init__(self, n: int, size: int, expect: int, backlog: int) -> None:
        self.n, self.size, self.expect, self.backlog = n, size, expect, backlog
        self.accepted = n == expect

    def predict(self, expect: int) -> None:
        """The firmware is now predicted to expect line ``expect`` when it reads this one."""
        self.expect = expect
        self.accepted = self.n == expect


class MarlinProtocol(Session):
    """Streams a job to a Marlin-protocol firmware (see the module docstring)."""

    protocol = "marlin"

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.firmware = answers.identify("", self.machine.flavour)
        self.rx_usable = self.serial.rx_buffer_bytes - 1
        self.job_texts = job_texts(self.job)
        self.job_sums = text_checksums(self.job_texts)  # None: a text is not ASCII
        biggest_n = 10 ** len(str(2 * len(self.job) + 1000)) - 1
        longest = max(map(len, self.job_texts), default=0)
        self.longest_frame = len(frame_marlin(biggest_n, "x" * longest))
        self.probe_frame = len(frame_marlin(biggest_n, PROBE))
        self.job_window = self.rx_usable - 2 * self.probe_frame
        if self.job_window < self.longest_frame:
            raise FabkitError(
                f"a {longest}-character command does not fit in the "
                f"{self.serial.rx_buffer_bytes}-byte receive buffer of {self.machine.name}"
            )
        self.byte_cap = self.job_window
        self.regrow_after = REGROW_LINES
        self.clean_lines = 0
        self.max_lines = self.options.window_lines or self.serial.planner_depth
        self.texts: list[str] = list(HANDSHAKE)  # by line number, fixed once sent
        self.origin: list[int] = [HOUSEKEEPING, HOUSEKEEPING, HOUSEKEEPING]  # job index or kind
        self.cursor = len(HANDSHAKE)  # the line the firmware expects after all in flight
        self.highest_sent = len(HANDSHAKE) - 1
        self.acked = self.highest_sent  # lines up to this one are known accepted
        self.certain = self.highest_sent  # ... proven so by an answer naming its line
        self.backward = 0  # requests in a row for a line proven accepted
        self.takers: dict[int, int] = {}  # line asked for -> copies it may have taken since
        self.tallied = self.highest_sent  # every ok up to this line is counted or named lost
        self.oks = 0  # oks counted since (module docstring: Lines a firmware may not have run)
        self.maybe_pairs = 0  # ... of them, taken as refusals' pairs too
        self.inflight: deque[Transmission] = deque()
        self.inflight_bytes = 0
        self.inflight_lines = 0  # of them, predicted accepted
        self.pair_ok = False  # the next ok pairs with a refusal
        self.pair_unsure = False  # ... perhaps (the firmware did not say): probe
        self.pairs_seen = False  # the firmware sent an ok that could only be a refusal's
        self.error_line = False  # an Error: line whose Resend has not come yet
        self.error_says: tuple[int | None, int | None] = (None, None)  # expects, refused
        self.unknown_echo: str | None = None
        self.pending_error: tuple[str, float] | None = None
        self.probe_wanted = False
        self.final_probe: int | None = None  # the M105 after the last line
        self.unreported: deque[int] | None = None  # M105s not yet reported (Anchors)
        self.report_after_ok = False  # ... a report comes after the M105's ok, not before
        self.job_next = 0
        self.since_probe = 0
        self.sync_every = SYNC_EVERY
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
            sent = [i for n, i in enumerate(self.origin) if i >= 0 and n <= self.highest_sent]
            raise self.stopped_error(stopped, self.stop_point, max(sent, default=-1))
        return self.report()

    @property
    def done_lines(self) -> int:
        """Job lines known to be executed (a prefix of the job)."""
        for n in range(min(self.acked, len(self.texts) - 1), 0, -1):
            if self.origin[n] >= 0:
                return self.origin[n] + 1
        return 0

    @property
    def sent_lines(self) -> int:
        """Job lines written to the port at least once (a prefix of the job)."""
        for n in range(self.highest_sent, 0, -1):
            if self.origin[n] >= 0:
                return self.origin[n] + 1
        return 0

    def _stream(self) -> bool:
        """Send ahead within the window; False if an abort's safe stop was not confirmed.
        At the end every ok is due: those that never came are named."""
        finished = self.pump(self._done, self._send_ahead, self._on_line, self._on_silence)
        if finished and not self.aborting and self.final_probe is not None:
            self._went_past(self.final_probe)
        return finished

    def _send_ahead(self) -> None:
        if b"\n" not in self.rx and self.pending_error is None:
            self._fill()  # answer everything received before sending more

    def pump(
        self,
        done: Callable[[], bool],
        send: Callable[[], None],
        on_line: Callable[[str], None],
        on_silence: Callable[[], None],
    ) -> bool:
        """Until ``done()``: ``send()`` what may be sent, then answer the next line the
        firmware wrote (``on_line``) or its silence (``on_silence``). Ctrl-C begins the
        safe stop, which then has ``options.finish_s`` to be confirmed; returns whether the
        stream ended ``done`` (False: the safe stop was not confirmed in time)."""
        deadline = None
        control, read_line = self.control, self.read_line
        while not done():
            if control.aborted and not self.aborting:
                self.begin_abort()
                deadline = time.monotonic() + self.options.finish_s
            if deadline is not None and time.monotonic() > deadline:
                break
            if self.pending_error is not None:
                self.check_pending_error()
            send()
            line = read_line()
            if line is None:
                on_silence()
            else:
                on_line(line)
        return done()

    def _done(self) -> bool:
        """The M105 after the last job (or safe-stop) line is answered."""
        return self.final_probe is not None and self.acked >= self.final_probe

    # -- handshake -------------------------------------------------------------------------

    def _handshake(self) -> None:
        """``N0 M110 N0``, ``N1 M115``, ``N2 M105`` until the M105 is answered, in any of
        the forms :func:`~fabkit.link.answers.m105_answer` reads (a board that resets when
        the port opens loses the first try). A try is repeated only once the line has
        fallen quiet: two tries in flight at once would let the later one's ``M110``
        reset the count under the job's first lines."""
        deadline = time.monotonic() + self.options.handshake_s
        self.discard_input()
        frames = [frame_marlin(n, text) for n, text in enumerate(HANDSHAKE)]
        while time.monotonic() < deadline:
            for frame in frames:
                self.write(frame)
            lines: list[str] = []
            retry_at = min(time.monotonic() + 2.0, deadline)
            while time.monotonic() < retry_at:
                line = self.read_line()
                if line is None:
                    continue
                if classify(line).kind == answers.RESEND:
                    break
                lines.append(line)
                form = answers.m105_answer(lines, len(HANDSHAKE) - 1)
                if form is not None:
                    if form == answers.NAMED_OK:  # acknowledged when queued: let them run
                        lines += self._read_until(answers.TEMPERATURES, 1.0)
                    self._configure(lines, form)
                    return
            self._settle()
        raise FabkitError(
            f"no answer from {self.port_name} at {self.serial.baud} baud: is it a "
            "Marlin-protocol machine and the baud rate right?"
        )

    def _configure(self, lines: list[str], form: str) -> None:
        """What the firmware said about itself (its ``FIRMWARE_NAME`` lines) decides the
        window; how it answered M105 (``form``) decides which reports are anchors (module
        docstring)."""
        report = " ".join(line for line in lines if "FIRMWARE_NAME" in line)
        self.firmware = answers.identify(report, self.machine.flavour)
        if self.firmware.drains:
            self.max_lines = min(self.max_lines, DRAINING_MAX_LINES)
        if not self.firmware.sequenced:
            self.max_lines = 1
        if form in (answers.AFTER_OK, answers.BEFORE_OK):
            self.unreported = deque()
            self.report_after_ok = form == answers.AFTER_OK

    def _read_until(self, kind: str, limit_s: float) -> list[str]:
        """The lines read until an answer of ``kind`` (or ``limit_s``)."""
        stop = time.monotonic() + limit_s
        lines = []
        while time.monotonic() < stop:
            line = self.read_line()
            if line is None:
                continue
            lines.append(line)
            if classify(line).kind == kind:
                break
        return lines

    def _settle(self, quiet_s: float = 0.3, limit_s: float = 3.0) -> None:
        """Read and drop lines until none came for ``quiet_s`` (at most ``limit_s``)."""
        stop = time.monotonic() + limit_s
        while time.monotonic() < stop and time.monotonic() - self.last_rx_s < quiet_s:
            self.read_line()

    # -- sending ---------------------------------------------------------------------------

    def _fill(self) -> None:
        """Send from ``cursor`` while the window has room, the lines in one write; a line
        gets its number when it is first sent."""
        if self.control.paused and not self.aborting:
            return
        texts, inflight, takers, sums = self.texts, self.inflight, self.takers, self.job_sums
        frames = []
        while True:
            n = self.cursor
            if n < len(texts):
                text, origin = texts[n], self.origin[n]
            else:
                following = self._following()
                if following is None:
                    break
                text, origin = following
            probe = origin in (PROBE_LINE, HOUSEKEEPING)
            if self.inflight_lines >= self.max_lines + (2 if probe else 0):
                break
            if origin >= 0 and sums is not None:
                frame = frame_summed(n, text, sums[origin])
            else:
                frame = frame_marlin(n, text)
            size = len(frame)
            backlog = self.inflight_bytes + size
            if backlog > (self.rx_usable if probe else self.byte_cap):
                break
            if n == len(texts):
                self._number(text, origin)
            inflight.append(Transmission(n, size, n, backlog))
            self.inflight_bytes = backlog
            self.inflight_lines += 1
            self.transmissions += 1
            if n > self.highest_sent:
                self.highest_sent = n
            self.cursor = n + 1
            if n in takers:
                takers[n] += 1
            frames.append(frame)
        if frames:
            self.write(b"".join(frames))

    def _following(self) -> tuple[str, int] | None:
        """The line that comes after every numbered one (text, origin): a wanted or
        periodic probe, the next job line, a safe-stop line or, after all of them, the
        final M105; None when the final M105 is numbered and no probe is wanted."""
        job_left = self.job_next < len(self.job_texts) and not self.aborting
        periodic = job_left and self.firmware.drains and self.since_probe >= self.sync_every
        if self.probe_wanted or periodic:
            return PROBE, PROBE_LINE
        if job_left:
            return self.job_texts[self.job_next], self.job_next
        if self.tail:
            return self.tail[0], SAFE_STOP
        return (PROBE, PROBE_LINE) if self.final_probe is None else None

    def _number(self, text: str, origin: int) -> None:
        """Give the line :meth:`_following` chose the next number."""
        if origin == PROBE_LINE:
            final = (self.job_next == len(self.job) or self.aborting) and not self.tail
            self.probes += not (self.probe_wanted or final)  # a periodic one
            self.probe_wanted = False
            self.since_probe = 0
            if final:
                self.final_probe = len(self.texts)
        elif origin == SAFE_STOP:
            self.tail.pop(0)
        else:
            self.job_next += 1
            self.since_probe += 1
        if self.unreported is not None:
            if code_of(text) in REPORTING_CODES:
                self.unreported = None  # its reports would pass for an M105's
            elif code_of(text) == PROBE:
                self.unreported.append(len(self.texts))
        self.texts.append(text)
        self.origin.append(origin)

    def _want_probe(self) -> None:
        """An M105 as soon as every line already numbered is sent."""
        if not self.probe_wanted:
            self.probes += 1
        self.probe_wanted = True

    def begin_abort(self) -> None:
        """The safe-stop snippet follows the lines in flight, with an ``M114`` after its
        ``M410`` (which drops the planned moves): where the tool stopped says which line
        to resume from."""
        self.aborting = True
        self.final_probe = None  # the safe stop goes after it
        self.tail = self.machine.render("safe_stop_gcode")
        at = next((i + 1 for i, text in enumerate(self.tail) if code_of(text) == "M410"), 0)
        self.tail.insert(at, WHERE)
        self.warnings.append("aborted by the user: safe-stop snippet sent")

    # -- answers ---------------------------------------------------------------------------

    def _on_line(self, line: str) -> None:
        answer = classify(line)
        kind = answer.kind
        if kind == answers.OK:
            self._on_ok(answer)
        elif kind == answers.RESEND:
            self.pending_error = None  # the error before it was a line error
            self._on_refusal(answer.number)
        elif kind == answers.SKIP:
            self._on_refusal(None)
        else:
            if kind == answers.TEMPERATURES and self.unreported is not None:
                self._on_report()
            self.on_other(answer, line)

    def on_other(self, answer: Answer, line: str) -> None:
        """Everything but acknowledgements and resend requests (both protocols' loops)."""
        kind = answer.kind
        if kind == answers.LINE_ERROR:
            self.error_line = True
            self.error_says = answers.refused_line(line)
        elif kind == answers.ERROR:
            self.pending_error = (line, time.monotonic() + ERROR_GRACE_S)
        elif kind == answers.FATAL:
            raise self._reported(line)
        elif kind == answers.OVERFLOW:
            self._on_overflow(answer)
        elif kind == answers.START:
            held = self.serial.planner_depth + QUEUED_COMMANDS
            drops = "the firmware's planned moves and queued commands"
            raise self.reset_error(self.done_lines, self.sent_lines, held, drops)
        elif kind == answers.UNKNOWN_COMMAND:
            self.unknown_echo = answer.text
        elif kind == answers.WAIT and self.inflight:
            self._want_probe()
        elif kind == answers.TEMPERATURES:
            heating = any(code_of(self.texts[t.n]) in ("M109", "M190") for t in self.inflight)
            if " W:" in line or heating:
                self.heating_note = "heating " + line.strip().split(" W:")[0]
                self.show(self.done_lines, self.heating_note)
        elif kind == answers.BUSY:  # its pace: a silence shorter than that is a busy command
            now = time.monotonic()
            gap = now - self.last_busy_s
            if gap < 10.0:
                self.busy_gap_s = gap if self.busy_gap_s is None else min(self.busy_gap_s, gap)
            self.last_busy_s = now
        elif kind == answers.POSITION and self.aborting and self.stop_point is None:
            where = answers.position(line)
            if all(axis in where for axis in "XYZ"):
                self.stop_point = (where["X"], where["Y"], where["Z"])
        elif kind == answers.OTHER and self.inflight:
            self._want_probe()  # perhaps a garbled answer: find out now

    def _reported(self, line: str) -> FabkitError:
        """The one line for an error the machine reported: it answers the oldest line in
        flight (where that is a job line, the file line is named)."""
        origin = self.origin[self.inflight[0].n] if self.inflight else -1
        if origin >= 0:
            where = f"at file line {self.job[origin].file_line} ({self.job[origin].text})"
        else:
            where = f"after file line {self.file_line_after(self.done_lines)}"
        return FabkitError(f"{self.port_name} reported '{line}' {where}")

    def check_pending_error(self) -> None:
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
        now = self.last_rx_s  # when it was read
        last = self.last_ok_s if self.last_ok_s >= self.last_tx_s else self.last_tx_s
        gap = now - last  # the machine's pace, not our waits
        self.ok_gap_s = 0.8 * self.ok_gap_s + 0.2 * gap
        self.last_ok_s = now
        echo, self.unknown_echo = self.unknown_echo, None
        if answer.ignored or (echo is not None and not self._echoed(echo)):
            return
        named = answer.number is not None or answer.temperatures
        if (self.error_line or self.pair_ok) and not named:  # the refusal's own ok
            if self.error_line and self.inflight:  # whose resend request was lost
                self._retire()
                self._want_probe()
            if self.pair_unsure:  # perhaps no ok after a resend request (Marlin 2.0.x)
                self._want_probe()
            self._paired()
            self.pair_ok = self.pair_unsure = self.error_line = False
            return
        self.pair_ok = self.pair_unsure = False  # a named answer: the pair did not come
        sent = self._answered(answer)
        self._went_past(self.highest_sent, due=False)  # every line sent has its ok
        if sent is None:
            return
        if sent.n > self.acked:
            self.acked = sent.n
        self.backward = 0
        if echo is not None:
            self.warnings.append(f"the machine did not know '{self.texts[sent.n]}'")
        self._grow()
        self.show(self._progress(), self.heating_note)

    def _paired(self) -> None:
        """An ``ok`` taken as a refusal's pair. With no line in flight predicted accepted,
        no line can have sent it: the firmware pairs its refusals (whatever it says of
        itself, VirtualPrinter with ``brokenResend`` does not), and the oks taken for pairs
        before were pairs. Until one such is seen it may be a line's ``ok``, and is counted
        as one that may be a pair; a firmware that sends none (Marlin 2.0.x) has only
        lines' oks (module docstring: Lines a firmware may not have run)."""
        if self.firmware.resend_ok is False:
            self.oks += 1
        elif self.inflight_lines == 0:
            self.pairs_seen = True
            self.oks -= self.maybe_pairs
            self.maybe_pairs = 0
        elif not self.pairs_seen:
            self.oks += 1
            self.maybe_pairs += 1

    def _echoed(self, echo: str) -> bool:
        """Whether the ``ok`` after an unknown-command ``echo`` answers a line in flight: an
        echo of the line itself does (the firmware took its number and did not know it);
        an echo ending in a line's text is that line with its N word garbled, run
        unchecked and not accepted (its number is still expected); any other echo is a
        fragment of a line split by a corrupted byte, answered already."""
        texts = [self.texts[t.n] for t in self.inflight]
        if self.firmware.echo_word:
            return echo in (text.split(" ", 1)[0] for text in texts)
        if echo in texts:
            return True
        if any(echo.endswith(" " + text) for text in texts):
            sent = self._retire()
            self._predict(sent.expect)
        return False

    def _answered(self, answer: Answer) -> Transmission | None:
        """The transmission an acceptance answers, taken out of the window with every one
        before it (module docstring: Which answer, Anchors); the ``ok`` is counted."""
        self.oks += 1
        if answer.number is not None:
            named = self._oldest(lambda t: t.n == answer.number)
            if named is not None:
                if named is self._oldest(lambda t: True):  # as counted: not a garbled number
                    self._anchor(named.n)
                return self._retire_through(named)
        if answer.temperatures:
            probe = self._oldest(lambda t: self.texts[t.n] == PROBE)
            if probe is not None:
                self._anchor(probe.n)
                return self._retire_through(probe)
        while self.inflight and not self.inflight[0].accepted:
            self._retire()  # drained, or its refusal was lost: an ok is never its
        return self._retire() if self.inflight else None

    def _on_report(self) -> None:
        """A temperature report on a line of its own from a firmware that answers M105 so:
        the report of the oldest M105 not yet reported, whose transmission, if still in
        flight, is an anchor; the firmware's ``ok`` for it came before the report, or comes
        after it (module docstring: Anchors). A report that no M105 asked for means the
        firmware reports unasked: reports are no anchors from then on."""
        if not self.unreported:
            self.unreported = None
            return
        n = self.unreported.popleft()
        self._went_past(n if self.report_after_ok else n - 1)  # its ok came, or comes next
        probe = self._oldest(lambda t: t.n == n)
        if probe is None:  # its ok retired it, as counted: no answer was lost
            self._rebase(0)
            return
        self._rebase(self._retire_before(probe))
        if self.report_after_ok:
            self._retire()
        self.acked = max(self.acked, n)
        self.certain = max(self.certain, n)
        self._progress()

    def _anchor(self, n: int) -> None:
        """The ``ok`` just counted names line ``n`` (module docstring: Anchors)."""
        self.certain = max(self.certain, n)
        self._went_past(n, answered=n)

    def _went_past(self, last: int, answered: int | None = None, *, due: bool = True) -> None:
        """The firmware accepted every line up to ``last`` (``answered``: a line among them
        whose own ``ok`` said so). Every accepted line gets one ``ok``, so the lines after
        ``tallied`` are owed ``last - tallied`` of them; those that did not come lost
        their ``ok`` (``due``: all have been sent by now; else, as after a resend request,
        some may still come, and the count starts afresh only if none is missing). More
        oks than lines (a fragment's, a stray one) cannot be placed: the count goes on
        until it balances (module docstring: Lines a firmware may not have run)."""
        missing = last - self.tallied - self.oks
        balanced = missing == 0 and not self.maybe_pairs
        if last <= self.tallied or not (balanced or missing > 0 and due):
            return
        if missing:
            self._name_lost(missing, last, answered)
        self.tallied, self.oks, self.maybe_pairs = last, 0, 0

    def _name_lost(self, missing: int, last: int, answered: int | None) -> None:
        """``missing`` oks of the lines after ``tallied`` up to ``last`` never came: each
        of those lines if they are as many, else all of them as ones of which some did."""
        numbers = [n for n in range(self.tallied + 1, last + 1) if n != answered]
        lines = [self.origin[n] for n in numbers if self.origin[n] >= 0]
        if not lines:
            return  # probes' oks
        if missing == len(numbers):
            for index in lines:
                self.name_unrun(index, OK_LOST)
            return
        first, final = self.job[lines[0]].file_line, self.job[lines[-1]].file_line
        why = oks_lost(missing, first, final)
        for index in lines:
            self.name_unrun(index, why, shared=True)

    def _oldest(self, match) -> Transmission | None:
        return next((t for t in self.inflight if t.accepted and match(t)), None)

    def _retire_through(self, sent: Transmission) -> Transmission:
        self._rebase(self._retire_before(sent))
        return self._retire()

    def _retire_before(self, sent: Transmission) -> int:
        """Take the transmissions before ``sent`` out of the window; how many of them were
        predicted accepted (their answers were lost)."""
        lost = 0
        while self.inflight[0] is not sent:
            lost += self.inflight[0].accepted
            self._retire()
        return lost

    def _retire(self) -> Transmission:
        sent = self.inflight.popleft()
        self.inflight_bytes -= sent.size
        self.inflight_lines -= sent.accepted
        return sent

    def _rebase(self, lost: int) -> None:
        """An anchor found ``lost`` answers lost: probe more often on draining firmwares
        if so, less often if not."""
        if lost:
            self.sync_every = max(SYNC_EVERY_MIN, self.sync_every // 2)
        else:
            self.sync_every = min(SYNC_EVERY_MAX, 2 * self.sync_every)

    def _on_refusal(self, x: int | None) -> None:
        """``Resend: x`` (or Repetier's ``skip``, ``x`` None): a transmission in flight was
        refused; compare with its prediction (module docstring)."""
        expects, refused = self.error_says if self.error_line else (None, None)
        self.error_line = False
        if x is None:  # skip: a line sent after a refused one; its ok follows
            self.pair_ok = True
            if self.inflight:
                self._retire()
            return
        if self.firmware.resend_ok is not False:
            self.pair_ok = True
            self.pair_unsure = self.firmware.resend_ok is None
        sent = self._refused(x if expects == x else None, refused if expects == x else None)
        if x < 1 or x > self.highest_sent + 1:
            return  # garbled: the firmware cannot expect a line never sent
        if self._asks_backward(x):
            return
        if expects == x:
            self._claimed(sent, refused, x)
        if sent is not None and x == sent.expect:  # as predicted: the firmware has x - 1
            self._went_past(x - 1, due=False)
        if sent is not None and not sent.accepted and x == sent.expect:
            return  # as predicted: one more answer from a discarded window
        self.resends += 1
        if sent is not None and sent.accepted:
            self._suspect_overflow(sent)
        self._asked(x)
        self._predict(x)

    def _asked(self, x: int) -> None:
        """The firmware asks for line ``x``: it has no line from ``x`` on, so of each it can
        take only the copies still in flight and those sent from now on (module docstring:
        Lines a firmware may not have run). A line known accepted is left alone: a request
        for it would be a garbled one."""
        first = max(x, self.acked + 1)
        for n in range(first, self.highest_sent + 1):
            self.takers[n] = 0
        for sent in self.inflight:
            if sent.n >= first:
                self.takers[sent.n] += 1

    def _claimed(self, sent: Transmission | None, refused: int | None, x: int) -> None:
        """The error line named the refused line ``refused`` and the firmware asks for a
        later line ``x``: it refused a copy of a line it says it has. When that copy was
        the last it could have taken since it asked for the line, it never took one, and
        the line may not have run."""
        if refused is None or refused >= x or sent is None or sent.n != refused:
            return
        left = self.takers.get(refused)
        if left is None:
            return
        self.takers[refused] = left - 1
        if left == 1:
            self.oks += 1  # it took the line without an ok, which is not owed any more
            if self.origin[refused] >= 0:
                self.name_unrun(self.origin[refused], REFUSED_COPY)

    def _asks_backward(self, x: int) -> bool:
        """A request for a line an answer naming it proved accepted: a garbled number,
        which the next answer corrects (so it is not followed), or a firmware that lost
        its place: ``BACKWARD_LIMIT`` such requests in a row (a probe goes out after
        the first, so they are fresh answers) are a reset, and sending those lines
        again would run them twice."""
        if x > self.certain:
            self.backward = 0
            return False
        self.backward += 1
        if self.backward >= BACKWARD_LIMIT:
            reason = f"the machine asked for line {x} again, which it had acknowledged: it reset"
            raise self.lost(self.done_lines, reason, self.sent_lines)
        self._want_probe()
        return True

    def _refused(self, expects: int | None, number: int | None) -> Transmission | None:
        """The refused transmission, out of the window: the oldest one, or, where the error
        line named the refused number, the oldest copy of it (the ones before it were
        answered and their answers lost; those the firmware is past were accepted)."""
        if not self.inflight:
            return None
        if number is not None and any(t.n == number for t in self.inflight):
            while self.inflight[0].n != number:
                sent = self._retire()
                if expects is not None and sent.accepted and sent.n < expects:
                    self.acked = max(self.acked, sent.n)
        return self._retire()

    def _predict(self, x: int) -> None:
        """The firmware expects line ``x`` next: predict every transmission in flight again
        and continue from the first line none of them will deliver."""
        expect = x
        lines = 0
        for sent in self.inflight:
            sent.predict(expect)
            if sent.n == expect:
                expect += 1
                lines += 1
        self.inflight_lines = lines
        self.cursor = expect
        self.acked = min(self.acked, x - 1)

    def _suspect_overflow(self, sent: Transmission) -> None:
        """A line refused while others were unanswered before it: the receive buffer may be
        smaller than the profile says (bytes that do not fit are lost, the line garbled),
        so the byte window shrinks below what was unanswered then. It grows back after
        ``regrow_after`` clean lines, which doubles each time it shrinks: a buffer that
        really is smaller costs a few resends, a corrupted byte little."""
        if sent.backlog <= sent.size:
            return
        self.byte_cap = max(self.longest_frame, min(self.byte_cap, sent.backlog * 3 // 4))
        self.regrow_after = min(16 * REGROW_LINES, 2 * self.regrow_after)
        self.clean_lines = 0

    def _grow(self) -> None:
        """A clean line: after enough of them a shrunk byte window grows again."""
        self.clean_lines += 1
        if self.byte_cap < self.job_window and self.clean_lines >= self.regrow_after:
            self.byte_cap = min(self.job_window, self.byte_cap + max(8, self.longest_frame // 2))
            self.clean_lines = 0

    def _progress(self) -> int:
        """The job lines done (:attr:`done_lines`), noting when that last changed."""
        done = self.done_lines
        if done != self.last_done:
            self.last_done = done
            self.last_progress_s = time.monotonic()
        return done

    # -- silence ---------------------------------------------------------------------------

    def _on_silence(self) -> None:
        if not self.inflight:
            if self.final_probe is not None and self.cursor == len(self.texts):
                self._want_probe()  # the final probe's answer was assumed lost: another
            return
        now = time.monotonic()
        options = self.options
        probe_after = min(max(8 * self.ok_gap_s, options.probe_min_s), options.probe_max_s)
        quiet = now - max(self.last_rx_s, self.last_tx_s)
        if quiet < probe_after and now - self.last_rx_s <= options.dead_s:
            return  # the common case, decided cheaply
        waiting = any(code_of(self.texts[t.n]) in WAIT_CODES for t in self.inflight)
        limit = options.wait_dead_s if waiting else options.dead_s
        if now - self.last_rx_s > limit:
            raise self.lost(self.done_lines, f"no answer for {limit:g} s", self.sent_lines)
        if waiting:  # heat-ups report every 1 s, busy: comes every 2 s
            probe_after = max(probe_after, WAIT_PROBE_S)
        if self.busy_gap_s is not None:  # a firmware that says busy: would have said so
            probe_after = max(probe_after, 1.5 * self.busy_gap_s)
        if quiet < probe_after or now - self.last_probe_s < probe_after:
            return
        self.last_probe_s = now
        while self.inflight and not self.inflight[0].accepted:
            self._retire()  # refused lines the firmware has not answered by now: drained
        if not waiting and self._idle_for_long(now):
            self.recoveries += 1  # nothing can be left in the firmware's buffer
            while self.inflight:
                self._retire()
        self._want_probe()

    def _idle_for_long(self, now: float) -> bool:
        """Silent for ``assume_idle_s``; or answering probes (lost answers can leave
        them unplaced) but no job line done, with no ``busy:``, for ``probe_max_s``: a
        firmware busy with a line answers no probe behind it."""
        if now - self.last_rx_s > self.options.assume_idle_s:
            return True
        busy = self.busy_gap_s is not None and now - self.last_busy_s < 1.5 * self.busy_gap_s
        return not busy and now - self.last_progress_s > self.options.probe_max_s
