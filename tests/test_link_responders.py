"""Machines that are not fabkit's emulator: small pty responders with other buffer models.

Each responder serves the master side of a pseudo-terminal from a thread and answers a
Marlin-style line protocol (``N<n> ...*<xor>``, ``ok``, ``Error:`` + ``Resend:`` + ``ok``
for a bad line, ``ok T:`` for M105 (or, with ``m105``, the report on a line of its own
after or before the ``ok``), a ``FIRMWARE_NAME`` for M115 that names no known firmware)
with its own model of time and buffers, written here independently of
:mod:`fabkit.link.emulator.port`:

* :class:`LatencyResponder` acks every line after a fixed latency, whatever came before
  (no buffer model at all: a fast USB firmware behind a slow link);
* :class:`PacedResponder` has a 64-byte receive ring that loses bytes when full and
  works on one line at a time at a fixed pace, acknowledging it when done (or, in the
  harshest variant, as soon as it is taken from the ring: then the ring must hold every
  unanswered line);
* :class:`BusyResponder` acks after a latency, but every 10th line takes longer, with
  ``echo:busy: processing`` meanwhile, and says ``wait`` when idle with nothing to do.

:func:`naive_send` is a one-line-per-``ok`` sender as simple hosts do it, the yardstick
for the send-ahead (``benchmarks/link_throughput.py`` prints the ratios).
"""

from __future__ import annotations

import multiprocessing
import os
import re
import select
import time
import tty
from collections import deque

import pytest
import serial

from fabkit.gcode.read import Command, frame_marlin, marlin_checksum
from fabkit.link.host.ports import open_port
from fabkit.link.host.send import stream_job
from fabkit.link.host.session import LinkOptions
from fabkit.machines import load_machine
from tests.test_link_support import HOUSEKEEPING, marlin_job

_FRAME = re.compile(rb"N(\d+) (.*)\*(\d+)$")


class Responder:
    """A pty whose far end answers like a simple firmware; subclasses decide when.

    The machine runs in its own process (a thread would share the interpreter lock with
    the sender and slow it down, or the sender it). After the ``with`` block,
    ``executed`` lists the accepted commands in order, ``max_unanswered`` is the most
    lines that had arrived and not yet been answered and ``lost_bytes`` counts bytes
    that did not fit a receive buffer. ``m105``: where the M105 report goes, ``"ok_line"``
    (``ok T:...``), ``"after_ok"`` or ``"before_ok"`` (a line of its own)."""

    m105 = "ok_line"

    def __init__(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)
        self.executed: list[str] = []
        self.last_n = 0
        self.lost_bytes = 0
        self.max_unanswered = 0
        self.out: deque[tuple[float, bytes]] = deque()
        context = multiprocessing.get_context("fork")
        self._stop = context.Event()
        self._results = context.Queue()
        self._process = context.Process(target=self._run, daemon=True)

    def job_lines(self) -> list[str]:
        """The accepted commands without the sender's own (handshake, probes)."""
        return [text for text in self.executed if text not in HOUSEKEEPING]

    def __enter__(self) -> Responder:
        self._process.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self.executed, self.lost_bytes, self.max_unanswered = self._results.get(timeout=10)
        self._process.join(timeout=5)
        os.close(self.master)
        os.close(self.slave)

    def _run(self) -> None:
        self._serve()
        self._results.put((self.executed, self.lost_bytes, self.max_unanswered))

    def _serve(self) -> None:
        while not self._stop.is_set():
            now = time.monotonic()
            data = b""
            while self.out and self.out[0][0] <= now:
                data += self.out.popleft()[1]
            if data:
                os.write(self.master, data)
            self.tick(now)
            wake = min(self.out[0][0] if self.out else now + 0.005, self.next_event(now))
            ready, _, _ = select.select([self.master], [], [], min(0.005, max(0.0, wake - now)))
            if ready:
                self.receive(os.read(self.master, 4096), time.monotonic())

    def say(self, text: str, at: float) -> None:
        when = max(at, self.out[-1][0]) if self.out else at
        self.out.append((when, text.encode() + b"\n"))

    def answer(self, raw: bytes, at: float) -> None:
        """Check one line as Marlin does and queue its answer for time ``at``."""
        line = raw.strip()
        match = _FRAME.match(line)
        if match is None:
            return self._reject("No Checksum with line number", at)
        n, text, checksum = int(match.group(1)), match.group(2).decode(), int(match.group(3))
        if marlin_checksum(line[: line.rindex(b"*")]) != checksum:
            return self._reject("checksum mismatch", at)
        if text.startswith("M110"):
            self.last_n = n
        elif n != self.last_n + 1:
            return self._reject("Line Number is not Last Line Number+1", at)
        self.last_n = n
        self.executed.append(text)
        if text == "M105":
            self._report(at)
        elif text == "M115":
            self.say("FIRMWARE_NAME:TestResponder 0.1 PROTOCOL_VERSION:1.0", at)
            self.say("ok", at)
        else:
            self.say("ok", at)
        return None

    def _report(self, at: float) -> None:
        report = "T:21.0 /0.0 B:20.5 /0.0 @:0 B@:0"
        lines = {"ok_line": [f"ok {report}"], "after_ok": ["ok", report]}
        for line in lines.get(self.m105, [report, "ok"]):
            self.say(line, at)

    def _reject(self, reason: str, at: float) -> None:
        self.say(f"Error:{reason}, Last Line: {self.last_n}", at)
        self.say(f"Resend: {self.last_n + 1}", at)
        self.say("ok", at)

    def receive(self, data: bytes, now: float) -> None:
        raise NotImplementedError

    def tick(self, now: float) -> None:
        """Time passes (called at least every 5 ms, and at :meth:`next_event`)."""

    def next_event(self, now: float) -> float:
        """When :meth:`tick` has something to do next."""
        return now + 0.005


class LatencyResponder(Responder):
    """Answers each line ``latency_s`` after it arrived; any number may be in flight."""

    def __init__(self, latency_s: float) -> None:
        super().__init__()
        self.latency_s = latency_s
        self.partial = b""
        self.due: deque[float] = deque()

    def receive(self, data: bytes, now: float) -> None:
        self.partial += data
        while b"\n" in self.partial:
            raw, self.partial = self.partial.split(b"\n", 1)
            self.due.append(now + self.latency_s)
            self.max_unanswered = max(self.max_unanswered, len(self.due))
            self.answer(raw, now + self.latency_s)

    def tick(self, now: float) -> None:
        while self.due and self.due[0] <= now:
            self.due.popleft()


class PacedResponder(Responder):
    """A ``ring_bytes`` receive ring (bytes that do not fit are lost) from which one line
    at a time is taken and worked on for ``pace_s``; it is answered when the work is
    done (``ack="done"``, as Marlin does) or when it is taken (``ack="taken"``, as
    Repetier does: then every unanswered line sits in the ring). A full ring without a
    line end counts as a line."""

    def __init__(self, ring_bytes: int = 64, pace_s: float = 0.002, ack: str = "done") -> None:
        super().__init__()
        self.ring_bytes = ring_bytes
        self.pace_s = pace_s
        self.ack_taken = ack == "taken"
        self.ring = bytearray()
        self.free_at = 0.0  # the line being worked on is done then
        self.working: bytes | None = None

    def receive(self, data: bytes, now: float) -> None:
        """Bytes fill the ring; an idle machine takes a line as soon as it is complete."""
        while data:
            room = self.ring_bytes - 1 - len(self.ring)  # one byte of a ring stays empty
            self.ring += data[:room]
            data = data[room:]
            waiting = self.ring.count(b"\n") + (self.working is not None and not self.ack_taken)
            self.max_unanswered = max(self.max_unanswered, waiting)
            taken = self.working is None and self._ready()
            self.tick(now)
            if data and not taken:
                self.lost_bytes += len(data)
                return

    def _ready(self) -> bool:
        return b"\n" in self.ring or len(self.ring) >= self.ring_bytes - 1

    def next_event(self, now: float) -> float:
        return self.free_at if self.working is not None or self._ready() else now + 0.005

    def tick(self, now: float) -> None:
        if now < self.free_at:
            return
        if self.working is not None:
            if not self.ack_taken:
                self.answer(self.working, now)
            self.working = None
        if self._ready():
            raw, _, rest = bytes(self.ring).partition(b"\n")
            self.ring = bytearray(rest)
            self.working = raw
            self.free_at = now + self.pace_s
            if self.ack_taken:
                self.answer(raw, now)


class BusyResponder(LatencyResponder):
    """Lines run one after the other, answered ``latency_s`` after they end (a USB link);
    most take no time, but every 10th works ``work_s`` with ``echo:busy: processing``
    every ``busy_s`` meanwhile; ``wait`` after ``idle_s`` with nothing left to answer."""

    def __init__(self, latency_s: float = 0.001, work_s: float = 0.05, busy_s: float = 0.02):
        super().__init__(latency_s)
        self.work_s = work_s
        self.busy_s = busy_s
        self.idle_s = 0.1
        self.free_at = 0.0
        self.last_seen = time.monotonic()

    def receive(self, data: bytes, now: float) -> None:
        self.partial += data
        while b"\n" in self.partial:
            raw, self.partial = self.partial.split(b"\n", 1)
            start = max(now, self.free_at)
            slow = len(self.executed) % 10 == 9
            done = start + (self.work_s if slow else 0.0)
            if slow:
                for k in range(1, int(self.work_s / self.busy_s) + 1):
                    self.say("echo:busy: processing", start + k * self.busy_s + self.latency_s)
            self.free_at = done
            self.due.append(done + self.latency_s)
            self.max_unanswered = max(self.max_unanswered, len(self.due))
            self.answer(raw, done + self.latency_s)
        self.last_seen = now

    def tick(self, now: float) -> None:
        super().tick(now)
        idle = not self.due and not self.out and now - max(self.last_seen, self.free_at)
        if idle and idle > self.idle_s:
            self.say("wait", now)
            self.last_seen = now


def naive_send(path: str, job: list[Command], timeout_s: float = 10.0) -> float:
    """Send ``job`` one line per ``ok`` (resending on ``Resend:``); returns lines/s."""
    port = serial.Serial(path, 115200, timeout=timeout_s)
    port.reset_input_buffer()
    start = time.monotonic()
    texts = ["M110 N0", *(c.text for c in job)]
    n = 0
    while n < len(texts):
        port.write(frame_marlin(n, texts[n]))
        while True:
            line = port.readline().decode("latin-1").strip()
            if not line:
                raise TimeoutError(f"no answer to line {n}")
            resend = re.match(r"Resend:\s*(\d+)", line)
            if resend:
                n = int(resend.group(1)) - 1
            if line.startswith("ok"):
                break
        n += 1
    elapsed = time.monotonic() - start
    port.close()
    return len(job) / elapsed


def fabkit_send(path: str, job: list[Command], machine: str = "marlin_generic") -> float:
    """Send ``job`` with fabkit's send-ahead; returns lines/s."""
    port = open_port(path, 115200)
    report = stream_job(port, job, load_machine(machine), options=LinkOptions(probe_min_s=0.02))
    port.close()
    return report.lines_per_s


@pytest.mark.slow
def test_fabkit_sends_ahead_where_the_firmware_buffers_lines():
    job = marlin_job(400)
    with LatencyResponder(0.002) as machine:
        fabkit_send(machine.path, job)
    assert machine.job_lines() == [c.text for c in job]
    assert machine.max_unanswered >= 2  # two lines in flight: twice a ping-pong's rate


@pytest.mark.slow
def test_a_64_byte_ring_that_drops_bytes_is_found_and_never_costs_a_line():
    # marlin_generic says 128 bytes; this ring holds 64 and loses what does not fit:
    # the lines it loses come back as line errors, the window shrinks to what fits
    job = marlin_job(600)
    with PacedResponder(64, 0.002, ack="taken") as machine:
        fabkit_send(machine.path, job)
    assert machine.job_lines() == [c.text for c in job]
    assert 0 < machine.lost_bytes < 100  # it had to find out, and did so at once


@pytest.mark.slow
def test_busy_and_wait_lines_keep_the_link_going():
    job = marlin_job(300)
    with BusyResponder() as machine:
        fabkit_send(machine.path, job)
    assert machine.job_lines() == [c.text for c in job]


def test_the_naive_sender_is_a_fair_yardstick():
    job = marlin_job(200)
    with PacedResponder(64, 0.001, ack="taken") as machine:
        assert naive_send(machine.path, job) > 0
    assert machine.executed[1:] == [c.text for c in job] and machine.lost_bytes == 0
