"""Targets from data: height maps and meshes, fitted with a smooth surface.

Two geometry kinds, both height fields z = f(x, y) over the data's footprint:

* ``{ kind = "heightmap", file = "...", extent = [x0, x1, y0, y1], z_scale = 1.0 }`` reads
  a grid from ``.npy``, ``.npz``, ``.csv`` or a single-channel (16-bit) ``.png``/``.tif``.
  Row j, column i holds the height at (x0 + i hx, y0 + j hy), so ``extent`` gives the
  coordinates of the first and last columns and rows; images are stored top row first,
  so their top row is y1. NaN cells, cells where an ``.npz`` ``mask`` is True, and cells
  equal to ``nodata`` (raw value) are holes. An ``.npz`` may carry its own ``x`` (nx,)
  and ``y`` (ny,) node coordinates instead of ``extent``.
* ``{ kind = "mesh", file = "....stl|obj|ply", axis = "z" }`` reads a triangle mesh with
  trimesh, refuses it unless it is a height field over the plane normal to ``axis``,
  and resamples it on a grid: at its own vertices when they form a regular grid,
  otherwise at its mean vertex spacing. The chart is (x, y) for axis z, (y, z) for
  axis x and (z, x) for axis y.

Both take an optional ``smoothing`` (chart units; one length or [along chart axis 1,
along chart axis 2]); without it the smoothing is chosen from the data's noise
(see :mod:`fabkit.problem.surfaces.fit`). The chart domain is the footprint: grid cells whose
corners are data and more than ``HOLE_MARGIN`` nodes from any hole; leaving it is a
solver stop (``contains`` is False).
"""

from __future__ import annotations

import contextlib
import io
import logging
import re
import warnings
from abc import abstractmethod
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, Self

import numpy as np
from scipy import ndimage

from fabkit.errors import FabkitError
from fabkit.limits import CSV_BYTES, MAGNITUDE, MESH_BYTES, MESH_FACES, RASTER_HITS
from fabkit.npzfile import ArrayHeader, Check, check_magnitude, npz_keys, read_npy, read_npz
from fabkit.problem.surfaces.base import Surface, graph_geometry
from fabkit.problem.surfaces.fit import SurfaceFit, fit_grid
from fabkit.readfile import decode_utf8, read_limited
from fabkit.tomlfile import Table, expected, real

MIN_SIDE = 8
"""Fewest nodes per side of a height grid."""
MAX_SIDE = 2048
"""Most nodes per side of a height grid."""
MESH_MAX_SIDE = 1024
"""Most nodes per side when resampling an irregular mesh."""
MAX_CELL_ASPECT = 4.0
"""Largest ratio of a grid cell's sides; more usually means a transposed grid or wrong extent."""
HOLE_MARGIN = 2.0
"""Nodes this close to a hole (in node spacings) are outside the footprint: the fit is
less reliable there."""
QUADRATIC_NEIGHBOURS = 16
"""Vertices in each local quadratic fit when resampling an irregular mesh."""
K_SAMPLES = 250_000
"""Most footprint cells at which the K range of the summary is evaluated."""
IMAGE_MODES = {"I;16", "I;16B", "I;16L", "I", "F", "L"}
"""Pillow modes of single-channel images (16-bit, 32-bit integer or float, 8-bit)."""
CHARTS = {"x": (1, 2, 0), "y": (2, 0, 1), "z": (0, 1, 2)}
"""For each height axis: indices in (x, y, z) of chart coordinate 1, chart coordinate 2, height."""
GRID_FORMATS = (".npy", ".npz", ".csv", ".png", ".tif", ".tiff")
MESH_FORMATS = (".stl", ".obj", ".ply")


@dataclass(frozen=True)
class HeightGrid:
    """Heights z (ny, nx), NaN = hole, with node (i, j) at origin + (i, j) * spacing."""

    z: np.ndarray
    origin: tuple[float, float]
    spacing: tuple[float, float]


@dataclass(frozen=True)
class _Nodes:
    """The nodes of a resampling grid: (ny, nx) = ``shape``, node (i, j) at
    origin + (i, j) * spacing (chart units)."""

    origin: tuple[float, float]
    spacing: tuple[float, float]
    shape: tuple[int, int]

    def points(self, columns: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Chart points (..., 2) of the nodes in ``columns`` i and ``rows`` j (...)."""
        (x0, y0), (hx, hy) = self.origin, self.spacing
        return np.stack([x0 + columns * hx, y0 + rows * hy], -1)


class DataSurface(Surface):
    """A height field fitted to data; chart = the two coordinates across ``axis``.

    g = I + grad f grad f^T, Gamma^i_jk = f_i f_jk / (1 + |grad f|^2) and
    K = (f_xx f_yy - f_xy^2) / (1 + |grad f|^2)^2, from the fit's closed-form derivatives.
    """

    options: tuple[str, ...]
    """The kind's own keys in its geometry table, besides kind, file and smoothing."""
    formats: tuple[str, ...]
    """The file name endings the kind reads."""

    def __init__(self, name: str, source: str, grid: HeightGrid, fit: SurfaceFit, axis: str = "z"):
        self.name, self.source, self.fit, self.axis = name, source, fit, axis
        self.chart = tuple("xyz"[i] for i in CHARTS[axis][:2])
        ny, nx = grid.z.shape
        (x0, y0), (hx, hy) = grid.origin, grid.spacing
        self.bounds = ((x0, x0 + (nx - 1) * hx), (y0, y0 + (ny - 1) * hy))
        self.footprint = footprint_cells(np.isfinite(grid.z))
        self.curvature_range = self._curvature_range()

    @classmethod
    def from_table(cls, name: str, t: Table, base_dir: Path) -> Self:
        """The surface of a spec's geometry table: its ``file`` (relative to ``base_dir``,
        one of ``formats``), the kind's ``options`` and ``smoothing``, read and fitted."""
        t.check_keys({"kind", "file", *cls.options, "smoothing"})
        return cls._load(name, data_file(t, base_dir, cls.formats), t)

    @classmethod
    @abstractmethod
    def _load(cls, name: str, path: Path, t: Table) -> Self:
        """The surface of the existing data file ``path``, with the rest of ``table``."""

    def geometry(self, r: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return graph_geometry(self.fit.derivatives(r)[1:])

    def embed(self, r: np.ndarray) -> np.ndarray:
        r = np.asarray(r, dtype=float)
        columns = (r[..., 0], r[..., 1], self.fit.derivatives(r)[0])
        order = np.argsort(CHARTS[self.axis])
        return np.stack([columns[k] for k in order], axis=-1)

    def contains(self, r: np.ndarray) -> np.ndarray:
        r = np.asarray(r, dtype=float)
        inside = super().contains(r)
        cells = self.footprint
        (x0, _), (y0, _) = self.bounds
        (hx, hy) = self.fit.spacing
        with np.errstate(invalid="ignore"):
            i = np.clip((r[..., 0] - x0) / hx, 0, cells.shape[1] - 1)
            j = np.clip((r[..., 1] - y0) / hy, 0, cells.shape[0] - 1)
        i = np.where(inside, i, 0).astype(np.intp)
        j = np.where(inside, j, 0).astype(np.intp)
        return inside & cells[j, i]

    def describe(self) -> str:
        (x0, x1), (y0, y1) = self.bounds
        a, b = self.chart
        ny, nx = self.fit.shape
        fit = self.fit
        how = f"chosen from noise {fit.noise:.2g}" if fit.chosen else "set"
        k_low, k_high = self.curvature_range
        return (
            f"{self.kind} {self.source}, {nx} x {ny} grid over {a} [{x0:g}, {x1:g}], "
            f"{b} [{y0:g}, {y1:g}], footprint {self.footprint.mean():.0%} of it; "
            f"fit rms {fit.residual:.2g}, smoothing {fit.smoothing[0]:.3g} x "
            f"{fit.smoothing[1]:.3g} ({how}); K in [{k_low:.3g}, {k_high:.3g}]"
        )

    def _curvature_range(self) -> tuple[float, float]:
        """(min, max) of K at the centres of footprint cells (a regular subsample if many)."""
        rows, columns = np.nonzero(self.footprint)
        stride = max(1, int(np.ceil(len(rows) / K_SAMPLES)))
        (x0, _), (y0, _) = self.bounds
        hx, hy = self.fit.spacing
        centres = np.stack(
            [x0 + (columns[::stride] + 0.5) * hx, y0 + (rows[::stride] + 0.5) * hy], axis=-1
        )
        curvature = self.curvature(centres)
        return float(curvature.min()), float(curvature.max())


class HeightMap(DataSurface):
    """``kind = "heightmap"``: a height grid from a file."""

    kind = "heightmap"
    options = ("extent", "z_scale", "nodata")
    formats = GRID_FORMATS

    @classmethod
    def _load(cls, name: str, path: Path, t: Table) -> HeightMap:
        where = t.at()
        extent = _extent(t["extent"], t.at("extent")) if "extent" in t else None
        z_scale = t.number("z_scale", default=1.0)
        if z_scale == 0:
            t.expected("z_scale", "a non-zero number", t["z_scale"])
        nodata = t.number("nodata") if "nodata" in t else None
        smoothing = _smoothing(t)
        grid, fit = _heightmap_fit(
            str(path), _stamp(path), extent, z_scale, nodata, smoothing, where
        )
        return cls(name, path.name, grid, fit)


class MeshSurface(DataSurface):
    """``kind = "mesh"``: a triangle mesh that is a height field over the plane normal to axis."""

    kind = "mesh"
    options = ("axis",)
    formats = MESH_FORMATS

    @classmethod
    def _load(cls, name: str, path: Path, t: Table) -> MeshSurface:
        axis = t.text("axis", tuple(CHARTS), default="z")
        smoothing = _smoothing(t)
        grid, fit = _mesh_fit(str(path), _stamp(path), axis, smoothing, t.at())
        return cls(name, path.name, grid, fit, axis)


def footprint_cells(valid: np.ndarray) -> np.ndarray:
    """(ny - 1, nx - 1) True for grid cells whose four corners are data nodes more than
    HOLE_MARGIN node spacings from every hole, for valid (ny, nx) data nodes."""
    trusted = valid if valid.all() else ndimage.distance_transform_edt(valid) > HOLE_MARGIN
    return trusted[:-1, :-1] & trusted[1:, :-1] & trusted[:-1, 1:] & trusted[1:, 1:]


def data_file(t: Table, base_dir: Path, formats: tuple[str, ...]) -> Path:
    """The existing, non-empty data file named by ``file``, relative to base_dir."""
    where = t.at()
    name = t.raw("file", 'a file name, like file = "face.npy"')
    if not isinstance(name, str) or not name:
        t.expected("file", 'a file name, like file = "face.npy"', name)
    path = Path(base_dir) / name
    if path.suffix.lower() not in formats:
        raise FabkitError(
            f"{where}.file: '{name}' has an unsupported format (use {', '.join(formats)})"
        )
    if not path.is_file():
        raise FabkitError(f"{where}.file: '{path}' does not exist")
    if path.stat().st_size == 0:
        raise FabkitError(f"{where}.file: '{path}' is empty")
    return path


def _stamp(path: Path) -> tuple[int, int]:
    """(modification time ns, size): a fitted file is refitted when it changes."""
    status = path.stat()
    return status.st_mtime_ns, status.st_size


def _smoothing(t: Table) -> tuple[float, float] | None:
    """``smoothing = L`` or ``[L1, L2]`` (chart units, >= 0), or None when absent."""
    if "smoothing" not in t:
        return None
    value = t["smoothing"]
    values = value if isinstance(value, list) else [value, value]
    if len(values) != 2:
        t.expected("smoothing", "a length or two, like 0.5 or [0.5, 1]", value)
    where = t.at("smoothing")
    lengths = tuple(real(v, where, nonnegative=True, bound=MAGNITUDE) for v in values)
    return lengths[0], lengths[1]


def _extent(value: Any, where: str) -> tuple[float, float, float, float]:
    what = "[x0, x1, y0, y1] with x0 < x1 and y0 < y1"
    if not isinstance(value, list) or len(value) != 4:
        expected(where, what, value)
    x0, x1, y0, y1 = (real(v, f"{where}[{i}]") for i, v in enumerate(value))
    check_magnitude(np.array([x0, x1, y0, y1]), "extent", where)
    if not (x0 < x1 and y0 < y1):
        expected(where, what, value)
    return x0, x1, y0, y1


@lru_cache(maxsize=8)
def _heightmap_fit(
    path: str,
    stamp: tuple[int, int],
    extent: tuple[float, float, float, float] | None,
    z_scale: float,
    nodata: float | None,
    smoothing: tuple[float, float] | None,
    where: str,
) -> tuple[HeightGrid, SurfaceFit]:
    """Read and fit a height map (cached on the file's stamp and the settings)."""
    values, coordinates = read_grid(Path(path), where)
    if nodata is not None:
        values = np.where(values == nodata, np.nan, values)
    with np.errstate(over="ignore"):
        heights = values * z_scale
    _check_heights(heights, Path(path).name, where)
    grid = _place(heights, coordinates, extent, where)
    return grid, _fit(grid, smoothing, where)


@lru_cache(maxsize=8)
def _mesh_fit(
    path: str,
    stamp: tuple[int, int],
    axis: str,
    smoothing: tuple[float, float] | None,
    where: str,
) -> tuple[HeightGrid, SurfaceFit]:
    """Read, check, resample and fit a mesh (cached on the file's stamp and the settings)."""
    vertices, faces = read_mesh(Path(path), where)
    grid = mesh_grid(vertices[:, list(CHARTS[axis])], faces, axis, where)
    return grid, _fit(grid, smoothing, where)


def _fit(grid: HeightGrid, smoothing: tuple[float, float] | None, where: str) -> SurfaceFit:
    """The fit of a grid that has a footprint left."""
    if not footprint_cells(np.isfinite(grid.z)).any():
        raise FabkitError(
            f"{where}.file: no grid cell has data at its four corners away from holes "
            "(too many holes)"
        )
    return fit_grid(grid.z, grid.origin, grid.spacing, smoothing)


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


def _check_heights(heights: np.ndarray, name: str, where: str) -> None:
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


def _place(
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


def _stl_intact(data: bytes) -> bool:
    """A text STL (``solid ...``), or a binary one exactly as long as the triangle count in
    its header says (84 bytes + 50 a triangle): trimesh 5 reads a truncated binary STL as
    an empty mesh instead of refusing it."""
    if data.lstrip()[:5].lower() == b"solid" and b"facet" in data[:4096]:
        return True
    count = int.from_bytes(data[80:84], "little") if len(data) >= 84 else -1
    return len(data) == 84 + 50 * count


def read_mesh(path: Path, where: str) -> tuple[np.ndarray, np.ndarray]:
    """The mesh's vertices (V, 3) and triangles (T, 3) as vertex indices, checked finite and
    non-empty.

    The file (at most MESH_BYTES) is handed to trimesh as bytes without a name, so that no
    other file it names is opened (an OBJ's material library, a texture image that may be
    a decompression bomb, a PLY's ``TextureFile``), and trimesh's warnings and log lines
    are held back (the command line prints one line).
    """
    import trimesh

    data = read_limited(path, f"{where}.file: mesh", MESH_BYTES)
    kind = path.suffix.lower().lstrip(".")
    unreadable = FabkitError(
        f"{where}.file: '{path.name}' is not a readable mesh (corrupt, truncated or not "
        f"really {path.suffix.lower()})"
    )
    if kind == "stl" and not _stl_intact(data):
        raise unreadable
    try:
        with _quiet("trimesh"), warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            mesh = trimesh.load(io.BytesIO(data), file_type=kind, force="mesh", skip_materials=True)
    # trimesh's loaders raise many exception types on corrupt input (struct, index, key,
    # value and unicode errors among them; an ImportError when it tries to guess the text
    # encoding of binary garbage); all of them mean the same to the user.
    except Exception:  # noqa: BLE001
        raise unreadable from None
    faces = getattr(mesh, "faces", None)
    if faces is None or len(faces) == 0:
        raise FabkitError(f"{where}.file: '{path.name}' contains no triangles (empty or corrupt)")
    if len(faces) > MESH_FACES:
        raise FabkitError(
            f"{where}.file: '{path.name}' has {len(faces)} triangles, more than the limit of "
            f"{MESH_FACES}"
        )
    vertices = np.asarray(mesh.vertices, dtype=float)
    if not np.all(np.isfinite(vertices)):
        raise FabkitError(f"{where}.file: '{path.name}' has non-finite vertex coordinates")
    check_magnitude(vertices, "vertices", f"{where}.file: '{path.name}'")
    return vertices, np.asarray(faces)


@contextlib.contextmanager
def _quiet(logger_name: str) -> Iterator[None]:
    """The named logger silenced for the duration (a library's log lines would be extra
    lines on stderr)."""
    logger = logging.getLogger(logger_name)
    disabled, logger.disabled = logger.disabled, True
    try:
        yield
    finally:
        logger.disabled = disabled


def mesh_grid(vertices: np.ndarray, faces: np.ndarray, axis: str, where: str) -> HeightGrid:
    """Resample a mesh on a grid: vertices (V, 3) = (chart 1, chart 2, height), faces (T, 3).

    Refuses meshes that are not height fields: faces facing both ways across the chart
    plane (folds, overhangs, closed solids) or chart points covered twice at different
    heights. Vertices on a regular lattice give the grid and its heights directly;
    otherwise grid nodes covered by the mesh take local quadratic fits of the nearest
    vertices (so the fit sees the smooth surface, not the kinks of the triangles).
    """
    triangles = vertices[faces]
    plane = triangles[..., :2]
    edges = plane[:, 1:] - plane[:, :1]
    doubled_area = edges[:, 0, 0] * edges[:, 1, 1] - edges[:, 0, 1] * edges[:, 1, 0]
    if not np.abs(doubled_area).max() > 0:
        raise FabkitError(
            f"{where}.file: the mesh covers no area over the plane normal to {axis} (its "
            "triangles are degenerate or edge-on)"
        )
    span = np.ptp(plane.reshape(-1, 2), axis=0)
    if span.min() <= 1e-6 * span.max():
        raise FabkitError(
            f"{where}.file: the mesh spans {span[0]:.3g} x {span[1]:.3g} over the plane normal "
            f"to {axis}: too thin to be a surface"
        )
    orientation = 1.0 if doubled_area.sum() >= 0 else -1.0
    flipped = int(np.sum(doubled_area * orientation < -1e-9 * np.abs(doubled_area).max()))
    if flipped:
        raise FabkitError(
            f"{where}.file: the mesh is not a height field over {axis}: {flipped} of "
            f"{len(triangles)} faces face the other way (folds, overhangs or a closed solid); "
            f"export only the surface seen from the {axis} axis"
        )
    upright = np.abs(doubled_area) > 1e-12 * np.abs(doubled_area).max()
    area = np.abs(doubled_area).sum() / 2
    nodes, on_lattice = _mesh_nodes(vertices[:, :2], area)
    z = _rasterise(triangles[upright], nodes, axis, where)
    if not np.isfinite(z).any():
        raise FabkitError(f"{where}.file: the mesh covers no grid node")
    if not on_lattice:
        z = _local_quadratics(vertices, z, nodes)
    return HeightGrid(z, nodes.origin, nodes.spacing)


def _mesh_nodes(points: np.ndarray, area: float) -> tuple[_Nodes, bool]:
    """The grid for a mesh's chart points (V, 2) covering chart area ``area``, and whether
    it is the vertices' own lattice: that if they form one, else the mean vertex spacing
    over their bounds (at most MESH_MAX_SIDE nodes a side)."""
    lattice = [_lattice(points[:, k]) for k in (0, 1)]
    if all(item is not None for item in lattice):
        (x0, hx, nx), (y0, hy, ny) = lattice
        return _Nodes((x0, y0), (hx, hy), (ny, nx)), True
    low, high = points.min(0), points.max(0)
    step = max(np.sqrt(area / len(points)), np.max(high - low) / (MESH_MAX_SIDE - 1))
    counts = np.maximum(np.floor((high - low) / step).astype(int) + 1, MIN_SIDE)
    spacing = (high - low) / (counts - 1)
    return _Nodes((low[0], low[1]), (spacing[0], spacing[1]), (counts[1], counts[0])), False


def _local_quadratics(vertices: np.ndarray, z: np.ndarray, nodes: _Nodes) -> np.ndarray:
    """z (ny, nx) with every finite node replaced by the value at the node of the weighted
    least-squares quadratic through its nearest vertices (V, 3).

    Weights (1 - (d / R)^2)^2 fall to zero at the distance R of the
    (QUADRATIC_NEIGHBOURS + 1)-th nearest vertex, so the values vary smoothly from node to node.
    """
    from scipy.spatial import cKDTree

    rows, columns = np.nonzero(np.isfinite(z))
    points = nodes.points(columns, rows)
    count = min(QUADRATIC_NEIGHBOURS + 1, len(vertices))
    distance, nearest = cKDTree(vertices[:, :2]).query(points, k=count)
    weight = np.clip(1 - (distance / distance[:, -1:]) ** 2, 0, None) ** 2
    offsets = (vertices[nearest, :2] - points[:, None, :]) / np.asarray(nodes.spacing)
    dx, dy = offsets[..., 0], offsets[..., 1]
    design = np.stack([np.ones_like(dx), dx, dy, dx * dx, dx * dy, dy * dy], axis=-1)
    normal = np.einsum("mk,mka,mkb->mab", weight, design, design)
    moments = np.einsum("mk,mka,mk->ma", weight, design, vertices[nearest, 2])
    ridge = 1e-9 * np.trace(normal, axis1=1, axis2=2)[:, None, None] * np.eye(6)
    fitted = z.copy()
    fitted[rows, columns] = np.linalg.solve(normal + ridge, moments[..., None])[:, 0, 0]
    return fitted


def _lattice(values: np.ndarray) -> tuple[float, float, int] | None:
    """(first, step, count) if values (m,) take evenly spaced distinct levels (up to float32
    rounding), as the vertices of a meshed height grid do; else None."""
    levels = np.unique(values)
    scale = max(float(np.ptp(levels)), float(np.abs(levels).max()), 1e-300)
    starts = np.concatenate([[True], np.diff(levels) > 1e-5 * scale])
    groups = np.split(levels, np.flatnonzero(starts)[1:])
    if not MIN_SIDE <= len(groups) <= MAX_SIDE:
        return None
    centres = np.array([group.mean() for group in groups])
    steps = np.diff(centres)
    if np.ptp(steps) > 1e-3 * steps.mean():
        return None
    return float(centres[0]), float(steps.mean()), len(centres)


def _rasterise(triangles: np.ndarray, nodes: _Nodes, axis: str, where: str) -> np.ndarray:
    """Heights (ny, nx) of triangles (T, 3, 3) at grid nodes by linear interpolation in each
    triangle; NaN where no triangle covers a node. Refuses nodes covered at two heights."""
    node, height = _node_hits(triangles, nodes, where)
    size = nodes.shape[0] * nodes.shape[1]
    low, high = np.full(size, np.inf), np.full(size, -np.inf)
    np.minimum.at(low, node, height)
    np.maximum.at(high, node, height)
    heights = triangles[..., 2]
    tolerance = 1e-5 * max(float(np.ptp(heights)), max(nodes.spacing))
    twice = np.flatnonzero(high - low > tolerance)
    if twice.size:
        j, i = np.unravel_index(twice[0], nodes.shape)
        a, b = nodes.points(i, j)
        raise FabkitError(
            f"{where}.file: the mesh is not a height field over {axis}: it covers the point "
            f"({a:.4g}, {b:.4g}) twice, at heights {low[twice[0]]:.4g} and "
            f"{high[twice[0]]:.4g} (overlapping sheets)"
        )
    counts = np.bincount(node, minlength=size)
    with np.errstate(invalid="ignore", divide="ignore"):
        z = np.bincount(node, weights=height, minlength=size) / counts
    return z.reshape(nodes.shape)


def _node_hits(triangles: np.ndarray, nodes: _Nodes, where: str) -> tuple[np.ndarray, np.ndarray]:
    """Every (flat node index, interpolated height) pair with the node inside a
    triangle (within rounding), vectorised over the nodes of each triangle's bounding box
    (at most RASTER_HITS of them, counted before the work arrays are made)."""
    ny, nx = nodes.shape
    local = (triangles[..., :2] - np.asarray(nodes.origin)) / np.asarray(nodes.spacing)
    first = np.clip(np.ceil(local.min(1) - 1e-6), 0, [nx - 1, ny - 1]).astype(np.intp)
    last = np.clip(np.floor(local.max(1) + 1e-6), -1, [nx - 1, ny - 1]).astype(np.intp)
    width = np.maximum(last - first + 1, 0)
    counts = width[:, 0] * width[:, 1]
    if counts.sum() > RASTER_HITS:
        raise FabkitError(
            f"{where}.file: resampling the mesh would test {counts.sum()} (triangle, grid node) "
            f"pairs, more than the limit of {RASTER_HITS} (overlapping or very long triangles?)"
        )
    triangle = np.repeat(np.arange(len(triangles)), counts)
    offset = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    i = first[triangle, 0] + offset % width[triangle, 0]
    j = first[triangle, 1] + offset // width[triangle, 0]
    corner = local[triangle, 0]
    u = local[triangle, 1] - corner
    v = local[triangle, 2] - corner
    p = np.stack([i, j], axis=-1) - corner
    determinant = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
    flat = determinant == 0  # upright in mm, but no area left on the grid's scale
    determinant = np.where(flat, 1.0, determinant)
    s = (p[:, 0] * v[:, 1] - p[:, 1] * v[:, 0]) / determinant
    t = (u[:, 0] * p[:, 1] - u[:, 1] * p[:, 0]) / determinant
    inside = ~flat & (s >= -1e-6) & (t >= -1e-6) & (s + t <= 1 + 1e-6)
    heights = triangles[triangle, :, 2]
    height = (
        heights[:, 0] + s * (heights[:, 1] - heights[:, 0]) + t * (heights[:, 2] - heights[:, 0])
    )
    return (j * nx + i)[inside], height[inside]
