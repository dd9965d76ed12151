"""Height grids from files: ``.npy``, ``.npz``, ``.csv`` and single-channel images.

``read_grid`` reads a file's raw values (NaN = hole) and its own node coordinates, if
any, checked against the side limits before the data is decoded; ``place_grid`` puts
heights on their nodes (from ``extent`` or the file's coordinates) as a
:class:`HeightGrid`. The height map surface that uses them is in
:mod:`fabkit.problem.surfaces.data`.
"""

from __future__ import annotations

import io
import re
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fabkit.errors import FabkitError
from fabkit.files.npzfile import ArrayHeader, Check, check_magnitude, npz_keys, read_npy, read_npz
from fabkit.files.readfile import decode_utf8, read_limited
from fabkit.limits import CSV_BYTES

MIN_SIDE = 8
"""Fewest nodes per side of a height grid."""
MAX_SIDE = 2048
"""Most nodes per side of a height grid."""
MAX_CELL_ASPECT = 4.0
"""Largest ratio of a grid cell's sides; more usually means a transposed grid or wrong extent."""
IMAGE_MODES = {"I;16", "I;16B", "I;16L", "I", "F", "L"}
"""Pillow modes of single-channel images (16-bit, 32-bit integer or float, 8-bit)."""
GRID_FORMATS = (".npy", ".npz", ".csv", ".png", ".tif", ".tiff")


@dataclass(frozen=True)
class HeightGrid:
    """Heights z (ny, nx), NaN = hole, with node (i, j) at origin + (i, j) * spacing."""

    z: np.ndarray
    origin: tuple[float, float]
    spacing: tuple[float, float]


def read_grid(path: Path, where: str) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray] | None]:
    """Raw values (ny, nx) as floats (NaN = hole) and the file's own node coordinates
    (x (nx,), y (ny,)) if it has them."""
    suffix = path.suffix.lower()
    if suffix == ".npy":
        values, coordinates = _read_npy(path, where), None
    elif suffix == ".npz":
        values, coordinates = _read_npz(path, where)
    elif suffix == ".csv":
        values, coordinates = _read_csv(path, where), None
    else:
        values, coordinates = _read_image(path, where), None
    return _check_values(values, path, where), coordinates


def _read_npy(path: Path, where: str) -> np.ndarray:
    """The array of an .npy file, its header checked (a 2D grid within the side limits)
    before the data is read."""
    return read_npy(path, f"{where}.file: '{path.name}'", _grid_header_check(path, where, ""))


def _read_npz(path: Path, where: str) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray] | None]:
    """Heights from key ``z`` (or the only array), holes from ``mask``, coordinates ``x``, ``y``."""
    keys = npz_keys(path, f"{where}.file: '{path.name}'")
    if "z" not in keys and len(keys) != 1:
        raise FabkitError(
            f"{where}.file: '{path.name}' needs an array named 'z' (has {sorted(keys)})"
        )
    unknown = sorted(keys - {"z", "mask", "x", "y"}) if "z" in keys else []
    if unknown:
        raise FabkitError(f"{where}.file: '{path.name}' holds an unknown array '{unknown[0]}'")
    heights = "z" if "z" in keys else next(iter(keys))
    arrays = read_npz(
        path, f"{where}.file: '{path.name}'", check=_grid_header_check(path, where, heights)
    )
    values = arrays[heights]
    if "mask" in arrays:
        mask = np.asarray(arrays["mask"], dtype=bool)
        if mask.shape != values.shape:
            raise FabkitError(f"{where}.file: 'mask' in '{path.name}' has another shape than 'z'")
        values = np.where(mask, np.nan, values)
    if ("x" in arrays) != ("y" in arrays):
        raise FabkitError(f"{where}.file: '{path.name}' must hold both 'x' and 'y', or neither")
    if "x" not in arrays:
        return values, None
    return values, (np.ravel(arrays["x"]).astype(float), np.ravel(arrays["y"]).astype(float))


def _grid_header_check(path: Path, where: str, key: str) -> Check:
    """A check of .npy headers: array ``key`` is a 2D grid within the side limits."""

    def check(headers: Mapping[str, ArrayHeader]) -> None:
        shape = headers[key].shape
        if len(shape) != 2:
            raise FabkitError(
                f"{where}.file: '{path.name}' holds a {len(shape)}D array; a height grid is 2D"
            )
        _check_shape(shape, path.name, where)

    return check


def _read_csv(path: Path, where: str) -> np.ndarray:
    """A CSV grid of numbers (at most CSV_BYTES). Errors never quote the file's text (it
    may be a link to another file): they name the row and column."""
    what = f"{where}.file: height map"
    text = decode_utf8(read_limited(path, what, CSV_BYTES), what, path.name)
    try:
        with warnings.catch_warnings():
            # an empty grid is refused by the side check, not announced by numpy
            warnings.simplefilter("ignore", UserWarning)
            return np.loadtxt(io.StringIO(text), delimiter=",", ndmin=2, comments="#")
    except ValueError as exc:
        found = re.search(r"at row (\d+)(?:, column (\d+))?", str(exc))
        place = ""
        if found:
            place = f"row {int(found[1]) + 1}" + (f", column {found[2]}" if found[2] else "")
            place = f" at {place}"
        raise FabkitError(
            f"{where}.file: '{path.name}' is not a grid of numbers{place} (a value that is not "
            "a number, or rows of different lengths); write holes as nan"
        ) from None


def _read_image(path: Path, where: str) -> np.ndarray:
    """Single-channel image as an array, flipped so that row 0 is the bottom (y0); its
    size is checked from its header before its pixels are decoded."""
    from PIL import Image, UnidentifiedImageError

    formats = ["PNG"] if path.suffix.lower() == ".png" else ["TIFF"]
    try:
        with warnings.catch_warnings():
            # Pillow warns of images over MAX_IMAGE_PIXELS; the side check refuses them
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            image = Image.open(path, formats=formats)
        with image:
            width, height = image.size
            _check_shape((height, width), path.name, where)
            image.load()
            mode, values = image.mode, np.array(image)
    except Image.DecompressionBombError:
        raise FabkitError(
            f"{where}.file: '{path.name}' is an image of more than {2 * Image.MAX_IMAGE_PIXELS} "
            f"pixels; need {MIN_SIDE} to {MAX_SIDE} nodes per side"
        ) from None
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError, EOFError) as exc:
        reason = str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__
        raise FabkitError(
            f"{where}.file: '{path.name}' is not a readable image ({reason})"
        ) from None
    if mode not in IMAGE_MODES:
        raise FabkitError(
            f"{where}.file: '{path.name}' is a {mode} image; save heights as a single-channel "
            "(grayscale) 16-bit image"
        )
    return values[::-1]


def _numeric(array: np.ndarray, path: Path, where: str) -> np.ndarray:
    if array.dtype.kind not in "biuf":
        raise FabkitError(f"{where}.file: '{path.name}' holds {array.dtype} values, not numbers")
    return array


def _check_values(values: np.ndarray, path: Path, where: str) -> np.ndarray:
    """Float heights (ny, nx): 2D, numeric, sides within limits."""
    values = _numeric(np.asarray(values), path, where).astype(float)
    if values.ndim != 2:
        raise FabkitError(
            f"{where}.file: '{path.name}' holds a {values.ndim}D array; a height grid is 2D"
        )
    _check_shape(values.shape, path.name, where)
    return values


def check_heights(heights: np.ndarray, name: str, where: str) -> None:
    """Heights (raw values times z_scale): no infinities, some finite, all within
    +-MAGNITUDE."""
    if np.isinf(heights).any():
        raise FabkitError(f"{where}.file: '{name}' contains infinite heights (after z_scale)")
    if not np.isfinite(heights).any():
        raise FabkitError(f"{where}.file: '{name}' has no finite heights")
    check_magnitude(heights, "heights", f"{where}.file: '{name}'")


def _check_shape(shape: tuple[int, int], name: str, where: str) -> None:
    if min(shape) < MIN_SIDE or max(shape) > MAX_SIDE:
        raise FabkitError(
            f"{where}.file: '{name}' is a {shape[0]} x {shape[1]} grid; "
            f"need {MIN_SIDE} to {MAX_SIDE} nodes per side"
        )


def place_grid(
    z: np.ndarray,
    coordinates: tuple[np.ndarray, np.ndarray] | None,
    extent: tuple[float, float, float, float] | None,
    where: str,
) -> HeightGrid:
    """The grid of heights z (ny, nx) over the extent or the file's coordinates, checked."""
    ny, nx = z.shape
    if coordinates is None and extent is None:
        raise FabkitError(f"{where}: missing key 'extent' = [x0, x1, y0, y1]")
    if coordinates is not None:
        own = _coordinate_extent(coordinates, (ny, nx), where)
        if extent is not None and not np.allclose(own, extent, rtol=0, atol=1e-6 * _span(own)):
            raise FabkitError(
                f"{where}.extent: {list(extent)} does not match the file's coordinates "
                f"{[round(v, 6) for v in own]}"
            )
        extent = own
    x0, x1, y0, y1 = extent
    spacing = ((x1 - x0) / (nx - 1), (y1 - y0) / (ny - 1))
    aspect = spacing[0] / spacing[1]
    if not 1 / MAX_CELL_ASPECT <= aspect <= MAX_CELL_ASPECT:
        raise FabkitError(
            f"{where}.extent: {[x0, x1, y0, y1]} gives {spacing[0]:.3g} x {spacing[1]:.3g} "
            f"cells for a grid of {ny} rows x {nx} columns; cells more than "
            f"{MAX_CELL_ASPECT:g} times longer one way mean a wrong extent or a transposed grid"
        )
    return HeightGrid(z, (x0, y0), spacing)


def _span(extent: tuple[float, ...]) -> float:
    return max(extent[1] - extent[0], extent[3] - extent[2])


def _coordinate_extent(
    coordinates: tuple[np.ndarray, np.ndarray], shape: tuple[int, int], where: str
) -> tuple[float, float, float, float]:
    """(x0, x1, y0, y1) from evenly spaced increasing node coordinates x (nx,), y (ny,)."""
    x, y = coordinates
    if (len(y), len(x)) != shape:
        raise FabkitError(
            f"{where}.file: 'x' and 'y' have {len(x)} and {len(y)} values for a grid of "
            f"{shape[0]} rows x {shape[1]} columns"
        )
    for label, values in (("x", x), ("y", y)):
        steps = np.diff(values)
        if (
            not (np.all(np.isfinite(values)) and steps.min() > 0)
            or np.ptp(steps) > 1e-6 * steps.mean()
        ):
            raise FabkitError(f"{where}.file: '{label}' must be evenly spaced and increasing")
    return float(x[0]), float(x[-1]), float(y[0]), float(y[-1])
