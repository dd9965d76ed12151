"""Exposure planning for a light writer: the director field sampled on the writer's pixel
grid (:class:`DirectorGrid`), its angle binned into N exposures centred on k * pi / N
(binning error at most pi / 2N), every feature's light channel (``dose_mj_cm2``, the
polarised alignment dose; ``cure_dose_mj_cm2``, an unpolarised cure after them) binned
into dose levels, and each exposure's optics (director, polariser and half-wave-plate
angles, dose, time): an :class:`ExposurePlan`, plain data. :mod:`fabkit.writers.laser`
writes it as maps, masks, a manifest and scan lines.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any, Protocol

import numpy as np
import shapely

from fabkit.errors import FabkitError
from fabkit.field.flat import director_angle
from fabkit.machines import DEFAULT_RELATION, RELATIONS, LaserOptics, MachineProfile
from fabkit.process import Process, Resolution

DEFAULT_BINS = 18
"""Angle bins (10 degrees each, binning error <= 5 degrees)."""
DEFAULT_DOSE_MJ_CM2 = 1000.0
"""Dose when there is no eps-to-dose calibration (typical of azo-dye photoalignment)."""
DEFAULT_DOSE_LEVELS = 4
CHUNK = 1 << 16
"""Pixels sampled at once."""
LIGHT_CHANNELS = ("dose_mj_cm2", "cure_dose_mj_cm2")
"""The channels a light writer exposes."""


class FieldLike(Protocol):
    """What :func:`sample_field` needs (``fabkit.field.flat.FlatField`` has it): mm, radians."""

    outline: shapely.Geometry
    mm_per_unit: float | None

    def sample(self, points: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]: ...

    @property
    def names(self) -> tuple[str, ...]: ...


@dataclass(frozen=True, eq=False)
class DirectorGrid:
    """theta (rows, cols) rad, mask (rows, cols) bool, ``features`` (name -> (rows, cols)
    eps), the pixel pitch (mm) and the lower-left corner ``origin_mm`` (sheet frame); see
    the module docstring. theta is reduced to [0, pi); pixels with non-finite theta or a
    non-finite feature leave the mask. ``mm_per_unit``: the design's scale, if any."""

    theta: np.ndarray
    mask: np.ndarray
    features: Mapping[str, np.ndarray]
    pixel_mm: float
    origin_mm: tuple[float, float] = (0.0, 0.0)
    mm_per_unit: float | None = None

    def __post_init__(self) -> None:
        theta = np.asarray(self.theta, dtype=float)
        mask = np.asarray(self.mask, dtype=bool)
        if theta.ndim != 2 or mask.shape != theta.shape or theta.size == 0:
            raise FabkitError("director grid: theta and mask must be 2-D arrays of one shape")
        if not (math.isfinite(self.pixel_mm) and self.pixel_mm > 0):
            raise FabkitError(f"director grid: pixel pitch must be > 0 mm, got {self.pixel_mm}")
        mask = mask & np.isfinite(theta)
        features = {}
        for name, values in self.features.items():
            if np.shape(values) != theta.shape:
                raise FabkitError(
                    f"director grid: {name} must have the shape of theta {theta.shape}"
                )
            features[name] = np.asarray(values, dtype=float)
            mask &= np.isfinite(features[name])
        if not mask.any():
            raise FabkitError("director grid: the mask selects no pixel")
        features = {name: np.where(mask, values, np.nan) for name, values in features.items()}
        object.__setattr__(self, "features", features)
        object.__setattr__(self, "theta", np.where(mask, np.mod(theta, np.pi), np.nan))
        object.__setattr__(self, "mask", mask)

    @property
    def shape(self) -> tuple[int, int]:
        return self.theta.shape

    def centres(self) -> tuple[np.ndarray, np.ndarray]:
        """Pixel-centre x (cols,) and y (rows,) in the sheet frame, mm (y decreasing)."""
        rows, cols = self.shape
        x = self.origin_mm[0] + self.pixel_mm * (np.arange(cols) + 0.5)
        y = self.origin_mm[1] + self.pixel_mm * (rows - np.arange(rows) - 0.5)
        return x, y

    @property
    def size_mm(self) -> tuple[float, float]:
        """Field size (width, height), mm."""
        return self.shape[1] * self.pixel_mm, self.shape[0] * self.pixel_mm


def sample_field(field: FieldLike, pixel_mm: float) -> DirectorGrid:
    """Sample a flat-sheet field on pixel centres covering its outline (mask = inside)."""
    if not (math.isfinite(pixel_mm) and pixel_mm > 0):
        raise FabkitError(f"pixel pitch must be > 0 mm, got {pixel_mm}")
    x0, y0, x1, y1 = field.outline.bounds
    cols, rows = (max(1, math.ceil((hi - lo) / pixel_mm)) for lo, hi in ((x0, x1), (y0, y1)))
    if rows * cols > 50_000_000:
        raise FabkitError(f"{cols} x {rows} pixels is too many; use a coarser --pixel")
    blank = DirectorGrid(np.zeros((rows, cols)), np.ones((rows, cols)), {}, pixel_mm, (x0, y0))
    x, y = blank.centres()
    xx, yy = np.meshgrid(x, y)
    mask = shapely.contains_xy(field.outline, xx, yy)
    if not mask.any():
        raise FabkitError(f"pixel pitch {pixel_mm} mm leaves no pixel inside the outline")
    points = np.column_stack([xx[mask], yy[mask]])
    theta = np.full(mask.shape, np.nan)
    features = {name: np.full(mask.shape, np.nan) for name in field.names}
    angles, values = [], {name: [] for name in field.names}
    for a in range(0, len(points), CHUNK):  # bounded memory
        angle, sampled = field.sample(points[a : a + CHUNK])
        angles.append(angle)
        for name in field.names:
            values[name].append(sampled[name])
    theta[mask] = np.concatenate(angles)
    for name in field.names:
        features[name][mask] = np.concatenate(values[name])
    return DirectorGrid(theta, mask, features, pixel_mm, (x0, y0), field.mm_per_unit)


@dataclass(frozen=True)
class LaserSettings:
    """Exposure settings (angles in degrees, dose mJ/cm^2, intensity mW/cm^2, power mW).

    ``process`` gives the channels of the grid's features (dose and cure dose; None: no
    channel); ``ignore`` names features left out on purpose; ``dose`` is the alignment
    dose where no channel sets it; ``intensity_mw_cm2`` (if known) gives the exposure
    times; ``scan_speed_mm_s`` defaults to the profile's print speed; ``max_power_mw``
    (if known) bounds the scan power.
    """

    bins: int = DEFAULT_BINS
    relation: str = DEFAULT_RELATION
    input_polarisation_deg: float = 0.0
    dose: float = DEFAULT_DOSE_MJ_CM2
    dose_levels: int = DEFAULT_DOSE_LEVELS
    intensity_mw_cm2: float | None = None
    scan_speed_mm_s: float | None = None
    max_power_mw: float | None = None
    process: Process | None = None
    ignore: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if not 1 <= self.bins <= 1000:
            raise FabkitError(f"bins must be 1..1000, got {self.bins}")
        if not 1 <= self.dose_levels <= 256:
            raise FabkitError(f"dose levels must be 1..256, got {self.dose_levels}")
        if self.relation not in RELATIONS:
            raise FabkitError(f"relation '{self.relation}' is not one of {', '.join(RELATIONS)}")
        if not self.dose > 0:
            raise FabkitError(f"dose must be > 0 mJ/cm^2, got {self.dose}")

    @classmethod
    def for_machine(cls, machine: MachineProfile, **overrides: Any) -> LaserSettings:
        """Settings from the profile where it has them (its process's channels included),
        then ``overrides`` (None ignored)."""
        optics = machine.laser or LaserOptics()
        values: dict[str, Any] = {
            "relation": optics.relation,
            "input_polarisation_deg": optics.input_polarisation_deg,
            "intensity_mw_cm2": optics.intensity_mw_cm2,
            "max_power_mw": optics.max_power_mw,
            "scan_speed_mm_s": machine.process.print_speed_mm_s,
            "dose_levels": optics.dose_levels or DEFAULT_DOSE_LEVELS,
            "bins": optics.bins or DEFAULT_BINS,
            "process": machine.process,
        }
        values.update({k: v for k, v in overrides.items() if v is not None})
        return cls(**values)

    def resolve(self, grid: DirectorGrid) -> Resolution:
        """The light channels of ``grid``'s features; any other channel, or a feature no
        channel encodes (unless ignored), is a one-line error."""
        if self.process is None:
            process = Process(1.0, 1.0, 1.0, 1.0, source="the laser settings")
        else:
            process = self.process
        ignore = tuple(name for name in self.ignore if name in grid.features)
        resolution = process.resolve(tuple(grid.features), ignore)
        for channel in resolution.channels:
            for name in channel.parameters:
                if name not in LIGHT_CHANNELS:
                    raise FabkitError(
                        f"the laser writer cannot expose the {name} channel "
                        f"({', '.join(channel.features)}): it sets "
                        f"{' and '.join(LIGHT_CHANNELS)}; print roads with --format gcode"
                    )
        return resolution


@dataclass(frozen=True, eq=False)
class Binning:
    """Angle bins: label (rows, cols) in 0..bins-1 (-1 outside), centres (bins,) rad, and
    the absolute binning error (rows, cols) rad (NaN outside)."""

    label: np.ndarray
    centres: np.ndarray
    error: np.ndarray

    @property
    def max_error(self) -> float:
        return float(np.nanmax(self.error))

    @property
    def rms_error(self) -> float:
        return float(np.sqrt(np.nanmean(self.error**2)))


def bin_angles(grid: DirectorGrid, bins: int) -> Binning:
    """Bin theta into ``bins`` bins centred on k * pi / bins (error <= pi / (2 bins))."""
    width = np.pi / bins
    label = np.where(grid.mask, np.rint(np.nan_to_num(grid.theta) / width) % bins, -1)
    label = label.astype(np.int64)
    centres = np.arange(bins) * width
    error = np.abs(director_angle(grid.theta - centres[np.maximum(label, 0)]))
    return Binning(label, centres, np.where(grid.mask, error, np.nan))


@dataclass(frozen=True)
class Exposure:
    """One DMD exposure (angles in degrees, dose mJ/cm^2, time s or None)."""

    order: int
    director_deg: float
    polariser_deg: float
    half_wave_plate_deg: float
    dose_mj_cm2: float
    exposure_s: float | None
    pixels: int


@dataclass(frozen=True)
class CureExposure:
    """One unpolarised exposure of the cure channel (dose mJ/cm^2, time s or None)."""

    order: int
    dose_mj_cm2: float
    exposure_s: float | None
    pixels: int


@dataclass(frozen=True, eq=False)
class ExposurePlan:
    """Every domain pixel's exposure index (rows, cols; -1 outside), the exposures in
    order, the dose map (mJ/cm^2, NaN outside) and the binning; with a cure channel, its
    dose map, each pixel's cure exposure and the cure exposures; the resolved channels."""

    index: np.ndarray
    exposures: tuple[Exposure, ...]
    dose: np.ndarray
    binning: Binning
    dose_error_mj_cm2: float
    resolution: Resolution
    cure: np.ndarray | None = None
    cure_index: np.ndarray | None = None
    cure_exposures: tuple[CureExposure, ...] = ()
    cure_error_mj_cm2: float = 0.0
    clipped: tuple[str, ...] = ()


def plan_exposures(grid: DirectorGrid, settings: LaserSettings) -> ExposurePlan:
    """Bin angle and dose; one exposure per non-empty (angle bin, dose level) pair, and one
    cure exposure per non-empty cure level."""
    resolution = settings.resolve(grid)
    binning = bin_angles(grid, settings.bins)
    maps, clipped = _channel_maps(grid, resolution)
    dose = maps.get("dose_mj_cm2", np.where(grid.mask, settings.dose, np.nan))
    level, level_dose = _dose_levels(dose, grid.mask, settings.dose_levels)
    combined = np.where(grid.mask, binning.label * settings.dose_levels + level, -1)
    used, inverse = np.unique(combined[grid.mask], return_inverse=True)
    index = np.full(grid.shape, -1)
    index[grid.mask] = inverse
    counts = np.bincount(inverse, minlength=len(used))
    exposures = []
    for k, code in enumerate(used):
        angle_bin, dose_level = divmod(int(code), settings.dose_levels)
        director = math.degrees(binning.centres[angle_bin])
        polariser = _polariser_deg(director, settings.relation)
        exposures.append(
            Exposure(
                order=k + 1,
                director_deg=round(director, 6),
                polariser_deg=round(polariser, 6),
                half_wave_plate_deg=round(
                    _half_wave_plate_deg(polariser, settings.input_polarisation_deg), 6
                ),
                dose_mj_cm2=float(level_dose[dose_level]),
                exposure_s=_seconds(level_dose[dose_level], settings),
                pixels=int(counts[k]),
            )
        )
    error = np.nanmax(np.abs(dose - level_dose[level])[grid.mask])
    plan = ExposurePlan(index, tuple(exposures), dose, binning, float(error), resolution)
    if "cure_dose_mj_cm2" in maps:
        plan = _with_cure(plan, maps["cure_dose_mj_cm2"], grid, settings, len(exposures))
    return replace(plan, clipped=clipped)


def _channel_maps(
    grid: DirectorGrid, resolution: Resolution
) -> tuple[dict[str, np.ndarray], tuple[str, ...]]:
    """Each light channel's map (mJ/cm^2, NaN outside) and a note per clipped channel."""
    maps, clipped = {}, []
    for channel in resolution.channels:
        eps = {name: grid.features[name][grid.mask] for name in channel.features}
        coded = channel.encode(eps, channel.label)
        for name, values in coded.values.items():
            maps[name] = np.full(grid.shape, np.nan)
            maps[name][grid.mask] = values
        if coded.clipped_fraction:
            clipped.append(
                f"eps clipped to the table of {channel.label} on {coded.clipped_fraction:.1%}"
            )
    return maps, tuple(clipped)


def _with_cure(
    plan: ExposurePlan,
    cure: np.ndarray,
    grid: DirectorGrid,
    settings: LaserSettings,
    before: int,
) -> ExposurePlan:
    """The cure channel's levels and its unpolarised exposures (ordered after the others)."""
    level, level_dose = _dose_levels(cure, grid.mask, settings.dose_levels)
    used, inverse = np.unique(level[grid.mask], return_inverse=True)
    index = np.full(grid.shape, -1)
    index[grid.mask] = inverse
    counts = np.bincount(inverse, minlength=len(used))
    exposures = tuple(
        CureExposure(
            order=before + k + 1,
            dose_mj_cm2=float(level_dose[code]),
            exposure_s=_seconds(level_dose[code], settings),
            pixels=int(counts[k]),
        )
        for k, code in enumerate(used.tolist())
    )
    error = float(np.nanmax(np.abs(cure - level_dose[level])[grid.mask]))
    return replace(
        plan, cure=cure, cure_index=index, cure_exposures=exposures, cure_error_mj_cm2=error
    )


def _seconds(dose: float, settings: LaserSettings) -> float | None:
    """Exposure time (s) of a dose (mJ/cm^2) at the settings' intensity, if known."""
    return float(dose / settings.intensity_mw_cm2) if settings.intensity_mw_cm2 else None


def _dose_levels(dose: np.ndarray, mask: np.ndarray, levels: int) -> tuple[np.ndarray, np.ndarray]:
    """Equal-width dose levels over the dose range: (rows, cols) level and (levels,)
    dose of each level (its centre), so the dose error is at most half a level."""
    low, high = float(np.nanmin(dose)), float(np.nanmax(dose))
    if high - low <= 1e-12 * max(high, 1.0):
        return np.zeros(dose.shape, dtype=np.int64), np.full(levels, low)
    width = (high - low) / levels
    level = np.clip(np.floor((np.nan_to_num(dose, nan=low) - low) / width), 0, levels - 1)
    return np.where(mask, level, 0).astype(np.int64), low + (np.arange(levels) + 0.5) * width


def _polariser_deg(director_deg: float, relation: str) -> float:
    """Polarisation angle (degrees in [0, 180)) that aligns the director at ``director_deg``."""
    return (director_deg + (90.0 if relation == "perpendicular" else 0.0)) % 180.0


def _half_wave_plate_deg(polarisation_deg: float, input_deg: float) -> float:
    """Fast-axis angle a in [0, 90) turning input polarisation p0 into 2 a - p0."""
    return ((polarisation_deg + input_deg) / 2.0) % 90.0
