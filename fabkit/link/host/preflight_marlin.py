"""Marlin 2.x, Klipper, RepRapFirmware and Hyrel commands on the tracked machine.

Rules from Marlin ``gcode/motion/G0_G1.cpp`` and ``G2_G3.cpp``, ``geometry/G92.cpp``,
``config/M220.cpp``, ``M221.cpp``, ``control/M42.cpp``, ``module/motion.cpp``
(``set_axis_is_at_home`` clears the G92 shift) and ``gcode.h`` (G90/G91 also set E's
mode), and Klipper ``klippy/extras/gcode_move.py`` (E is relative if G91 or M83; the
modes are :class:`fabkit.gcode.modes.DistanceModes`):

* Machine position = logical position + the G92 shift; the job is assumed to start
  without one. Homing an axis clears it; ``G28`` of X or Y alone may first raise Z
  (Marlin ``Z_HOMING_HEIGHT``, homing macros), so Z is then unknown.
* Modes persist across jobs: a move needs G90/G91 from the job, an absolute E move an
  E position (``G92 E``) and E mode from the job, a feed move an F from the job (Marlin
  would use the feed an earlier job left). ``M220 S`` scales every later feed,
  ``M221 S`` the E travel; both are assumed 100 % at the start (the panel can change
  them at any time: that is outside any file check).
* Arcs lie in XY (centre I J, or radius R; Klipper refuses R, P adds whole turns).
* ``M42`` may only repeat a pin write of the profile's own G-code (a valve): with ``I``
  Marlin writes even protected pins (steppers, heaters). A line of the profile's own
  G-code that the check does not model is accepted as written, and the position is
  unknown after it. Everything else that can move or heat is refused, named.
"""

from __future__ import annotations

from dataclasses import replace

from fabkit.gcode.modes import DistanceModes
from fabkit.gcode.read import Block, GcodeError, is_extended
from fabkit.link.arcs import centre_arc, radius_arc
from fabkit.link.host.tracker import AXES, ArcMove, Span, Speed, Tracker

_TAKES: dict[str, tuple[str, str]] = {
    "G0": ("XYZEF", ""), "G1": ("XYZEF", ""), "G2": ("XYZEFIJRP", ""),
    "G3": ("XYZEFIJRP", ""), "G4": ("PS", ""), "G21": ("", ""), "G28": ("", "XYZ"),
    "G90": ("", ""), "G91": ("", ""), "G92": ("XYZE", ""), "M82": ("", ""), "M83": ("", ""),
    "M17": ("", "XYZE"), "M18": ("S", "XYZE"), "M84": ("S", "XYZE"), "M104": ("SRBTF", ""),
    "M109": ("SRBTF", ""), "M140": ("SR", ""), "M190": ("SR", ""), "M105": ("T", ""),
    "M106": ("SPT", ""), "M107": ("P", ""), "M114": ("", ""), "M115": ("", ""),
    "M117": ("", ""), "M118": ("", ""), "M0": ("", ""), "M1": ("", ""),
    "M201": ("XYZET", ""), "M203": ("XYZET", ""), "M204": ("PRTS", ""),
    "M205": ("XYZEBSTJ", ""), "M220": ("S", ""), "M221": ("ST", ""), "M300": ("SP", ""),
    "M400": ("", ""), "M410": ("", ""), "M42": ("PS", ""), "M3": ("SO", "I"),
    "M4": ("SO", "I"), "M5": ("", "I"), "M7": ("", ""), "M8": ("", ""), "M9": ("", ""),
    "T0": ("", ""), "G29": ("", ""),
}  # fmt: skip
"""The commands the check models: letters that need a number, letters that may stand alone."""
_FLAVOUR_TAKES = {
    "marlin": _TAKES,
    "hyrel": _TAKES,
    "klipper": {code: takes for code, takes in _TAKES.items() if code != "G29"},
    "reprap": {**_TAKES, "M116": ("PHCS", ""), "M568": ("PSRA", ""), "G10": ("PSRLXYZ", "")},
}
_UNCHECKABLE = {
    "M110": "fabkit numbers the lines itself, and M110 would reset the numbering",
    "T1": "a tool change may move the head (parking, tool offsets)",
    "T2": "a tool change may move the head (parking, tool offsets)",
    "T3": "a tool change may move the head (parking, tool offsets)",
    "M229": "a Hyrel extrusion setting the check does not model",
    "M721": "Hyrel's unprime moves the extruder at rates set outside the file",
    "M722": "Hyrel's prime moves the extruder at rates set outside the file",
    "M756": "a Hyrel extrusion setting the check does not model",
}
_KLIPPER_QUIET = frozenset({
    "SET_PRESSURE_ADVANCE", "SET_VELOCITY_LIMIT", "SET_FAN_SPEED", "SET_LED", "SET_DISPLAY_TEXT",
    "TEMPERATURE_WAIT", "TURN_OFF_HEATERS", "SET_INPUT_SHAPER", "SET_IDLE_TIMEOUT", "STATUS",
    "GET_POSITION",
})  # fmt: skip
"""Klipper extended commands that move nothing and heat nothing."""
MAX_OVERRIDE_PERCENT = 999.0
"""Marlin's own panel range for M220/M221 ends here; larger values wrap in its int16."""


class MarlinDialect:
    """The modal state of one job on a Marlin-like firmware (see the module docstring)."""

    def __init__(
        self, tracker: Tracker, flavour: str, pin_writes: list[Block], trusted: set[str]
    ) -> None:
        self.t = tracker
        self.flavour = flavour
        self.takes = _FLAVOUR_TAKES[flavour]
        self.pin_writes = pin_writes
        self.trusted = trusted
        self.modes = DistanceModes(flavour)  # unknown until the job sets them
        self.feed: float | None = None  # mm/min
        self.feed_percent = 100.0
        self.flow_percent = 100.0
        self.shift = [Span.at(0.0)] * 3
        self.e: float | None = None

    def run(self, text: str, block: Block) -> None:
        """Check one command and apply it (GcodeError at the first problem)."""
        label = text if len(text) <= 40 else text[:37] + "..."
        code = block.codes[0]
        if code not in self.takes and " ".join(text.upper().split()) in self.trusted:
            self._trusted(label)
        elif code in self.takes:
            if code != "M42":  # M42 is checked as a whole line
                self._letters(label, code, block)
            getattr(self, "_" + code, self._quiet)(label, block)
        elif code in _UNCHECKABLE:
            raise GcodeError(f"{label} cannot be checked: {_UNCHECKABLE[code]}")
        elif self.flavour == "klipper" and is_extended(text):
            self._extended(label, code, block)
        else:
            raise GcodeError(f"unknown command {code} for flavour {self.flavour}")

    def _letters(self, label: str, code: str, block: Block) -> None:
        valued, alone = self.takes[code]
        for letter in block.values:
            if letter not in valued + alone:
                raise GcodeError(
                    f"{label} cannot be checked: the check does not model {letter} in {code}"
                )
        for letter in block.flags:
            if letter in valued:
                raise GcodeError(f"{label}: {letter} without a number")
            if letter not in alone:
                raise GcodeError(
                    f"{label} cannot be checked: the check does not model {letter} in {code}"
                )

    def _quiet(self, label: str, block: Block) -> None:
        """A command that moves and heats nothing."""

    def _trusted(self, label: str) -> None:
        """A line of the profile's own G-code that the check does not model."""
        for i in range(3):
            self.t.lose(i, f"after '{label}' from the machine's own G-code")

    def _extended(self, label: str, code: str, block: Block) -> None:
        if code == "SET_HEATER_TEMPERATURE":
            heater = block.params.get("HEATER", "")
            target = _number(label, block.params.get("TARGET", "0"))
            if heater.startswith("extruder") or heater == "heater_bed":
                self.t.temperature(code, "TARGET=", target, heater != "heater_bed")
                return
        elif code in _KLIPPER_QUIET:
            return
        raise GcodeError(
            f"{label} cannot be checked: a Klipper extended command or macro may move or "
            "heat the machine"
        )

    # -- moves -----------------------------------------------------------------------------

    def _G0(self, label: str, block: Block) -> None:
        self._line(label, "G0", block)

    def _G1(self, label: str, block: Block) -> None:
        self._line(label, "G1", block)

    def _line(self, label: str, code: str, block: Block) -> None:
        speed = self._speed(code, block)
        end = self._targets(label, block)
        de = self._extrude(label, block)
        if any(axis in block.values for axis in "XYZE"):
            self.t.move(label, end, speed=self._required(code, speed), de=de)

    def _G2(self, label: str, block: Block) -> None:
        self._arc(label, "G2", block)

    def _G3(self, label: str, block: Block) -> None:
        self._arc(label, "G3", block)

    def _arc(self, label: str, code: str, block: Block) -> None:
        values = block.values
        if "R" in values and ("I" in values or "J" in values):
            raise GcodeError(f"{label}: R together with I/J (firmwares pick different ones)")
        if "R" in values and self.flavour == "klipper":
            raise GcodeError(f"{label}: Klipper refuses R arcs: give the centre with I and J")
        speed = self._required(code, self._speed(code, block))
        start = [self.t.known(label, i) for i in (0, 1)]
        end = self._targets(label, block)
        de = self._extrude(label, block)
        if not all(s.exact for s in start) or not all(e is not None and e.exact for e in end[:2]):
            raise GcodeError(f"{label} cannot be checked: an arc from or to an uncertain point")
        a, b = (start[0].lo, start[1].lo), (end[0].lo, end[1].lo)
        clockwise = code == "G2"
        turns = values.get("P", 0.0)  # G2_G3.cpp: whole circles first, in either form
        if not (turns.is_integer() and 0 <= turns <= 100):
            raise GcodeError(f"{label}: P (whole turns) must be a whole number 0-100")
        if "R" in values:
            arc = replace(radius_arc(a, b, values["R"], clockwise), turns=int(turns))
        elif "I" in values or "J" in values:
            offset = (values.get("I", 0.0), values.get("J", 0.0))
            arc = centre_arc(a, b, offset, clockwise, int(turns))
        else:
            raise GcodeError(f"{label}: an arc needs I and J (centre) or R (radius)")
        self.t.move(label, end, speed=speed, de=de, arc=ArcMove(arc, 0, 1))

    def _speed(self, code: str, block: Block) -> Speed | None:
        """The speed of a move (None: no feed known yet); F sets the modal feed, except on
        Hyrel's G0, where F is for that move only and its absence means the rapid rate."""
        given = block.values.get("F")
        if given is not None and given <= 0:
            raise GcodeError(f"feed F{given:g} must be positive")
        if code == "G0" and self.flavour == "hyrel":
            return Speed("rapid") if given is None else self._scaled(given)
        if given is not None:
            self.feed = given
        return None if self.feed is None else self._scaled(self.feed)

    def _scaled(self, feed_mm_min: float) -> Speed:
        return Speed("feed", feed_mm_min / 60.0 * self.feed_percent / 100.0)

    @staticmethod
    def _required(code: str, speed: Speed | None) -> Speed:
        if speed is None:
            raise GcodeError(f"{code} before any feed rate (F) was set")
        return speed

    def _targets(self, label: str, block: Block) -> list[Span | None]:
        end = list(self.t.pos)
        for i, axis in enumerate(AXES):
            if axis not in block.values:
                continue
            if self.modes.absolute is None:
                raise GcodeError(
                    f"{label} cannot be checked: no G90/G91 in the job before it, and the "
                    "distance mode an earlier job left is unknown"
                )
            value = block.values[axis]
            absolute = self.modes.absolute
            end[i] = self.shift[i] + value if absolute else self.t.relative(label, i, value)
        return end

    def _extrude(self, label: str, block: Block) -> float:
        """The E travel of a move (firmware units, after the M221 flow factor)."""
        if "E" not in block.values:
            return 0.0
        value, relative = block.values["E"], self.modes.e_relative
        if relative is None:
            raise GcodeError(
                f"{label} cannot be checked: the job has not set the E mode (M82/M83 after "
                "G90/G91), and the one an earlier job left is unknown"
            )
        if relative:
            delta = value
            self.e = None if self.e is None else self.e + value
        elif self.e is None:
            raise GcodeError(
                f"{label} cannot be checked: absolute E from an unknown E position: set it "
                "with G92 E0 first, or use relative E (M83)"
            )
        else:
            delta, self.e = value - self.e, value
        return delta * self.flow_percent / 100.0

    def _G90(self, label: str, block: Block) -> None:
        self.modes.apply("G90")

    def _G91(self, label: str, block: Block) -> None:
        self.modes.apply("G91")

    def _M82(self, label: str, block: Block) -> None:
        self.modes.apply("M82")

    def _M83(self, label: str, block: Block) -> None:
        self.modes.apply("M83")

    def _G4(self, label: str, block: Block) -> None:
        """A dwell moves nothing (its time counts in fabkit.gcode.duration)."""

    def _G92(self, label: str, block: Block) -> None:
        """Set the logical position: the shift becomes machine - value (G92.cpp)."""
        if not block.values:
            raise GcodeError(
                f"{label} cannot be checked: without axis words Klipper sets every axis to 0 "
                "and Marlin does nothing"
            )
        for i, axis in enumerate(AXES):
            if axis in block.values:
                self.shift[i] = self.t.known(label, i) - block.values[axis]
        if "E" in block.values:
            self.e = block.values["E"]

    def _G28(self, label: str, block: Block) -> None:
        named = [i for i, axis in enumerate(AXES) if axis in block.values or axis in block.flags]
        for i in named or [0, 1, 2]:
            self.t.home(i)
            self.shift[i] = Span.at(0.0)
        if named and 2 not in named:
            self.t.lose(2, f"'{label}' may raise Z before homing (Z_HOMING_HEIGHT)")

    def _G29(self, label: str, block: Block) -> None:
        for i in range(3):
            self.t.lose(i, f"'{label}' probes the bed and leaves the head where it ends")

    def _M18(self, label: str, block: Block) -> None:
        """Motors off (unless S only sets the timeout): the axes may be pushed by hand."""
        if "S" in block.values:
            return
        named = [i for i, a in enumerate(AXES) if a in block.values or a in block.flags]
        stays_e = "E" in block.values or "E" in block.flags
        for i in named or ([] if stays_e else [0, 1, 2]):
            self.t.lose(i, f"'{label}' turned its motor off")

    _M84 = _M18

    def _M410(self, label: str, block: Block) -> None:
        for i in range(3):
            self.t.lose(i, f"'{label}' stopped the planned moves wherever they were")

    # -- overrides, pins, heaters ----------------------------------------------------------

    def _M220(self, label: str, block: Block) -> None:
        if "S" in block.values:
            self.feed_percent = self._percent(label, block.values["S"])

    def _M221(self, label: str, block: Block) -> None:
        if block.values.get("T", 0.0) != 0.0:
            raise GcodeError(f"{label} cannot be checked: the check follows extruder T0 only")
        if "S" in block.values:
            self.flow_percent = self._percent(label, block.values["S"])

    def _percent(self, label: str, value: float) -> float:
        """An override as the firmware keeps it (Marlin: a whole number, truncated)."""
        percent = float(int(value)) if self.flavour in ("marlin", "hyrel") else value
        if not 0 < percent <= MAX_OVERRIDE_PERCENT:
            raise GcodeError(
                f"{label}: an override must be between 1 and {MAX_OVERRIDE_PERCENT:g} %"
            )
        return percent

    def _M42(self, label: str, block: Block) -> None:
        if block.flags or not any(block.values == write.values for write in self.pin_writes):
            known = ", ".join(dict.fromkeys(_m42_text(w) for w in self.pin_writes)) or "none"
            raise GcodeError(
                f"{label} cannot be checked: M42 may only repeat a pin write of the machine's "
                f"own G-code ({known})"
            )

    def _M104(self, label: str, block: Block) -> None:
        self._heat(label, block, nozzle=True)

    _M109 = _M104

    def _M140(self, label: str, block: Block) -> None:
        self._heat(label, block, nozzle=False)

    _M190 = _M140

    def _heat(self, label: str, block: Block, *, nozzle: bool) -> None:
        code = block.codes[0]
        for letter in "SRB":
            if letter in block.values:
                self.t.temperature(code, letter, block.values[letter], nozzle)

    def _M568(self, label: str, block: Block) -> None:
        self._heat(label, block, nozzle=True)

    def _G10(self, label: str, block: Block) -> None:
        """RepRapFirmware: ``G10 P<tool> S R`` sets tool temperatures; anything else (work
        offsets with L, firmware retraction without P) is not modelled."""
        if "P" not in block.values or "L" in block.values or set(block.values) & set("XYZ"):
            raise GcodeError(
                f"{label} cannot be checked: only G10 P<tool> S<C> R<C> (temperatures) is modelled"
            )
        self._heat(label, block, nozzle=True)

    def _T0(self, label: str, block: Block) -> None:
        if self.flavour == "reprap":
            raise GcodeError(
                f"{label} cannot be checked: RepRapFirmware runs the tool change macros "
                "(tfree, tpre, tpost), which may move"
            )


def _number(label: str, text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise GcodeError(f"{label}: '{text}' is not a number") from None


def _m42_text(block: Block) -> str:
    return " ".join(["M42", *(f"{k}{v:g}" for k, v in block.values.items())])
