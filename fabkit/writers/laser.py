"""Laser-writer patterns for photoalignment: angle maps, binned DMD masks, scan lines.

Input is a :class:`~fabkit.toolpath.exposure.DirectorGrid`: the director angle theta, the
shape mask and every designable feature sampled on a square pixel grid of the flat sheet;
the exposures are planned by :func:`~fabkit.toolpath.exposure.plan_exposures`. Each feature is
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
   parameter (:attr:`~fabkit.toolpath.exposure.LaserSettings.relation`); the half-wave
   plate turns the fixed input polarisation p0 to 2 a - p0 for fast axis a.
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
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from fabkit.errors import FabkitError
from fabkit.machines import MachineProfile
from fabkit.toolpath.exposure import (
    CureExposure,
    DirectorGrid,
    Exposure,
    ExposurePlan,
    LaserSettings,
    plan_exposures,
)
from fabkit.version import __version__
from fabkit.writers.common import (
    IMAGE_FORMATS,
    check_inside,
    placement_offset,
)
from fabkit.writers.line_table import Word, render

MANIFEST_FORMAT = "fabkit-laser-manifest/2"
SIDECAR_FORMAT = "fabkit-angle-map/1"
PREVIEW_HEIGHT_IN = 5.0
"""Height of the preview's panels (inches at 100 dpi)."""
PREVIEW_PIXELS = 1000
"""The most pixels along a side a preview panel shows (its panel is at most 800 px across
at 100 dpi): a larger pattern is shown every k-th pixel, which the picture cannot tell
from the whole at that size (Fig. 3 at 20 mm, 3 million pixels: matplotlib took 2.5 s to
resample it)."""
ANGLE_CONVENTION = (
    "theta in [0, pi) counter-clockwise from the sheet +x axis (+y up); images have x to "
    "the right and y down (row 0 = largest y); origin_mm = lower-left image corner"
)
_SCAN_WORDS = (Word(" X", 4), Word(" Y", 4), Word(" A", 3), Word(" S", 3), Word(" F", 1))


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
    image_format: str = "png",
) -> LaserSummary:
    """Plan the exposures (:func:`fabkit.toolpath.exposure.plan_exposures`) and write the
    angle map, masks, manifest, preview (and scan lines) into ``out_dir``; images as
    ``image_format`` (png or tiff)."""
    if image_format not in IMAGE_FORMATS:
        raise FabkitError(f"image format '{image_format}' is not png or tiff")
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
    suffix = "png" if image_format == "png" else "tif"
    plan = plan_exposures(grid, settings)
    masks = _mask_files(plan, suffix)
    if machine.gcode and plan.cure is not None:
        raise FabkitError(
            f"machine {machine.name} cannot expose the cure_dose_mj_cm2 channel "
            f"({'+'.join(plan.resolution.channel_of('cure_dose_mj_cm2').features)}): a "
            "scanning writer has one polarised beam; use a DMD writer such as dmd_photoalign"
        )
    scan = _scan_text(grid, plan, settings, machine, origin) if machine.gcode else None
    manifest = _manifest(grid, plan, settings, machine, origin, suffix, masks, scan is not None)
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
        *masks[0],
        *masks[1],
    ]
    with _atomic_directory(out_dir) as tmp:
        _write_maps(tmp, grid, plan, sidecar, suffix)
        for k, name in enumerate(masks[0]):
            _save_mask(plan.index == k, tmp / name)
        for k, name in enumerate(masks[1]):
            _save_mask(plan.cure_index == k, tmp / name)
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


def _mask_files(plan: ExposurePlan, suffix: str) -> tuple[list[str], list[str]]:
    """The mask file of every alignment exposure and of every cure exposure, in order."""
    return (
        [f"masks/exposure_{k + 1:03d}.{suffix}" for k in range(len(plan.exposures))],
        [f"masks/cure_{k + 1:03d}.{suffix}" for k in range(len(plan.cure_exposures))],
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
    every = -(-max(rows, cols) // PREVIEW_PIXELS)  # the shown pixels' step
    shown = (slice(None, None, every), slice(None, None, every))
    mask = grid.mask[shown]
    centres = np.degrees(plan.binning.centres)[np.maximum(plan.binning.label[shown], 0)]
    doses = [exposure.dose_mj_cm2 for exposure in plan.exposures]
    delivered = np.where(mask, np.array(doses)[np.maximum(plan.index[shown], 0)], np.nan)
    panel_width = float(np.clip(PREVIEW_HEIGHT_IN * cols / rows, 2.5, 8.0)) + 1.8
    count = 2 if plan.cure is None else 3
    figure = Figure(figsize=(count * panel_width, PREVIEW_HEIGHT_IN + 0.8), layout="constrained")
    angle_ax, dose_ax, *cure_ax = figure.subplots(1, count)
    panels = [
        (
            angle_ax,
            np.where(mask, centres, np.nan),
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
        cured = np.where(mask, cure_doses[np.maximum(plan.cure_index[shown], 0)], np.nan)
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


def _save_mask(mask: np.ndarray, path: Path) -> None:
    """One exposure's mask (1 bit per pixel); a PNG at zlib's fastest level with its
    run-length strategy: the masks are mostly runs of one value, and at the default level
    their encoding took most of a pattern's time (Fig. 3 at 20 mm: 293 masks of 3 million
    pixels, 2.8 s; 4x faster at level 1, and run-length a quarter faster again, 9.9 -> 7.3
    ms a mask, the files a quarter smaller). Any PNG reader reads it: the strategy only
    chooses how zlib finds repeats."""
    options = {"compress_level": 1, "compress_type": zlib.Z_RLE} if path.suffix == ".png" else {}
    Image.fromarray(mask).save(path, **options)


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
    masks: tuple[list[str], list[str]],
    scan: bool,
) -> dict[str, Any]:
    half_bin = 90.0 / settings.bins
    return {
        "format": MANIFEST_FORMAT,
        "generator": f"fabkit {__version__}",
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
        "exposures": [_listed(e, f) for e, f in zip(plan.exposures, masks[0], strict=True)],
        "cure_dose_error_mj_cm2": plan.cure_error_mj_cm2,
        "cure_exposures": [
            _listed(e, f) for e, f in zip(plan.cure_exposures, masks[1], strict=True)
        ],
    }


def _listed(exposure: Exposure | CureExposure, file: str) -> dict[str, Any]:
    """An exposure as the manifest lists it: its order, its mask file, its optics."""
    fields = vars(exposure)
    return {"order": fields["order"], "file": file, **fields}


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
        f"; fabkit {__version__} laser scan for {machine.name}",
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
