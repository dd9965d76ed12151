"""The machine as the pre-flight check follows it, and the checks against its profile.

Positions are machine coordinates (mm), one :class:`Span` per axis X, Y, Z: exact, or
an interval where the firmware decides (a G38 probe stops somewhere on its path), or
``None`` when unknown (before homing or an absolute move, after motors off, bed
probing, a quick stop or a profile macro), with the reason kept for the message. The
firmware dialects (:mod:`fabkit.link.host.preflight_grbl`, :mod:`fabkit.link.host.preflight_marlin`)
turn each command into calls here; every refusal is a one-line
:class:`~fabkit.gcode.read.GcodeError`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from fabkit.gcode.read import GcodeError
from fabkit.link.arcs import Arc
from fabkit.machines import MachineProfile

AXES = "XYZ"
TOL_MM = 1e-6
START_UNKNOWN = "not homed and not yet moved to an absolute position"


@dataclass(frozen=True)
class Span:
    """A coordinate known to lie in [lo, hi] (mm); lo == hi when it is known exactly."""

    lo: float
    hi: float

    @staticmethod
    def at(value: float) -> Span:
        """Exactly ``value``."""
        return Span(value, value)

    @property
    def exact(self) -> bool:
        return self.hi - self.lo <= TOL_MM

    @property
    def mid(self) -> float:
        return 0.5 * (self.lo + self.hi)

    def __add__(self, other: Span | float) -> Span:
        if isinstance(other, Span):
            return Span(self.lo + other.lo, self.hi + other.hi)
        return Span(self.lo + other, self.hi + other)

    def __sub__(self, other: Span | float) -> Span:
        if isinstance(other, Span):
            return Span(self.lo - other.hi, self.hi - other.lo)
        return Span(self.lo - other, self.hi - other)


@dataclass(frozen=True)
class Speed:
    """How a move's speed is set: ``rapid`` (the controller's own maximum rates, not in the
    file: GRBL G0, G28/G30, Hyrel G0 without F), ``feed`` (``value`` mm/s) or ``duration``
    (GRBL G93 inverse time: the move takes ``value`` s whatever its length)."""

    kind: str
    value: float = 0.0


@dataclass(frozen=True)
class ArcMove:
    """An arc in the plane of axes ``a`` and ``b`` (indices into XYZ); the third moves
    linearly."""

    arc: Arc
    a: int
    b: int


class Tracker:
    """Positions, flow and the running totals of one job on one machine."""

    def __init__(self, machine: MachineProfile) -> None:
        self.machine = machine
        self.pos: list[Span | None] = [None, None, None]
        self.unknown = [START_UNKNOWN] * 3
        self.flow_on = False
        self.bounds: list[list[float] | None] = [None, None, None]
        self.moves = 0

    # -- positions -------------------------------------------------------------------------

    def known(self, label: str, i: int) -> Span:
        """The position of axis ``i``, or a refusal saying why it is unknown."""
        span = self.pos[i]
        if span is None:
            raise GcodeError(
                f"{label} cannot be checked: the {AXES[i]} position is unknown "
                f"({self.unknown[i]}): home it or move it to an absolute position first"
            )
        return span

    def relative(self, label: str, i: int, delta: float) -> Span:
        """Axis ``i`` moved by ``delta`` mm from where it is."""
        return self.known(label, i) + delta

    def home(self, i: int) -> None:
        """Axis ``i`` homed: at 0, or the envelope bound nearest to it."""
        lo, hi = self.machine.envelope.axis(AXES[i].lower())
        self.pos[i] = Span.at(min(max(0.0, lo), hi))

    def lose(self, i: int, why: str) -> None:
        """Axis ``i`` is somewhere the check cannot know, because ``why``."""
        self.pos[i] = None
        self.unknown[i] = why

    def inside(self, i: int, span: Span) -> None:
        """Both ends of ``span`` inside the envelope of axis ``i``; record them."""
        axis = AXES[i]
        lo, hi = self.machine.envelope.axis(axis.lower())
        for value in (span.lo, span.hi):
            if not lo - TOL_MM <= value <= hi + TOL_MM:
                raise GcodeError(
                    f"{axis}={value:.3f} mm is outside the envelope {axis.lower()}_mm = "
                    f"[{lo:g}, {hi:g}] of machine {self.machine.name}"
                )
        seen = self.bounds[i]
        if seen is None:
            self.bounds[i] = [span.lo, span.hi]
        else:
            seen[0], seen[1] = min(seen[0], span.lo), max(seen[1], span.hi)

    # -- moves -----------------------------------------------------------------------------

    def move(
        self,
        label: str,
        end: list[Span | None],
        *,
        speed: Speed,
        de: float = 0.0,
        arc: ArcMove | None = None,
    ) -> None:
        """Check a move to ``end`` (machine mm; an axis that does not move keeps its entry
        of :attr:`pos`, known or not) with ``de`` of E travel, then make it."""
        start = self.pos
        for i, span in enumerate(end):
            if span is not start[i] and span is not None:
                self.inside(i, span)
        if arc is not None:
            self._arc_inside(label, start, arc)
        self._speed(label, start, end, de, speed, arc)
        self.pos = list(end)
        self.moves += 1

    def probe(self, label: str, end: list[Span | None], speed: Speed) -> None:
        """A G38 probe toward ``end``: checked like a move; it stops anywhere on the way."""
        start = list(self.pos)
        self.move(label, end, speed=speed)
        for i, (a, b) in enumerate(zip(start, end, strict=True)):
            if a is not b and a is not None and b is not None:
                self.pos[i] = Span(min(a.lo, b.lo), max(a.hi, b.hi))
            elif a is not b:
                self.lose(i, f"{label} stopped somewhere on its way from an unknown position")

    def _arc_inside(self, label: str, start: list[Span | None], move: ArcMove) -> None:
        for i in (move.a, move.b):
            span = start[i]
            if span is None or not span.exact:
                raise GcodeError(
                    f"{label} cannot be checked: an arc needs an exactly known start, and "
                    f"{AXES[i]} is {self.unknown[i] if span is None else 'uncertain (probed)'}"
                )
        for a, b in move.arc.extremes():
            self.inside(move.a, Span.at(a))
            self.inside(move.b, Span.at(b))

    def _speed(
        self,
        label: str,
        start: list[Span | None],
        end: list[Span | None],
        de: float,
        speed: Speed,
        arc: ArcMove | None,
    ) -> None:
        """Feed against the travel / print limit; each axis's share against its limit."""
        deltas = [_delta(a, b) for a, b in zip(start, end, strict=True)]
        length = self._length(deltas, arc)
        if speed.kind == "rapid":
            return
        if speed.kind == "duration":
            if None in deltas:
                raise GcodeError(
                    f"{label} cannot be checked: an inverse-time (G93) move from an uncertain "
                    "position has an unknown speed"
                )
            mm_s = length / speed.value if speed.value > 0 else math.inf
        else:
            mm_s = speed.value
        printing = de > 0 or self.flow_on
        self.limit(label, "feed", mm_s, "print_mm_s" if printing else "travel_mm_s")
        for axis, share in zip("xyze", _shares(deltas, de, length, arc), strict=True):
            self.limit(label, f"{axis.upper()} speed", mm_s * share, f"{axis}_mm_s")

    @staticmethod
    def _length(deltas: list[float | None], arc: ArcMove | None) -> float:
        if arc is not None:
            linear = 3 - arc.a - arc.b
            return arc.arc.length(deltas[linear] or 0.0)
        return math.hypot(*(d or 0.0 for d in deltas))

    def limit(self, label: str, what: str, value: float, key: str) -> None:
        """``value`` (mm/s) within ``[limits] key``."""
        limit = getattr(self.machine.limits, key)
        if value > limit * (1 + 1e-9) + TOL_MM:
            shown = "an unbounded" if math.isinf(value) else f"{value:.3f} mm/s"
            raise GcodeError(
                f"{what} {shown} exceeds [limits] {key} = {limit:g} mm/s of machine "
                f"{self.machine.name}"
            )

    # -- other limits ----------------------------------------------------------------------

    def temperature(self, label: str, letter: str, value: float, nozzle: bool) -> None:
        """A heater set point (degrees C) within the profile's maximum, and not negative
        (Marlin stores it as a 16-bit integer: -65236 would become 300)."""
        temps = self.machine.temperature
        limit = temps.nozzle_max_c if nozzle else temps.bed_max_c
        name = "nozzle_max_c" if nozzle else "bed_max_c"
        if value < 0:
            raise GcodeError(f"{label}: {letter}{value:g} is a negative temperature")
        if value > limit + TOL_MM:
            raise GcodeError(
                f"{label} {letter}{value:g}: {value:g} C exceeds [temperature] {name} = "
                f"{limit:g} C of machine {self.machine.name}"
            )

    def power(self, label: str, value: float) -> None:
        """A laser writer's ``S`` (mW) within ``[laser] max_power_mw``, when known."""
        laser = self.machine.laser
        limit = laser.max_power_mw if laser is not None else None
        if limit is not None and value > limit + TOL_MM:
            raise GcodeError(
                f"{label}: laser power S{value:g} mW exceeds [laser] max_power_mw = "
                f"{limit:g} mW of machine {self.machine.name}"
            )


def _delta(a: Span | None, b: Span | None) -> float | None:
    """The travel of one axis (mm); None when it is uncertain."""
    if a is b:
        return 0.0
    if a is None or b is None or not (a.exact and b.exact):
        return None
    return b.lo - a.lo


def _shares(
    deltas: list[float | None], de: float, length: float, arc: ArcMove | None
) -> list[float]:
    """Each axis's largest share of the path speed (X, Y, Z, E): |d| / length on a line,
    the whole planar part on an arc's plane axes (its tangent turns through them), 1 for
    an axis whose travel is uncertain (the move may run along it alone)."""
    if length <= 0:  # E alone, or travel only along uncertain axes
        return [1.0 if d is None else 0.0 for d in deltas] + [1.0 if de else 0.0]
    shares = [1.0 if d is None else abs(d) / length for d in deltas]
    if arc is not None:
        linear = 3 - arc.a - arc.b
        planar = math.sqrt(max(0.0, 1.0 - shares[linear] ** 2))
        shares[arc.a] = shares[arc.b] = planar
    return [*shares, abs(de) / length]
