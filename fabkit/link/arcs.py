"""Arcs (G2/G3) as the firmwares trace them, in the arc's plane (mm, rad).

Both forms are read the way the firmwares compute them:

* centre form (``I J`` / ``K``): the centre is start + offset; the radius is the start's
  distance (GRBL ``gcode.c`` refuses an end point off that circle by more than 0.005 mm
  and 0.1 % or 0.5 mm, error:33; Marlin ``G2_G3.cpp`` does not check and heads for the
  end point in its last segment, so the same rule is applied to every firmware);
* radius form (``R``): the centre lies on the chord's perpendicular bisector, on the
  right of the travel for a clockwise arc with positive R and on the other side for a
  negative R (an arc over 180 degrees); GRBL refuses ``|R|`` shorter than half the chord
  (error:33), Marlin then silently uses the chord's midpoint (a bigger arc), so it is
  refused for every firmware.

The sweep follows GRBL's ``mc_arc`` and Marlin's ``plan_arc``: an end point equal to the
start makes a full circle. The path's extreme coordinates are its end points and the
points where it crosses the axis directions through the centre (the bounding box); a
sweep within :data:`NEAR_FULL` of none or a full turn counts as a full circle, because
single-precision firmware may land on either side.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from fabkit.gcode.read import GcodeError

NEAR_FULL = 1e-4
"""Sweeps closer than this (rad) to 0 or a full turn are checked as full circles."""
END_TOLERANCE_MM = 0.005
"""GRBL's allowed difference of the start and end radii (with 0.1 % of the radius)."""
END_LIMIT_MM = 0.5


@dataclass(frozen=True)
class Arc:
    """An arc in its plane: centre (a, b) mm, radius mm, start angle and signed sweep (rad,
    positive counter-clockwise), and whole extra turns (Marlin's ``P``)."""

    centre: tuple[float, float]
    radius: float
    start_angle: float
    sweep: float
    turns: int = 0

    def extremes(self) -> list[tuple[float, float]]:
        """The points of the path with an extreme coordinate along a or b (besides its end
        points): the circle's quarter points that the sweep passes."""
        full = self.turns > 0 or not NEAR_FULL < abs(self.sweep) < 2 * math.pi - NEAR_FULL
        out = []
        for k in range(4):
            angle = k * math.pi / 2
            if full or _within(angle, self.start_angle, self.sweep):
                ca, cb = self.centre
                out.append((ca + self.radius * math.cos(angle), cb + self.radius * math.sin(angle)))
        return out

    def length(self, linear_mm: float = 0.0) -> float:
        """Path length (mm) with ``linear_mm`` of travel along the third axis (a helix)."""
        flat = self.radius * (abs(self.sweep) + 2 * math.pi * self.turns)
        return math.hypot(flat, linear_mm)


def _within(angle: float, start: float, sweep: float) -> bool:
    """``angle`` lies on the sweep from ``start`` (either direction), ends included."""
    offset = (angle - start) % (2 * math.pi)
    if sweep >= 0:
        return offset <= sweep + 1e-12 or offset >= 2 * math.pi - 1e-12
    return offset <= 1e-12 or offset >= 2 * math.pi + sweep - 1e-12


def centre_arc(
    start: tuple[float, float],
    end: tuple[float, float],
    offset: tuple[float, float],
    clockwise: bool,
    turns: int = 0,
) -> Arc:
    """The arc from ``start`` to ``end`` around ``start + offset`` (GcodeError if the end
    point is off the circle by GRBL's rule, or the radius is zero)."""
    centre = (start[0] + offset[0], start[1] + offset[1])
    radius = math.hypot(*offset)
    if radius <= 0:
        raise GcodeError("arc of zero radius (I, J and K all 0)")
    off = abs(math.hypot(end[0] - centre[0], end[1] - centre[1]) - radius)
    if off > END_TOLERANCE_MM and (off > END_LIMIT_MM or off > 0.001 * radius):
        raise GcodeError(
            f"the arc's end point is {off:.3f} mm off its circle of radius {radius:.3f} mm"
        )
    return _arc(start, end, centre, radius, clockwise, turns)


def radius_arc(
    start: tuple[float, float], end: tuple[float, float], r: float, clockwise: bool
) -> Arc:
    """The arc of signed radius ``r`` from ``start`` to ``end`` (GcodeError if impossible)."""
    dx, dy = end[0] - start[0], end[1] - start[1]
    chord = math.hypot(dx, dy)
    if chord <= 0:
        raise GcodeError("an R arc needs an end point different from its start")
    if r == 0 or 4 * r * r < chord * chord:
        raise GcodeError(
            f"arc radius R{r:g} is shorter than half the distance to the end point "
            f"({chord / 2:.3f} mm): no such arc"
        )
    # gcode.c: centre = start + (x - y h, y + x h) / 2 with h = -+sqrt(4 r^2 - d^2) / d,
    # negative for a clockwise arc, sign flipped again for a negative R.
    h = math.sqrt(max(4 * r * r - chord * chord, 0.0)) / chord
    if clockwise:
        h = -h
    if r < 0:
        h = -h
    centre = (start[0] + 0.5 * (dx - dy * h), start[1] + 0.5 * (dy + dx * h))
    return _arc(start, end, centre, abs(r), clockwise, 0)


def _arc(
    start: tuple[float, float],
    end: tuple[float, float],
    centre: tuple[float, float],
    radius: float,
    clockwise: bool,
    turns: int,
) -> Arc:
    """The sweep as mc_arc / plan_arc compute it: from the start vector to the end vector,
    in the arc's direction; an end on the start is a full circle."""
    ra, rb = start[0] - centre[0], start[1] - centre[1]
    ta, tb = end[0] - centre[0], end[1] - centre[1]
    sweep = math.atan2(ra * tb - rb * ta, ra * ta + rb * tb)
    if clockwise and sweep >= -1e-9:
        sweep -= 2 * math.pi
    elif not clockwise and sweep <= 1e-9:
        sweep += 2 * math.pi
    return Arc(centre, radius, math.atan2(rb, ra), sweep, turns)
