"""Parts shared by the emulated firmwares: wires, trace, counters, heaters, the machine's
config and the firmware base; the motion planner is :mod:`fabkit.link.emulator.motion`.

Everything runs on one clock, in seconds, given by the caller (``t``); nothing here
sleeps or reads the real time. Bytes travel at ``byte_s`` seconds per byte (10 bits
per byte at the emulated baud rate; 0 = instantaneous) plus a fixed ``latency_s``.
"""

from __future__ import annotations

import math
import random
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from fabkit.link.emulator.motion import Motion

INF = math.inf
_EPS = 1e-6  # of a byte time: keeps float arrival times from missing a byte


@dataclass(slots=True)
class TraceEntry:
    """One command the emulated machine executed, in order.

    ``n`` is the Marlin line number (None for unnumbered lines and GRBL), ``command``
    the text as parsed (line number and checksum removed); the position (mm) is the
    logical tool position after the command, as the firmware would report it;
    ``t_s`` is the emulator time at which it was executed; ``checked``: False for a
    numbered line the firmware ran without a checksum (Repetier, Smoothieware and
    RepRapFirmware accept one, so a corrupted ``*`` or ``;`` lets a damaged line run).
    Read-only by use, not frozen: one is made for every command run, and a frozen
    dataclass's ``__init__`` takes three times as long.
    """

    n: int | None
    command: str
    x_mm: float
    y_mm: float
    z_mm: float
    e_mm: float
    t_s: float
    checked: bool = True


@dataclass
class Counters:
    """Live counts of what happened inside the emulator (mutated as it runs).
    ``dropped_ok_lines``: the numbers of the lines whose own ``ok`` was dropped, in order
    (``dropped_oks`` also counts those that pair with a refusal or answer no line)."""

    executed: int = 0
    corrupted_lines: int = 0
    dropped_oks: int = 0
    dropped_ok_lines: list[int] = field(default_factory=list)
    garbled_lines: int = 0
    spurious_lines: int = 0
    rejected_lines: int = 0
    drained_bytes: int = 0
    overflow_bytes: int = 0
    unknown_commands: int = 0
    unchecked_lines: int = 0  # numbered lines run without a checksum (a corrupted '*')
    max_rx_bytes: int = 0
    resets: int = 0


@dataclass(frozen=True)
class Faults:
    """Fault injection settings (probabilities per line; counts of executed commands)."""

    corrupt: float = 0.0
    drop_ok: float = 0.0
    garble: float = 0.0
    noise: float = 0.0
    reset_after: int | None = None
    disconnect_after: int | None = None


@dataclass(eq=False)
class Input:
    """Host-to-machine bytes: the wire (with timing) and the firmware's receive ring.

    While the firmware reads, complete lines are taken as their newline arrives; while
    it is busy, arriving bytes fill the ring up to ``capacity`` and the rest are lost
    (counted in ``overflow_bytes``). ``realtime`` bytes (GRBL's ``? ! ~`` and Ctrl-X)
    never enter the ring: they become events at their arrival time.
    """

    byte_s: float
    latency_s: float
    capacity: int
    counters: Counters
    realtime: bytes = b""
    chunks: deque[list] = field(default_factory=deque, init=False)
    """Bytes on the wire: [t of byte 0, data, consumed offset] per write."""
    free_at: float = field(default=-INF, init=False)
    pending: bytearray = field(default_factory=bytearray, init=False)
    rt_events: deque[tuple[float, int]] = field(default_factory=deque, init=False)
    instant: bool = field(default=False, init=False)
    """Bytes arrive as they are written (no byte time, no latency, no real-time bytes to
    pick off): a write behind an empty wire goes straight to ``pending``. Nothing reads the
    ring before the emulator has caught up with the write's time, and by then every byte
    of it has arrived: taking them on arrival or when looked at is the same."""

    def __post_init__(self) -> None:
        self.instant = self.byte_s == 0 and self.latency_s == 0 and not self.realtime

    def push(self, data: bytes, now: float) -> None:
        """The host writes ``data`` at ``now``; it reaches the machine byte by byte."""
        if self.instant and not self.chunks and now >= self.free_at:
            self.pending += data  # all in at ``now``: the next look takes it all at once
            self.free_at = now
            return
        start = max(now, self.free_at)
        self.free_at = start + len(data) * self.byte_s
        base = start + self.byte_s + self.latency_s
        if not self.realtime or len(data.translate(None, self.realtime)) == len(data):
            self.chunks.append([base, data, 0])
            return
        run_start = 0
        for i, byte in enumerate(data):
            if byte in self.realtime:
                if i > run_start:
                    self.chunks.append([base + run_start * self.byte_s, data[run_start:i], 0])
                self.rt_events.append((base + i * self.byte_s, byte))
                run_start = i + 1
        if run_start < len(data):
            self.chunks.append([base + run_start * self.byte_s, data[run_start:], 0])

    def _arrived(self, chunk: list, t: float) -> int:
        """How many not-yet-consumed bytes of ``chunk`` have arrived by ``t``."""
        t0, data, off = chunk
        if self.byte_s == 0:
            return len(data) - off if t >= t0 else 0
        k = math.floor((t - t0) / self.byte_s + _EPS) + 1
        return max(0, min(len(data), k) - off)

    def _take_arrived(self, t: float) -> bytes:
        if not self.chunks:
            return b""
        taken = bytearray()
        while self.chunks:
            chunk = self.chunks[0]
            n = self._arrived(chunk, t)
            if n == 0:
                break
            taken += chunk[1][chunk[2] : chunk[2] + n]
            chunk[2] += n
            if chunk[2] < len(chunk[1]):
                break
            self.chunks.popleft()
        return bytes(taken)

    def next_newline_time(self) -> float:
        """When the next complete line is available (-inf: already)."""
        if b"\n" in self.pending:
            return -INF
        for t0, data, off in self.chunks:
            i = data.find(b"\n", off)
            if i >= 0:
                return t0 + i * self.byte_s
        return INF

    def next_realtime_time(self) -> float:
        return self.rt_events[0][0] if self.rt_events else INF

    def pop_realtime(self) -> int:
        return self.rt_events.popleft()[1]

    def take_line(self, t: float) -> bytes | None:
        """The next complete line (without its newline) arrived by ``t``, or None."""
        i = self.pending.find(b"\n")
        if i < 0:
            if not self.chunks:
                return None
            self.pending += self._take_arrived(t)
            i = self.pending.find(b"\n")
            if i < 0:
                return None
        line = bytes(self.pending[:i])
        del self.pending[: i + 1]
        return line

    def fill(self, t: float) -> None:
        """The firmware is busy: bytes arrived by ``t`` wait in the ring or are lost."""
        if len(self.pending) > self.capacity:
            self.counters.overflow_bytes += len(self.pending) - self.capacity
            del self.pending[self.capacity :]
        arrived = self._take_arrived(t)
        room = self.capacity - len(self.pending)
        if len(arrived) > room:
            self.counters.overflow_bytes += len(arrived) - room
            arrived = arrived[:room]
        self.pending += arrived
        self.counters.max_rx_bytes = max(self.counters.max_rx_bytes, len(self.pending))

    def drain(self, t: float) -> None:
        """Throw away everything received by ``t`` (Marlin does so on a line error)."""
        dropped = len(self.pending) + len(self._take_arrived(t))
        self.counters.drained_bytes += dropped
        self.pending.clear()


@dataclass(eq=False)
class Output:
    """Machine-to-host lines, with byte timing and the faults that hit them."""

    byte_s: float
    latency_s: float
    eol: bytes
    faults: Faults
    rng: random.Random
    counters: Counters
    noise_lines: tuple[str, ...]
    items: deque[tuple[float, bytes]] = field(default_factory=deque, init=False)
    free_at: float = field(default=-INF, init=False)
    faultless: bool = field(default=True, init=False)
    """No fault hits a line (none configured): :meth:`line` draws no random number."""

    def __post_init__(self) -> None:
        self.faultless = not (self.faults.noise or self.faults.drop_ok or self.faults.garble)

    def line(self, text: str, t: float, answers: int | None = None) -> None:
        """Send one line at ``t``, subject to the injected faults; ``answers``: the number
        of the line this ``ok`` acknowledges, if it is one."""
        if self.faultless:
            self.raw(text.encode("latin-1") + self.eol, t)
            return
        faults, rng = self.faults, self.rng
        if faults.noise and rng.random() < faults.noise:
            self.counters.spurious_lines += 1
            self.raw(rng.choice(self.noise_lines).encode("latin-1") + self.eol, t)
        if faults.drop_ok and text.startswith("ok") and rng.random() < faults.drop_ok:
            self.counters.dropped_oks += 1
            if answers is not None:
                self.counters.dropped_ok_lines.append(answers)
            return
        data = text.encode("latin-1")
        if faults.garble and data and rng.random() < faults.garble:
            self.counters.garbled_lines += 1
            data = flip_bit(data, rng)
        self.raw(data + self.eol, t)

    def raw(self, data: bytes, t: float) -> None:
        """Send bytes at ``t`` without faults."""
        start = max(t, self.free_at)
        self.free_at = start + len(data) * self.byte_s
        self.items.append((self.free_at + self.latency_s, data))

    def next_time(self) -> float:
        return self.items[0][0] if self.items else INF

    def take(self, now: float) -> bytes:
        """The bytes that have reached the host by ``now``."""
        out = bytearray()
        while self.items and self.items[0][0] <= now:
            out += self.items.popleft()[1]
        return bytes(out)


def flip_bit(data: bytes, rng: random.Random) -> bytes:
    """``data`` with one random bit of one random byte flipped (a UART bit error)."""
    i = rng.randrange(len(data))
    return data[:i] + bytes([data[i] ^ (1 << rng.randrange(8))]) + data[i + 1 :]


class Heater:
    """A first-order heater: the temperature approaches the set point with time constant
    ``tau_s`` (scaled by the emulator's time scale; 0 = instantly), degrees C."""

    AMBIENT_C = 25.0

    def __init__(self, tau_s: float) -> None:
        self.tau_s = tau_s
        self.temp_c = self.AMBIENT_C
        self.target_c = 0.0
        self.t_ref = 0.0

    def _goal(self) -> float:
        return max(self.target_c, self.AMBIENT_C)

    def update(self, t: float) -> None:
        goal = self._goal()
        if self.tau_s <= 0:
            self.temp_c = goal
        elif t > self.t_ref:
            self.temp_c = goal + (self.temp_c - goal) * math.exp(-(t - self.t_ref) / self.tau_s)
        self.t_ref = max(t, self.t_ref)

    def set_target(self, target_c: float, t: float) -> None:
        self.update(t)
        self.target_c = target_c

    def reach_time(self, t: float, window_c: float = 1.0) -> float:
        """When the temperature will be within ``window_c`` of the set point."""
        self.update(t)
        gap = abs(self.temp_c - self._goal())
        if gap <= window_c or self.tau_s <= 0:
            return t
        return t + self.tau_s * math.log(gap / window_c)


@dataclass(frozen=True)
class EmulatorConfig:
    """Everything that defines one emulated machine (see ``docs/link.md`` for the URL).

    ``baud`` sets the byte timing (10 bits per byte; 0 = instantaneous). ``time_scale``
    multiplies move, dwell and heating times (0 = instantaneous). ``dialect`` names the
    Marlin-protocol firmware (:data:`fabkit.link.emulator.dialects.DIALECTS`); ``resend_ok``,
    ``drain``, ``ack_on_queue`` and ``ack_numbered``, when not None, override whether it
    sends ``ok`` after a resend request, empties its receive buffer on a line error,
    acknowledges a line when it queues it (before its output) and names it in the
    ``ok``. ``accel_mm_s2`` (X, Y), ``z_accel_mm_s2``, ``e_accel_mm_s2`` and
    ``junction_deviation_mm`` give the planner its accelerations (0: none, every move
    at its feed from end to end; a Z or E value of 0 takes the X/Y one). ``grbl_bf``:
    GRBL's status reports carry ``Bf:`` (``$10`` bit 1); ``grbl_opt``: its ``$I`` build
    info names the planner and buffer sizes.
    """

    personality: str = "marlin"
    baud: int = 115200
    time_scale: float = 1.0
    latency_s: float = 0.0
    rx_buffer_bytes: int = 128
    planner_depth: int = 16
    command_slots: int = 4
    dialect: str = "marlin-2.1"
    resend_ok: bool | None = None
    drain: bool | None = None
    ack_on_queue: bool | None = None
    ack_numbered: bool | None = None
    keepalive_s: float = 2.0
    heater_tau_s: float = 20.0
    rapid_mm_s: float = 50.0
    accel_mm_s2: float = 0.0
    z_accel_mm_s2: float = 0.0
    e_accel_mm_s2: float = 0.0
    junction_deviation_mm: float = 0.013
    grbl_bf: bool = True
    grbl_opt: bool = True
    seed: int = 0
    faults: Faults = Faults()

    def motion(self, depth: int | None = None) -> Motion:
        """A fresh :class:`Motion` for this machine (``depth`` blocks, default the planner's)."""
        xy = self.accel_mm_s2
        accel = (xy, xy, self.z_accel_mm_s2 or xy, self.e_accel_mm_s2 or xy)
        return Motion(
            depth or self.planner_depth,
            self.time_scale,
            self.rapid_mm_s,
            accel,
            self.junction_deviation_mm,
        )


@dataclass(eq=False)
class Firmware:
    """What every emulated firmware holds: its config, the wires in and out, the trace and
    counters it keeps, the random source of its faults, and the hook it calls when the
    line drops. A firmware (:mod:`~fabkit.link.emulator.marlin`,
    :mod:`~fabkit.link.emulator.grbl`) adds its protocol loop and interpreter, ``_start``
    (what it sets up once, called last on construction) and ``_reset_state`` (its state
    after a reset)."""

    config: EmulatorConfig
    inp: Input
    out: Output
    trace: list[TraceEntry]
    counters: Counters
    rng: random.Random
    on_disconnect: Callable[[float], None]
    halted: bool = field(default=False, init=False)

    def __post_init__(self) -> None:
        self._start()

    def _start(self) -> None:
        raise NotImplementedError
