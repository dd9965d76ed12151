"""The checks of a G-code job (:mod:`fabkit.writers.gcode`), on its rows before anything
is written: every motion row's kinematics (:class:`Kinematics`), travels slowed to the
per-axis limits (:func:`slow_travels`), and the first row outside the envelope or above a
feed, axis, E-rate, temperature or pressure limit refused, naming its layer, move and
vertex (:func:`check_rows`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from fabkit.errors import FabkitError
from fabkit.machines import MachineProfile
from fabkit.toolpath.model import Toolpath
from fabkit.writers.gcode_rows import (
    COL_F,
    COL_S,
    COL_X,
    COL_Y,
    COL_Z,
    F_SCALE,
    ROW_G0,
    ROW_G1,
    ROW_M104,
    ROW_PRESSURE,
    XYZ_SCALE,
    Paths,
    Rows,
)


@dataclass(frozen=True)
class Kinematics:
    """Per motion row (in output order): index into the rows (K,), machine position after
    the row (K, 3) mm (NaN while unknown), displacement (K, 3) and length (K,) mm (NaN
    after an unknown position), feed (K,) mm/s."""

    rows: np.ndarray
    position: np.ndarray
    step: np.ndarray
    length: np.ndarray
    speed: np.ndarray

    @classmethod
    def of(cls, rows: Rows) -> Kinematics:
        index = np.flatnonzero(rows.motion())
        position = rows.values[index][:, [COL_X, COL_Y, COL_Z]]
        step = _steps(position)
        return cls(
            rows=index,
            position=position,
            step=step,
            length=np.linalg.norm(step, axis=1),
            speed=rows.values[index, COL_F] / 60.0,
        )


def slow_travels(rows: Rows, machine: MachineProfile) -> Rows:
    """Travel (G0) rows with their feed lowered so that no axis exceeds its limit (a layer
    change moves Z, whose limit is low); print feeds are never changed. The cap holds on
    the positions as planned (the writer's own check) and as written (rounded: the file's
    reader, ``fabkit send``'s pre-flight check), and the feed is rounded down to the
    written step: rounded to nearest, a layer change of Fig. 3 came out 10.009 mm/s in Z
    against a limit of 10."""
    kin = Kinematics.of(rows)
    travel = rows.prefix[kin.rows] == ROW_G0
    written = np.rint(kin.position * XYZ_SCALE) / XYZ_SCALE
    limits = np.array([machine.limits.axis_mm_s(name) for name in "xyz"])
    cap = np.minimum(_axis_cap(kin.step, limits), _axis_cap(_steps(written), limits))
    cap_mm_min = np.floor(cap * 60.0 * F_SCALE) / F_SCALE
    feed = kin.speed * 60.0
    feed = np.where(travel & (feed > cap_mm_min), cap_mm_min, feed)
    values = rows.values.copy()
    values[kin.rows, COL_F] = feed
    return replace(rows, values=values)


def _steps(position: np.ndarray) -> np.ndarray:
    """(K, 3) displacement of every motion row from the one before (NaN first)."""
    return np.diff(position, axis=0, prepend=np.full((1, 3), np.nan))


def _axis_cap(step: np.ndarray, limits: np.ndarray) -> np.ndarray:
    """(K,) the highest feed (mm/s) at which no axis of ``step`` (K, 3) exceeds its
    limit (``limits`` (3,) mm/s); inf for a move of no length."""
    with np.errstate(invalid="ignore", divide="ignore"):
        share = np.abs(step) / np.linalg.norm(step, axis=1)[:, None]
        return np.nan_to_num(np.min(limits / share, axis=1), nan=np.inf)


def check_rows(
    rows: Rows,
    kin: Kinematics,
    paths: Paths,
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
    printing = paths.printing[rows.move[kin.rows]] & (word == ROW_G1)
    tolerance = 1 + 1e-9
    checks = [
        (printing, limits.print_mm_s, "print speed"),
        (word == ROW_G0, limits.travel_mm_s, "travel speed"),
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


def _check_temperature(rows: Rows, paths: Paths, machine: MachineProfile) -> None:
    at = np.flatnonzero(rows.prefix == ROW_M104)
    if not len(at):
        return
    values = rows.values[at, COL_S]
    highest = machine.temperature.nozzle_max_c
    bad = np.flatnonzero(values > highest)
    if len(bad):
        raise FabkitError(
            f"{_where(rows, at[bad[0]], paths)}: nozzle temperature {values[bad[0]]:g} C is "
            f"above the maximum {highest:g} C of {machine.name}"
        )


def _check_pressure(rows: Rows, paths: Paths, machine: MachineProfile) -> None:
    at = np.flatnonzero(rows.prefix == ROW_PRESSURE)
    if not len(at) or machine.pressure is None:
        return
    kpa = machine.pressure.kpa(rows.values[at, COL_S])
    bad = np.flatnonzero((kpa > machine.pressure.max_kpa * (1 + 1e-9)) | (kpa < 0))
    if len(bad):
        raise FabkitError(
            f"{_where(rows, at[bad[0]], paths)}: dispense pressure {kpa[bad[0]]:g} kPa is "
            f"outside 0..{machine.pressure.max_kpa:g} kPa of {machine.name}"
        )


def _where(rows: Rows, row: int, paths: Paths) -> str:
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
