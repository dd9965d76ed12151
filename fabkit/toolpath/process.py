"""Process settings for toolpaths, and the eps encoding through a calibration table.

The settings live in the ``[process]`` table of a machine profile (``machines/*.toml``,
read by :mod:`fabkit.machines`); ``--process FILE`` replaces that table with the one in
FILE, read by :func:`load_process` here with the profile reader (the same keys)::

    [process]
    road_width_mm = 0.4
    layer_height_mm = 0.3
    print_speed_mm_s = 8
    travel_speed_mm_s = 30

    [process.calibration]          # optional: eps -> one process parameter
    parameter = "print_speed_mm_s" # or extrusion_multiplier, temperature_c, line_spacing_mm
    eps = [0.1, 0.3, 0.5, 0.7]     # strictly increasing
    value = [20, 12, 6, 2]         # strictly monotone, positive
    clip = false                   # true: clip eps to the table (with a warning)

The encoding is monotone piecewise-cubic (PCHIP) interpolation of the table: it never
overshoots between measured points and keeps the table's direction. eps outside the
table is an error naming both ranges, unless ``clip`` is set; then eps is clipped and a
warning gives the clipped fraction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.interpolate import PchipInterpolator

from fabkit.errors import FabkitError
from fabkit.machines import PRINT_PARAMETERS, ProcessProfile, load_machine, parse_process
from fabkit.tomlfile import read_toml

DEFAULT_MACHINE = "marlin_diw_pneumatic"
"""The profile whose ``[process]`` is used when no machine is given (a pneumatic DIW
printer; see ``machines/marlin_diw_pneumatic.toml``)."""

PROCESS_KEYS = ("road_width_mm", "layer_height_mm", "print_speed_mm_s", "travel_speed_mm_s")
PARAMETERS = (*PRINT_PARAMETERS, "channel_width_mm")
"""Calibrated parameters: the print ones, and the channel width of baromorphs."""


@dataclass(frozen=True)
class Calibration:
    """eps (increasing) against one process parameter (strictly monotone, positive)."""

    parameter: str
    eps: tuple[float, ...]
    value: tuple[float, ...]
    clip: bool = False

    def __post_init__(self) -> None:
        where = "[process.calibration]"
        if self.parameter not in PARAMETERS:
            raise FabkitError(
                f"{where} parameter '{self.parameter}' is not one of {', '.join(PARAMETERS)}"
            )
        eps, value = np.asarray(self.eps, float), np.asarray(self.value, float)
        if len(eps) < 2 or len(eps) != len(value):
            raise FabkitError(f"{where} eps and value need the same length, at least 2")
        if not (np.isfinite(eps).all() and np.isfinite(value).all()):
            raise FabkitError(f"{where} eps and value must be finite numbers")
        if np.any(np.diff(eps) <= 0):
            raise FabkitError(f"{where} eps must be strictly increasing")
        steps = np.diff(value)
        if not (np.all(steps > 0) or np.all(steps < 0)):
            raise FabkitError(f"{where} value must be strictly increasing or decreasing in eps")
        if np.any(value <= 0):
            raise FabkitError(f"{where} value must hold positive numbers only")

    @property
    def eps_range(self) -> tuple[float, float]:
        return self.eps[0], self.eps[-1]


@dataclass(frozen=True)
class Process:
    """Road width and layer height (mm), print and travel speed (mm/s), calibration."""

    road_width_mm: float
    layer_height_mm: float
    print_speed_mm_s: float
    travel_speed_mm_s: float
    calibration: Calibration | None = None
    source: str = ""

    def __post_init__(self) -> None:
        for key in PROCESS_KEYS:
            value = getattr(self, key)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise FabkitError(f"[process] {key} must be a positive number, got {value!r}")

    def with_overrides(self, **values: float | None) -> Process:
        """A copy with the given (non-None) settings replaced."""
        return replace(self, **{k: v for k, v in values.items() if v is not None})


@dataclass(frozen=True)
class Encoding:
    """Per-vertex values of the calibrated parameter, and the fraction of eps clipped."""

    value: np.ndarray
    clipped_fraction: float


def encode_eps(eps: np.ndarray, calibration: Calibration) -> Encoding:
    """The calibrated parameter for each eps (monotone PCHIP interpolation of the table)."""
    eps = np.asarray(eps, dtype=float)
    low, high = calibration.eps_range
    if not np.isfinite(eps).all():
        raise FabkitError("eps is not finite everywhere on the print paths")
    outside = (eps < low) | (eps > high)
    if outside.any() and not calibration.clip:
        raise FabkitError(
            f"eps on the print paths spans [{eps.min():.4g}, {eps.max():.4g}], outside the "
            f"calibrated range [{low:g}, {high:g}] of [process.calibration] "
            "(extend the table, or set clip = true / --clip-eps)"
        )
    curve = PchipInterpolator(np.asarray(calibration.eps), np.asarray(calibration.value))
    return Encoding(curve(np.clip(eps, low, high)), float(outside.mean()) if len(eps) else 0.0)


def process_from_profile(profile: ProcessProfile, source: str) -> Process:
    """A :class:`Process` from a machine profile's ``.process`` (``fabkit.machines``)."""
    table = profile.calibration
    calibration = None
    if table is not None:
        calibration = Calibration(table.parameter, table.eps, table.value, table.clip)
    values = {key: float(getattr(profile, key)) for key in PROCESS_KEYS}
    return Process(**values, calibration=calibration, source=source)


def machine_process(name_or_path: str | None) -> Process:
    """The ``[process]`` of a machine profile (name or path), or of the default DIW one."""
    name = name_or_path or DEFAULT_MACHINE
    return process_from_profile(load_machine(name).process, f"machine {name}")


def load_process(path: str | Path) -> Process:
    """Read the ``[process]`` table of a TOML file (module docstring); one-line errors."""
    path = Path(path)
    table = read_toml(path, "process")
    if "process" not in table:
        raise FabkitError(f"{path}: missing table [process]")
    return process_from_profile(parse_process(table["process"], path), str(path))
