"""The pre-flight check of a run of plain moves at once, on a Marlin-like firmware.

A run (:class:`fabkit.gcode.columns.MoveRun`: consecutive ``G0``/``G1`` commands of X Y Z
E F words) is checked in columns with the same operations on the same numbers as
:meth:`MarlinDialect._line <fabkit.link.host.preflight_marlin.MarlinDialect._line>` and
:meth:`Tracker.move <fabkit.link.host.tracker.Tracker.move>` apply to each command:
machine positions (absolute: the G92 shift plus the value; relative: added in order),
the modal feed (``F``, scaled by M220), E travel (relative or from the last E, scaled by
M221), the envelope, the feed against the print or travel limit and each axis's share
against its own. Only a run that passes every check with a margin, from a plain start
(every axis known exactly, no sign of zero to keep), is applied here; any other is left
untouched for the per-command path, which then refuses it (or passes it) with exactly
its own message and line. The axis shares use ``sqrt`` of squares where the tracker uses
``math.hypot``: they differ by a few units in the last place, far inside the margin.
"""

from __future__ import annotations

import numpy as np

from fabkit.gcode.columns import MoveRun, accumulated, filled
from fabkit.link.host.preflight_marlin import MarlinDialect
from fabkit.link.host.tracker import TOL_MM, Span

SHARE_MARGIN = 1e-9
"""Relative margin (far above the error of an axis share's few roundings) under a limit
within which a run's axis speeds are left to the per-command path."""


def switch_code(switch: tuple[int, bool] | None) -> int:
    """A pin write's number in :attr:`MoveRun.other <fabkit.gcode.columns.MoveRun.other>`:
    0 when it switches no ink, else 1 + 2 * ink + on (ink 0 or 1)."""
    return 0 if switch is None else 1 + 2 * switch[0] + int(switch[1])


class MarlinRuns:
    """Runs of plain moves on ``dialect``'s state (its tracker's too), with the profile's
    own pin writes among them (:attr:`MoveRun.other`: :func:`switch_code`)."""

    def __init__(self, dialect: MarlinDialect) -> None:
        self.d = dialect
        self.t = dialect.t

    def apply(self, run: MoveRun, inks: list[bool]) -> list[bool] | None:
        """Check ``run`` and apply it from the inks' flow ``inks`` (the first, the second);
        the inks' flow after it, or None (nothing changed) when it is not certain to pass:
        the per-command path must take it."""
        d, t = self.d, self.t
        spans = [*t.pos, *d.shift]
        if any(s is None or s.lo != s.hi for s in spans):
            return None
        moving = run.given[:, :4].any(axis=1)
        feed = self._feed(run)
        ends = self._ends(run)
        extruded = self._extruded(run)
        if feed is None or ends is None or extruded is None or np.isnan(feed[moving]).any():
            return None
        de, e_after = extruded
        flows = _flows(run.other, inks)
        flowing = flows[:, 0] | flows[:, 1]
        if not self._inside(run, ends) or not self._fast_enough(ends, de, feed, moving, flowing):
            return None
        self._commit(run, ends, e_after, int(moving.sum()))
        return [bool(flows[-1, 0]), bool(flows[-1, 1])]

    def _feed(self, run: MoveRun) -> np.ndarray | None:
        """(n,) mm/s after M220 (NaN: no feed yet), or None for an F the check refuses."""
        f, given = run.values[:, 4], run.given[:, 4]
        if (f[given] <= 0).any():
            return None
        feed = self.d.feed
        mm_min = filled(np.nan if feed is None else feed, given, f[given])
        return mm_min / 60.0 * self.d.feed_percent / 100.0

    def _ends(self, run: MoveRun) -> np.ndarray | None:
        """(n, 3) machine X, Y, Z after each move (mm), or None without a distance mode."""
        absolute = self.d.modes.absolute
        if absolute is None and run.given[:, :3].any():
            return None
        ends = np.empty((len(run), 3))
        for i in range(3):
            given = run.given[:, i]
            start = self.t.pos[i].lo
            new = run.values[given, i]
            new = self.d.shift[i].lo + new if absolute else accumulated(start, new)
            ends[:, i] = filled(start, given, new)
        return ends

    def _extruded(self, run: MoveRun) -> tuple[np.ndarray, float | None] | None:
        """(n,) E travel after M221 and the E position after the run, or None when the
        check cannot read an E move (E mode unknown, absolute E from an unknown E)."""
        d = self.d
        given = run.given[:, 3]
        de = np.zeros(len(run))
        if not given.any():
            return de, d.e
        values = run.values[given, 3]
        relative = d.modes.e_relative
        if relative is None or (not relative and d.e is None):
            return None
        if relative:
            delta = values
            e_after = None if d.e is None else float(accumulated(d.e, values)[-1])
        else:
            delta = values - np.concatenate(([d.e], values[:-1]))
            e_after = float(values[-1])
        de[given] = delta * d.flow_percent / 100.0
        return de, e_after

    def _inside(self, run: MoveRun, ends: np.ndarray) -> bool:
        """Every named axis's end inside the envelope, and no -0.0 among them (the
        tracker's bounds keep the first of equal values: a sign of zero would depend on
        the order)."""
        for i, axis in enumerate("xyz"):
            named = ends[run.given[:, i], i]
            lo, hi = self.t.machine.envelope.axis(axis)
            outside = (named < lo - TOL_MM) | (named > hi + TOL_MM)
            if outside.any() or ((named == 0) & np.signbit(named)).any():
                return False
        return True

    def _fast_enough(
        self,
        ends: np.ndarray,
        de: np.ndarray,
        feed: np.ndarray,
        moving: np.ndarray,
        flowing: np.ndarray,
    ) -> bool:
        """The feed within the print (E forward, or material flowing) or travel limit, each
        axis's share within its own, with :data:`SHARE_MARGIN` for the shares
        (Tracker._speed)."""
        t = self.t
        limits = t.machine.limits
        start = np.array([[s.lo for s in t.pos]])
        deltas = np.diff(np.concatenate((start, ends)), axis=0)[moving]
        de, mm_s = de[moving], feed[moving]
        printing = (de > 0) | flowing[moving]
        ceiling = np.where(printing, limits.print_mm_s, limits.travel_mm_s)
        if (mm_s > ceiling * (1 + 1e-9) + TOL_MM).any():
            return False
        length = np.sqrt((deltas * deltas).sum(axis=1))
        flat = length <= 0
        safe = np.where(flat, 1.0, length)
        shares = np.abs(np.column_stack((deltas, de))) / safe[:, None]
        shares[flat] = 0.0
        shares[flat, 3] = (de[flat] != 0).astype(float)
        axis_limits = np.array([limits.x_mm_s, limits.y_mm_s, limits.z_mm_s, limits.e_mm_s])
        ceiling = axis_limits * (1 + 1e-9) + TOL_MM
        return bool((mm_s[:, None] * shares * (1 + SHARE_MARGIN) <= ceiling).all())

    def _commit(self, run: MoveRun, ends: np.ndarray, e_after: float | None, moves: int) -> None:
        """Leave the state as the per-command path would after ``run``."""
        d, t = self.d, self.t
        f_given = run.given[:, 4]
        if f_given.any():
            d.feed = float(run.values[f_given, 4][-1])
        if run.given[:, 3].any():
            d.e = e_after
        for i in range(3):
            named = ends[run.given[:, i], i]
            if not len(named):
                continue
            t.pos[i] = Span.at(float(named[-1]))
            lo, hi = float(named.min()), float(named.max())
            seen = t.bounds[i]
            t.bounds[i] = [lo, hi] if seen is None else [min(seen[0], lo), max(seen[1], hi)]
        t.moves += moves


def _flows(other: np.ndarray, inks: list[bool]) -> np.ndarray:
    """(n, 2) bool: whether each ink flows after each command of a run (its pin writes:
    ``other`` > 0, :func:`switch_code`), from ``inks``."""
    out = np.empty((len(other), 2), dtype=bool)
    for ink in (0, 1):
        switches = (other > 0) & ((other - 1) // 2 == ink)
        on = ((other[switches] - 1) % 2).astype(float)
        out[:, ink] = filled(float(inks[ink]), switches, on) > 0
    return out
