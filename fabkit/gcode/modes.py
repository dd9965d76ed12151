"""Distance modes as each firmware holds them: G90/G91 for the axes, and E's mode.

One table of facts, each from the firmware's source, and one state machine that every
reader of a job (the pre-flight check, ``fabkit verify``, the duration estimate) feeds
with G90, G91, M82 and M83:

=============== ===================================================================
flavour         E is relative when
=============== ===================================================================
marlin, hyrel   the last of G90/G91/M82/M83 says so: G90/G91 set E's mode too
                (Marlin ``gcode/gcode.h``: ``set_relative_mode`` sets every axis;
                ``M82``/``M83`` then set E alone, ``gcode/units/M82_M83.cpp``)
klipper         G91 is on or M83 is on: G90/G91 and M82/M83 are two flags
                (klippy/extras/gcode_move.py: ``absolute_coord`` and
                ``absolute_extrude``; a move's E is relative unless both are set)
reprap          RepRapFirmware documents both readings in different releases: only
                where both agree is the mode known (else None: the check refuses an E
                move it cannot read, and the estimate and verify take Marlin's)
grbl            no E axis
=============== ===================================================================
"""

from __future__ import annotations

from dataclasses import dataclass

FLAVOURS_WITH_E = ("marlin", "hyrel", "klipper", "reprap")


@dataclass
class DistanceModes:
    """G90/G91 and E's mode of one firmware ``flavour`` (module docstring); None where a
    job has not set a mode (what an earlier job left is unknown), unless started from
    :meth:`assumed`."""

    flavour: str
    absolute: bool | None = None  # G90 / G91
    e_relative_last: bool | None = None  # the last of G90/G91/M82/M83 (Marlin's reading)
    absolute_extrude: bool | None = None  # M82 / M83 alone (Klipper's second flag)

    @classmethod
    def assumed(cls, flavour: str) -> DistanceModes:
        """The modes a firmware starts in: absolute axes, absolute E."""
        return cls(flavour, absolute=True, e_relative_last=False, absolute_extrude=True)

    def apply(self, code: str) -> bool:
        """Apply ``code`` if it sets a distance mode; whether it did."""
        if code in ("G90", "G91"):
            self.absolute = code == "G90"
            self.e_relative_last = code == "G91"
        elif code in ("M82", "M83"):
            self.e_relative_last = code == "M83"
            self.absolute_extrude = code == "M82"
        else:
            return False
        return True

    @property
    def e_relative(self) -> bool | None:
        """Whether a move's E is relative now (None: unknown)."""
        if self.flavour in ("marlin", "hyrel"):
            return self.e_relative_last
        two_flags = None
        if self.absolute is False or self.absolute_extrude is False:
            two_flags = True
        elif self.absolute and self.absolute_extrude:
            two_flags = False
        if self.flavour == "klipper":
            return two_flags
        if self.flavour == "reprap":
            return self.e_relative_last if self.e_relative_last == two_flags else None
        return None

    def e_relative_or_marlin(self) -> bool:
        """E's mode where a reader must decide: this firmware's, else Marlin's reading."""
        known = self.e_relative
        return bool(self.e_relative_last) if known is None else known
