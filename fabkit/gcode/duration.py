"""How long a job will take: the moves planned as the firmware's planner plans them.

:func:`estimate` walks the commands with their modal state (G90/G91, M82/M83, G92, G28
and GRBL's ``$H``, feed, GRBL's G93/G94 feed mode) and plans every move the way Marlin's
and GRBL's planners do (Marlin/src/module/planner.cpp ``_buffer_steps`` and
``recalculate``, grbl/planner.c ``plan_buffer_line`` and ``planner_recalculate``):

* a block's nominal speed is its feed (under GRBL's G93, inverse time, its length times
  F/60: the move takes 60/F s, grbl/planner.c ``programmed_rate *= millimeters``),
  lowered until no axis exceeds its ``[limits] <axis>_mm_s``; its acceleration is
  ``[limits] acceleration_mm_s2`` (X, Y), ``z_acceleration_mm_s2`` and
  ``e_acceleration_mm_s2``, lowered until no axis exceeds its own share (each axis's
  acceleration scaled by the move's length over its component);
* the speed at the junction of two moves is limited by junction deviation
  (``[limits] junction_deviation_mm``): ``v^2 = a * d * sin(theta/2) / (1 - sin(theta/2))``
  with theta the angle between the moves' directions (a straight continuation is
  limited only by the two nominal speeds, a reversal stops);
* a backward and a forward pass make every entry speed reachable from its neighbours
  at the block's acceleration, starting and ending at rest and stopping at every
  command that waits for motion to end (G4, M400, G28, M109, M190, M0/M1);
* each block then takes the time of its trapezoidal (or triangular) speed profile.

The whole file is one look-ahead here, while a firmware sees only its planner's blocks
(16): when the host keeps the planner full the two agree closely. Dwells (G4) add their
time; heat-ups and homing cannot be known and are listed instead.

Units: mm, mm/s, mm/s^2, s. G-code feeds (``F``) are mm/min; under G93 (GRBL only, as in
gnea/grbl ``gcode.c``) ``F`` is 1/min and belongs to its own command: none carries over to
the next, and after a switch back to G94 the feed is unset until an ``F``; ``M2``/``M30``
return to G94. An arc under G93 takes 60/F s over its length, as the G-code standard and
the pre-flight check have it (GRBL 1.1 itself runs the arc's segments at F times their
number, in mm/min: grbl/motion_control.c ``mc_arc``; the number depends on its arc
tolerance, $12).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from fabkit.gcode.columns import MoveRun, Rows, filled, job_spans, plain_codes
from fabkit.gcode.position import MOTION, Position
from fabkit.gcode.read import (
    MAX_LINE_CHARS,
    Block,
    Command,
    GcodeError,
    firmware_reader,
    job_texts,
)
from fabkit.machines import MachineProfile
from fabkit.progress import clock

STOPS = frozenset({"G4", "M400", "G28", "G29", "M109", "M190", "M0", "M1", "M600", "M226", "$H"})
"""Commands that wait until every planned move has ended (the planner empties)."""
UNKNOWN_TIME = frozenset({"G28", "G29", "M109", "M190", "M0", "M1", "M600", "M226", "$H"})
"""Commands whose duration depends on the machine (homing, heating, the user)."""
MIN_JUNCTION_MM_S = 0.05  # Marlin's MINIMUM_PLANNER_SPEED


@dataclass(frozen=True)
class Kinematics:
    """What limits motion on one machine: per-axis X, Y, Z, E values (mm/s, mm/s^2).

    ``rapid_mm_s``: the speed of a GRBL ``G0`` (the machine's maximum rate), None where
    ``G0`` moves at the feed (Marlin); ``junction_deviation_mm`` as above.
    """

    max_mm_s: tuple[float, float, float, float]
    accel_mm_s2: tuple[float, float, float, float]
    junction_deviation_mm: float
    rapid_mm_s: float | None

    @classmethod
    def of(cls, machine: MachineProfile) -> Kinematics:
        """The machine's limits as the planner uses them."""
        limits = machine.limits
        xy = limits.acceleration_mm_s2
        return cls(
            max_mm_s=(limits.x_mm_s, limits.y_mm_s, limits.z_mm_s, limits.e_mm_s),
            accel_mm_s2=(xy, xy, limits.z_acceleration_mm_s2, limits.e_acceleration_mm_s2),
            junction_deviation_mm=limits.junction_deviation_mm,
            rapid_mm_s=limits.travel_mm_s if machine.flavour == "grbl" else None,
        )


class Positions(Sequence[tuple[float | None, ...]]):
    """The logical X, Y, Z, E after each command of a job (mm): ``xyze`` (n, 4) float64,
    NaN where unknown; item ``i`` is a tuple with None where unknown."""

    def __init__(self, xyze: np.ndarray) -> None:
        self.xyze = xyze

    def __len__(self) -> int:
        return len(self.xyze)

    def __getitem__(self, index: int) -> tuple[float | None, ...]:  # type: ignore[override]
        return tuple(None if math.isnan(v) else v for v in self.xyze[index].tolist())

    def __iter__(self) -> Iterator[tuple[float | None, ...]]:
        return (self[i] for i in range(len(self)))

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Positions) and np.array_equal(
            self.xyze, other.xyze, equal_nan=True
        )

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True)
class Estimate:
    """The planned time of a job (s).

    ``end_s[i]``: the motion clock when command ``i`` (of the job) has finished (its
    move, or its dwell); ``positions[i]``: the logical X, Y, Z, E after command ``i``
    (None where unknown; :class:`Positions`); ``waits``: commands whose time is not
    included; ``moves``: the commands that move (as the pre-flight check counts them).
    """

    end_s: tuple[float, ...]
    positions: Positions
    waits: tuple[str, ...]
    moves: int = 0

    @property
    def total_s(self) -> float:
        return self.end_s[-1] if self.end_s else 0.0

    def remaining_s(self, done: int) -> float:
        """The time left once the first ``done`` commands have run."""
        if done <= 0:
            return self.total_s
        return self.total_s - self.end_s[min(done, len(self.end_s)) - 1]

    def stopped_in(
        self, point: tuple[float, float, float], last: int, window: int, tol_mm: float = 0.05
    ) -> int | None:
        """The first command the machine had not finished when it stopped at ``point``
        (X, Y, Z, mm), looking at the moves among the ``window`` commands up to index
        ``last`` (the planner holds at most that many): the move whose path passes through
        the point (the next one if the point is its end), the earliest if several do;
        None if none does."""
        for index in range(max(0, last - window), last + 1):
            start = self.positions[index - 1][:3] if index > 0 else (None,) * 3
            end = self.positions[index][:3]
            if None in start or None in end or start == end:
                continue
            if _off_segment(point, start, end) <= tol_mm:
                at_end = math.dist(point, end) <= tol_mm
                return index + 1 if at_end else index
        return None

    def summary(self) -> str:
        """One line for the user."""
        text = f"estimated duration: {clock(self.total_s)} (moves and dwells"
        if self.waits:
            kinds = ", ".join(sorted(set(self.waits)))
            text += f"; not counted: {len(self.waits)} waits for {kinds}"
        return text + ")"


def _off_segment(point: Sequence[float], start: Sequence[float], end: Sequence[float]) -> float:
    """The distance (mm) from ``point`` to the segment ``start``-``end``."""
    d = [b - a for a, b in zip(start, end, strict=True)]
    length2 = sum(c * c for c in d)
    along = sum((p - a) * c for p, a, c in zip(point, start, d, strict=True)) / length2
    along = min(1.0, max(0.0, along))
    return math.dist(point, [a + along * c for a, c in zip(start, d, strict=True)])


_AXIS_COMMANDS = frozenset({"G92", "G28", "G30", "G10", "G53", "G38.2", "G38.3", "G38.4", "G38.5"})
"""GRBL commands that take a block's axis words themselves (gcode.c: ``axis_command``);
without one, axis words move the machine in the modal motion mode."""


class _Walker:
    """Modal state while walking a job: the position (logical mm,
    :class:`~fabkit.gcode.position.Position`), the feed (mm/s, or 1/s under G93) and the
    motion mode."""

    def __init__(self, kinematics: Kinematics, flavour: str) -> None:
        self.k = kinematics
        self.position = Position.start(flavour)
        self.feed: float | None = None
        self.inverse = False  # GRBL G93: F is 1/min, the block's own
        self.motion = "G1"

    def step(self, block: Block) -> list[float] | None:
        """Apply one command as its firmware read it; the move it makes as X, Y, Z, E
        deltas, or None."""
        grbl = self.k.rapid_mm_s is not None
        codes, values = block.codes, block.values
        given = values["F"] / 60.0 if values.get("F", 0.0) > 0 else None
        mode = next((c for c in codes if c in ("G93", "G94")), None)
        if grbl and mode is not None and self.inverse != (mode == "G93"):
            self.inverse = mode == "G93"
            self.feed = None  # a switch of feed mode does not carry the last F
        if self.inverse:
            self.feed = given  # zeroed before and after every block (gcode.c)
        elif given is not None:
            self.feed = given
        if grbl and ("M2" in codes or "M30" in codes):
            self.inverse = False  # program end: G94
        for code in codes:
            self.position.apply(code, values, block.flags)  # G90/G91/M82/M83, G92, G28
        motion = next((c for c in codes if c in MOTION), None)
        if motion is not None:
            self.motion = motion
        elif not grbl or set(codes) & _AXIS_COMMANDS:
            return None  # only GRBL moves on axis words alone (its modal motion)
        move = self.position.move(values)
        return None if move is None else list(move.deltas())


def estimate(job: Sequence[Command], machine: MachineProfile) -> Estimate:
    """Plan ``job`` on ``machine`` (see the module docstring). Each command is read as the
    machine's firmware reads it (:func:`~fabkit.gcode.read.firmware_reader`); one it
    refuses moves nothing (the pre-flight check names it). On a Marlin-like firmware, runs
    of plain moves are read and planned as columns (:meth:`Planner.add_run`: the same
    numbers)."""
    read = firmware_reader(machine)
    planner = Planner(machine)
    texts = job_texts(job)
    if not planner.takes_runs:
        _add_each(planner, read, texts)
        return planner.estimate()
    for start, stop, run in job_spans(texts, MAX_LINE_CHARS, plain_codes(machine.flavour), {}):
        if run is not None and planner.takes_runs:
            planner.add_run(run)
        else:
            _add_each(planner, read, texts[start:stop])
    return planner.estimate()


def _add_each(planner: Planner, read: Callable[[str], Block], texts: Sequence[str]) -> None:
    """Each command of ``texts`` read and added to ``planner`` (a refused one: empty)."""
    for text in texts:
        try:
            block = read(text)
        except GcodeError:
            block = Block(())
        planner.add(block)


class Planner:
    """:func:`estimate` one command at a time: :meth:`add` every command of a job as its
    firmware read it, in order (or a run of plain moves at once, :meth:`add_run`), then
    :meth:`estimate`. For a caller that reads each command once for several purposes
    (``fabkit send``: the pre-flight check and the plan,
    :func:`fabkit.link.host.job.prepare_job`)."""

    def __init__(self, machine: MachineProfile) -> None:
        self.kinematics = Kinematics.of(machine)
        self.walker = _Walker(self.kinematics, machine.flavour)
        self.planned = _Moves()
        self.dwell_s = Rows(1)  # s, per command
        self.positions = Rows(4)  # logical X, Y, Z, E after each command, NaN: unknown
        self.waits: list[str] = []
        self.segment, self.moves = 0, 0

    @property
    def takes_runs(self) -> bool:
        """Whether :meth:`add_run` plans the next commands: on a Marlin-like firmware (no
        rapid rate of its own), in units per minute (not inverse time)."""
        return self.kinematics.rapid_mm_s is None and not self.walker.inverse

    def add(self, block: Block) -> None:
        """The next command of the job, as its firmware read it (a refused one: an empty
        block, which moves nothing)."""
        index = self.dwell_s.count
        walker = self.walker
        deltas = walker.step(block)
        self.positions.append(walker.position.logical)
        dwell = 0.0
        if deltas is not None:
            self.moves += 1
            self.planned.add(deltas, walker, block.values, self.kinematics, index, self.segment)
        stops = [code for code in block.codes if code in STOPS]
        if stops:
            self.waits += [code for code in stops if code in UNKNOWN_TIME]
            if "G4" in stops:
                values = block.values
                dwell = values.get("P", 0.0) / 1000.0 + values.get("S", 0.0)
            self.segment += 1  # the planner empties: the next move starts at rest
        self.dwell_s.append((dwell,))

    def add_run(self, run: MoveRun) -> None:
        """The next commands of the job: a run of plain G0/G1 moves
        (:mod:`fabkit.gcode.columns`) on a Marlin-like firmware, planned exactly as
        :meth:`add` of each would (the same operations on the same numbers, in columns);
        the run's other commands (:attr:`MoveRun.other`) are pin writes: nothing here."""
        walker = self.walker
        if not self.takes_runs:
            raise ValueError("a run of plain moves is planned for Marlin-like firmwares only")
        index = self.dwell_s.count
        feed = _run_feed(walker.feed, run)
        start = _nan_row(walker.position.logical)
        logical = walker.position.walk(run.given[:, :4], run.values[:, :4])
        before = np.vstack((start, logical[:-1]))
        deltas = logical - before
        deltas[np.isnan(deltas)] = 0.0  # an end unknown: no travel counted
        moving = run.given[:, :4].any(axis=1)
        self.planned.add_run(
            deltas[moving],
            feed[moving],
            index + np.flatnonzero(moving),
            self.segment,
            self.kinematics,
        )
        self.moves += int(moving.sum())
        self.positions.extend(logical)
        self.dwell_s.extend(np.zeros((len(run), 1)))
        walker.feed = None if math.isnan(feed[-1]) else float(feed[-1])
        motions = np.flatnonzero(run.other < 0)  # the others move nothing (M42)
        if len(motions):
            walker.motion = "G0" if run.g0[motions[-1]] else "G1"

    def estimate(self) -> Estimate:
        """The plan of every command added so far."""
        finish = self.dwell_s.array()[:, 0]
        index, seconds = self.planned.seconds(self.kinematics)
        np.add.at(finish, index, seconds)
        end_s = np.cumsum(finish).tolist()
        return Estimate(
            tuple(end_s), Positions(self.positions.array()), tuple(self.waits), self.moves
        )


def _nan_row(values: Sequence[float | None]) -> np.ndarray:
    """(k,) float64: ``values`` with NaN for None."""
    return np.array([math.nan if v is None else v for v in values])


def _run_feed(feed: float | None, run: MoveRun) -> np.ndarray:
    """(n,) mm/s (NaN: none yet): the walker's feed after each move of ``run``."""
    f = run.values[:, 4]
    given = run.given[:, 4] & (f > 0)
    return filled(math.nan if feed is None else feed, given, f[given] / 60.0)


class _Moves:
    """The moves of a job as the planner sees them (one row per move of non-zero
    length): X, Y, Z, E deltas (mm), length (mm, an arc's along the arc), feed (mm/s, or
    1/s under G93), whether the feed is G93's inverse time (1.0), the command's index and
    the planner segment (moves between two commands that empty the planner)."""

    def __init__(self) -> None:
        self.rows = Rows(9)

    def add(
        self,
        deltas: list[float],
        walker: _Walker,
        values: dict[str, float],
        k: Kinematics,
        index: int,
        segment: int,
    ) -> None:
        dx, dy, dz = deltas[:3]
        xyz = math.sqrt(dx * dx + dy * dy + dz * dz)  # one order on every Python (not sum())
        length = xyz if xyz > 0 else abs(deltas[3])
        if walker.motion in ("G2", "G3") and ("I" in values or "J" in values):
            length = _arc_length(deltas, values, walker.motion)
        if length <= 0:
            return
        rapid = walker.motion == "G0" and k.rapid_mm_s is not None
        feed = k.rapid_mm_s if rapid else walker.feed or k.max_mm_s[0]
        inverse = bool(walker.inverse and walker.feed and not rapid)
        self.rows.append((*deltas, length, feed, float(inverse), index, segment))

    def add_run(
        self, deltas: np.ndarray, feed: np.ndarray, index: np.ndarray, segment: int, k: Kinematics
    ) -> None:
        """Lines of a Marlin-like firmware at once, as :meth:`add` of each: ``deltas``
        (m, 4) mm, ``feed`` (m,) mm/s (NaN: none yet), ``index`` (m,) their commands."""
        xyz = np.sqrt(
            deltas[:, 0] * deltas[:, 0] + deltas[:, 1] * deltas[:, 1] + deltas[:, 2] * deltas[:, 2]
        )
        length = np.where(xyz > 0, xyz, np.abs(deltas[:, 3]))
        keep = length > 0
        rows = np.empty((int(keep.sum()), 9))
        rows[:, :4] = deltas[keep]
        rows[:, 4] = length[keep]
        rows[:, 5] = np.where(np.isnan(feed[keep]), k.max_mm_s[0], feed[keep])
        rows[:, 6] = 0.0
        rows[:, 7] = index[keep]
        rows[:, 8] = segment
        self.rows.extend(rows)

    def seconds(self, k: Kinematics) -> tuple[np.ndarray, np.ndarray]:
        """(n,) command indices and (n,) s: each move's time, its entry and exit speeds
        planned by junction deviation and a backward and a forward pass (module
        docstring)."""
        rows = self.rows.array()
        if not len(rows):
            return np.zeros(0, dtype=int), np.zeros(0)
        length = rows[:, 4]
        unit = rows[:, :4] / length[:, None]
        feed = rows[:, 5]
        nominal = np.where(rows[:, 6] > 0, feed * length, feed)  # G93: the move takes 60/F s
        accel = np.full(len(length), math.inf)
        for axis in range(4):
            share = np.abs(unit[:, axis])
            moving = share > 0
            safe = np.where(moving, share, 1.0)
            nominal = np.where(moving, np.minimum(nominal, k.max_mm_s[axis] / safe), nominal)
            if k.accel_mm_s2[axis] > 0:
                accel = np.where(moving, np.minimum(accel, k.accel_mm_s2[axis] / safe), accel)
        segment = rows[:, 8]
        first = np.r_[True, segment[1:] != segment[:-1]]
        max_entry = np.r_[0.0, _junctions(unit, nominal, accel, k.junction_deviation_mm)]
        max_entry[first] = 0.0
        entry = _passes(length, accel, max_entry, first)
        exit_speed = np.r_[np.where(first[1:], 0.0, entry[1:]), 0.0]
        seconds = trapezoid_time(length, entry, exit_speed, nominal, accel)
        return rows[:, 7].astype(int), seconds


def _arc_length(deltas: list[float], values: dict[str, float], code: str) -> float:
    """Length of an I/J arc in the XY plane (with its Z travel)."""
    i, j = values.get("I", 0.0), values.get("J", 0.0)
    radius = math.hypot(i, j)
    start = math.atan2(-j, -i)
    stop = math.atan2(deltas[1] - j, deltas[0] - i)
    sweep = (stop - start) % (2 * math.pi)
    if code == "G2":
        sweep = (2 * math.pi - sweep) % (2 * math.pi)
    sweep = sweep or 2 * math.pi
    return math.hypot(radius * sweep, deltas[2])


def _junctions(
    unit: np.ndarray, nominal: np.ndarray, accel: np.ndarray, deviation_mm: float
) -> np.ndarray:
    """(n - 1,) mm/s: the highest speed at the junction of each move with the next."""
    before, after = unit[:-1], unit[1:]
    cos_theta = -np.einsum("ij,ij->i", before[:, :3], after[:, :3])
    no_xyz = ~before[:, :3].any(axis=1) | ~after[:, :3].any(axis=1)
    cos_theta = np.where(no_xyz, -np.einsum("ij,ij->i", before, after), cos_theta)
    limit = np.minimum(nominal[:-1], nominal[1:])
    with np.errstate(invalid="ignore", divide="ignore"):  # cos > 1 by rounding: set below
        sin_half = np.sqrt(0.5 * (1.0 - np.maximum(cos_theta, -0.999999)))
        v2 = accel[1:] * deviation_mm * sin_half / (1.0 - sin_half)
    speed = np.where(np.isinf(accel[1:]), limit, np.minimum(np.sqrt(v2), limit))
    return np.where(cos_theta > 0.999999, np.minimum(MIN_JUNCTION_MM_S, limit), speed)


MAX_SWEEPS = 64
"""Array sweeps of a pass before it is run one move at a time instead (a long chain of
moves each limited by the next, or the previous: a long ramp over short moves)."""


def _passes(
    length: np.ndarray, accel: np.ndarray, max_entry: np.ndarray, first: np.ndarray
) -> np.ndarray:
    """Entry speeds (mm/s): each at most its junction's, reachable backward from the
    next (at rest after a segment's last move) and forward from the previous.

    Each pass runs one move at a time (:func:`_passes_in_order`), and its result is the
    only fixed point of ``entry = min(bound, reach(neighbour))``: array sweeps of that map
    from the bound until nothing changes give the very same floats (each computed by the
    same operations from the same neighbour), far faster when the chains are short."""
    if np.isnan(length).any() or np.isnan(max_entry).any():
        return _passes_in_order(length, accel, max_entry, first)
    last = np.r_[first[1:], True]  # the move ends at rest: its segment's last
    backward = _sweep(max_entry, lambda x: np.where(last, 0.0, np.r_[x[1:], 0.0]), length, accel)
    if backward is None:
        return _passes_in_order(length, accel, max_entry, first)
    before = (np.r_[0.0, length[:-1]], np.r_[math.inf, accel[:-1]])
    forward = _sweep(backward, lambda x: np.r_[0.0, x[:-1]], *before, skip=first)
    return _passes_in_order(length, accel, max_entry, first) if forward is None else forward


def _sweep(
    bound: np.ndarray,
    neighbour: Callable[[np.ndarray], np.ndarray],
    length: np.ndarray,
    accel: np.ndarray,
    skip: np.ndarray | None = None,
) -> np.ndarray | None:
    """The fixed point of ``x = min(bound, reach(neighbour(x), length, accel))`` (``bound``
    where ``skip``), or None when :data:`MAX_SWEEPS` sweeps do not reach it."""
    free = np.isinf(accel)
    twice = 2.0 * np.where(free, 0.0, accel) * length
    x = bound
    for _ in range(MAX_SWEEPS):
        speed = neighbour(x)
        reach = np.where(free, math.inf, np.sqrt(speed * speed + twice))
        if skip is not None:
            reach = np.where(skip, math.inf, reach)
        new = np.minimum(bound, reach)
        if np.array_equal(new, x):
            return new
        x = new
    return None


def _passes_in_order(
    length: np.ndarray, accel: np.ndarray, max_entry: np.ndarray, first: np.ndarray
) -> np.ndarray:
    """:func:`_passes`, one move at a time."""
    lengths, accels, entry = length.tolist(), accel.tolist(), max_entry.tolist()
    starts = first.tolist()
    sqrt, inf = math.sqrt, math.inf
    exit_speed = 0.0
    for i in range(len(entry) - 1, -1, -1):  # the speed reached over the move
        a = accels[i]
        reach = inf if a == inf else sqrt(exit_speed * exit_speed + 2.0 * a * lengths[i])
        entry[i] = min(entry[i], reach)
        exit_speed = 0.0 if starts[i] else entry[i]
    for i in range(1, len(entry)):
        if not starts[i]:
            a, speed = accels[i - 1], entry[i - 1]
            reach = inf if a == inf else sqrt(speed * speed + 2.0 * a * lengths[i - 1])
            entry[i] = min(entry[i], reach)
    return np.asarray(entry)


def trapezoid_time(
    length: ArrayLike, entry: ArrayLike, exit_speed: ArrayLike, nominal: ArrayLike, accel: ArrayLike
) -> np.ndarray | float:
    """Seconds to cover ``length`` mm from ``entry`` to ``exit_speed`` (mm/s), cruising
    at most at ``nominal``, accelerating and braking at ``accel`` (mm/s^2); numbers or
    arrays of one shape alike."""
    length, entry, exit_speed, nominal, accel = np.broadcast_arrays(
        *(np.asarray(v, dtype=float) for v in (length, entry, exit_speed, nominal, accel))
    )
    free = np.isinf(accel)
    a = np.where(free, 1.0, accel)
    accelerate = (nominal * nominal - entry * entry) / (2.0 * a)
    brake = (nominal * nominal - exit_speed * exit_speed) / (2.0 * a)
    cruise = length - accelerate - brake
    trapezoid = (nominal - entry) / a + (nominal - exit_speed) / a + cruise / nominal
    peak = np.sqrt(np.maximum(0.0, (2.0 * a * length + entry * entry + exit_speed**2) / 2))
    triangle = np.maximum(0.0, (peak - entry) / a) + np.maximum(0.0, (peak - exit_speed) / a)
    cruising = accelerate + brake <= length
    seconds = np.where(free, length / nominal, np.where(cruising, trapezoid, triangle))
    return seconds if seconds.ndim else float(seconds)
