"""A faithful emulated machine (Marlin or GRBL) behind a serial line.

:class:`Emulator` is a discrete-event model driven by the caller's clock: the host
writes bytes at time ``now`` (:meth:`Emulator.host_write`) and collects the machine's
answers with :meth:`Emulator.poll`. The same object backs the ``sim://`` pyserial URL
(:mod:`fabkit.link.emulator.protocol_sim`) and :class:`PtyEmulator`, which serves it on the
master side of a pseudo-terminal so that a sender opens the slave like a real device.

URL: ``sim://marlin`` or ``sim://grbl`` with options ``?key=value&...`` (all optional):

=================  ===================================================================
baud               wire rate for byte timing, 10 bits per byte (default: the port's
                   baud rate); 0 = bytes arrive instantly
time_scale         factor on move, dwell and heating times (default 1; 0 = instant)
latency_ms         extra one-way delay, e.g. a USB adapter (default 0)
rx                 receive buffer bytes (default 128; one stays empty: 127 usable)
planner            planner blocks (default 16); slots: Marlin command queue (4)
dialect            Marlin-protocol firmware: marlin-2.1 (default), marlin-2.0,
                   marlin-1.1, prusa, repetier, smoothieware, reprapfirmware
                   (:mod:`fabkit.link.emulator.dialects`)
resend_ok, drain   override the dialect: ok after a resend request, drain on error (0/1)
ack_on_queue,      override the dialect: ok when a line is queued, before its output
ack_numbered       (M105: ok, then T:... when it runs), ok <n> naming the line (0/1);
                   dialect=repetier&ack_numbered=0 is Repetier built without
                   ACK_WITH_LINENUMBER, ack_on_queue=1 answers as OctoPrint's
                   VirtualPrinter with okBeforeCommandOutput
keepalive_s        Marlin busy: interval (default 2); heat_tau_s heater constant (20)
corrupt            probability that a host line gets one bit flipped on the way
drop_ok            probability that an ``ok`` is lost
garble             probability that a machine line gets one bit flipped
noise              probability of a spurious line before a machine line
reset_after        the machine resets after executing this many commands
disconnect_after   the line goes dead after this many commands (their ok delivered)
accel, z_accel,    planner accelerations, mm/s^2: X/Y, Z, E (default 0: none, every
e_accel, jd        move at its feed; Z and E default to X/Y's) and junction deviation,
                   mm (0.013)
bf, opt            GRBL: Bf: in status reports, buffer sizes in $I (0/1, default 1)
seed               random seed of the faults (default 0)
=================  ===================================================================
"""

from __future__ import annotations

import array
import fcntl
import math
import os
import random
import select
import termios
import threading
import time
import tty
from dataclasses import replace
from urllib.parse import parse_qs, urlsplit

from fabkit.link.emulator.dialects import DIALECTS
from fabkit.link.emulator.firmware import (
    INF,
    Counters,
    EmulatorConfig,
    Faults,
    Input,
    Output,
    TraceEntry,
    flip_bit,
)
from fabkit.link.emulator.grbl import REALTIME, GrblFirmware
from fabkit.link.emulator.marlin import MarlinFirmware

PERSONALITIES = ("marlin", "grbl")


def _fraction(text: str) -> float:
    value = float(text)
    if not 0.0 <= value <= 1.0:
        raise ValueError("must be between 0 and 1")
    return value


def _non_negative(text: str) -> float:
    value = float(text)
    if not 0 <= value < math.inf:
        raise ValueError("must be a finite number >= 0")
    return value


def _count(text: str) -> int:
    value = int(text)
    if value < 1:
        raise ValueError("must be >= 1")
    return value


def _dialect(text: str) -> str:
    if text not in DIALECTS:
        raise ValueError(f"must be one of {', '.join(DIALECTS)}")
    return text


def _flag(text: str) -> bool:
    if text not in ("0", "1"):
        raise ValueError("must be 0 or 1")
    return text == "1"


_OPTIONS = {
    "baud": ("baud", lambda text: int(_non_negative(text))),
    "time_scale": ("time_scale", _non_negative),
    "latency_ms": ("latency_s", lambda text: _non_negative(text) / 1000.0),
    "rx": ("rx_buffer_bytes", _count),
    "planner": ("planner_depth", _count),
    "slots": ("command_slots", _count),
    "dialect": ("dialect", _dialect),
    "resend_ok": ("resend_ok", _flag),
    "drain": ("drain", _flag),
    "ack_on_queue": ("ack_on_queue", _flag),
    "ack_numbered": ("ack_numbered", _flag),
    "keepalive_s": ("keepalive_s", _non_negative),
    "heat_tau_s": ("heater_tau_s", _non_negative),
    "accel": ("accel_mm_s2", _non_negative),
    "z_accel": ("z_accel_mm_s2", _non_negative),
    "e_accel": ("e_accel_mm_s2", _non_negative),
    "jd": ("junction_deviation_mm", _non_negative),
    "bf": ("grbl_bf", _flag),
    "opt": ("grbl_opt", _flag),
    "seed": ("seed", int),
}
_FAULT_OPTIONS = {
    "corrupt": _fraction,
    "drop_ok": _fraction,
    "garble": _fraction,
    "noise": _fraction,
    "reset_after": _count,
    "disconnect_after": _count,
}


def config_from_url(url: str, baud: int) -> EmulatorConfig:
    """The emulator a ``sim://`` URL describes; ``baud`` is the port's rate (ValueError)."""
    parts = urlsplit(url)
    personality = parts.netloc.lower()
    if parts.scheme.lower() != "sim" or personality not in PERSONALITIES:
        raise ValueError(f"'{url}' is not sim://marlin or sim://grbl")
    settings: dict[str, object] = {"personality": personality, "baud": baud}
    faults: dict[str, object] = {}
    for key, values in parse_qs(parts.query, keep_blank_values=True).items():
        if key not in _OPTIONS and key not in _FAULT_OPTIONS:
            known = ", ".join([*_OPTIONS, *_FAULT_OPTIONS])
            raise ValueError(f"unknown sim option '{key}' (known: {known})")
        try:
            if key in _OPTIONS:
                field, convert = _OPTIONS[key]
                settings[field] = convert(values[-1])
            else:
                faults[key] = _FAULT_OPTIONS[key](values[-1])
        except ValueError as exc:
            raise ValueError(f"sim option {key}={values[-1]!r}: {exc}") from None
    return replace(EmulatorConfig(), **settings, faults=Faults(**faults))


class Emulator:
    """One emulated machine; the caller supplies the time (s, any monotonic clock)."""

    def __init__(self, config: EmulatorConfig, now: float = 0.0) -> None:
        if config.personality not in PERSONALITIES:
            raise ValueError(f"unknown emulator personality {config.personality!r}")
        self.config = config
        byte_s = 10.0 / config.baud if config.baud else 0.0
        grbl = config.personality == "grbl"
        firmware_class = GrblFirmware if grbl else MarlinFirmware
        self.rng = random.Random(config.seed)
        self.counters = Counters()
        self.trace: list[TraceEntry] = []
        self.input = Input(
            byte_s,
            config.latency_s,
            config.rx_buffer_bytes - 1,
            self.counters,
            REALTIME if grbl else b"",
        )
        self.output = Output(
            byte_s,
            config.latency_s,
            GrblFirmware.eol if grbl else MarlinFirmware.eol_for(config),
            config.faults,
            self.rng,
            self.counters,
            firmware_class.noise_lines,
        )
        self.firmware = firmware_class(
            config, self.input, self.output, self.trace, self.counters, self.rng, self._dead
        )
        self.direct = not grbl and self.input.instant and self.firmware.direct
        """Move lines may skip the event loop (:meth:`_write_moves`)."""
        self._now = now
        self._dead_at: float | None = None
        self.disconnected = False
        self.firmware.boot(now)

    def _dead(self, t: float) -> None:
        """The line goes dead once the output queued so far has been delivered."""
        self._dead_at = self.output.items[-1][0] if self.output.items else t

    def host_write(self, data: bytes, now: float) -> None:
        """The host writes ``data`` at ``now`` (lost if the line is dead)."""
        if self.direct and self._write_moves(data, now):
            return
        self.advance(now)
        if self._dead_at is None:
            self.input.push(self._corrupt(data), now)
            self.advance(now)

    def _write_moves(self, data: bytes, now: float) -> bool:
        """Whole move lines written to an idle machine on an instant wire, with nothing due
        by ``now`` (:attr:`direct`): the firmware runs them at once
        (:meth:`MarlinFirmware.take_moves`), which is all that :meth:`advance` would do
        (catch up with ``now``, take the lines as they arrive, run them, find nothing
        more). False, with nothing done, for anything else."""
        inp = self.input
        if inp.pending or inp.chunks or now < inp.free_at or self._dead_at is not None:
            return False
        t = self._now if self._now > now else now
        if not self.firmware.take_moves(data, t):
            return False
        self._now = t
        inp.free_at = now
        return True

    def poll(self, now: float) -> bytes:
        """Run the machine up to ``now``; the bytes that reached the host by then."""
        self.advance(now)
        data = self.output.take(now)
        if self._dead_at is not None and now >= self._dead_at and not self.output.items:
            self.disconnected = True
        return data

    def next_time(self) -> float:
        """When something will next happen (inf: nothing until the host writes)."""
        fw, inp = self.firmware, self.input
        t = min(self.output.next_time(), inp.next_realtime_time())
        if self._dead_at is not None:
            return min(t, self._dead_at)
        t = min(t, fw.next_time())
        if fw.reading:
            t = min(t, inp.next_newline_time())
        return max(t, self._now)

    def advance(self, now: float) -> None:
        """Process every event up to ``now`` in time order."""
        fw, inp = self.firmware, self.input
        reading = fw.reading
        while self._dead_at is None:
            t_rt = inp.rt_events[0][0] if inp.rt_events else INF
            t_fw = fw.next_time()
            t_nl = inp.next_newline_time() if reading else INF
            t_line = t_fw if t_fw <= t_nl else t_nl
            t = t_rt if t_rt <= t_line else t_line
            if t > now or t == INF:  # nothing due, or nothing ever (``now`` may be inf)
                break
            if t < self._now:
                t = self._now
            self._now = t
            if not reading:
                inp.fill(t)
            if t_rt <= t_line:
                fw.realtime(inp.pop_realtime(), t)
            else:
                fw.run(t)
            reading = fw.reading
        if not reading:
            inp.fill(now)
        if self._now < now < INF:  # run to the end (inf): the clock stays at the last event
            self._now = now

    def _corrupt(self, data: bytes) -> bytes:
        """Flip one bit in each complete line with probability ``faults.corrupt``."""
        p = self.config.faults.corrupt
        if not p or b"\n" not in data:
            return data
        lines = data.split(b"\n")
        for i, line in enumerate(lines[:-1]):
            if line and self.rng.random() < p:
                self.counters.corrupted_lines += 1
                lines[i] = flip_bit(line, self.rng)
        return b"\n".join(lines)

    def stats(self) -> Counters:
        """A copy of the counters."""
        return replace(self.counters, dropped_ok_lines=list(self.counters.dropped_ok_lines))


class PtyEmulator:
    """An :class:`Emulator` serving the master side of a pseudo-terminal from a thread.

    Use as a context manager; open :attr:`path` (the slave device) with pyserial like
    any serial port. The emulator uses the real clock (``time.monotonic``).
    """

    def __init__(self, config: EmulatorConfig) -> None:
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        self.path = os.ttyname(self._slave)
        self.emulator = Emulator(config, now=time.monotonic())
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="pty-emulator", daemon=True)

    def __enter__(self) -> PtyEmulator:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        for fd in (self._master, self._slave):
            if fd >= 0:
                os.close(fd)

    def _serve(self) -> None:
        emulator = self.emulator
        while not self._stop.is_set():
            now = time.monotonic()
            out = emulator.poll(now)
            if out:
                os.write(self._master, out)
            if emulator.disconnected:
                self._unread_drained(deadline=now + 1.0)
                os.close(self._master)
                self._master = -1
                return
            wait = min(max(emulator.next_time() - now, 0.0), 0.02)
            ready, _, _ = select.select([self._master], [], [], wait)
            if ready:
                emulator.host_write(os.read(self._master, 4096), time.monotonic())

    def _unread_drained(self, deadline: float) -> None:
        """Wait until the sender has read everything sent (closing would discard it)."""
        waiting = array.array("i", [0])
        time.sleep(0.02)  # let the pty layer move the last write to the slave's queue
        while time.monotonic() < deadline:
            fcntl.ioctl(self._slave, termios.FIONREAD, waiting)
            if waiting[0] == 0:
                return
            time.sleep(0.005)
