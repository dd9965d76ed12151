"""Where a job's moves go: the position state every reader of a job walks.

The duration estimate and ``fabkit verify`` follow a job command by command through one
:class:`Position` (the pre-flight check keeps intervals of where the head may be instead,
:mod:`fabkit.link.host.tracker`, and the distance modes of :mod:`fabkit.gcode.modes`):

* X, Y, Z: the *logical* position (what the job's coordinates mean) and the shift G92
  makes, machine = logical + shift (Marlin ``gcode/geometry/G92.cpp``: ``position_shift``;
  Klipper ``klippy/extras/gcode_move.py``: ``base_position``);
* E: its logical position (``G92 E`` sets it; no shift matters for E's differences);
* G90/G91 and M82/M83 as each firmware holds them (:class:`~fabkit.gcode.modes.DistanceModes`);
* G28 (and GRBL's ``$H``): the axes it names (every axis when it names none) at 0, their
  shift cleared (Marlin ``G28.cpp``: homing sets the position to the home position, 0
  on these machines, and ``set_axis_is_at_home`` clears the shift).

``None`` is a coordinate the job has not set (what an earlier job left is unknown): a
relative move from it stays unknown. E starts unknown too, or at ``e_mm`` for a reader
that takes the firmware as it powers up (``fabkit verify``: E = 0). Units are the job's:
mm (G21; the pre-flight check refuses G20 before any of this runs).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from fabkit.gcode.columns import accumulated, filled
from fabkit.gcode.modes import DistanceModes

AXES = "XYZE"
MOTION = frozenset({"G0", "G1", "G2", "G3"})


@dataclass(frozen=True)
class Move:
    """One move's ``start`` and ``end``, logical X, Y, Z, E (None: unknown), and
    ``machine_start`` / ``machine_end``, X, Y, Z in the machine's frame."""

    start: tuple[float | None, ...]
    end: tuple[float | None, ...]
    machine_start: tuple[float | None, ...]
    machine_end: tuple[float | None, ...]

    def deltas(self) -> tuple[float, ...]:
        """X, Y, Z, E travelled (0 where an end is unknown)."""
        return tuple(
            0.0 if a is None or b is None else b - a
            for a, b in zip(self.start, self.end, strict=True)
        )


@dataclass
class Position:
    """The position state of one firmware ``flavour`` (module docstring)."""

    flavour: str
    modes: DistanceModes = field(init=False)
    logical: list[float | None] = field(default_factory=lambda: [None] * 4)
    shift: list[float | None] = field(default_factory=lambda: [0.0] * 3)

    def __post_init__(self) -> None:
        self.modes = DistanceModes.assumed(self.flavour)

    @classmethod
    def start(cls, flavour: str, e_mm: float | None = None) -> Position:
        """The state at the start of a job: X, Y, Z unknown, E at ``e_mm``."""
        return cls(flavour, logical=[None, None, None, e_mm])

    def machine(self) -> tuple[float | None, ...]:
        """X, Y, Z in the machine's frame (None: unknown)."""
        return tuple(
            None if p is None or s is None else p + s
            for p, s in zip(self.logical[:3], self.shift, strict=True)
        )

    def apply(
        self, code: str, values: Mapping[str, float], flags: frozenset[str] = frozenset()
    ) -> bool:
        """Apply a distance mode, G92 or G28 / $H; whether ``code`` was one of them."""
        if self.modes.apply(code):
            return True
        if code == "G92":
            self.set(values)
        elif code in ("G28", "$H"):
            self.home([a for a in "XYZ" if a in values or a in flags] or list("XYZ"))
        else:
            return False
        return True

    def set(self, values: Mapping[str, float]) -> None:
        """G92: the named axes' logical position; the machine does not move."""
        for i, axis in enumerate(AXES):
            if axis not in values:
                continue
            if i < 3:
                machine = self.machine()[i]
                self.shift[i] = None if machine is None else machine - values[axis]
            self.logical[i] = values[axis]

    def home(self, axes: list[str]) -> None:
        """The ``axes`` at 0 (logical and machine)."""
        for axis in axes:
            i = AXES.index(axis)
            self.logical[i] = 0.0
            self.shift[i] = 0.0

    def move(self, values: Mapping[str, float]) -> Move | None:
        """Go to a move's targets (absolute or relative as the modes say); None when it
        names no axis."""
        if not any(axis in values for axis in AXES):
            return None
        start, machine_start = tuple(self.logical), self.machine()
        for i, axis in enumerate(AXES):
            if axis not in values:
                continue
            relative = self.modes.e_relative_or_marlin() if axis == "E" else not self.modes.absolute
            here = self.logical[i]
            self.logical[i] = (
                values[axis] if not relative else None if here is None else here + values[axis]
            )
        return Move(start, tuple(self.logical), machine_start, self.machine())

    def walk(self, given: np.ndarray, values: np.ndarray) -> np.ndarray:
        """Go through n moves at once (no mode or shift changing between them): their X,
        Y, Z, E words ``values`` (n, 4) where ``given`` (n, 4); the logical X, Y, Z, E
        after each (n, 4; NaN: unknown), the same numbers as :meth:`move` of each in turn
        (absolute: the value; relative: added in order)."""
        start = [np.nan if v is None else v for v in self.logical]
        out = np.empty((len(given), 4))
        for i in range(4):
            relative = self.modes.e_relative_or_marlin() if i == 3 else not self.modes.absolute
            new = values[given[:, i], i]
            new = accumulated(start[i], new) if relative else new
            out[:, i] = filled(start[i], given[:, i], new)
        if len(out):
            self.logical = [None if np.isnan(v) else v for v in out[-1].tolist()]
        return out
