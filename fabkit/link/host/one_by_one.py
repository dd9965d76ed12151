"""One line at a time: streaming to a firmware that checks no line numbers (RepRapFirmware),
for :class:`~fabkit.link.host.marlin.MarlinProtocol` after its handshake.

RepRapFirmware 3 drops a line with a bad checksum without a word and does not check line
numbers (src/GCodes/GCodeBuffer/StringParser.cpp ``LineFinished``), so a resend cannot
be asked for and lines sent ahead would run out of order after a dropped one. The link
therefore keeps one line unanswered. When a line stays unanswered (dropped, or its
``ok`` lost), ``M114`` asks where the machine is: the firmware runs it after the line,
so the position says whether the line ran (the position after it, or the one before);
once a probe is out, an ``ok`` no longer counts for the line (it may be the probe's,
with its position garbled).

A line that moves nothing (a mode, a set point, an output) is sent again: such commands
can run twice. Every position answer is followed by the ``M114``'s own ``ok``, which is
not counted; no new line goes out while a probe is unanswered, so an answer is never
taken for a later line's.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Protocol

from fabkit.errors import FabkitError
from fabkit.gcode.duration import STOPS, estimate
from fabkit.gcode.read import Command, code_of, frame_marlin
from fabkit.link import answers
from fabkit.link.answers import Answer, classify
from fabkit.link.host.session import LinkControl, LinkOptions
from fabkit.machines import MachineProfile

DROPPED = -4
"""The origin (``MarlinProtocol.origin``) of a line found dropped: not a job line any more.
The other origins of non-job lines, -1 to -3, are :mod:`fabkit.link.host.marlin`'s."""
POSITION_TOL_MM = 0.02  # the firmware reports positions to 0.01 mm or better


class NumberedLink(Protocol):
    """What the one-by-one stream uses of the
    :class:`~fabkit.link.host.marlin.MarlinProtocol` that runs it (named here so that this
    module imports nothing of that one's, which imports it): the session's job, port and
    counters (:class:`~fabkit.link.host.session.Session`) and the numbered lines' state."""

    job: Sequence[Command]
    machine: MachineProfile
    options: LinkOptions
    control: LinkControl
    aborting: bool
    last_rx_s: float
    last_tx_s: float
    transmissions: int
    resends: int
    probes: int
    warnings: list[str]
    texts: list[str]  # by line number, fixed once sent
    origin: list[int]  # by line number: the job index, or the kind of a non-job line
    tail: list[str]  # the safe stop's lines still to send
    acked: int
    highest_sent: int
    pending_error: tuple[str, float] | None
    ok_gap_s: float
    last_ok_s: float
    stop_point: tuple[float, float, float] | None
    heating_note: str

    def pump(
        self,
        done: Callable[[], bool],
        send: Callable[[], None],
        on_line: Callable[[str], None],
        on_silence: Callable[[], None],
    ) -> bool: ...
    @property
    def done_lines(self) -> int: ...
    def write(self, data: bytes) -> None: ...
    def show(self, done: int, note: str = "", *, force: bool = False) -> None: ...
    def lost(self, done: int, reason: str, sent: int | None = None) -> FabkitError: ...
    def on_other(self, answer: Answer, line: str) -> None: ...


class OneByOne:
    """Runs the job of ``proto`` (after its handshake) one line at a time."""

    def __init__(self, proto: NumberedLink) -> None:
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
        return self.proto.pump(
            self._done, self._send_when_answered, self._on_line, self._on_silence
        )

    def _send_when_answered(self) -> None:
        """The next line, once the last one and every probe are answered."""
        if self.current is None and not self.probes and self.proto.pending_error is None:
            self._send_next()

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
        proto.origin.append(index)
        proto.transmissions += 1
        proto.highest_sent = n
        proto.write(frame_marlin(n, text))
        self.sent_s = time.monotonic()
        return n

    # -- answers ---------------------------------------------------------------------------

    def _on_line(self, line: str) -> None:
        proto = self.proto
        answer = classify(line)
        if answer.kind == answers.OK:
            self._on_ok()
        elif answer.kind == answers.POSITION:
            seen = answers.position(line)
            if proto.aborting and not self.probes and all(axis in seen for axis in "XYZ"):
                proto.stop_point = (seen["X"], seen["Y"], seen["Z"])
            self._on_position(seen)
        elif answer.kind == answers.RESEND and self.current is not None:
            proto.pending_error = None
            self._finish(ran=False)  # RepRapFirmware 2: "rs" instead of an ok
        else:
            proto.on_other(answer, line)

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
        index = proto.origin[n]
        if ran:
            proto.acked = n
        else:
            proto.resends += 1
            proto.origin[n] = DROPPED  # not a job line any more
            proto.acked = n
            if index >= 0:
                self.next_job = index
            else:
                proto.tail.insert(0, proto.texts[n])
        proto.show(proto.done_lines, proto.heating_note)

    def _ran(self, n: int, seen: dict[str, float]) -> bool | None:
        """Whether line ``n`` ran, judged by the reported position ``seen``: the position
        after it (True) or before it (False); None if it is neither (a garbled answer)."""
        proto = self.proto
        index = proto.origin[n]
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
