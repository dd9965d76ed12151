"""Read a laser writer's patterns back as the writer exposes them: director and doses.

The folder written by ``fabkit export --format laser`` holds ``manifest.json`` and one
1-bit mask per exposure. A DMD writer projects each mask in turn with its light: the
half-wave plate at ``half_wave_plate_deg`` turns the input polarisation p0 into
2 a - p0, and the material's director lies perpendicular (or parallel, per
``director_relation``) to that polarisation; every pixel a mask covers receives its dose.
So, per pixel: the director from the plate angle of the exposure that covers it, the
alignment dose as the sum over the exposures covering it, the cure dose as the sum over
the cure exposures (manifest format 2), and how many alignment exposures covered it
(more than one is an overlap). Nothing of the writer is used.

Large fields are read back on cells of several pixels (at most :data:`MAX_SIDE` cells a
side): the director averaged as a tensor, doses and coverage averaged over the pixels
covered.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from fabkit.errors import FabkitError
from fabkit.files.readfile import read_json
from fabkit.verify.raster import Readback
from fabkit.verify.read_gcode import Placement

FORMATS = ("fabkit-laser-manifest/1", "fabkit-laser-manifest/2")
MAX_SIDE = 600
"""Cells along the longer side of a laser read-back."""
MAX_PIXELS = 100_000_000
"""Most pixels of a laser pattern verify reads."""
MAX_MASKS = 10_000
"""Most exposure masks of a laser pattern verify reads."""


def read_laser(folder: str | Path) -> tuple[Readback, Placement, dict[str, Any]]:
    """The pattern in ``folder`` on a grid in the *machine* frame (mm), the placement the
    manifest records, and the manifest; one-line errors."""
    folder = Path(folder)
    manifest = _manifest(folder)
    width, height = _pair(manifest, "image_size_px", int)
    if not (width > 0 and height > 0) or width * height > MAX_PIXELS:
        raise FabkitError(f"{folder}: {width} x {height} pixels is more than verify reads")
    pitch = _number(manifest, "pixel_pitch_mm")
    hits = np.zeros((height, width), dtype=np.int32)
    cos2 = np.zeros((height, width))
    sin2 = np.zeros((height, width))
    dose = np.zeros((height, width))
    p0 = _number(manifest, "input_polarisation_deg", positive=False)
    turn = 90.0 if manifest.get("director_relation") == "perpendicular" else 0.0
    if len(_list(manifest, "exposures")) + len(manifest.get("cure_exposures") or []) > MAX_MASKS:
        raise FabkitError(f"{folder}/manifest.json: more than {MAX_MASKS} exposures")
    for exposure in _list(manifest, "exposures"):
        mask = _mask(folder, exposure, (height, width))
        plate = _number(exposure, "half_wave_plate_deg", positive=False)
        director = math.radians((2 * plate - p0 - turn) % 180.0)
        hits += mask
        cos2 += mask * math.cos(2 * director)
        sin2 += mask * math.sin(2 * director)
        dose += mask * _number(exposure, "dose_mj_cm2")
    values = {"dose_mj_cm2": dose}
    cures = _list(manifest, "cure_exposures") if "cure_exposures" in manifest else []
    if cures:
        cure = np.zeros((height, width))
        for exposure in cures:
            cure += _mask(folder, exposure, (height, width)) * _number(exposure, "dose_mj_cm2")
        values["cure_dose_mj_cm2"] = cure
    origin = _pair(manifest, "origin_mm", float)
    readback = _cells(hits, cos2, sin2, values, pitch, origin)
    offset = manifest.get("sheet_offset_mm")
    scale = manifest.get("mm_per_unit")
    placement = Placement(
        tuple(float(v) for v in offset[:2]) if isinstance(offset, list) else None,
        float(scale) if isinstance(scale, int | float) else None,
        f"{folder.name}/manifest.json",
    )
    return readback, placement, manifest


def _cells(
    hits: np.ndarray,
    cos2: np.ndarray,
    sin2: np.ndarray,
    values: dict[str, np.ndarray],
    pitch: float,
    origin: tuple[float, float],
) -> Readback:
    """Image arrays (row 0 at the top) as a read-back on cells of k x k pixels."""
    rows, cols = hits.shape
    k = max(1, math.ceil(max(rows, cols) / MAX_SIDE))
    covered = (hits > 0).astype(float)

    def block(image: np.ndarray) -> np.ndarray:
        """Sum over k x k blocks, as (x, y) cells with y increasing."""
        padded = np.zeros((math.ceil(rows / k) * k, math.ceil(cols / k) * k))
        padded[:rows, :cols] = image  # row 0 stays the top row; padding below
        summed = padded.reshape(padded.shape[0] // k, k, padded.shape[1] // k, k).sum((1, 3))
        return summed[::-1].T

    count = block(covered)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = {name: block(v * covered) / count for name, v in values.items()}
        hit = np.where(count > 0, block(hits.astype(float)) / np.maximum(count, 1), 0.0)
        theta = np.where(count > 0, 0.5 * np.arctan2(block(sin2), block(cos2)), np.nan)
    top = rows * pitch  # the image's top edge above its lower-left corner
    bottom = top - math.ceil(rows / k) * k * pitch  # cells start at the padded bottom
    return Readback(
        origin=(origin[0], origin[1] + bottom),
        cell_mm=k * pitch,
        hits=hit,
        theta=theta,
        values={name: np.where(count > 0, v, np.nan) for name, v in mean.items()},
        width_mm=pitch,
        notes=(f"read on cells of {k} x {k} pixels",) if k > 1 else (),
    )


def _manifest(folder: Path) -> dict[str, Any]:
    path = folder / "manifest.json"
    if not path.is_file():
        raise FabkitError(f"{folder}: no manifest.json (not a laser pattern folder)")
    manifest = read_json(path, "laser manifest")
    if not isinstance(manifest, dict) or manifest.get("format") not in FORMATS:
        raise FabkitError(f"{path}: not a fabkit laser manifest ({', '.join(FORMATS)})")
    return manifest


def _mask(folder: Path, exposure: dict[str, Any], shape: tuple[int, int]) -> np.ndarray:
    name = exposure.get("file")
    if not isinstance(name, str) or ".." in Path(name).parts or Path(name).is_absolute():
        raise FabkitError(f"{folder}/manifest.json: exposure file {name!r} is not in the folder")
    path = folder / name
    try:
        with Image.open(path) as image:
            if image.size != shape[::-1]:  # checked before the pixels are decoded
                raise FabkitError(f"{path}: the mask is {image.size} pixels, not {shape[::-1]}")
            mask = np.asarray(image.convert("L")) > 0
    except (OSError, ValueError, Image.DecompressionBombError) as exc:
        raise FabkitError(f"{path}: cannot read the mask ({exc})") from None
    return mask


def _list(table: dict[str, Any], key: str) -> list[dict[str, Any]]:
    value = table.get(key)
    if not isinstance(value, list) or not all(isinstance(item, dict) for item in value):
        raise FabkitError(f"manifest.json: {key} must be a list of objects")
    return value


def _number(table: dict[str, Any], key: str, positive: bool = True) -> float:
    value = table.get(key)
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise FabkitError(f"manifest.json: {key} must be a finite number, got {value!r}")
    if positive and value <= 0:
        raise FabkitError(f"manifest.json: {key} must be > 0, got {value!r}")
    return float(value)


def _pair(table: dict[str, Any], key: str, kind: type) -> tuple[Any, Any]:
    value = table.get(key)
    if not (isinstance(value, list) and len(value) == 2):
        raise FabkitError(f"manifest.json: {key} must be a pair of numbers, got {value!r}")
    try:
        return kind(value[0]), kind(value[1])
    except (TypeError, ValueError):
        raise FabkitError(f"manifest.json: {key} must be a pair of numbers") from None
