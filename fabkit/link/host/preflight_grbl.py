"""GRBL 1.1 (and grblHAL) blocks on the tracked machine: modal state, offsets, every motion.

Rules from gnea/grbl ``gcode.c`` (STEP 3, error checks; STEP 4, execution order):

* Machine position = work position + the active work offset (G54-G59, set in the
  controller or with ``G10 L2``/``L20``) + the ``G92`` offset + the tool length offset
  (Z, ``G43.1``). The job is assumed to start with G54 active and all three zero (the
  state after a reset); G55-G59 are unknown until the job sets them with G10.
* Modes persist across jobs, so the job must set what its moves rely on: units (G21),
  distance mode (G90/G91), feed mode (G94/G93), a motion word before bare axis words, a
  plane (G17-G19) before an arc, F before a feed move. A move that needs a mode the job
  has not set is refused.
* ``G28``/``G30`` go through the intermediate point their axis words give (a rapid move,
  checked) to the position stored with ``G28.1``/``G30.1``, unknown unless the job
  stored it. ``G53`` moves in machine coordinates. ``G93`` (inverse time): the move
  takes 60/F s, so its speed is its length times F/60. ``G38.x`` probes toward the target
  and stops anywhere on the way. ``G92.1``, ``G28.1``, ``G30.1`` with axis words also
  move (implicit motion mode). ``M2``/``M30`` reset G1, G17, G90, G94, G54, spindle and
  coolant off.
* A block GRBL answers with ``error:N`` is refused with that number; ``G0`` runs at the
  controller's own rates ($110-$112), which the profile's travel limit must cover.
"""

from __future__ import annotations

from fabkit.gcode.modes import DistanceModes
from fabkit.gcode.read import Block, GcodeError, grbl_reject
from fabkit.link.arcs import Arc, centre_arc, radius_arc
from fabkit.link.host.tracker import AXES, ArcMove, Span, Speed, Tracker

_MOTION = ("G0", "G1", "G2", "G3", "G38.2", "G38.3", "G38.4", "G38.5", "G80")
_NON_MODAL = ("G4", "G10", "G28", "G28.1", "G30", "G30.1", "G53", "G92", "G92.1")
_PLANES = {"G17": (0, 1, "IJ"), "G18": (2, 0, "KI"), "G19": (1, 2, "JK")}
_WCS = ("G54", "G55", "G56", "G57", "G58", "G59")
_LENGTH_WORDS = "XYZIJKR"
MAX_LINE_NUMBER = 10_000_000


class GrblDialect:
    """The GRBL parser state of one job (see the module docstring)."""

    def __init__(self, tracker: Tracker, extra_axes: str = "") -> None:
        self.t = tracker
        self.extra = extra_axes
        self.units_mm: bool | None = None
        self.modes = DistanceModes("grbl")  # G90/G91 (GRBL has no E)
        self.inverse_time: bool | None = None
        self.motion: str | None = None
        self.plane: str | None = None
        self.feed: float | None = None  # mm/min (G94) or 1/min (G93)
        self.wcs: list[list[Span | None]] = [[Span.at(0.0)] * 3] + [[None] * 3 for _ in range(5)]
        self.active = 0
        self.g92 = [Span.at(0.0)] * 3
        self.tlo = 0.0
        self.stored: dict[str, list[Span | None]] = {"G28": [None] * 3, "G30": [None] * 3}

    # -- one block ---------------------------------------------------------------------

    def run(self, text: str, block: Block) -> None:
        """Check one block and apply it (GcodeError at the first problem)."""
        if block.codes[:1] and block.codes[0].startswith("$"):
            self._system(block.codes[0])
            return
        self._block(_Parsed(self, text, block))

    def _system(self, code: str) -> None:
        if code != "$H":
            raise GcodeError(f"unknown command {code} for flavour grbl")
        for i in range(3):
            self.t.home(i)

    def _block(self, p: _Parsed) -> None:
        self._units(p)
        self._check_words(p)
        if "S" in p.values and self.t.machine.kind == "laser_writer":
            self.t.power(p.label, p.values["S"])
        self.plane = p.plane
        self.units_mm = p.units_mm
        self._tool_length(p)
        self.active = p.wcs
        for code in p.g:
            self.modes.apply(code)
        self._non_modal(p)
        self.inverse_time = p.inverse
        self.feed = p.feed
        self._motion(p)
        if "M2" in p.m or "M30" in p.m:
            self._program_end()

    def _units(self, p: _Parsed) -> None:
        length_words = any(letter in p.values for letter in _LENGTH_WORDS + "F" + self.extra)
        if length_words and p.units_mm is None:
            raise GcodeError(
                f"{p.label} cannot be checked: no G21 in the job before it, and the units an "
                "earlier job left are unknown (put G21 at the top)"
            )

    # -- error checks (gcode.c STEP 3) -------------------------------------------------

    def _check_words(self, p: _Parsed) -> None:
        """GRBL's block errors that need the modal state, then its unused-word rule."""
        if p.values.get("N", 0.0) > MAX_LINE_NUMBER:
            raise p.reject(27, "line number above 10000000")
        if "G4" in p.g and "P" not in p.values:
            raise p.reject(28, "G4 needs P (seconds)")
        if p.axis_command == "tool" and "G43.1" in p.g and set(p.axes) != {"Z"}:
            raise p.reject(37, "G43.1 takes exactly one Z word")
        if "G10" in p.g:
            self._check_g10(p)
        if ("G92" in p.g or "G10" in p.g) and not p.axes:
            raise p.reject(26, "no axis words")
        if "G53" in p.g and p.motion not in ("G0", "G1"):
            raise p.reject(30, "G53 needs G0 or G1")
        if p.motion == "G80" and p.axes:
            raise p.reject(31, "axis words with G80 (no motion mode)")
        used = set("NFST")
        if p.axis_command:
            used |= set("XYZ" + self.extra)
        if "G4" in p.g or "G10" in p.g or "M56" in p.m:
            used.add("P")
        if "G10" in p.g:
            used.add("L")
        if p.axis_command == "motion" and p.motion in ("G2", "G3"):
            used |= {"R"} if "R" in p.values else set("IJK")
        unused = sorted(set(p.values) - used)
        if unused:
            raise p.reject(36, f"unused word {unused[0]}")

    @staticmethod
    def _check_g10(p: _Parsed) -> None:
        if "P" not in p.values or "L" not in p.values:
            raise p.reject(28, "G10 needs P and L")
        if p.values["L"] not in (2.0, 20.0):
            raise p.reject(20, "only G10 L2 and L20 are supported")
        if not float(p.values["P"]).is_integer() or p.values["P"] > 6:
            raise p.reject(29, "G10 P must be a whole number 0-6")
        if p.values["L"] == 2.0 and "R" in p.values:
            raise p.reject(20, "G10 L2 takes no R")

    # -- execution (gcode.c STEP 4) ----------------------------------------------------

    def _tool_length(self, p: _Parsed) -> None:
        if "G49" in p.g:
            self.tlo = 0.0
        elif "G43.1" in p.g:
            self.tlo = p.values["Z"]

    def _non_modal(self, p: _Parsed) -> None:
        code = p.non_modal
        if code == "G10":
            self._set_wcs(p)
        elif code == "G92":  # G92 = MPos - G5x - TLO - value
            for i in p.axis_indices:
                here = self.t.known(p.label, i) - self._wcs(p, i, p.wcs)
                self.g92[i] = here - (self.tlo if i == 2 else 0.0) - p.values[AXES[i]]
        elif code == "G92.1":
            self.g92 = [Span.at(0.0)] * 3
        elif code in ("G28.1", "G30.1"):
            self.stored[code[:3]] = list(self.t.pos)
        elif code in ("G28", "G30"):
            self._go_home(p, code)

    def _set_wcs(self, p: _Parsed) -> None:
        """G10 L2 sets a work offset; L20 sets it so that the current position reads the
        given value (WCS = MPos - G92 - TLO - value)."""
        number = int(p.values["P"])
        index = number - 1 if number > 0 else p.wcs
        for i in p.axis_indices:
            value = p.values[AXES[i]]
            if p.values["L"] == 2.0:
                self.wcs[index][i] = Span.at(value)
            else:
                here = self.t.known(p.label, i) - self.g92[i] - (self.tlo if i == 2 else 0.0)
                self.wcs[index][i] = here - value

    def _go_home(self, p: _Parsed, code: str) -> None:
        """G28/G30: rapid to the intermediate point (if axis words), then to the stored one."""
        stored = self.stored[code]
        if p.axis_indices:
            self.t.move(p.label, self._targets(p), speed=Speed("rapid"))
        moving = p.axis_indices or [0, 1, 2]
        for i in moving:
            if stored[i] is None:
                raise GcodeError(
                    f"{p.label} cannot be checked: it goes on to the {AXES[i]} position stored "
                    f"in the controller by {code}.1, which the job has not set"
                )
        end = list(self.t.pos)
        for i in moving:
            end[i] = stored[i]
        self.t.move(p.label, end, speed=Speed("rapid"))

    def _motion(self, p: _Parsed) -> None:
        if p.motion_word is None and p.axis_command != "motion":
            return
        if p.motion is None:
            raise GcodeError(
                f"{p.label} cannot be checked: axis words without G0/G1 before any motion "
                "word in the job, and the motion mode an earlier job left is unknown"
            )
        self.motion = p.motion
        if p.axis_command != "motion" or p.motion == "G80":
            return
        speed = self._speed(p)
        if not p.axes:
            if p.motion in ("G2", "G3") or p.motion.startswith("G38"):
                raise p.reject(26, "no axis words")
            return
        if p.extra_axes and p.motion not in ("G0", "G1"):
            raise GcodeError(
                f"{p.label} cannot be checked: {p.extra_axes} is followed with G0/G1 only"
            )
        end = self._targets(p)
        if p.motion in ("G2", "G3"):
            self.t.move(p.label, end, speed=speed, arc=self._arc(p, end))
        elif p.motion.startswith("G38"):
            if _same(self.t.pos, end):
                raise p.reject(33, "the probe target is the current position")
            self.t.probe(p.label, end, speed)
        else:
            self.t.move(p.label, end, speed=speed)

    def _speed(self, p: _Parsed) -> Speed:
        if p.motion == "G0":
            return Speed("rapid")
        if p.inverse is None:
            raise GcodeError(
                f"{p.label} cannot be checked: no G94/G93 in the job before it, and the feed "
                "mode an earlier job left is unknown"
            )
        if p.inverse and p.motion.startswith("G38"):
            raise GcodeError(f"{p.label} cannot be checked: a probe in inverse-time mode (G93)")
        if not p.feed:
            raise GcodeError(f"{p.motion} before any feed rate (F) was set")
        if p.inverse:
            return Speed("duration", 60.0 / p.feed)
        return Speed("feed", p.feed / 60.0)

    def _targets(self, p: _Parsed) -> list[Span | None]:
        """Machine coordinates of the block's axis words (G53: as given)."""
        end = list(self.t.pos)
        for i in p.axis_indices:
            value = p.values[AXES[i]]
            if "G53" in p.g:
                end[i] = Span.at(value)
            elif p.absolute is None:
                raise GcodeError(
                    f"{p.label} cannot be checked: no G90/G91 in the job before it, and the "
                    "distance mode an earlier job left is unknown"
                )
            elif p.absolute:
                end[i] = self._offset(p, i) + value
            else:
                end[i] = self.t.relative(p.label, i, value)
        return end

    def _offset(self, p: _Parsed, i: int) -> Span:
        """Work to machine offset of axis ``i``: G5x + G92 (+ tool length on Z)."""
        offset = self._wcs(p, i, p.wcs) + self.g92[i]
        return offset + self.tlo if i == 2 else offset

    def _wcs(self, p: _Parsed, i: int, index: int) -> Span:
        span = self.wcs[index][i]
        if span is None:
            raise GcodeError(
                f"{p.label} cannot be checked: the {_WCS[index]} offset of {AXES[i]} is stored "
                f"in the controller; set it in the job first (G10 L2 P{index + 1})"
            )
        return span

    def _arc(self, p: _Parsed, end: list[Span | None]) -> ArcMove:
        if p.plane is None:
            raise GcodeError(
                f"{p.label} cannot be checked: no G17/G18/G19 in the job before this arc, and "
                "the plane an earlier job left is unknown"
            )
        a, b, offsets = _PLANES[p.plane]
        if AXES[a] not in p.values and AXES[b] not in p.values:
            raise p.reject(32, "no axis words in the arc's plane")
        start = [self.t.known(p.label, i) for i in (a, b)]
        stop = [end[a], end[b]]
        if not all(s.exact for s in start + stop if s is not None):
            raise GcodeError(f"{p.label} cannot be checked: an arc from or to an uncertain point")
        s0, s1, e0, e1 = start[0].lo, start[1].lo, stop[0].lo, stop[1].lo
        clockwise = p.motion == "G2"
        if "R" in p.values:
            if _same(self.t.pos, end):
                raise p.reject(33, "an R arc needs an end point different from its start")
            arc: Arc = radius_arc((s0, s1), (e0, e1), p.values["R"], clockwise)
        else:
            if not any(letter in p.values for letter in offsets):
                raise p.reject(35, "no arc centre offsets in the plane")
            offset = (p.values.get(offsets[0], 0.0), p.values.get(offsets[1], 0.0))
            arc = centre_arc((s0, s1), (e0, e1), offset, clockwise)
        return ArcMove(arc, a, b)

    def _program_end(self) -> None:
        """M2/M30: the modes LinuxCNC resets (gcode.c [21. Program flow])."""
        self.motion, self.plane, self.inverse_time = "G1", "G17", False
        self.modes.apply("G90")
        self.active = 0
        self.t.flow_on = False


class _Parsed:
    """One block's words and the modes it runs in (the block's own mode words first)."""

    def __init__(self, dialect: GrblDialect, text: str, block: Block) -> None:
        self.text = text
        self.g = [c for c in block.codes if c.startswith("G")]
        self.m = [c for c in block.codes if c.startswith("M")]
        self.values = dict(block.values)
        self.label = text if len(text) <= 40 else text[:37] + "..."
        self.axes = [a for a in "XYZ" + dialect.extra if a in self.values]
        self.axis_indices = [i for i, a in enumerate(AXES) if a in self.values]
        self.extra_axes = "".join(a for a in dialect.extra if a in self.values)
        self.motion_word = next((c for c in self.g if c in _MOTION), None)
        self.non_modal = next((c for c in self.g if c in _NON_MODAL), None)
        self.axis_command = self._axis_command()
        self.motion = self.motion_word or dialect.motion
        self.plane = next((c for c in self.g if c in _PLANES), dialect.plane)
        self.absolute = _mode(self.g, "G90", "G91", dialect.modes.absolute)
        self.units_mm = True if "G21" in self.g else dialect.units_mm
        self.inverse = _mode(self.g, "G93", "G94", dialect.inverse_time)
        self.wcs = next((_WCS.index(c) for c in self.g if c in _WCS), dialect.active)
        self.feed = self._feed(dialect)
        if self.extra_axes and (self.non_modal or self.axis_command != "motion"):
            raise GcodeError(
                f"{self.label} cannot be checked: {self.extra_axes} is followed with G0/G1 only"
            )

    def reject(self, number: int, reason: str) -> GcodeError:
        return grbl_reject(self.text, number, reason)

    def _axis_command(self) -> str | None:
        """What the axis words mean (gcode.c STEP 2 and [0.]): a motion, a non-modal command's
        data (G10, G28, G30, G92), a tool length offset, or nothing."""
        kinds = []
        if self.non_modal in ("G10", "G28", "G30", "G92"):
            kinds.append("non-modal")
        if self.motion_word not in (None, "G80"):
            kinds.append("motion")
        if "G43.1" in self.g or "G49" in self.g:
            kinds.append("tool")
        if len(kinds) > 1:
            raise self.reject(24, "two commands that use axis words")
        if kinds:
            return kinds[0]
        return "motion" if self.axes else None

    def _feed(self, dialect: GrblDialect) -> float | None:
        """The feed after this block: in G93 only the block's F (required on a feed move);
        in G94 the block's F or the last one, undefined after leaving G93."""
        given = self.values.get("F")
        if self.inverse:
            feed_move = self.axis_command == "motion" and self.motion not in ("G0", "G80", None)
            if feed_move and given is None:
                raise self.reject(22, "G93 (inverse time) needs F on every feed move")
            return given
        if given is not None:
            if given <= 0:
                raise GcodeError(f"feed F{given:g} must be positive")
            return given
        return dialect.feed if dialect.inverse_time is False else None


def _same(a: list[Span | None], b: list[Span | None]) -> bool:
    """The two positions are the same (unknown axes only where both are unknown)."""
    return all(x is y or (x is not None and x == y) for x, y in zip(a, b, strict=True))


def _mode(codes: list[str], on: str, off: str, current: bool | None) -> bool | None:
    if on in codes:
        return True
    if off in codes:
        return False
    return current
