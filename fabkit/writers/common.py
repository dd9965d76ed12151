"""What every writer shares: placing the sheet on the machine and keeping it inside.

Toolpaths and director fields live in the sheet's frame (mm, z up). A writer moves them
into machine coordinates by an offset: given explicitly, or by default the one that puts
the centre of the xy bounding box on the centre of the machine's xy envelope (z is kept:
the model's z is already the height above the bed).
"""

from __future__ import annotations

import numpy as np

from fabkit.errors import FabkitError
from fabkit.machines import MachineProfile

FORMATS = ("gcode", "dxf", "laser")
"""Output formats of ``fabkit export``."""
IMAGE_FORMATS = ("png", "tiff")
"""Image formats of the laser-writer maps and masks."""


def placement_offset(
    low: np.ndarray,
    high: np.ndarray,
    machine: MachineProfile | None,
    offset: tuple[float, ...] | None,
) -> np.ndarray:
    """The (3,) offset, mm, from sheet to machine coordinates.

    ``low``/``high`` are the (2,) or (3,) bounds of what is placed; ``offset`` is an
    explicit (x, y) or (x, y, z) offset, or None to centre the xy bounds on the envelope
    of ``machine`` (which may be None only when ``offset`` is given).
    """
    if offset is not None:
        if len(offset) not in (2, 3) or not np.isfinite(offset).all():
            raise FabkitError(f"offset {tuple(offset)} must be 2 or 3 finite numbers (mm)")
        return np.array([*offset, 0.0][:3], dtype=float)
    if machine is None:
        return np.zeros(3)
    env = machine.envelope
    centre = np.array([sum(env.x_mm) / 2, sum(env.y_mm) / 2])
    return np.array([*(centre - (np.asarray(low[:2]) + np.asarray(high[:2])) / 2), 0.0])


def check_inside(points: np.ndarray, machine: MachineProfile, what: str) -> None:
    """Refuse any finite (n, 2) or (n, 3) point outside the machine's envelope (mm)."""
    env = machine.envelope
    for axis, name in enumerate("xyz"[: points.shape[1]]):
        lo, hi = env.axis(name)
        column = points[:, axis]
        bad = np.flatnonzero(np.isfinite(column) & ((column < lo - 1e-9) | (column > hi + 1e-9)))
        if len(bad):
            raise FabkitError(
                f"{what}: {name.upper()} = {column[bad[0]]:.3f} mm is outside the envelope "
                f"of {machine.name} ({name} {lo:g}..{hi:g} mm); move or shrink the part "
                "(--offset) or pick a larger machine"
            )
