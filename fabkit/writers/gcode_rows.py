"""The row table of a G-code job (:mod:`fabkit.writers.gcode`): the toolpath placed on
the machine with its travels inserted (:class:`Paths`) and turned into rows, built with
numpy for all moves at once (:func:`build_rows`): the vertices' G0/G1 moves, the lifts and
retractions of travels, the layer and width comments, the channels' commands and the flow
and ink G-code, ordered by move and slot, then written modally (:meth:`Rows.modal`).
The columns of a row (:data:`WORDS`) and its prefixes (:data:`PREFIXES`, then the
profile's snippets) are what :func:`fabkit.writers.line_table.render` formats.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fabkit.errors import FabkitError
from fabkit.machines import MachineProfile
from fabkit.toolpath.model import PRINT, Toolpath
from fabkit.writers.common import placement_offset
from fabkit.writers.gcode_setup import Setup
from fabkit.writers.inks import alternate_inks
from fabkit.writers.line_table import Word

# Columns of the row table, and how each is written.
COL_L, COL_X, COL_Y, COL_Z, COL_E, COL_F, COL_S, COL_P, COL_W = range(9)
WORDS = (
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
XYZ_SCALE, E_SCALE, F_SCALE = 1e3, 1e5, 1e1
# Row prefixes: the fixed vocabulary, then the profile's snippets.
ROW_G0, ROW_G1, ROW_LAYER, ROW_TYPE, ROW_HEIGHT, ROW_WIDTH, ROW_M104, ROW_M163, ROW_M164 = range(9)
ROW_FLOW_ON, ROW_FLOW_OFF, ROW_INK2_ON, ROW_INK2_OFF, ROW_PRESSURE = range(9, 14)
PREFIXES = (
    "G0", "G1", ";LAYER:", ";TYPE:FILL", ";HEIGHT:", ";WIDTH:", "M104", "M163", "M164"
)  # fmt: skip
WIDTH_STEP_MM = 1e-3
"""``;WIDTH:`` is written to the micrometre, and again only where that value changes."""
# Order of rows inside one move (slot in the sort key). Vertex k's row comes at
# SLOT_VERTEX + 2 k - 1, the channel commands for its segment just before it (for the first
# segment: at SLOT_CHANNELS, before the flow is turned on).
SLOT_LAYER, SLOT_TYPE, SLOT_RETRACT, SLOT_LIFT, SLOT_CHANNELS, SLOT_FLOW_ON, SLOT_VERTEX = range(7)
MIX_STEP = 0.01
"""Mixing ratios are written in hundredths."""


def row_prefixes(setup: Setup) -> tuple[str, ...]:
    """Every row prefix by its number: the fixed vocabulary, then the profile's snippets."""
    return (
        *PREFIXES,
        setup.flow_on,
        setup.flow_off,
        setup.ink2_on,
        setup.ink2_off,
        setup.pressure,
    )


@dataclass(frozen=True)
class Paths:
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
        setup: Setup,
    ) -> Paths:
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
        shift = placement_offset(*column_bounds(fields["xyz"]), machine, offset)
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
        setup: Setup,
    ) -> Paths:
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
class Rows:
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
        return (self.prefix == ROW_G0) | (self.prefix == ROW_G1)

    def modal(self, setup: Setup) -> Rows:
        """Rows with X/Y/Z written only on change, E from the rounded running total, F on
        change of feed or motion word, and motion rows that move nothing dropped."""
        values, present = self.values.copy(), self.present.copy()
        motion = self.motion()
        rows = np.flatnonzero(motion)
        for column in (COL_X, COL_Y, COL_Z):
            present[rows, column] = _changed(values[rows, column], XYZ_SCALE)
        total = np.rint(np.cumsum(self.e_delta) * E_SCALE)
        step = np.diff(total, prepend=0.0)
        has_e = motion & (self.e_delta != 0) & (step != 0)
        values[:, COL_E] = (total if setup.e_mode == "absolute" else step) / E_SCALE
        present[:, COL_E] = has_e
        keep = ~motion | present[:, [COL_X, COL_Y, COL_Z, COL_E]].any(axis=1)
        columns = {name: getattr(self, name) for name in Rows.__dataclass_fields__}
        columns.update(values=values, present=present)
        kept = Rows(**{name: array[keep] for name, array in columns.items()})
        rows = np.flatnonzero(kept.motion())
        feed = np.rint(kept.values[rows, COL_F] * F_SCALE)
        word = kept.prefix[rows]
        fresh = np.ones(len(rows), dtype=bool)
        fresh[1:] = (feed[1:] != feed[:-1]) | (word[1:] != word[:-1])
        kept.present[rows, COL_F] = fresh
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
        """Rows for the moves ``move`` at ``slot``; ``columns`` name values of WORDS
        (L, X, Y, Z, E, F, S, P, W: a comment's value); a given column is present unless
        NaN."""
        n = len(move)
        values = np.full((n, len(WORDS)), np.nan)
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

    def build(self) -> Rows:
        joined = {k: np.concatenate([g[k] for g in self.groups]) for k in self.groups[0]}
        order = np.argsort(joined["key"], kind="stable")
        values = joined["values"][order]
        return Rows(
            prefix=joined["prefix"][order],
            values=values,
            present=np.isfinite(values),
            e_delta=joined["e_delta"][order].astype(float),
            volume=joined["volume"][order].astype(float),
            move=joined["move"][order],
            vertex=joined["vertex"][order],
        )


def build_rows(paths: Paths, setup: Setup, toolpath: Toolpath) -> Rows:
    """Every row of the job body (before modal omission), in output order."""
    start, xyz = paths.start, paths.xyz
    counts = np.diff(start)
    build = _RowBuilder(2 * int(counts.max()) + SLOT_VERTEX + 4)
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
        SLOT_VERTEX + 2 * local[v] - 1,
        np.where(printing_v[v], ROW_G1, ROW_G0),
        vertex=v,
        e_delta=volume[v] * setup.e_per_mm3,
        volume=volume[v],
        X=xyz[v, 0],
        Y=xyz[v, 1],
        Z=z[v],
        F=feed[v],
    )
    after = SLOT_VERTEX + 2 * counts - 2
    _travel_rows(build, paths, hop, z_hop, after, setup)
    printed = np.flatnonzero(printing_v & is_vertex)
    slot = np.where(local[printed] == 1, SLOT_CHANNELS, SLOT_VERTEX + 2 * local[printed] - 2)
    _width_rows(build, paths, printed, owner[printed], slot)
    _channel_rows(build, paths, printed, owner[printed], slot, setup)
    _flow_rows(build, paths, segment, after, setup)
    return build.build()


def _channel_rows(
    build: _RowBuilder,
    paths: Paths,
    printed: np.ndarray,
    owner: np.ndarray,
    slot: np.ndarray,
    setup: Setup,
) -> None:
    """The commands of the temperature, pressure and mixing channels: before each print
    segment whose written value differs from the last one written (machine order)."""
    channels = paths.channels
    if "temperature_c" in channels:
        value = np.rint(channels["temperature_c"][printed])
        fresh = _fresh(value)
        build.add(owner[fresh], slot[fresh], ROW_M104, vertex=printed[fresh], S=value[fresh])
    if "pressure_kpa" in channels:
        value = np.floor(channels["pressure_kpa"][printed] * setup.s_per_kpa + 0.5)
        fresh = _fresh(value)
        build.add(owner[fresh], slot[fresh], ROW_PRESSURE, vertex=printed[fresh], S=value[fresh])
    if "ink_fraction" in channels and setup.inks == "mixing":
        value = np.rint(channels["ink_fraction"][printed] / MIX_STEP) * MIX_STEP
        fresh = _fresh(value)
        at, where, vertex = owner[fresh], slot[fresh], printed[fresh]
        build.add(at, where, ROW_M163, vertex=vertex, S=0.0, P=1.0 - value[fresh])
        build.add(at, where, ROW_M163, vertex=vertex, S=1.0, P=value[fresh])
        build.add(at, where, ROW_M164, vertex=vertex, S=0.0)


def _fresh(value: np.ndarray) -> np.ndarray:
    """Where a modal value differs from the previous one (the first always)."""
    fresh = np.ones(len(value), dtype=bool)
    fresh[1:] = value[1:] != value[:-1]
    return fresh


def _flow_rows(
    build: _RowBuilder, paths: Paths, segment: np.ndarray, after: np.ndarray, setup: Setup
) -> None:
    """Flow on before and off after every print move (machines without an E axis); with
    two alternating inks, each run of one ink bracketed by that ink's on and off G-code
    (:func:`~fabkit.writers.inks.alternate_inks`: each layer repeats the rounding of the
    one below)."""
    prints = np.flatnonzero(paths.printing)
    if "ink_fraction" not in paths.channels or setup.inks != "alternate":
        if not setup.has_e:
            build.add(prints, SLOT_FLOW_ON, ROW_FLOW_ON)
            build.add(prints, after[prints], ROW_FLOW_OFF)
        return
    on = {0: ROW_FLOW_ON if setup.flow_on else -1, 1: ROW_INK2_ON}
    off = {0: ROW_FLOW_OFF if setup.flow_off else -1, 1: ROW_INK2_OFF}
    fraction = paths.channels["ink_fraction"]
    width = float(np.median(paths.width[paths.width > 0]))
    ink = alternate_inks(
        paths.xyz[:, :2], paths.start, prints, fraction, width, setup.piece_mm, paths.layer
    )
    rows: list[tuple[int, int, int]] = []  # (move, slot, prefix)
    for move in prints.tolist():
        a, b = paths.start[move] + 1, paths.start[move + 1]
        runs = ink[a:b]
        rows += [(move, SLOT_FLOW_ON, on[runs[0]]), (move, int(after[move]), off[runs[-1]])]
        for k in (np.flatnonzero(np.diff(runs)) + 1).tolist():  # segment k changes ink
            rows += [
                (move, SLOT_VERTEX + 2 * k, off[runs[k - 1]]),
                (move, SLOT_VERTEX + 2 * k, on[runs[k]]),
            ]
    table = np.array([row for row in rows if row[2] >= 0], dtype=np.int64).reshape(-1, 3)
    build.add(table[:, 0], table[:, 1], table[:, 2])


def _layer_height(toolpath: Toolpath, layer: np.ndarray) -> np.ndarray:
    heights = np.array([lay.height_mm for lay in toolpath.layers], dtype=float)
    return heights[layer]


def _layer_rows(build: _RowBuilder, paths: Paths, toolpath: Toolpath) -> None:
    """``;LAYER:n``, ``;TYPE:FILL`` and ``;HEIGHT:h`` (mm) before every layer's first move."""
    first = np.flatnonzero(np.diff(paths.layer, prepend=-1) != 0)
    build.add(first, SLOT_LAYER, ROW_LAYER, L=paths.layer[first].astype(float))
    build.add(first, SLOT_TYPE, ROW_TYPE)
    build.add(first, SLOT_TYPE, ROW_HEIGHT, W=_layer_height(toolpath, paths.layer[first]))


def _width_rows(
    build: _RowBuilder, paths: Paths, printed: np.ndarray, owner: np.ndarray, slot: np.ndarray
) -> None:
    """``;WIDTH:w`` (mm) before the first print segment and every one whose road width
    (rounded to WIDTH_STEP_MM) differs from the last written."""
    value = np.rint(paths.width[printed] / WIDTH_STEP_MM) * WIDTH_STEP_MM
    fresh = _fresh(value)
    build.add(owner[fresh], slot[fresh], ROW_WIDTH, vertex=printed[fresh], W=value[fresh])


def _travel_heights(paths: Paths, hop: np.ndarray, setup: Setup) -> np.ndarray:
    """(M,) height of every travel at its lift: highest vertex + travel lift, mm."""
    z = np.where(np.isfinite(paths.xyz[:, 2]), paths.xyz[:, 2], -np.inf)
    top = np.maximum.reduceat(z, paths.start[:-1])
    return np.where(hop, top + setup.lift_mm, top)


def _travel_rows(
    build: _RowBuilder,
    paths: Paths,
    hop: np.ndarray,
    z_hop: np.ndarray,
    after: np.ndarray,
    setup: Setup,
) -> None:
    """Retract and lift before, lower and un-retract after every hopping travel."""
    travels = np.flatnonzero(hop)
    first, last = paths.start[travels], paths.start[travels + 1] - 1
    here, there = paths.xyz[first], paths.xyz[last]
    if setup.retract > 0:
        build.add(
            travels,
            SLOT_RETRACT,
            ROW_G1,
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
            ROW_G1,
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
            SLOT_LIFT,
            ROW_G0,
            vertex=first,
            X=here[:, 0],
            Y=here[:, 1],
            Z=z_hop[travels],
            F=setup.z_feed,
        )
        build.add(
            travels,
            after[travels],
            ROW_G0,
            vertex=last,
            X=there[:, 0],
            Y=there[:, 1],
            Z=there[:, 2],
            F=setup.z_feed,
        )


def column_bounds(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(min, max) of each column of (n, k) points (column by column: far faster than
    reducing along axis 0 of a C-ordered array)."""
    columns = [points[:, k] for k in range(points.shape[1])]
    return np.array([c.min() for c in columns]), np.array([c.max() for c in columns])
