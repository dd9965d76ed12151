"""The emulated firmware's motion (:mod:`fabkit.link.emulator.firmware`): the tool
position, the modal state and the planner's timeline (:class:`Motion`), in mm, mm/s and
seconds on the caller's clock.

Moves are queued as blocks in a planner of fixed depth and planned as Marlin's and GRBL's
planners do (trapezoids, junction deviation, a first move's delay); a block's time and
the distance it has covered at a time are :func:`_trapezoid_time` and
:func:`_distance_at`, an arc's length :func:`_arc_length`.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

_AXES = "XYZE"
_XYZ = tuple(enumerate("XYZ"))
FIRST_MOVE_DELAY_S = 0.1  # Marlin's BLOCK_DELAY_FOR_1ST_MOVE: a first move waits for company


@dataclass(slots=True)
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
        self.at_feed = time_scale <= 0 or not any(a > 0 for a in accel_mm_s2)
        """Every block runs at its feed from end to end: no time, or no accelerations."""

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
        self._prune(t)
        return len(self.blocks) >= self.depth

    def busy(self, t: float) -> bool:
        return self.planned(t) > 0

    def free_time(self) -> float:
        """When the oldest planned block finishes (inf while held or empty)."""
        return self.blocks[0].end_t if self.blocks and self.held_since is None else math.inf

    def idle_time(self, t: float) -> float:
        """When the planner will be empty (inf while held with blocks left)."""
        self._prune(t)
        if not self.blocks:
            return t
        return math.inf if self.held_since is not None else self.blocks[-1].end_t

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
        for i, axis in _XYZ:
            if axis in values:
                value = values[axis] * self.unit_mm
                out[i] = value if self.absolute else out[i] + value
        if "E" in values:
            out[3] = values["E"] if self.absolute_e else out[3] + values["E"]
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
        start, end = self.pos, self.target(values)  # a pos list is never changed once replaced
        length = _arc_length(start, end, values, arc) if arc else _distance(start, end)
        self.pos = end
        if length <= 0:
            return
        feed = self.rapid_mm_s if rapid or not self.feed_mm_s else self.feed_mm_s
        if self.blocks:
            self._prune(t)
        if self.at_feed:
            self._move_at_feed(start, end, length, (), feed, tag, t)
            return
        deltas = [b - a for a, b in zip(start, end, strict=True)]
        xyz = math.sqrt(sum(d * d for d in deltas[:3]))
        unit = tuple(d / (xyz or length) for d in deltas)
        accel = min(
            (a / abs(u) for a, u in zip(self.accel_mm_s2, unit, strict=True) if a > 0 and u),
            default=math.inf,
        )
        if math.isinf(accel):  # none of its axes accelerates
            self._move_at_feed(start, end, length, unit, feed, tag, t)
            return
        block = _Block(start, end, length, unit, feed, accel, 0.0, tag)
        if self.blocks:
            block.max_entry = self._junction(self.blocks[-1], block)
        self.blocks.append(block)
        self._replan(t)

    def _move_at_feed(
        self,
        start: list[float],
        end: list[float],
        length: float,
        unit: tuple[float, ...],
        feed: float,
        tag: int | None,
        t: float,
    ) -> None:
        """Plan a move at its feed (mm/s) from end to end (``accel`` inf; ``unit`` may be
        empty where no junction is ever planned). One that ends by ``t`` behind an empty
        planner (time scale 0) finishes now: any later look at the planner would prune it
        first, as the firmware's clock never goes back."""
        begin = max(t, self.blocks[-1].end_t) if self.blocks else t
        end_t = begin + length / feed * self.time_scale
        if end_t <= t and not self.blocks and self.held_since is None:
            self.finished.append(tag)
            self.stopped_at = list(end)
            return
        block = _Block(start, end, length, unit, feed, math.inf, 0.0, tag, feed, feed, begin, end_t)
        self.blocks.append(block)

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
    """The XYZ distance of ``a`` and ``b`` (``math.dist`` of their first three), else E's."""
    d = math.hypot(b[0] - a[0], b[1] - a[1], b[2] - a[2])
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
