"""G-code writer: a :class:`~fabkit.toolpath.model.Toolpath` as a machine's G-code file.

The toolpath (sheet frame, mm, mm/s) is placed on the machine (see
:mod:`fabkit.writers.common`) and turned into one table of rows, built with numpy for
all moves at once and formatted by :func:`fabkit.writers.line_table.render`:

* travels: retraction (E-axis machines), lift to ``max z + travel_lift_mm``, ``G0`` along
  the travel polyline, lowering, un-retraction. Travels shorter than
  ``retract_min_travel_mm`` neither lift nor retract. A print move that does not start
  where the previous move ended gets such a travel inserted.
* prints: ``G1`` to every vertex with ``F`` = speed x 60 (mm/min) and, on E-axis
  machines, E from the deposited volume ``length x width x layer height x flow`` (mm^3):
  E = volume x 4 / (pi d^2) for filament of diameter d, E = volume for ``volume`` units,
  E = volume x pulses per mm^3 for a pulse extruder. Absolute (M82) or relative (M83) E;
  relative values are differences of the rounded running total, so they add up exactly.
* machines without an E axis (pneumatic dispensers, beams: the profile's
  ``flow_on_gcode`` is not empty) get ``flow_on_gcode`` before and ``flow_off_gcode``
  after every print move; at constant pressure the volume per mm goes as 1 / speed, so
  the flow multiplier is written as feed = speed / flow. With *nominal E* (``[tool]
  nominal_e``, ``fabkit export --nominal-e``; Marlin only) such a machine's print moves
  also carry E, the road's volume as filament of ``filament_diameter_mm`` (M83 or M82),
  so that slicer G-code viewers draw the roads as extrusions of their width; the
  firmware ignores it (no extruder, or a cold one) and the valve still switches the flow.
  Its rate is checked against ``[limits] e_mm_s`` all the same (as the link's check
  does), so that a firmware with a working E axis could never slow a road for it.
* channels (one per feature, :attr:`Toolpath.channels`): ``print_speed_mm_s`` is the
  feed ``F``; ``extrusion_multiplier`` the E volume (or the feed on a machine without an
  E axis, when speed is not a channel too); ``line_spacing_mm`` is in the road positions;
  ``temperature_c`` is ``M104 S<C>``, ``pressure_kpa`` the profile's ``[pressure]``
  command ``S<n>``, and a mixing extruder's ``ink_fraction`` ``M163 S0 P<1-f>``,
  ``M163 S1 P<f>``, ``M164 S0``, each written before the first vertex where its written
  value (whole degrees, whole S steps, hundredths) changes. On a machine that alternates
  two inks, every road is cut into runs of one ink no shorter than ``[inks] piece_mm``
  (two-dimensional error diffusion, :mod:`fabkit.writers.inks`), each run bracketed by
  its ink's on and off G-code. A channel the machine cannot emit is refused, naming it.

Comments that slicer viewers read (Cura's ``plugins/GCodeReader/FlavorParser.py``,
PrusaSlicer's ``GCodeProcessor``): a header with ``;FLAVOR:``, ``;TIME:`` (s),
``;Filament used:`` (m), ``;LAYER_COUNT:``, the bounds, PrusaSlicer's estimated time and
filament lines; then at every layer ``;LAYER:n`` (n from 0), ``;TYPE:FILL`` (Cura's name
for infill: every road of a sheet is fill) and ``;HEIGHT:h`` (mm), and ``;WIDTH:w`` (mm,
to the micrometre) before the first print segment and wherever the road width changes.
Viewers tell extrusions from travels by E, hence nominal E above. X, Y, Z are written
only when they change, F when it changes or the motion word changes (G0 and G1 keep
separate feeds on some firmware).

Every row is checked before anything is written: positions inside the envelope (with
the lift), feeds within the print, travel and per-axis limits, E rate within the E limit,
temperature within the nozzle maximum; the first violation is a one-line
:class:`~fabkit.errors.FabkitError` naming the layer, move and vertex.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

import fabkit
from fabkit.atomic import atomic_path
from fabkit.errors import FabkitError
from fabkit.machines import MachineProfile
from fabkit.toolpath.model import PRINT, Toolpath
from fabkit.writers.common import placement_offset
from fabkit.writers.inks import alternate_inks
from fabkit.writers.line_table import Word, render

E_MODES = ("absolute", "relative")
E_UNITS = ("filament", "volume", "pulses")
DEFAULT_RETRACT_MIN_TRAVEL_MM = 1.0
"""Travels shorter than this (mm) neither lift nor retract (slicers' "minimum travel")."""

_FLAVOUR_NAMES = {
    "marlin": "Marlin",
    "klipper": "Klipper",
    "reprap": "RepRap",
    "grbl": "GRBL",
    "hyrel": "Hyrel",
}
# Columns of the row table, and how each is written.
_L, _X, _Y, _Z, _E, _F, _S, _P, _W = range(9)
_WORDS = (
    Word("", 0),
    Word(" X", 3),
    Word(" Y", 3),
    Word(" Z", 3),
    Word(" E", 5),
    Word(" F", 1),
    Word(" S", 0),
    Word(" P", 2),
    Word("", 3),
)
_XYZ_SCALE, _E_SCALE, _F_SCALE = 1e3, 1e5, 1e1
# Row prefixes: the fixed vocabulary, then the profile's snippets.
_G0, _G1, _LAYER, _TYPE, _HEIGHT, _WIDTH, _M104, _M163, _M164 = range(9)
_FLOW_ON, _FLOW_OFF, _INK2_ON, _INK2_OFF, _PRESSURE = range(9, 14)
_PREFIXES = (
    "G0", "G1", ";LAYER:", ";TYPE:FILL", ";HEIGHT:", ";WIDTH:", "M104", "M163", "M164"
)  # fmt: skip
WIDTH_STEP_MM = 1e-3
"""``;WIDTH:`` is written to the micrometre, and again only where that value changes."""
# Order of rows inside one move (slot in the sort key). Vertex k's row comes at
# _VERTEX + 2 k - 1, the channel commands for its segment just before it (for the first
# segment: at _S_CHANNELS, before the flow is turned on).
_S_LAYER, _S_TYPE, _S_RETRACT, _S_LIFT, _S_CHANNELS, _S_FLOW_ON, _VERTEX = range(7)
MIX_STEP = 0.01
"""Mixing ratios are written in hundredths."""
SUPPORTED = {
    "print_speed_mm_s": "the feed F",
    "extrusion_multiplier": "the E volume (or the feed without an E axis)",
    "line_spacing_mm": "the road positions",
    "temperature_c": "M104 S",
    "pressure_kpa": "the [pressure] command",
    "ink_fraction": "alternating inks ([inks] alternate) or M163/M164 ([inks] mixing)",
}
"""The channels a G-code file can carry, and how (some need the profile's support)."""


@dataclass(frozen=True)
class GcodeOptions:
    """Choices the profile does not fix; None means "from the profile, else the default".

    ``e_mode``: "absolute" (M82) or "relative" (M83); default: what the profile's start
    G-code selects, else relative. ``e_units``: "filament" (mm of filament), "volume"
    (mm^3 = uL) or "pulses"; default "volume" for flavour hyrel, else "filament".
    ``offset_mm``: sheet-to-machine offset (x, y[, z]); default: centred on the bed.
    ``nominal_e``: write nominal E on a Marlin machine without an E axis (module
    docstring); default: the profile's ``[tool] nominal_e``.
    """

    e_mode: str | None = None
    e_units: str | None = None
    filament_diameter_mm: float | None = None
    pulses_per_mm3: float | None = None
    offset_mm: tuple[float, ...] | None = None
    retract_min_travel_mm: float = DEFAULT_RETRACT_MIN_TRAVEL_MM
    nominal_e: bool | None = None


@dataclass(frozen=True)
class GcodeSummary:
    """What was written: counts, lengths (mm), volume (mm^3), E total, time (s), bounds."""

    lines: int
    motion_lines: int
    print_length_mm: float
    travel_length_mm: float
    volume_mm3: float
    e_total: float
    duration_s: float
    low_mm: tuple[float, float, float]
    high_mm: tuple[float, float, float]
    offset_mm: tuple[float, float, float]
    e_mode: str
    e_units: str
    nominal_e: bool = False


@dataclass(frozen=True)
class _Setup:
    """The resolved settings of one job."""

    has_e: bool
    e_mode: str
    e_units: str
    e_per_mm3: float
    lift_mm: float
    retract: float
    retract_feed: float
    z_feed: float
    travel_feed: float
    min_travel_mm: float
    flow_on: str
    flow_off: str
    ink2_on: str = ""
    ink2_off: str = ""
    pressure: str = ""
    inks: str = ""
    piece_mm: float = 0.0
    s_per_kpa: float = 0.0
    nominal_e: bool = False


def write_gcode(
    toolpath: Toolpath,
    machine: MachineProfile,
    path: str | Path,
    options: GcodeOptions | None = None,
) -> GcodeSummary:
    """Check and write ``toolpath`` as G-code for ``machine`` at ``path`` (atomically)."""
    text, summary = gcode_bytes(toolpath, machine, options)
    with atomic_path(path) as tmp:
        tmp.write_bytes(text)
    return summary


def gcode_bytes(
    toolpath: Toolpath, machine: MachineProfile, options: GcodeOptions | None = None
) -> tuple[bytes, GcodeSummary]:
    """The whole G-code file as ASCII bytes, and its summary; raises before any output."""
    options = options or GcodeOptions()
    setup = _setup(machine, options)
    check_channels(toolpath, machine)
    paths = _Paths.gather(toolpath, machine, options.offset_mm, setup)
    rows = _rows(paths, setup, toolpath)
    rows = _slow_travels(rows, machine)
    kinematics = _Kinematics.of(rows)
    _check(rows, kinematics, paths, machine, toolpath, setup.nominal_e)
    summary = _summary(rows, kinematics, paths, setup)
    rows = rows.modal(setup)
    body = render(rows.prefix, _prefixes(setup), rows.values, rows.present, _WORDS)
    head = _header(summary, toolpath, machine, setup)
    text = head + body + _lines(machine.render("end_gcode"))
    return text, replace(summary, lines=text.count(b"\n"), motion_lines=int(rows.motion().sum()))


def _setup(machine: MachineProfile, options: GcodeOptions) -> _Setup:
    if machine.gcode is None:
        raise FabkitError(
            f"machine {machine.name} takes no G-code (flavour none); use --format laser"
        )
    has_e = not machine.gcode.flow_on_gcode.strip()
    nominal = _nominal_e(machine, options, has_e)
    e_mode = options.e_mode or _profile_e_mode(machine)
    if e_mode not in E_MODES:
        raise FabkitError(f"E mode '{e_mode}' is not one of {', '.join(E_MODES)}")
    units = (
        "filament"
        if nominal
        else (
            options.e_units
            or machine.tool.e_units
            or ("volume" if machine.flavour == "hyrel" else "filament")
        )
    )
    if units not in E_UNITS:
        raise FabkitError(f"E units '{units}' is not one of {', '.join(E_UNITS)}")
    tool, limits = machine.tool, machine.limits
    return _Setup(
        has_e=has_e,
        e_mode=e_mode if has_e or nominal else "none",
        e_units=units if has_e or nominal else "none",
        e_per_mm3=_e_per_mm3(machine, options, units) if has_e or nominal else 0.0,
        lift_mm=tool.travel_lift_mm,
        retract=tool.retract_mm if has_e else 0.0,
        retract_feed=tool.retract_speed_mm_s * 60.0,
        z_feed=limits.z_mm_s * 60.0,
        travel_feed=machine.process.travel_speed_mm_s * 60.0,
        min_travel_mm=options.retract_min_travel_mm,
        flow_on=_snippet(machine, "flow_on_gcode"),
        flow_off=_snippet(machine, "flow_off_gcode"),
        ink2_on=_snippet(machine, "ink2_on_gcode"),
        ink2_off=_snippet(machine, "ink2_off_gcode"),
        pressure=machine.pressure.command if machine.pressure else "",
        inks=machine.inks.method if machine.inks else "",
        piece_mm=machine.inks.piece_mm if machine.inks else 0.0,
        s_per_kpa=(
            machine.pressure.s_max / machine.pressure.full_scale_kpa if machine.pressure else 0.0
        ),
        nominal_e=nominal,
    )


def _nominal_e(machine: MachineProfile, options: GcodeOptions, has_e: bool) -> bool:
    """Whether to write nominal E (module docstring); refuses it where it is not safe."""
    nominal = machine.tool.nominal_e if options.nominal_e is None else options.nominal_e
    if nominal and has_e:
        raise FabkitError(
            f"nominal E is for machines without an E axis; the flow of {machine.name} "
            "follows E already (its flow_on_gcode is empty)"
        )
    if nominal and machine.flavour != "marlin":
        raise FabkitError(
            f"nominal E needs flavour marlin (whose firmware ignores E without a hot "
            f"extruder); {machine.name} is flavour {machine.flavour}, which may refuse E words"
        )
    return nominal


def check_channels(toolpath: Toolpath, machine: MachineProfile) -> None:
    """Refuse, naming it, a channel of ``toolpath`` that ``machine``'s G-code cannot carry."""
    for name in toolpath.channels:
        reason = _unsupported(name, toolpath, machine)
        if reason:
            raise FabkitError(
                f"machine {machine.name} cannot carry the {name} channel "
                f"({toolpath.channels[name] or 'a feature'}) in G-code: {reason}"
            )


def _unsupported(name: str, toolpath: Toolpath, machine: MachineProfile) -> str:
    """Why the G-code for ``machine`` cannot carry channel ``name`` ("" if it can)."""
    gcode = machine.gcode
    has_e = gcode is not None and not gcode.flow_on_gcode.strip()
    if name not in SUPPORTED:
        return (
            "it is written by the laser writer (--format laser)"
            if "dose" in name
            else ("no G-code command sets it")
        )
    if name == "extrusion_multiplier" and not has_e and "print_speed_mm_s" in toolpath.channels:
        return (
            "without an E axis the multiplier is written as the feed (speed / multiplier), "
            "which the print_speed_mm_s channel already sets; encode the flow as pressure_kpa"
        )
    if name == "temperature_c":
        if machine.flavour == "grbl":
            return "GRBL has no temperature command"
        if machine.temperature.nozzle_max_c <= 0:
            return "it has no nozzle heater ([temperature] nozzle_max_c = 0)"
    if name == "pressure_kpa" and machine.pressure is None:
        return "its profile has no [pressure] table (the command that sets the pressure)"
    if name == "ink_fraction" and machine.inks is None:
        return "its profile has no [inks] table (a second ink: alternating, or a mixing extruder)"
    return ""


def _profile_e_mode(machine: MachineProfile) -> str:
    """The E mode the start G-code selects (the last M82/M83 in it), else relative."""
    mode = "relative"
    for line in machine.render("start_gcode"):
        word = line.split(";")[0].split()
        if word and word[0].upper() in ("M82", "M83"):
            mode = "absolute" if word[0].upper() == "M82" else "relative"
    return machine.tool.e_mode or mode


def _e_per_mm3(machine: MachineProfile, options: GcodeOptions, units: str) -> float:
    if units == "volume":
        return 1.0
    if units == "pulses":
        pulses = options.pulses_per_mm3 or machine.tool.pulses_per_mm3
        if not pulses or pulses <= 0:
            raise FabkitError("E units 'pulses' need pulses per mm^3 (--pulses-per-mm3)")
        return float(pulses)
    diameter = options.filament_diameter_mm or machine.tool.filament_diameter_mm
    if diameter <= 0:
        raise FabkitError(f"filament diameter must be > 0 mm, got {diameter}")
    return 4.0 / (math.pi * diameter**2)


def _snippet(machine: MachineProfile, key: str) -> str:
    return "\n".join(machine.render(key))


def _prefixes(setup: _Setup) -> tuple[str, ...]:
    return (
        *_PREFIXES,
        setup.flow_on,
        setup.flow_off,
        setup.ink2_on,
        setup.ink2_off,
        setup.pressure,
    )


def _lines(lines: list[str]) -> bytes:
    return "".join(f"{line}\n" for line in lines).encode("ascii")


@dataclass(frozen=True)
class _Paths:
    """All moves flattened in machine coordinates, with inserted travels.

    Vertex arrays (V,): xyz (V, 3) mm, width mm, speed mm/s, flow, and every channel
    (NaN on travels); move arrays (M,): start (M + 1,) vertex offsets, printing flag,
    layer index, and the index of the source move in ``toolpath.moves()`` (-1 for an
    inserted travel).
    """

    xyz: np.ndarray
    width: np.ndarray
    speed: np.ndarray
    flow: np.ndarray
    channels: dict[str, np.ndarray]
    start: np.ndarray
    printing: np.ndarray
    layer: np.ndarray
    source: np.ndarray
    offset: np.ndarray

    @classmethod
    def gather(
        cls,
        toolpath: Toolpath,
        machine: MachineProfile,
        offset: tuple[float, ...] | None,
        setup: _Setup,
    ) -> _Paths:
        moves = list(toolpath.moves())
        if not any(m.kind == PRINT for _, m in moves):
            raise FabkitError("the toolpath has no print moves: nothing to write")
        counts = np.array([len(m.xyz) for _, m in moves])
        fields = {
            name: np.concatenate([getattr(m, name) for _, m in moves])
            for name in ("xyz", "width", "speed", "flow")
        }
        for name in toolpath.channels:
            fields[name] = np.concatenate([m.channels[name] for _, m in moves])
        shift = placement_offset(*_bounds(fields["xyz"]), machine, offset)
        fields["xyz"] += shift
        start = np.concatenate([[0], np.cumsum(counts)])
        printing = np.array([m.kind == PRINT for _, m in moves])
        layer = np.array([i for i, _ in moves])
        return cls._with_travels(fields, start, printing, layer, shift, setup)

    @classmethod
    def _with_travels(
        cls,
        fields: dict[str, np.ndarray],
        start: np.ndarray,
        printing: np.ndarray,
        layer: np.ndarray,
        shift: np.ndarray,
        setup: _Setup,
    ) -> _Paths:
        """Insert a 2-vertex travel before every move that does not start where the last
        move ended (and before the first move, from an unknown position: NaN)."""
        xyz = fields["xyz"]
        first = xyz[start[:-1]]
        previous = np.vstack([np.full((1, 3), np.nan), xyz[start[1:-1] - 1]])
        jump = ~(np.abs(first - previous) <= 1e-6).all(axis=1)
        n_moves = len(printing)
        counts = np.diff(start) + 2 * jump
        new_start = np.concatenate([[0], np.cumsum(counts)])
        inserted = np.cumsum(jump)
        owner = np.repeat(np.arange(n_moves), np.diff(start))
        old_index = np.arange(len(xyz)) + 2 * inserted[owner]
        total = new_start[-1]
        out = {
            "xyz": np.empty((total, 3)),
            "width": np.zeros(total),
            "speed": np.full(total, setup.travel_feed / 60.0),
            "flow": np.zeros(total),
        }
        out.update({name: np.full(total, np.nan) for name in fields if name not in out})
        for name, array in out.items():
            array[old_index] = fields[name]
        jumps = np.flatnonzero(jump)
        travel_at = new_start[jumps]
        out["xyz"][travel_at] = previous[jumps]
        out["xyz"][travel_at + 1] = first[jumps]
        # move table: an inserted travel precedes its move
        move_counts = np.ones(n_moves, dtype=int) + jump
        moves = np.repeat(np.arange(n_moves), move_counts)
        is_inserted = np.zeros(len(moves), dtype=bool)
        is_inserted[np.cumsum(move_counts)[jump] - 2] = True
        lengths = np.where(is_inserted, 2, np.diff(start)[moves])
        base = {name: out.pop(name) for name in ("xyz", "width", "speed", "flow")}
        return cls(
            **base,
            channels=out,
            start=np.concatenate([[0], np.cumsum(lengths)]),
            printing=printing[moves] & ~is_inserted,
            layer=layer[moves],
            source=np.where(is_inserted, -1, moves),
            offset=shift,
        )

    def owner(self) -> np.ndarray:
        """(V,) move index of every vertex."""
        return np.repeat(np.arange(len(self.printing)), np.diff(self.start))


@dataclass(frozen=True)
class _Rows:
    """The row table in output order: prefix (R,), values (R, 9), present (R, 9), the
    E increment (R,) in E units and deposited volume (R,) mm^3 of each row, and
    provenance: move (R,) and vertex (R,) index (-1 for rows of no vertex)."""

    prefix: np.ndarray
    values: np.ndarray
    present: np.ndarray
    e_delta: np.ndarray
    volume: np.ndarray
    move: np.ndarray
    vertex: np.ndarray

    def motion(self) -> np.ndarray:
        return (self.prefix == _G0) | (self.prefix == _G1)

    def modal(self, setup: _Setup) -> _Rows:
        """Rows with X/Y/Z written only on change, E from the rounded running total, F on
        change of feed or motion word, and motion rows that move nothing dropped."""
        values, present = self.values.copy(), self.present.copy()
        motion = self.motion()
        rows = np.flatnonzero(motion)
        for column in (_X, _Y, _Z):
            present[rows, column] = _changed(values[rows, column], _XYZ_SCALE)
        total = np.rint(np.cumsum(self.e_delta) * _E_SCALE)
        step = np.diff(total, prepend=0.0)
        has_e = motion & (self.e_delta != 0) & (step != 0)
        values[:, _E] = (total if setup.e_mode == "absolute" else step) / _E_SCALE
        present[:, _E] = has_e
        keep = ~motion | present[:, [_X, _Y, _Z, _E]].any(axis=1)
        columns = {name: getattr(self, name) for name in _Rows.__dataclass_fields__}
        columns.update(values=values, present=present)
        kept = _Rows(**{name: array[keep] for name, array in columns.items()})
        rows = np.flatnonzero(kept.motion())
        feed = np.rint(kept.values[rows, _F] * _F_SCALE)
        word = kept.prefix[rows]
        fresh = np.ones(len(rows), dtype=bool)
        fresh[1:] = (feed[1:] != feed[:-1]) | (word[1:] != word[:-1])
        kept.present[rows, _F] = fresh
        return kept


def _changed(column: np.ndarray, scale: float) -> np.ndarray:
    """Where a modal axis value (rounded as written) differs from the previous row's;
    never where it is unknown (NaN)."""
    known = np.isfinite(column)
    rounded = np.where(known, np.rint(np.where(known, column, 0.0) * scale), np.nan)
    out = known.copy()
    out[1:] &= ~(rounded[1:] == rounded[:-1])
    return out


class _RowBuilder:
    """Collects groups of rows with sort keys, then orders them."""

    def __init__(self, key_stride: int) -> None:
        self.stride = key_stride
        self.groups: list[dict[str, np.ndarray]] = []

    def add(
        self,
        move: np.ndarray,
        slot: np.ndarray | int,
        prefix: int | np.ndarray,
        vertex: np.ndarray | int = -1,
        e_delta: np.ndarray | float = 0.0,
        volume: np.ndarray | float = 0.0,
        **columns: np.ndarray | float,
    ) -> None:
        """Rows for the moves ``move`` at ``slot``; ``columns`` name values of _WORDS
        (L, X, Y, Z, E, F, S, P, W: a comment's value); a given column is present unless
        NaN."""
        n = len(move)
        values = np.full((n, len(_WORDS)), np.nan)
        for name, column in columns.items():
            values[:, "LXYZEFSPW".index(name)] = column
        self.groups.append(
            {
                "key": move.astype(np.int64) * self.stride + slot,
                "prefix": np.broadcast_to(prefix, n),
                "values": values,
                "e_delta": np.broadcast_to(e_delta, n),
                "volume": np.broadcast_to(volume, n),
                "move": move,
                "vertex": np.broadcast_to(vertex, n),
            }
        )

    def build(self) -> _Rows:
        joined = {k: np.concatenate([g[k] for g in self.groups]) for k in self.groups[0]}
        order = np.argsort(joined["key"], kind="stable")
        values = joined["values"][order]
        return _Rows(
            prefix=joined["prefix"][order],
            values=values,
            present=np.isfinite(values),
            e_delta=joined["e_delta"][order].astype(float),
            volume=joined["volume"][order].astype(float),
            move=joined["move"][order],
            vertex=joined["vertex"][order],
        )


def _rows(paths: _Paths, setup: _Setup, toolpath: Toolpath) -> _Rows:
    """Every row of the job body (before modal omission), in output order."""
    start, xyz = paths.start, paths.xyz
    counts = np.diff(start)
    build = _RowBuilder(2 * int(counts.max()) + _VERTEX + 4)
    _layer_rows(build, paths, toolpath)
    # vertex rows
    owner = paths.owner()
    vertex = np.arange(len(xyz))
    local = vertex - start[owner]
    is_vertex = local > 0
    segment = np.zeros(len(xyz))
    segment[1:] = np.linalg.norm(np.diff(xyz, axis=0), axis=1)
    segment[~is_vertex] = 0.0
    printing_v = paths.printing[owner]
    travel_len = np.add.reduceat(segment, start[:-1])
    unknown_start = ~np.isfinite(xyz[start[:-1]]).all(axis=1)
    hop = ~paths.printing & ((travel_len >= setup.min_travel_mm) | unknown_start)
    z_hop = _travel_heights(paths, hop, setup)
    z = np.where(~printing_v & hop[owner], z_hop[owner], xyz[:, 2])
    volume = segment * paths.width * _layer_height(toolpath, paths.layer[owner]) * paths.flow
    volume = np.where(printing_v, volume, 0.0)
    feed = paths.speed * 60.0
    if not setup.has_e:
        feed = np.where(printing_v, feed / np.where(paths.flow > 0, paths.flow, 1.0), feed)
    v = np.flatnonzero(is_vertex)
    build.add(
        owner[v],
        _VERTEX + 2 * local[v] - 1,
        np.where(printing_v[v], _G1, _G0),
        vertex=v,
        e_delta=volume[v] * setup.e_per_mm3,
        volume=volume[v],
        X=xyz[v, 0],
        Y=xyz[v, 1],
        Z=z[v],
        F=feed[v],
    )
    after = _VERTEX + 2 * counts - 2
    _travel_rows(build, paths, hop, z_hop, after, setup)
    printed = np.flatnonzero(printing_v & is_vertex)
    slot = np.where(local[printed] == 1, _S_CHANNELS, _VERTEX + 2 * local[printed] - 2)
    _width_rows(build, paths, printed, owner[printed], slot)
    _channel_rows(build, paths, printed, owner[printed], slot, setup)
    _flow_rows(build, paths, segment, after, setup)
    return build.build()


def _channel_rows(
    build: _RowBuilder,
    paths: _Paths,
    printed: np.ndarray,
    owner: np.ndarray,
    slot: np.ndarray,
    setup: _Setup,
) -> None:
    """The commands of the temperature, pressure and mixing channels: before each print
    segment whose written value differs from the last one written (machine order)."""
    channels = paths.channels
    if "temperature_c" in channels:
        value = np.rint(channels["temperature_c"][printed])
        fresh = _fresh(value)
        build.add(owner[fresh], slot[fresh], _M104, vertex=printed[fresh], S=value[fresh])
    if "pressure_kpa" in channels:
        value = np.floor(channels["pressure_kpa"][printed] * setup.s_per_kpa + 0.5)
        fresh = _fresh(value)
        build.add(owner[fresh], slot[fresh], _PRESSURE, vertex=printed[fresh], S=value[fresh])
    if "ink_fraction" in channels and setup.inks == "mixing":
        value = np.rint(channels["ink_fraction"][printed] / MIX_STEP) * MIX_STEP
        fresh = _fresh(value)
        at, where, vertex = owner[fresh], slot[fresh], printed[fresh]
        build.add(at, where, _M163, vertex=vertex, S=0.0, P=1.0 - value[fresh])
        build.add(at, where, _M163, vertex=vertex, S=1.0, P=value[fresh])
        build.add(at, where, _M164, vertex=vertex, S=0.0)


def _fresh(value: np.ndarray) -> np.ndarray:
    """Where a modal value differs from the previous one (the first always)."""
    fresh = np.ones(len(value), dtype=bool)
    fresh[1:] = value[1:] != value[:-1]
    return fresh


def _flow_rows(
    build: _RowBuilder, paths: _Paths, segment: np.ndarray, after: np.ndarray, setup: _Setup
) -> None:
    """Flow on before and off after every print move (machines without an E axis); with
    two alternating inks, each run of one ink bracketed by that ink's on and off G-code
    (:func:`~fabkit.writers.inks.alternate_inks`: each layer repeats the rounding of the
    one below)."""
    prints = np.flatnonzero(paths.printing)
    if "ink_fraction" not in paths.channels or setup.inks != "alternate":
        if not setup.has_e:
            build.add(prints, _S_FLOW_ON, _FLOW_ON)
            build.add(prints, after[prints], _FLOW_OFF)
        return
    on = {0: _FLOW_ON if setup.flow_on else -1, 1: _INK2_ON}
    off = {0: _FLOW_OFF if setup.flow_off else -1, 1: _INK2_OFF}
    fraction = paths.channels["ink_fraction"]
    width = float(np.median(paths.width[paths.width > 0]))
    ink = alternate_inks(
        paths.xyz[:, :2], paths.start, prints, fraction, width, setup.piece_mm, paths.layer
    )
    rows: list[tuple[int, int, int]] = []  # (move, slot, prefix)
    for move in prints.tolist():
        a, b = paths.start[move] + 1, paths.start[move + 1]
        runs = ink[a:b]
        rows += [(move, _S_FLOW_ON, on[runs[0]]), (move, int(after[move]), off[runs[-1]])]
        for k in (np.flatnonzero(np.diff(runs)) + 1).tolist():  # segment k changes ink
            rows += [
                (move, _VERTEX + 2 * k, off[runs[k - 1]]),
                (move, _VERTEX + 2 * k, on[runs[k]]),
            ]
    table = np.array([row for row in rows if row[2] >= 0], dtype=np.int64).reshape(-1, 3)
    build.add(table[:, 0], table[:, 1], table[:, 2])


def _layer_height(toolpath: Toolpath, layer: np.ndarray) -> np.ndarray:
    heights = np.array([lay.height_mm for lay in toolpath.layers], dtype=float)
    return heights[layer]


def _layer_rows(build: _RowBuilder, paths: _Paths, toolpath: Toolpath) -> None:
    """``;LAYER:n``, ``;TYPE:FILL`` and ``;HEIGHT:h`` (mm) before every layer's first move."""
    first = np.flatnonzero(np.diff(paths.layer, prepend=-1) != 0)
    build.add(first, _S_LAYER, _LAYER, L=paths.layer[first].astype(float))
    build.add(first, _S_TYPE, _TYPE)
    build.add(first, _S_TYPE, _HEIGHT, W=_layer_height(toolpath, paths.layer[first]))


def _width_rows(
    build: _RowBuilder, paths: _Paths, printed: np.ndarray, owner: np.ndarray, slot: np.ndarray
) -> None:
    """``;WIDTH:w`` (mm) before the first print segment and every one whose road width
    (rounded to WIDTH_STEP_MM) differs from the last written."""
    value = np.rint(paths.width[printed] / WIDTH_STEP_MM) * WIDTH_STEP_MM
    fresh = _fresh(value)
    build.add(owner[fresh], slot[fresh], _WIDTH, vertex=printed[fresh], W=value[fresh])


def _travel_heights(paths: _Paths, hop: np.ndarray, setup: _Setup) -> np.ndarray:
    """(M,) height of every travel at its lift: highest vertex + travel lift, mm."""
    z = np.where(np.isfinite(paths.xyz[:, 2]), paths.xyz[:, 2], -np.inf)
    top = np.maximum.reduceat(z, paths.start[:-1])
    return np.where(hop, top + setup.lift_mm, top)


def _travel_rows(
    build: _RowBuilder,
    paths: _Paths,
    hop: np.ndarray,
    z_hop: np.ndarray,
    after: np.ndarray,
    setup: _Setup,
) -> None:
    """Retract and lift before, lower and un-retract after every hopping travel."""
    travels = np.flatnonzero(hop)
    first, last = paths.start[travels], paths.start[travels + 1] - 1
    here, there = paths.xyz[first], paths.xyz[last]
    if setup.retract > 0:
        build.add(
            travels,
            _S_RETRACT,
            _G1,
            vertex=first,
            e_delta=-setup.retract,
            X=here[:, 0],
            Y=here[:, 1],
            Z=here[:, 2],
            F=setup.retract_feed,
        )
        build.add(
            travels,
            after[travels] + 1,
            _G1,
            vertex=last,
            e_delta=setup.retract,
            X=there[:, 0],
            Y=there[:, 1],
            Z=there[:, 2],
            F=setup.retract_feed,
        )
    if setup.lift_mm > 0:
        build.add(
            travels,
            _S_LIFT,
            _G0,
            vertex=first,
            X=here[:, 0],
            Y=here[:, 1],
            Z=z_hop[travels],
            F=setup.z_feed,
        )
        build.add(
            travels,
            after[travels],
            _G0,
            vertex=last,
            X=there[:, 0],
            Y=there[:, 1],
            Z=there[:, 2],
            F=setup.z_feed,
        )


@dataclass(frozen=True)
class _Kinematics:
    """Per motion row (in output order): index into the rows (K,), machine position after
    the row (K, 3) mm (NaN while unknown), displacement (K, 3) and length (K,) mm (NaN
    after an unknown position), feed (K,) mm/s."""

    rows: np.ndarray
    position: np.ndarray
    step: np.ndarray
    length: np.ndarray
    speed: np.ndarray

    @classmethod
    def of(cls, rows: _Rows) -> _Kinematics:
        index = np.flatnonzero(rows.motion())
        position = rows.values[index][:, [_X, _Y, _Z]]
        step = np.diff(position, axis=0, prepend=np.full((1, 3), np.nan))
        return cls(
            rows=index,
            position=position,
            step=step,
            length=np.linalg.norm(step, axis=1),
            speed=rows.values[index, _F] / 60.0,
        )


def _slow_travels(rows: _Rows, machine: MachineProfile) -> _Rows:
    """Travel (G0) rows with their feed lowered so that no axis exceeds its limit (a layer
    change moves Z, whose limit is low); print feeds are never changed."""
    kin = _Kinematics.of(rows)
    travel = rows.prefix[kin.rows] == _G0
    with np.errstate(invalid="ignore", divide="ignore"):
        share = np.abs(kin.step) / kin.length[:, None]
        limits = np.array([machine.limits.axis_mm_s(name) for name in "xyz"])
        cap = np.nan_to_num(np.min(limits / share, axis=1), nan=np.inf)
    feed = np.where(travel, np.minimum(kin.speed, cap), kin.speed) * 60.0
    values = rows.values.copy()
    values[kin.rows, _F] = feed
    return replace(rows, values=values)


def _check(
    rows: _Rows,
    kin: _Kinematics,
    paths: _Paths,
    machine: MachineProfile,
    toolpath: Toolpath,
    nominal_e: bool = False,
) -> None:
    """Refuse the first row outside the envelope or above a limit (see module docstring)."""

    def fail(k: int, problem: str) -> None:
        row = kin.rows[k] if k >= 0 else k
        raise FabkitError(f"{_where(rows, row, paths)}: {problem}")

    for axis, name in enumerate("xyz"):
        lo, hi = machine.envelope.axis(name)
        column = kin.position[:, axis]
        bad = np.flatnonzero((column < lo - 1e-9) | (column > hi + 1e-9))
        if len(bad):
            fail(
                bad[0],
                f"{name.upper()} = {column[bad[0]]:.3f} mm is outside the envelope "
                f"of {machine.name} ({name} {lo:g}..{hi:g} mm); use --offset or a larger "
                "machine",
            )
    limits = machine.limits
    moving = kin.length > 0
    bad = np.flatnonzero(moving & ~(kin.speed > 0))
    if len(bad):
        fail(bad[0], f"feed {kin.speed[bad[0]]:g} mm/s must be > 0")
    e_only = (kin.step == 0).all(axis=1) | ~np.isfinite(kin.length)
    e_only &= rows.e_delta[kin.rows] != 0
    word = rows.prefix[kin.rows]
    printing = paths.printing[rows.move[kin.rows]] & (word == _G1)
    tolerance = 1 + 1e-9
    checks = [
        (printing, limits.print_mm_s, "print speed"),
        (word == _G0, limits.travel_mm_s, "travel speed"),
        (e_only, limits.e_mm_s, "E (retraction) speed"),
    ]
    for mask, limit, what in checks:
        bad = np.flatnonzero(mask & (kin.speed > limit * tolerance))
        if len(bad):
            fail(
                bad[0],
                f"{what} {kin.speed[bad[0]]:g} mm/s is above the limit "
                f"{limit:g} mm/s of {machine.name}",
            )
    with np.errstate(invalid="ignore", divide="ignore"):
        for axis, name in enumerate("xyz"):
            component = np.abs(kin.step[:, axis]) / kin.length * kin.speed
            limit = limits.axis_mm_s(name)
            bad = np.flatnonzero(moving & (component > limit * tolerance))
            if len(bad):
                fail(
                    bad[0],
                    f"{name.upper()} axis speed {component[bad[0]]:g} mm/s is above "
                    f"the limit {limit:g} mm/s of {machine.name}",
                )
        e_rate = np.abs(rows.e_delta[kin.rows]) * kin.speed / kin.length
        bad = np.flatnonzero(moving & (e_rate > limits.e_mm_s * tolerance))
        if len(bad):
            hint = (
                "raise [limits] e_mm_s to the firmware's E limit, or leave out nominal E"
                if nominal_e
                else "print slower or thinner"
            )
            fail(
                bad[0],
                f"E rate {e_rate[bad[0]]:g} per s is above the limit "
                f"{limits.e_mm_s:g} of {machine.name}; {hint}",
            )
    _check_temperature(rows, paths, machine)
    _check_pressure(rows, paths, machine)


def _check_temperature(rows: _Rows, paths: _Paths, machine: MachineProfile) -> None:
    at = np.flatnonzero(rows.prefix == _M104)
    if not len(at):
        return
    values = rows.values[at, _S]
    highest = machine.temperature.nozzle_max_c
    bad = np.flatnonzero(values > highest)
    if len(bad):
        raise FabkitError(
            f"{_where(rows, at[bad[0]], paths)}: nozzle temperature {values[bad[0]]:g} C is "
            f"above the maximum {highest:g} C of {machine.name}"
        )


def _check_pressure(rows: _Rows, paths: _Paths, machine: MachineProfile) -> None:
    at = np.flatnonzero(rows.prefix == _PRESSURE)
    if not len(at) or machine.pressure is None:
        return
    kpa = machine.pressure.kpa(rows.values[at, _S])
    bad = np.flatnonzero((kpa > machine.pressure.max_kpa * (1 + 1e-9)) | (kpa < 0))
    if len(bad):
        raise FabkitError(
            f"{_where(rows, at[bad[0]], paths)}: dispense pressure {kpa[bad[0]]:g} kPa is "
            f"outside 0..{machine.pressure.max_kpa:g} kPa of {machine.name}"
        )


def _where(rows: _Rows, row: int, paths: _Paths) -> str:
    """Where a row comes from: ``layer 2, move 7 (print), vertex 3``."""
    move = rows.move[row]
    layer = paths.layer[move]
    source = paths.source[move]
    if source < 0:
        return f"layer {layer}, travel to move {paths.source[move + 1]}"
    kind = "print" if paths.printing[move] else "travel"
    text = f"layer {layer}, move {source} ({kind})"
    if rows.vertex[row] >= 0:
        text += f", vertex {rows.vertex[row] - paths.start[move]}"
    return text


def _summary(rows: _Rows, kin: _Kinematics, paths: _Paths, setup: _Setup) -> GcodeSummary:
    printing = paths.printing[rows.move[kin.rows]]
    length = np.nan_to_num(kin.length)
    e = rows.e_delta[kin.rows]
    with np.errstate(invalid="ignore", divide="ignore"):
        seconds = np.where(length > 0, length, np.abs(e)) / kin.speed
    low, high = _bounds(kin.position[np.isfinite(kin.position).all(axis=1)])
    return GcodeSummary(
        lines=0,
        motion_lines=0,
        print_length_mm=float(length[printing].sum()),
        travel_length_mm=float(length[~printing].sum()),
        volume_mm3=float(rows.volume.sum()),
        e_total=float(e[printing].sum()),
        duration_s=float(np.nan_to_num(seconds, posinf=0.0).sum()),
        low_mm=tuple(low.tolist()),
        high_mm=tuple(high.tolist()),
        offset_mm=tuple(paths.offset.tolist()),
        e_mode=setup.e_mode,
        e_units=setup.e_units,
        nominal_e=setup.nominal_e,
    )


def _bounds(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(min, max) of each column of (n, k) points (column by column: far faster than
    reducing along axis 0 of a C-ordered array)."""
    columns = [points[:, k] for k in range(points.shape[1])]
    return np.array([c.min() for c in columns]), np.array([c.max() for c in columns])


def _header(
    summary: GcodeSummary, toolpath: Toolpath, machine: MachineProfile, setup: _Setup
) -> bytes:
    """Header comments (Cura and PrusaSlicer keys), start G-code and the E mode."""
    low, high = summary.low_mm, summary.high_mm
    heights = sorted({layer.height_mm for layer in toolpath.layers})
    lines = [
        f";FLAVOR:{_FLAVOUR_NAMES.get(machine.flavour, machine.flavour)}",
        f";Generated with fabkit {fabkit.__version__} for machine {machine.name}",
        f";TIME:{round(summary.duration_s)}",
    ]
    if setup.e_units == "filament":
        lines.append(f";Filament used: {summary.e_total / 1000:.5f}m")
    lines += [
        f";Layer height: {heights[0]:g}",
        f";LAYER_COUNT:{len(toolpath.layers)}",
        *(
            f";{key}:{value:.3f}"
            for key, value in zip(
                ("MINX", "MINY", "MINZ", "MAXX", "MAXY", "MAXZ"), (*low, *high), strict=True
            )
        ),
        f"; estimated printing time (normal mode) = {_duration_text(summary.duration_s)}",
        f"; filament used [cm3] = {summary.volume_mm3 / 1000:.4f}",
    ]
    if setup.e_units == "filament":
        lines.append(f"; filament used [mm] = {summary.e_total:.2f}")
    lines += [
        f";fabkit printing path {summary.print_length_mm:.3f} mm, non-printing path "
        f"{summary.travel_length_mm:.3f} mm, volume {summary.volume_mm3:.4f} mm^3, "
        f"time {summary.duration_s:.1f} s",
        f";fabkit E mode {setup.e_mode}, E units {setup.e_units}, "
        f"{setup.e_per_mm3:.6g} E per mm^3, offset "
        + ",".join(f"{v:.3f}" for v in summary.offset_mm)
        + " mm",
        ";fabkit channels: "
        + (
            ", ".join(f"{name} ({features or '?'})" for name, features in toolpath.channels.items())
            or "none"
        ),
        *_scale_line(toolpath),
    ]
    if setup.nominal_e:
        lines.append(
            ";fabkit nominal E: for G-code viewers only; the firmware ignores it (no hot "
            "extruder) and the valve G-code switches the flow"
        )
    lines += machine.render("start_gcode")
    if setup.has_e or setup.nominal_e:
        lines += ["M82", "G92 E0"] if setup.e_mode == "absolute" else ["M83"]
    return _lines(lines)


def _scale_line(toolpath: Toolpath) -> list[str]:
    """``;fabkit scale: S mm per design unit`` when the toolpath comes from a design."""
    scale = toolpath.meta.get("mm_per_unit")
    if not isinstance(scale, int | float) or isinstance(scale, bool):
        return []
    return [f";fabkit scale: {scale:.9g} mm per design unit"]


def _duration_text(seconds: float) -> str:
    """``1h 2m 3s`` (PrusaSlicer's style)."""
    total = round(seconds)
    hours, rest = divmod(total, 3600)
    minutes, secs = divmod(rest, 60)
    parts = [f"{hours}h"] if hours else []
    if hours or minutes:
        parts.append(f"{minutes}m")
    return " ".join([*parts, f"{secs}s"])
