"""Parts shared by the emulated firmwares: wires, trace, counters, motion and heaters.

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

INF = math.inf
_EPS = 1e-6  # of a byte time: keeps float arrival times from missing a byte


@dataclass(frozen=True)
class TraceEntry:
    """One command the emulated machine executed, in order.

    ``n`` is the Marlin line number (None for unnumbered lines and GRBL), ``command``
    the text as parsed (line number and checksum removed); the position (mm) is the
    logical tool position after the command, as the firmware would report it;
    ``t_s`` is the emulator time at which it was executed; ``checked``: False for a
    numbered line the firmware ran without a checksum (Repetier, Smoothieware and
    RepRapFirmware accept one, so a corrupted ``*`` or ``;`` lets a damaged line run).
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
    """Live counts of what happened inside the emulator (mutated as it runs)."""

    executed: int = 0
    corrupted_lines: int = 0
    dropped_oks: int = 0
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

    def push(self, data: bytes, now: float) -> None:
        """The host writes ``data`` at ``now``; it reaches the machine byte by byte."""
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

    def line(self, text: str, t: float) -> None:
        """Send one line at ``t``, subject to the injected faults."""
        faults, rng = self.faults, self.rng
        if faults.noise and rng.random() < faults.noise:
            self.counters.spurious_lines += 1
            self.raw(rng.choice(self.noise_lines).encode("latin-1") + self.eol, t)
        if faults.drop_ok and text.startswith("ok") and rng.random() < faults.drop_ok:
            self.counters.dropped_oks += 1
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


_AXES = "XYZE"
FIRST_MOVE_DELAY_S = 0.1  # Marlin's BLOCK_DELAY_FOR_1ST_MOVE: a first move waits for company


@dataclass
class _Block:
    """One planned move (mm, mm/s, mm/s^2, s): from ``start`` to ``end`` (X, Y, Z, E)
    along ``unit``; ``tag`` names the command that made it."""

    start: list[float]
    end: list[float]
    length: float
    unit: tuple[float, ...]
    nominal: float
    accel: float
    max_entry: float
    tag: int | None
    entry: float = 0.0
    exit: float = 0.0
    begin_t: float = 0.0
    end_t: float = 0.0


class Motion:
    """Tool position, modal state and the planner's timeline (mm, mm/s, s).

    Moves are queued in a planner of ``depth`` blocks and run one after the other.
    Without accelerations (``accel_mm_s2`` all 0) each takes length / feed. With them the
    planner works as Marlin's and GRBL's do, seeing only its own blocks: each block
    accelerates at the lowest of its axes' accelerations (scaled by the axis's share of
    the move), the speed at a junction is limited by junction deviation
    (``junction_deviation_mm``), and every time a block is added the blocks not yet
    started are re-planned backwards from a stop after the newest one and forwards
    from the running block's fixed exit speed; a planner that runs dry makes the
    machine stop; a move into an empty planner waits ``FIRST_MOVE_DELAY_S`` for others
    to plan with it. Durations are multiplied by ``time_scale``. ``pos`` is the logical
    position after the last planned move (what M114 reports); :meth:`position_at` is
    where the tool really is. A feed hold (GRBL ``!``) freezes the timeline until
    resumed; :meth:`clear` stops at once (M410, a reset). ``finished`` lists the tags
    of the blocks that ran to their end, in order.
    """

    def __init__(
        self,
        depth: int,
        time_scale: float,
        rapid_mm_s: float,
        accel_mm_s2: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0),
        junction_deviation_mm: float = 0.013,
    ) -> None:
        self.depth = depth
        self.time_scale = time_scale
        self.rapid_mm_s = rapid_mm_s
        self.accel_mm_s2 = accel_mm_s2
        self.junction_deviation_mm = junction_deviation_mm
        self.pos = [0.0, 0.0, 0.0, 0.0]
        self.absolute = True
        self.absolute_e = True
        self.unit_mm = 1.0
        self.feed_mm_s: float | None = None
        self.blocks: deque[_Block] = deque()
        self.held_since: float | None = None
        self.finished: list[int | None] = []
        self.stopped_at: list[float] = list(self.pos)  # where the last block ended

    def _prune(self, t: float) -> None:
        if self.held_since is None:
            while self.blocks and self.blocks[0].end_t <= t:
                block = self.blocks.popleft()
                self.finished.append(block.tag)
                self.stopped_at = list(block.end)

    def planned(self, t: float) -> int:
        """Blocks in the planner (not yet finished) at ``t``."""
        self._prune(t)
        return len(self.blocks)

    def full(self, t: float) -> bool:
        return self.planned(t) >= self.depth

    def busy(self, t: float) -> bool:
        return self.planned(t) > 0

    def free_time(self) -> float:
        """When the oldest planned block finishes (inf while held or empty)."""
        return self.blocks[0].end_t if self.blocks and self.held_since is None else INF

    def idle_time(self, t: float) -> float:
        """When the planner will be empty (inf while held with blocks left)."""
        self._prune(t)
        if not self.blocks:
            return t
        return INF if self.held_since is not None else self.blocks[-1].end_t

    def hold(self, t: float) -> None:
        if self.held_since is None:
            self._prune(t)
            self.held_since = t

    def resume(self, t: float) -> None:
        if self.held_since is not None:
            shift = t - self.held_since
            for block in self.blocks:
                block.begin_t += shift
                block.end_t += shift
            self.held_since = None

    def clear(self, t: float) -> None:
        """Stop at once: the planned moves are dropped, the tool stays where it is."""
        self._prune(t)
        self.pos = self.position_at(t)
        self.stopped_at = list(self.pos)
        self.blocks.clear()
        self.held_since = None

    def target(self, values: dict[str, float]) -> list[float]:
        """The position after a move with ``values`` (axis letter -> number)."""
        out = list(self.pos)
        for i, axis in enumerate(_AXES):
            if axis in values:
                value = values[axis] * (self.unit_mm if axis != "E" else 1.0)
                absolute = self.absolute_e if axis == "E" else self.absolute
                out[i] = value if absolute else out[i] + value
        return out

    def move(
        self,
        values: dict[str, float],
        t: float,
        *,
        rapid: bool,
        arc: int = 0,
        tag: int | None = None,
    ) -> None:
        """Plan a move (call only when not ``full``); updates the position."""
        if "F" in values and values["F"] > 0:
            self.feed_mm_s = values["F"] * self.unit_mm / 60.0
        start, end = list(self.pos), self.target(values)
        length = _arc_length(start, end, values, arc) if arc else _distance(start, end)
        feed = self.rapid_mm_s if rapid or not self.feed_mm_s else self.feed_mm_s
        self.pos = end
        if length <= 0:
            return
        self._prune(t)
        deltas = [b - a for a, b in zip(start, end, strict=True)]
        xyz = math.sqrt(sum(d * d for d in deltas[:3]))
        unit = tuple(d / (xyz or length) for d in deltas)
        accel = min(
            (a / abs(u) for a, u in zip(self.accel_mm_s2, unit, strict=True) if a > 0 and u),
            default=INF,
        )
        block = _Block(start, end, length, unit, feed, accel, 0.0, tag)
        if self.time_scale <= 0 or math.isinf(accel):
            begin = max(t, self.blocks[-1].end_t) if self.blocks else t
            block.begin_t, block.end_t = begin, begin + length / feed * self.time_scale
            block.entry = block.exit = feed
            self.blocks.append(block)
            return
        if self.blocks:
            block.max_entry = self._junction(self.blocks[-1], block)
        self.blocks.append(block)
        self._replan(t)

    def _junction(self, prev: _Block, block: _Block) -> float:
        """The highest speed at the junction (mm/s): junction deviation, as in Marlin and
        GRBL (``v^2 = a d sin(theta/2) / (1 - sin(theta/2))``)."""
        limit = min(prev.nominal, block.nominal)
        cos_theta = -sum(a * b for a, b in zip(prev.unit[:3], block.unit[:3], strict=True))
        if cos_theta > 0.999999:
            return 0.0
        if cos_theta < -0.999999:
            return limit
        sin_half = math.sqrt(0.5 * (1.0 - cos_theta))
        speed2 = block.accel * self.junction_deviation_mm * sin_half / (1.0 - sin_half)
        return min(limit, math.sqrt(speed2))

    def _replan(self, t: float) -> None:
        """Re-plan the blocks not yet started (see the class docstring)."""
        blocks = self.blocks
        newest = len(blocks) - 1
        first = next((i for i in range(newest) if blocks[i].begin_t > t), newest)
        running = blocks[first - 1] if first > 0 else None
        exit_speed = 0.0
        for i in range(len(blocks) - 1, first - 1, -1):
            block = blocks[i]
            block.exit = exit_speed
            reach = math.sqrt(exit_speed * exit_speed + 2 * block.accel * block.length)
            block.entry = min(block.max_entry, reach)
            exit_speed = block.entry
        if running is not None:
            begin = running.end_t
        elif first < newest:  # waiting for its delay: it keeps its start
            begin = blocks[first].begin_t
        else:
            begin = t + FIRST_MOVE_DELAY_S * self.time_scale
        entry = running.exit if running is not None else 0.0
        for i in range(first, len(blocks)):
            block = blocks[i]
            block.entry = min(block.entry, entry) if i == first else block.entry
            reach = math.sqrt(block.entry * block.entry + 2 * block.accel * block.length)
            if i + 1 < len(blocks):
                blocks[i + 1].entry = min(blocks[i + 1].entry, reach)
                block.exit = blocks[i + 1].entry
            block.begin_t = begin
            block.end_t = begin + self.time_scale * _trapezoid_time(block)
            begin = block.end_t
            entry = block.exit

    def position_at(self, t: float) -> list[float]:
        """Where the tool is at ``t`` (mm; X, Y, Z, E)."""
        if self.held_since is not None:
            t = min(t, self.held_since)
        for block in self.blocks:
            if block.begin_t <= t < block.end_t:
                done = _distance_at(block, (t - block.begin_t) / (self.time_scale or 1.0))
                fraction = min(1.0, done / block.length)
                return [a + (b - a) * fraction for a, b in zip(block.start, block.end, strict=True)]
            if t < block.begin_t:
                return list(block.start)
        return list(self.blocks[-1].end) if self.blocks else list(self.stopped_at)

    def set_position(self, values: dict[str, float]) -> None:
        """G92: the current position takes the given coordinates."""
        for i, axis in enumerate(_AXES):
            if axis in values:
                self.pos[i] = values[axis]
        self.stopped_at = list(self.pos)

    def home(self, values: dict[str, float]) -> None:
        """G28 / $H: the named axes (all of X, Y, Z if none) go to 0."""
        axes = [a for a in "XYZ" if a in values] or list("XYZ")
        for axis in axes:
            self.pos[_AXES.index(axis)] = 0.0
        self.stopped_at = list(self.pos)


def _trapezoid_time(block: _Block) -> float:
    """Seconds for the block from its entry to its exit speed (unscaled)."""
    a, v0, v1, vn, length = block.accel, block.entry, block.exit, block.nominal, block.length
    up = (vn * vn - v0 * v0) / (2 * a)
    down = (vn * vn - v1 * v1) / (2 * a)
    if up + down <= length:
        return (vn - v0) / a + (vn - v1) / a + (length - up - down) / vn
    peak = math.sqrt(max(0.0, a * length + (v0 * v0 + v1 * v1) / 2))
    return max(0.0, peak - v0) / a + max(0.0, peak - v1) / a


def _distance_at(block: _Block, tau: float) -> float:
    """The distance covered ``tau`` seconds (unscaled) into the block."""
    a, v0, v1, vn, length = block.accel, block.entry, block.exit, block.nominal, block.length
    if math.isinf(a):
        return vn * tau
    up = (vn * vn - v0 * v0) / (2 * a)
    down = (vn * vn - v1 * v1) / (2 * a)
    if up + down > length:  # triangle: no cruise
        vn = math.sqrt(max(0.0, a * length + (v0 * v0 + v1 * v1) / 2))
        up = (vn * vn - v0 * v0) / (2 * a)
        down = length - up
    t_up = (vn - v0) / a
    t_cruise = (length - up - down) / vn if vn > 0 else 0.0
    if tau <= t_up:
        return v0 * tau + a * tau * tau / 2
    if tau <= t_up + t_cruise:
        return up + vn * (tau - t_up)
    tau -= t_up + t_cruise
    return min(length, up + vn * t_cruise + vn * tau - a * tau * tau / 2)


def _distance(a: list[float], b: list[float]) -> float:
    d = math.dist(a[:3], b[:3])
    return d if d > 0 else abs(a[3] - b[3])


def _arc_length(a: list[float], b: list[float], values: dict[str, float], arc: int) -> float:
    """Length of a G2 (arc=2, clockwise) / G3 arc in XY given by I, J (else the chord)."""
    if "I" not in values and "J" not in values:
        return _distance(a, b)
    cx, cy = a[0] + values.get("I", 0.0), a[1] + values.get("J", 0.0)
    r = math.hypot(a[0] - cx, a[1] - cy)
    start = math.atan2(a[1] - cy, a[0] - cx)
    stop = math.atan2(b[1] - cy, b[0] - cx)
    sweep = (stop - start) % (2 * math.pi)
    if arc == 2:
        sweep = (2 * math.pi - sweep) % (2 * math.pi)
    sweep = sweep or 2 * math.pi
    return math.hypot(r * sweep, b[2] - a[2])


@dataclass(frozen=True)
class EmulatorConfig:
    """Everything that defines one emulated machine (see ``docs/link.md`` for the URL).

    ``baud`` sets the byte timing (10 bits per byte; 0 = instantaneous). ``time_scale``
    multiplies move, dwell and heating times (0 = instantaneous). ``dialect`` names the
    Marlin-protocol firmware (:data:`fabkit.link.emulator.dialects.DIALECTS`); ``resend_ok``
    and ``drain``, when not None, override whether it sends ``ok`` after a resend
    request and empties its receive buffer on a line error. ``accel_mm_s2`` (X, Y),
    ``z_accel_mm_s2``, ``e_accel_mm_s2`` and ``junction_deviation_mm`` give the planner
    its accelerations (0: none, every move at its feed from end to end; a Z or E value
    of 0 takes the X/Y one). ``grbl_bf``: GRBL's status reports carry ``Bf:`` (``$10``
    bit 1); ``grbl_opt``: its ``$I`` build info names the planner and buffer sizes.
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
