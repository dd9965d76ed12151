"""Read a G-code file back as the machine runs it: where material goes, and how.

Every command is read by the firmware's own reader (:mod:`fabkit.gcode.read`: GRBL, or
Marlin and the Marlin-likes) and followed through the machine's modal state: the position
(:class:`fabkit.gcode.position.Position`: absolute or relative positions (G90/G91) and E
(M82/M83, and G91 as each firmware reads it), G92 position shifts, homing (G28: the homed
axes at 0); E at 0 when the file starts, as a firmware powers up), the feed (F, mm/min), the
material switches of the profile (``flow_on_gcode`` / ``flow_off_gcode`` for the first
ink, ``ink2_on_gcode`` / ``ink2_off_gcode`` for the second: valves, a beam or tool
changes), the dispense pressure (the profile's ``[pressure]`` command ``S<n>``), the
nozzle temperature (M104/M109 S) and a mixing extruder's ratio (M163 S<i> P<w>, applied
by M164).

A move deposits material when E advances (machines whose flow follows E) or while a
material switch is on (the others). Each depositing move is a :class:`Segment` of a road;
a road ends where the machine stops depositing. Arcs (G2/G3) and positions the file never
sets are refused, naming the line. Nothing of the writer is used: the placement of the
sheet on the machine is read from fabkit's own header comments (``;fabkit ... offset
X,Y,Z mm`` and ``;fabkit scale: S mm per design unit``) when the file has them, and so
are the E units per mm^3 it was written with (``;fabkit E mode M, E units U, K E per
mm^3``: export's --e-units, --filament-diameter or --pulses-per-mm3 may differ from the
profile's tool, which gives them for any other file).
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fabkit.errors import FabkitError
from fabkit.gcode.columns import MoveRun, Rows, filled, job_spans, plain_codes
from fabkit.gcode.position import Position
from fabkit.gcode.read import (
    MAX_LINE_CHARS,
    Block,
    Command,
    GcodeError,
    firmware_reader,
    is_extended,
    read_job,
)
from fabkit.machines import MachineProfile

HEADER_LINES = 200
"""Leading lines searched for fabkit's placement comments."""
_OFFSET = re.compile(r";fabkit .*offset\s+([-+\d.eE]+),([-+\d.eE]+)(?:,([-+\d.eE]+))?\s*mm")
_SCALE = re.compile(r";fabkit scale:\s*([-+\d.eE]+)\s*mm per design unit")
_E_PER_MM3 = re.compile(r";fabkit E mode \S+, E units \S+, ([-+\d.eE]+) E per mm\^3")
_MARLIN_LIKE = ("marlin", "klipper", "reprap", "hyrel")


@dataclass(frozen=True)
class Placement:
    """Where the sheet sits on the machine: ``offset_mm`` (x, y) from the sheet's frame to
    the machine's, ``mm_per_unit`` its scale (None = unknown), and where they came from."""

    offset_mm: tuple[float, float] | None
    mm_per_unit: float | None
    source: str


@dataclass(frozen=True, eq=False)
class Printed:
    """What a G-code file deposits, machine coordinates, per depositing segment (n,):
    ``start``, ``end`` (n, 3) mm; ``feed`` mm/s; ``volume`` mm^3 (NaN without an E axis);
    ``pressure`` kPa, ``temperature`` C, ``mix`` the second ink's share of a mixing
    extruder (NaN where never set); ``ink`` 0/1 the ink switched on; ``road`` (n,) int.
    ``layers`` counts the heights printed at; ``placement`` from the header."""

    start: np.ndarray
    end: np.ndarray
    feed: np.ndarray
    volume: np.ndarray
    pressure: np.ndarray
    temperature: np.ndarray
    mix: np.ndarray
    ink: np.ndarray
    road: np.ndarray
    layers: int
    placement: Placement
    commands: int


_ACTIONS = {
    "flow_on_gcode": ("first", True),
    "flow_off_gcode": ("first", False),
    "ink2_on_gcode": ("second", True),
    "ink2_off_gcode": ("second", False),
}


class _Machine:
    """The modal state of one job (see the module docstring)."""

    def __init__(self, machine: MachineProfile, written_e_per_mm3: float | None = None) -> None:
        if machine.gcode is None:
            raise FabkitError(f"machine {machine.name} takes no G-code (flavour none)")
        self.machine = machine
        self.grbl = machine.flavour == "grbl"
        self.read = firmware_reader(machine)
        self.has_e = not machine.gcode.flow_on_gcode.strip()
        if not self.has_e:
            self.e_per_mm3 = 0.0
        elif written_e_per_mm3 is not None and written_e_per_mm3 > 0:
            self.e_per_mm3 = written_e_per_mm3  # what fabkit wrote it with (its options)
        else:
            self.e_per_mm3 = e_per_mm3(machine)
        self.switches = self._switches()
        self.pressure_block = self.read(machine.pressure.command) if machine.pressure else None
        self.position = Position.start("grbl" if self.grbl else machine.flavour, e_mm=0.0)
        self.feed = math.nan
        self.on = {"first": False, "second": False}
        self.pressure = math.nan
        self.temperature = math.nan
        self.weights = [math.nan, math.nan]
        self.mix = math.nan
        self.depositing = False
        self.road = -1
        self.rows = Rows(13)  # every depositing move's row, in the file's order
        # no switch or pressure line of the profile is a G0/G1 (then a plain move may be
        # one, which only the per-command path follows)
        own = [*self.switches, *([_signature(self.pressure_block)] if self.pressure_block else [])]
        self.moves_only_move = not any(sig[0] in (("G0",), ("G1",)) for sig in own)

    def _switches(self) -> dict[tuple, tuple[str, bool]]:
        """The profile's material switch lines, by their reading (a line that is both an
        on and an off of one ink is left out)."""
        found: dict[tuple, set[tuple[str, bool]]] = {}
        for key, action in _ACTIONS.items():
            for line in self.machine.render(key):
                found.setdefault(_signature(self.read(line)), set()).add(action)
        return {sig: next(iter(acts)) for sig, acts in found.items() if len(acts) == 1}

    def run(self, block: Block) -> None:
        action = self.switches.get(_signature(block))
        if action is not None:
            ink, state = action
            self.on[ink] = state
            return
        if self.pressure_block is not None and _is_pressure(block, self.pressure_block):
            self.pressure = float(self.machine.pressure.kpa(block.values["S"]))
            return
        for code in block.codes:
            if self.position.apply(code, block.values, block.flags):  # modes, G92, G28
                if code == "G28":
                    self.depositing = False  # homing ends the road
                continue
            handler = getattr(self, "_" + code.replace(".", "_"), None)
            if handler is not None:
                handler(block)

    def run_moves(self, run: MoveRun) -> bool:
        """A run of plain G0/G1 moves at once (:mod:`fabkit.gcode.columns`), giving the
        rows and state :meth:`run` of each would; False, with nothing changed, where the
        per-command path must take it (GRBL; a profile whose switch or pressure line is a
        plain move; material deposited from a position the file never set, which that
        path names)."""
        if self.grbl or not self.moves_only_move:
            return False
        position, saved = self.position, list(self.position.logical)
        feed = filled(self.feed, run.given[:, 4], run.values[run.given[:, 4], 4] / 60.0)
        moving = run.given[:, :4].any(axis=1)
        before = np.array([np.nan if v is None else v for v in saved])
        walked = position.walk(run.given[moving, :4], run.values[moving, :4])
        logical_before = np.vstack((before, walked[:-1]))
        shift = np.array([np.nan if v is None else v for v in position.shift])
        old, new = logical_before[:, :3] + shift, walked[:, :3] + shift
        delta_e = walked[:, 3] - logical_before[:, 3]
        delta_e[np.isnan(delta_e)] = 0.0  # an end unknown: no E counted
        moved = _differs(old[:, 0], new[:, 0]) | _differs(old[:, 1], new[:, 1])
        on = self.on["first"] or self.on["second"]
        flowing = delta_e > 0 if self.has_e else np.full(len(walked), on)
        deposit = flowing & moved
        if not np.isfinite(old[deposit]).all() or not np.isfinite(new[deposit]).all():
            position.logical = saved
            return False
        ends = ~deposit & (((moved | _differs(old[:, 2], new[:, 2])) & ~flowing) | (delta_e < 0))
        self.feed = float(feed[-1])
        self._add_rows(old, new, feed[moving], delta_e, deposit, ends)
        return True

    def _add_rows(
        self,
        old: np.ndarray,
        new: np.ndarray,
        feed: np.ndarray,
        delta_e: np.ndarray,
        deposit: np.ndarray,
        ends: np.ndarray,
    ) -> None:
        """The rows of a run's moves that deposit, numbered into roads as :meth:`_move`
        numbers them: a road starts at a depositing move after a move that ended one (a
        travel, a retraction) or at the first; other moves change nothing."""
        events = deposit | ends
        depositing = deposit[events]
        starts = depositing & ~np.r_[self.depositing, depositing[:-1]]
        roads = self.road + np.cumsum(starts)
        if len(depositing):
            self.depositing = bool(depositing[-1])
            self.road = int(roads[-1])
        volume = delta_e / self.e_per_mm3 if self.has_e else np.full(len(delta_e), np.nan)
        rows = np.empty((int(deposit.sum()), 13))
        rows[:, 0:3], rows[:, 3:6] = old[deposit], new[deposit]
        rows[:, 6], rows[:, 7] = feed[deposit], volume[deposit]
        rows[:, 8:11] = (self.pressure, self.temperature, self.mix)
        rows[:, 11] = 1 if self.on["second"] else 0
        rows[:, 12] = roads[depositing]
        self.rows.extend(rows)

    # -- motion ---------------------------------------------------------------------

    def _G2(self, block: Block) -> None:
        raise GcodeError("verify does not follow arcs (G2/G3)")

    _G3 = _G2

    def _G0(self, block: Block) -> None:
        self._move(block)

    _G1 = _G0

    # -- process state --------------------------------------------------------------

    def _M104(self, block: Block) -> None:
        if "S" in block.values:
            self.temperature = block.values["S"]

    _M109 = _M104

    def _M163(self, block: Block) -> None:
        index = int(block.values.get("S", -1))
        if index in (0, 1) and "P" in block.values:
            self.weights[index] = block.values["P"]

    def _M164(self, block: Block) -> None:
        total = self.weights[0] + self.weights[1]
        self.mix = self.weights[1] / total if total > 0 else math.nan

    # -- motion -------------------------------------------------------------------

    def _move(self, block: Block) -> None:
        values = block.values
        if "F" in values:
            self.feed = values["F"] / 60.0
        move = self.position.move(values)
        if move is None:
            return
        old = [math.nan if v is None else v for v in move.machine_start]
        new = [math.nan if v is None else v for v in move.machine_end]
        delta_e = move.deltas()[3]
        moved = _differ(old[0], new[0]) or _differ(old[1], new[1])
        flowing = delta_e > 0 if self.has_e else (self.on["first"] or self.on["second"])
        if not (flowing and moved):
            if ((moved or _differ(old[2], new[2])) and not flowing) or delta_e < 0:
                self.depositing = False  # a travel or a retraction ends the road
            return
        if not all(math.isfinite(v) for v in (*old, *new)):
            raise GcodeError("material is deposited from a position the file never set")
        if not self.depositing:
            self.road += 1
            self.depositing = True
        volume = delta_e / self.e_per_mm3 if self.has_e else math.nan
        self.rows.append(
            (
                *old,
                *new,
                self.feed,
                volume,
                self.pressure,
                self.temperature,
                self.mix,
                1 if self.on["second"] else 0,
                self.road,
            )
        )


def _differs(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """:func:`_differ` of each pair of ``a`` and ``b`` (n,)."""
    unknown = np.isnan(a) | np.isnan(b)
    with np.errstate(invalid="ignore"):
        return np.where(unknown, np.isnan(a) != np.isnan(b), np.abs(a - b) > 1e-9)


def _differ(a: float, b: float) -> bool:
    """Two coordinates differ (NaN = unknown differs from everything but NaN)."""
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) != math.isnan(b)
    return abs(a - b) > 1e-9


def _signature(block: Block) -> tuple:
    return (block.codes, tuple(sorted(block.values.items())), tuple(sorted(block.flags)))


def _is_pressure(block: Block, command: Block) -> bool:
    """``block`` is the pressure command with an S word."""
    if block.codes != command.codes or "S" not in block.values:
        return False
    return all(block.values.get(k) == v for k, v in command.values.items())


def e_per_mm3(machine: MachineProfile) -> float:
    """E units per mm^3 of material, from the profile's tool (docs/machines.md)."""
    units = machine.tool.e_units or ("volume" if machine.flavour == "hyrel" else "filament")
    if units == "volume":
        return 1.0
    if units == "pulses":
        if not machine.tool.pulses_per_mm3:
            raise FabkitError(
                f"machine {machine.name}: E counts pulses but [tool] pulses_per_mm3 is not set"
            )
        return float(machine.tool.pulses_per_mm3)
    return 4.0 / (math.pi * machine.tool.filament_diameter_mm**2)


def read_gcode(path: str | Path, machine: MachineProfile, *, fast: bool = True) -> Printed:
    """Read ``path`` as ``machine`` runs it (module docstring); one-line errors. On a
    Marlin-like firmware, runs of plain moves are read as columns
    (:mod:`fabkit.gcode.columns`; ``fast=False``: every command one at a time, the same
    result)."""
    path = Path(path)
    commands = read_job(path)
    header = _header(path)
    found = next(filter(None, map(_E_PER_MM3.search, header)), None)
    state = _Machine(machine, float(found.group(1)) if found else None)
    if fast and machine.flavour in _MARLIN_LIKE:
        codes = plain_codes(machine.flavour)
        for start, stop, run in job_spans(commands.texts, MAX_LINE_CHARS, codes, {}):
            if run is None or not state.run_moves(run):
                _run_each(state, commands[start:stop], path, machine.flavour)
    else:
        _run_each(state, commands, path, machine.flavour)
    rows = state.rows.array()
    start, end = rows[:, 0:3], rows[:, 3:6]
    heights = np.unique(np.round(start[:, 2], 6)) if len(rows) else np.zeros(0)
    return Printed(
        start=start,
        end=end,
        feed=rows[:, 6],
        volume=rows[:, 7],
        pressure=rows[:, 8],
        temperature=rows[:, 9],
        mix=rows[:, 10],
        ink=rows[:, 11].astype(np.int8),
        road=rows[:, 12].astype(np.int64),
        layers=len(heights),
        placement=read_placement(header, path.name),
        commands=len(commands),
    )


def _run_each(state: _Machine, commands: Sequence[Command], path: Path, flavour: str) -> None:
    """The per-command path: each of ``commands`` read and run (one-line errors naming
    the file line)."""
    for command in commands:
        text = command.text
        try:
            if flavour == "klipper" and is_extended(text):
                continue
            state.run(state.read(text))
        except GcodeError as exc:
            raise FabkitError(f"{path}:{command.file_line}: {exc}") from None


def _header(path: Path) -> list[str]:
    """The first :data:`HEADER_LINES` lines of a G-code file (fabkit's records are there)."""
    with path.open(encoding="ascii", errors="replace") as handle:
        return [line for _, line in zip(range(HEADER_LINES), handle, strict=False)]


def read_placement(header: list[str], name: str) -> Placement:
    """fabkit's placement comments among the ``header`` lines of the G-code file ``name``."""
    offset, scale = None, None
    for line in header:
        found = _OFFSET.search(line)
        if found:
            offset = (float(found.group(1)), float(found.group(2)))
        found = _SCALE.search(line)
        if found:
            scale = float(found.group(1))
    return Placement(offset, scale, f"{name} header")
