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

The files are read by :mod:`fabkit.problem.surfaces.grids` (height grids) and
:mod:`fabkit.problem.surfaces.meshes` (meshes, resampled on a grid).
"""

from __future__ import annotations

from abc import abstractmethod
from functools import lru_cache
from pathlib import Path
from typing import Any, Self

import numpy as np
from scipy import ndimage

from fabkit.errors import FabkitError
from fabkit.files.npzfile import check_magnitude
from fabkit.files.tomlfile import Table, expected, real
from fabkit.limits import MAGNITUDE
from fabkit.problem.surfaces.base import Surface, graph_geometry
from fabkit.problem.surfaces.fit import SurfaceFit, fit_grid
from fabkit.problem.surfaces.grids import (
    GRID_FORMATS,
    HeightGrid,
    check_heights,
    place_grid,
    read_grid,
)
from fabkit.problem.surfaces.meshes import MESH_FORMATS, mesh_grid, read_mesh

HOLE_MARGIN = 2.0
"""Nodes this close to a hole (in node spacings) are outside the footprint: the fit is
less reliable there."""
K_SAMPLES = 250_000
"""Most footprint cells at which the K range of the summary is evaluated."""
CHARTS = {"x": (1, 2, 0), "y": (2, 0, 1), "z": (0, 1, 2)}
"""For each height axis: indices in (x, y, z) of chart coordinate 1, chart coordinate 2, height."""


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
    check_heights(heights, Path(path).name, where)
    grid = place_grid(heights, coordinates, extent, where)
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
