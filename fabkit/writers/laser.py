"""Laser-writer patterns for photoalignment: angle maps, binned DMD masks, scan lines.

Input is a :class:`DirectorGrid`: the director angle theta, the shape mask and every
designable feature sampled on a square pixel grid of the flat sheet. Each feature is
exposed through its channel of the process (:mod:`fabkit.process`): ``dose_mj_cm2``, the
dose of the polarised alignment exposures, and ``cure_dose_mj_cm2``, a second,
unpolarised exposure set after them (a curing or cross-linking dose); any other channel
is refused, naming it, and so is a feature no channel encodes (unless ignored).
Conventions, also written into every sidecar and manifest:

* theta is in [0, pi), counter-clockwise from the sheet's +x axis (+y up);
* images are stored as usual, x to the right and **y down**: row 0 is the largest y;
* ``origin_mm`` is the sheet-frame position of the image's lower-left *corner*; pixel
  (row r, column c) has its centre at ``origin + pitch * (c + 1/2, rows - r - 1/2)``.

Outputs (:func:`write_laser`, one directory):

a. ``angle.png`` (16-bit, theta = value * pi / 65536), ``mask.png`` (8-bit, 255 inside),
   ``dose.png`` (16-bit, dose = value * scale / 65535, mJ/cm^2) and the sidecar
   ``angle.json``; ``--image-format tiff`` writes .tif instead of .png.
b. For DMD/SLM exposure: theta is binned into N bins centred on k * pi / N (so the
   binning error is at most half a bin, pi / 2N) and the dose into levels; every
   non-empty (angle, dose) pair becomes a 1-bit mask ``masks/exposure_NNN.png``. Each
   domain pixel lies in exactly one mask. ``manifest.json`` (schema:
   ``docs/laser-manifest.schema.json``) lists, in exposure order, each mask's director,
   polarisation (= polariser) and half-wave-plate angle, dose and exposure time, with
   the pixel pitch and field size. With a cure channel, its dose is binned into levels
   too: ``cure_dose.png`` and one mask per non-empty level ``masks/cure_NNN.png``,
   listed as ``cure_exposures`` (unpolarised, after the alignment exposures). Whether
   the director lies parallel or perpendicular to the polarisation is a material
   parameter (:attr:`LaserSettings.relation`); the half-wave plate turns the fixed
   input polarisation p0 to 2 a - p0 for fast axis a.
c. For scanning writers (a laser_writer profile that takes G-code): ``scan.gcode``, raster lines
   along x in serpentine order, one ``G1`` per run of one exposure, with the wave-plate
   fast axis as ``A`` (degrees) and the laser power as ``S`` (mW) from
   P = dose * spot width * speed; ``G0`` moves (beam off) rotate the plate.

Plus ``preview.png`` (binned director angle as a cyclic hue and the dose, in machine mm).
Everything is checked (envelope, feeds, power) before the directory is written, and the
directory appears whole or not at all.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import shapely
from PIL import Image

import fabkit
from fabkit.errors import FabkitError
from fabkit.machines import DEFAULT_RELATION, RELATIONS, LaserOptics, MachineProfile
from fabkit.process import Process, Resolution
from fabkit.writers.common import (
    IMAGE_FORMATS,
    check_inside,
    placement_offset,
)
from fabkit.writers.line_table import Word, render

MANIFEST_FORMAT = "fabkit-laser-manifest/2"
SIDECAR_FORMAT = "fabkit-angle-map/1"
DEFAULT_BINS = 18
"""Angle bins (10 degrees each, binning error <= 5 degrees)."""
DEFAULT_DOSE_MJ_CM2 = 1000.0
"""Dose when there is no eps-to-dose calibration (typical of azo-dye photoalignment)."""
DEFAULT_DOSE_LEVELS = 4
CHUNK = 1 << 16
"""Pixels sampled at once."""
LIGHT_CHANNELS = ("dose_mj_cm2", "cure_dose_mj_cm2")
"""The channels a light writer exposes."""
PREVIEW_HEIGHT_IN = 5.0
"""Height of the preview's panels (inches at 100 dpi)."""
ANGLE_CONVENTION = (
    "theta in [0, pi) counter-clockwise from the sheet +x axis (+y up); images have x to "
    "the right and y down (row 0 = largest y); origin_mm = lower-left image corner"
)
_SCAN_WORDS = (Word(" X", 4), Word(" Y", 4), Word(" A", 3), Word(" S", 3), Word(" F", 1))


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
    image_format: str = "png"
    process: Process | None = None
    ignore: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if not 1 <= self.bins <= 1000:
            raise FabkitError(f"bins must be 1..1000, got {self.bins}")
        if not 1 <= self.dose_levels <= 256:
            raise FabkitError(f"dose levels must be 1..256, got {self.dose_levels}")
        if self.relation not in RELATIONS:
            raise FabkitError(f"relation '{self.relation}' is not one of {', '.join(RELATIONS)}")
        if self.image_format not in IMAGE_FORMATS:
            raise FabkitError(f"image format '{self.image_format}' is not png or tiff")
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
    error = np.abs(_wrap(grid.theta - centres[np.maximum(label, 0)]))
    return Binning(label, centres, np.where(grid.mask, error, np.nan))


def _wrap(angle: np.ndarray) -> np.ndarray:
    """An angle mod pi, in [-pi/2, pi/2)."""
    return np.mod(angle + np.pi / 2, np.pi) - np.pi / 2


@dataclass(frozen=True)
class Exposure:
    """One DMD exposure (angles in degrees, dose mJ/cm^2, time s or None)."""

    order: int
    file: str
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
    file: str
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


def plan_exposures(grid: DirectorGrid, settings: LaserSettings, suffix: str) -> ExposurePlan:
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
                file=f"masks/exposure_{k + 1:03d}.{suffix}",
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
        plan = _with_cure(plan, maps["cure_dose_mj_cm2"], grid, settings, suffix, len(exposures))
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
    suffix: str,
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
            file=f"masks/cure_{k + 1:03d}.{suffix}",
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


@dataclass(frozen=True)
class LaserSummary:
    """What was written: the files (relative to the directory), exposures, errors (deg)."""

    files: tuple[str, ...]
    exposures: int
    domain_pixels: int
    max_binning_error_deg: float
    rms_binning_error_deg: float
    origin_mm: tuple[float, float]
    scan_lines: int = 0
    manifest: dict[str, Any] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()


def write_laser(
    grid: DirectorGrid,
    out_dir: str | Path,
    machine: MachineProfile,
    settings: LaserSettings | None = None,
    offset_mm: tuple[float, ...] | None = None,
) -> LaserSummary:
    """Write the angle map, masks, manifest, preview (and scan lines) into ``out_dir``."""
    if machine.kind != "laser_writer":
        raise FabkitError(
            f"machine {machine.name} is a {machine.kind}; laser patterns need a laser_writer "
            "profile (e.g. dmd_photoalign)"
        )
    settings = settings or LaserSettings.for_machine(machine)
    out_dir = Path(out_dir)
    low = np.array(grid.origin_mm)
    shift = placement_offset(low, low + grid.size_mm, machine, offset_mm)[:2]
    origin = low + shift
    corners = origin + np.array([[0.0, 0.0], grid.size_mm])
    check_inside(corners, machine, "laser field")
    suffix = "png" if settings.image_format == "png" else "tif"
    plan = plan_exposures(grid, settings, suffix)
    if machine.gcode and plan.cure is not None:
        raise FabkitError(
            f"machine {machine.name} cannot expose the cure_dose_mj_cm2 channel "
            f"({'+'.join(plan.resolution.channel_of('cure_dose_mj_cm2').features)}): a "
            "scanning writer has one polarised beam; use a DMD writer such as dmd_photoalign"
        )
    scan = _scan_text(grid, plan, settings, machine, origin) if machine.gcode else None
    manifest = _manifest(grid, plan, settings, machine, origin, suffix, scan is not None)
    manifest["sheet_offset_mm"] = shift.tolist()
    sidecar = _sidecar(grid, plan, origin, suffix)
    files = [
        f"angle.{suffix}",
        f"mask.{suffix}",
        f"dose.{suffix}",
        *([f"cure_dose.{suffix}"] if plan.cure is not None else []),
        "angle.json",
        "manifest.json",
        "preview.png",
        *(e.file for e in plan.exposures),
        *(e.file for e in plan.cure_exposures),
    ]
    with _atomic_directory(out_dir) as tmp:
        _write_maps(tmp, grid, plan, sidecar, suffix)
        for k, exposure in enumerate(plan.exposures):
            Image.fromarray(plan.index == k).save(tmp / exposure.file)
        for k, cure in enumerate(plan.cure_exposures):
            Image.fromarray(plan.cure_index == k).save(tmp / cure.file)
        _write_preview(tmp / "preview.png", grid, plan, origin)
        _write_json(tmp / "manifest.json", manifest)
        if scan is not None:
            (tmp / "scan.gcode").write_bytes(scan)
            files.append("scan.gcode")
    return LaserSummary(
        files=tuple(files),
        exposures=len(plan.exposures),
        domain_pixels=int(grid.mask.sum()),
        max_binning_error_deg=math.degrees(plan.binning.max_error),
        rms_binning_error_deg=math.degrees(plan.binning.rms_error),
        origin_mm=tuple(origin.tolist()),
        scan_lines=scan.count(b"\n") if scan else 0,
        manifest=manifest,
        warnings=plan.clipped,
    )


def _dose_scale(plan: ExposurePlan) -> float:
    return float(np.nanmax(plan.dose))


def _write_maps(
    folder: Path, grid: DirectorGrid, plan: ExposurePlan, sidecar: dict[str, Any], suffix: str
) -> None:
    angle = np.rint(np.nan_to_num(grid.theta) / np.pi * 65536) % 65536
    Image.fromarray(np.where(grid.mask, angle, 0).astype(np.uint16)).save(
        folder / f"angle.{suffix}"
    )
    Image.fromarray((grid.mask * 255).astype(np.uint8)).save(folder / f"mask.{suffix}")
    dose = np.rint(np.nan_to_num(plan.dose) / _dose_scale(plan) * 65535)
    Image.fromarray(dose.astype(np.uint16)).save(folder / f"dose.{suffix}")
    if plan.cure is not None:
        cure = np.rint(np.nan_to_num(plan.cure) / np.nanmax(plan.cure) * 65535)
        Image.fromarray(cure.astype(np.uint16)).save(folder / f"cure_dose.{suffix}")
    (folder / "masks").mkdir()
    _write_json(folder / "angle.json", sidecar)


def _write_preview(path: Path, grid: DirectorGrid, plan: ExposurePlan, origin: np.ndarray) -> None:
    """Binned director angle (cyclic hue) and the dose each pixel's exposure delivers,
    axes in machine mm (RGB PNG)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    rows, cols = grid.shape
    extent = (
        origin[0],
        origin[0] + cols * grid.pixel_mm,
        origin[1],
        origin[1] + rows * grid.pixel_mm,
    )  # row 0 is the top row (module docstring)
    centres = np.degrees(plan.binning.centres)[np.maximum(plan.binning.label, 0)]
    doses = [exposure.dose_mj_cm2 for exposure in plan.exposures]
    delivered = np.where(grid.mask, np.array(doses)[np.maximum(plan.index, 0)], np.nan)
    panel_width = float(np.clip(PREVIEW_HEIGHT_IN * cols / rows, 2.5, 8.0)) + 1.8
    count = 2 if plan.cure is None else 3
    figure = Figure(figsize=(count * panel_width, PREVIEW_HEIGHT_IN + 0.8), layout="constrained")
    angle_ax, dose_ax, *cure_ax = figure.subplots(1, count)
    panels = [
        (
            angle_ax,
            np.where(grid.mask, centres, np.nan),
            "hsv",
            (0.0, 180.0),
            f"director angle (degrees, {len(plan.binning.centres)} bins)",
        ),
        (
            dose_ax,
            delivered,
            "viridis",
            (None, None),
            f"dose per exposure (mJ/cm^2, {len(set(doses))} levels)",
        ),
    ]
    if plan.cure is not None:
        cure_doses = np.array([exposure.dose_mj_cm2 for exposure in plan.cure_exposures])
        cured = np.where(grid.mask, cure_doses[np.maximum(plan.cure_index, 0)], np.nan)
        label = f"cure dose (mJ/cm^2, {len(cure_doses)} levels)"
        panels.append((cure_ax[0], cured, "magma", (None, None), label))
    for ax, values, cmap, (low, high), label in panels:
        image = ax.imshow(
            values, cmap=cmap, vmin=low, vmax=high, extent=extent, interpolation="nearest"
        )
        figure.colorbar(image, ax=ax, label=label)
        ax.set_title(label.split(" (")[0])
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
    canvas = FigureCanvasAgg(figure)
    canvas.draw()
    Image.fromarray(np.asarray(canvas.buffer_rgba())[..., :3]).save(path)


def _write_json(path: Path, data: dict[str, Any]) -> None:
    path.write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")


def _sidecar(
    grid: DirectorGrid, plan: ExposurePlan, origin: np.ndarray, suffix: str
) -> dict[str, Any]:
    return {
        "format": SIDECAR_FORMAT,
        "convention": ANGLE_CONVENTION,
        "pixel_pitch_mm": grid.pixel_mm,
        "image_size_px": [grid.shape[1], grid.shape[0]],
        "field_size_mm": list(grid.size_mm),
        "origin_mm": origin.tolist(),
        "angle": {
            "file": f"angle.{suffix}",
            "bits": 16,
            "decode": "theta_rad = value * pi / 65536",
        },
        "mask": {"file": f"mask.{suffix}", "bits": 8, "decode": "inside = value > 0"},
        "dose": {
            "file": f"dose.{suffix}",
            "bits": 16,
            "unit": "mJ/cm^2",
            "scale": _dose_scale(plan),
            "decode": "dose = value * scale / 65535",
        },
        **(
            {
                "cure_dose": {
                    "file": f"cure_dose.{suffix}",
                    "bits": 16,
                    "unit": "mJ/cm^2",
                    "scale": float(np.nanmax(plan.cure)),
                    "decode": "cure dose = value * scale / 65535",
                }
            }
            if plan.cure is not None
            else {}
        ),
    }


def _manifest(
    grid: DirectorGrid,
    plan: ExposurePlan,
    settings: LaserSettings,
    machine: MachineProfile,
    origin: np.ndarray,
    suffix: str,
    scan: bool,
) -> dict[str, Any]:
    half_bin = 90.0 / settings.bins
    return {
        "format": MANIFEST_FORMAT,
        "generator": f"fabkit {fabkit.__version__}",
        "machine": machine.name,
        "angle_convention": ANGLE_CONVENTION,
        "pixel_pitch_mm": grid.pixel_mm,
        "image_size_px": [grid.shape[1], grid.shape[0]],
        "field_size_mm": list(grid.size_mm),
        "origin_mm": origin.tolist(),
        "director_relation": settings.relation,
        "input_polarisation_deg": settings.input_polarisation_deg,
        "bins": settings.bins,
        "bin_width_deg": 2 * half_bin,
        "binning_error_deg": {
            "max": math.degrees(plan.binning.max_error),
            "rms": math.degrees(plan.binning.rms_error),
            "bound": half_bin,
        },
        "dose_unit": "mJ/cm^2",
        "dose_levels": settings.dose_levels,
        "dose_error_mj_cm2": plan.dose_error_mj_cm2,
        "domain_pixels": int(grid.mask.sum()),
        "files": {
            "angle_map": f"angle.{suffix}",
            "mask": f"mask.{suffix}",
            "dose_map": f"dose.{suffix}",
            "sidecar": "angle.json",
            "preview": "preview.png",
            "scan": "scan.gcode" if scan else None,
            "cure_dose_map": f"cure_dose.{suffix}" if plan.cure is not None else None,
        },
        "channels": {
            name: "+".join(channel.features)
            for channel in plan.resolution.channels
            for name in channel.parameters
        },
        "ignored_features": list(plan.resolution.ignored),
        "mm_per_unit": grid.mm_per_unit,
        "exposures": [vars(e) for e in plan.exposures],
        "cure_dose_error_mj_cm2": plan.cure_error_mj_cm2,
        "cure_exposures": [vars(e) for e in plan.cure_exposures],
    }


def _scan_text(
    grid: DirectorGrid,
    plan: ExposurePlan,
    settings: LaserSettings,
    machine: MachineProfile,
    origin: np.ndarray,
) -> bytes:
    """Raster scan lines (module docstring, item c), checked before they are returned."""
    runs = _runs(plan.index)
    rows, first, last, exposure = runs.T
    pitch = grid.pixel_mm
    y = origin[1] + pitch * (grid.shape[0] - rows - 0.5)
    x0, x1 = origin[0] + pitch * first, origin[0] + pitch * (last + 1)
    reverse = rows % 2 == 1
    start, end = np.where(reverse, x1, x0), np.where(reverse, x0, x1)
    speed = settings.scan_speed_mm_s or machine.process.print_speed_mm_s
    _check_scan_speed(speed, machine)
    dose = np.array([e.dose_mj_cm2 for e in plan.exposures])[exposure]
    power = dose * pitch * speed / 100.0  # mJ/cm^2 * mm * mm/s / (100 mm^2/cm^2) = mW
    if settings.max_power_mw is not None and power.max() > settings.max_power_mw:
        raise FabkitError(
            f"scan power {power.max():.3f} mW is above the limit {settings.max_power_mw:g} mW; "
            "scan slower (--scan-speed) or lower the dose"
        )
    plate = np.array([e.half_wave_plate_deg for e in plan.exposures])[exposure]
    n = len(runs)
    values = np.full((2 * n, len(_SCAN_WORDS)), np.nan)
    values[0::2, :3] = np.column_stack([start, y, plate])
    values[0::2, 4] = machine.process.travel_speed_mm_s * 60.0
    values[1::2, 0] = end
    values[1::2, 3] = power
    values[1::2, 4] = speed * 60.0
    check_inside(values[:, :2], machine, "laser scan")
    limits = machine.limits
    travel_limit = min(limits.travel_mm_s, limits.x_mm_s, limits.y_mm_s)
    if machine.process.travel_speed_mm_s > travel_limit:
        raise FabkitError(
            f"travel speed {machine.process.travel_speed_mm_s:g} mm/s of {machine.name} is "
            f"above its travel and axis limits ({travel_limit:g} mm/s)"
        )
    prefix = np.tile([0, 1], n)
    body = render(prefix, ("G0", "G1"), values, np.isfinite(values), _SCAN_WORDS)
    head = [
        f"; fabkit {fabkit.__version__} laser scan for {machine.name}",
        f"; {ANGLE_CONVENTION}",
        "; A = half-wave-plate fast axis (deg), S = laser power (mW), F = mm/min; "
        "G0 moves with the beam off",
        f"; {n} scan lines, pitch {pitch:g} mm, speed {speed:g} mm/s, "
        f"input polarisation {settings.input_polarisation_deg:g} deg, "
        f"director {settings.relation} to the polarisation",
        *machine.render("start_gcode"),
        *machine.render("flow_on_gcode"),
    ]
    tail = [*machine.render("flow_off_gcode"), *machine.render("end_gcode")]
    return _text(head) + body + _text(tail)


def _text(lines: list[str]) -> bytes:
    return "".join(f"{line}\n" for line in lines).encode("ascii")


def _check_scan_speed(speed: float, machine: MachineProfile) -> None:
    limit = min(machine.limits.print_mm_s, machine.limits.x_mm_s)
    if not 0 < speed <= limit:
        raise FabkitError(
            f"scan speed {speed:g} mm/s must be in (0, {limit:g}] mm/s for {machine.name}"
        )


def _runs(index: np.ndarray) -> np.ndarray:
    """(n, 4) runs of equal exposure index along each row: row, first col, last col,
    exposure (outside pixels, index -1, make no run)."""
    rows, cols = index.shape
    padded = np.full((rows, cols + 2), -1)
    padded[:, 1:-1] = index
    change = padded[:, 1:] != padded[:, :-1]  # (rows, cols + 1): boundary before col
    r, c = np.nonzero(change)
    starts_r, starts_c = r[:-1], c[:-1]
    ends_c = c[1:] - 1
    same_row = r[1:] == r[:-1]
    value = padded[starts_r, starts_c + 1]
    keep = same_row & (value >= 0)
    runs = np.column_stack([starts_r[keep], starts_c[keep], ends_c[keep], value[keep]])
    # serpentine: odd rows run right to left
    order = np.lexsort((np.where(runs[:, 0] % 2 == 1, -runs[:, 1], runs[:, 1]), runs[:, 0]))
    return runs[order]


@contextmanager
def _atomic_directory(final: Path) -> Iterator[Path]:
    """A temporary directory beside ``final``, renamed to it on success.

    An existing ``final`` must be a directory written before by this writer (it holds a
    manifest.json) or empty; it is replaced only once the new one is complete.
    """
    if final.exists():
        if not final.is_dir():
            raise FabkitError(f"-o {final}: exists and is not a directory")
        if any(final.iterdir()) and not (final / "manifest.json").is_file():
            raise FabkitError(f"-o {final}: a non-empty directory not written by fabkit")
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{final.name}.", suffix=".part", dir=final.parent))
    try:
        yield tmp
        old = None
        if final.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{final.name}.", suffix=".old", dir=final.parent))
            os.replace(final, old / final.name)
        os.replace(tmp, final)
        if old is not None:
            shutil.rmtree(old)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp)
