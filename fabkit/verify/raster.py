"""What a machine file makes on the flat sheet, on a grid: coverage, director, values.

:class:`Roads` are printed segments in the sheet's frame (mm) with their widths, the road
each belongs to, and the process values each was printed with (parameter name -> value
per segment). :func:`rasterise` lays them on a square grid: a cell is covered by a road
when its centre lies within half the road's width of the road's centreline (sampled
every half cell); ``hits`` counts the distinct roads covering a cell; the director is
the road direction, averaged over the roads covering a cell as the tensor
(cos 2 phi, sin 2 phi); each value is the mean over the roads covering the cell.

Two values are not read from single roads:

* ``ink_fraction`` of machines that alternate two inks along their roads: each road
  piece holds one ink (0 or 1), and the sheet's material is their mix over a few road
  widths, so the share is averaged with a Gaussian window of :data:`INK_WINDOW` road
  widths (normalised over the printed cells);
* ``line_spacing_mm``: the distance from every road sample to the nearest sample of
  another road.

A :class:`Readback` is the result, also made directly by the laser reader (pixels are
cells there).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from fabkit.errors import FabkitError

INK_WINDOW = 3.0
"""Standard deviation of the ink-share window, in road widths."""
MAX_CELLS = 25_000_000
"""Largest grid :func:`rasterise` makes."""
_CHUNK = 1 << 16


@dataclass(frozen=True, eq=False)
class Roads:
    """Printed segments, sheet frame (mm): ``start`` and ``end`` (n, 2), ``width`` (n,),
    ``road`` (n,) int (segments of one road share it), ``values`` parameter -> (n,) (NaN
    where unknown), ``ink`` (n,) 0/1 on machines that alternate two inks, else None."""

    start: np.ndarray
    end: np.ndarray
    width: np.ndarray
    road: np.ndarray
    values: dict[str, np.ndarray] = field(default_factory=dict)
    ink: np.ndarray | None = None

    def shifted(self, offset: np.ndarray) -> Roads:
        """The roads moved by ``-offset`` (machine to sheet frame, mm)."""
        shift = np.asarray(offset, dtype=float)[:2]
        return Roads(
            self.start - shift,
            self.end - shift,
            self.width,
            self.road,
            self.values,
            self.ink,
        )


@dataclass(frozen=True, eq=False)
class Readback:
    """A machine file's sheet on a grid (sheet frame): cell (i, j) has its centre at
    ``origin + cell_mm * (i + 1/2, j + 1/2)``; ``hits`` (nx, ny) the distinct roads or
    exposures covering it, ``theta`` (nx, ny) the director (rad, NaN where uncovered),
    ``values`` parameter -> (nx, ny) (NaN where unknown); ``width_mm`` the road width (or
    the pixel pitch, or the channel pitch); ``region`` (nx, ny) bool the cells the reading
    speaks for (None: all); ``notes`` what the reader saw fit to say."""

    origin: tuple[float, float]
    cell_mm: float
    hits: np.ndarray
    theta: np.ndarray
    values: dict[str, np.ndarray]
    width_mm: float
    notes: tuple[str, ...] = ()
    region: np.ndarray | None = None

    @property
    def shape(self) -> tuple[int, int]:
        return self.hits.shape

    def centres(self) -> tuple[np.ndarray, np.ndarray]:
        """Cell-centre x and y, each (nx, ny), mm."""
        nx, ny = self.shape
        x = self.origin[0] + self.cell_mm * (np.arange(nx) + 0.5)
        y = self.origin[1] + self.cell_mm * (np.arange(ny) + 0.5)
        return np.meshgrid(x, y, indexing="ij")


def rasterise(roads: Roads, cell_mm: float, margin_mm: float = 0.0) -> Readback:
    """Lay ``roads`` on a grid of ``cell_mm`` cells covering them (plus ``margin_mm``)."""
    if not len(roads.start):
        raise FabkitError("the machine file prints nothing (no road deposits material)")
    ends = np.concatenate([roads.start, roads.end])
    reach = float(roads.width.max()) / 2 + margin_mm + cell_mm
    low = ends.min(axis=0) - reach
    shape = np.ceil((ends.max(axis=0) + reach - low) / cell_mm).astype(int)
    if shape.prod() > MAX_CELLS:
        raise FabkitError(
            f"the print spans {shape[0]} x {shape[1]} cells of {cell_mm:g} mm, more than "
            f"{MAX_CELLS}; give a coarser --cell"
        )
    samples = _samples(roads, cell_mm / 2)
    spacing = _spacing(samples) if "line_spacing_mm" in roads.values else None
    cells, owner = _stamps(samples, low, cell_mm, shape)
    size = int(shape.prod())
    count = int(roads.road.max()) + 1
    pairs = np.unique(cells.astype(np.int64) * count + samples.road[owner])
    hits = np.bincount(pairs // count, minlength=size)
    weight = np.bincount(cells, minlength=size).astype(float)
    covered = weight > 0
    angle = samples.angle[owner]
    cos2 = np.bincount(cells, np.cos(2 * angle), minlength=size)
    sin2 = np.bincount(cells, np.sin(2 * angle), minlength=size)
    theta = np.where(covered, 0.5 * np.arctan2(sin2, cos2), np.nan)
    values = {}
    for name, per_segment in roads.values.items():
        per_sample = spacing if name == "line_spacing_mm" else per_segment[samples.segment]
        values[name] = _mean(cells, per_sample[owner], size)
    notes: list[str] = []
    if roads.ink is not None:
        ink = _mean(cells, roads.ink[samples.segment[owner]].astype(float), size)
        sigma = INK_WINDOW * float(np.median(roads.width)) / cell_mm
        values["ink_fraction"] = _window(ink.reshape(shape), covered.reshape(shape), sigma).ravel()
        notes.append(
            f"ink_fraction: share of the second ink over a Gaussian window of "
            f"{INK_WINDOW:g} road widths"
        )
    return Readback(
        origin=(float(low[0]), float(low[1])),
        cell_mm=cell_mm,
        hits=hits.reshape(shape),
        theta=theta.reshape(shape),
        values={name: v.reshape(shape) for name, v in values.items()},
        width_mm=float(np.median(roads.width)),
        notes=tuple(notes),
    )


@dataclass(frozen=True, eq=False)
class _Samples:
    """Points along the roads: position (m, 2), radius (m,), direction angle (m,), the
    segment (m,) and road (m,) each lies on."""

    points: np.ndarray
    radius: np.ndarray
    angle: np.ndarray
    segment: np.ndarray
    road: np.ndarray


def _samples(roads: Roads, step: float) -> _Samples:
    """Points every ``step`` (at most) along each segment, at the middle of equal parts."""
    delta = roads.end - roads.start
    length = np.linalg.norm(delta, axis=1)
    count = np.maximum(1, np.ceil(length / step)).astype(int)
    segment = np.repeat(np.arange(len(length)), count)
    first = np.repeat(np.cumsum(count) - count, count)
    fraction = (np.arange(count.sum()) - first + 0.5) / count[segment]
    points = roads.start[segment] + fraction[:, None] * delta[segment]
    angle = np.arctan2(delta[:, 1], delta[:, 0])[segment]
    return _Samples(points, roads.width[segment] / 2, angle, segment, roads.road[segment])


def _stamps(
    samples: _Samples, low: np.ndarray, cell: float, shape: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Flat cell index and sample index of every (cell, sample) pair with the cell's
    centre within the sample's radius."""
    reach = int(math.ceil(float(samples.radius.max()) / cell)) + 1
    offsets = np.arange(-reach, reach + 1)
    di, dj = (a.ravel() for a in np.meshgrid(offsets, offsets, indexing="ij"))
    cells_out, owners_out = [], []
    for a in range(0, len(samples.points), _CHUNK):
        points = samples.points[a : a + _CHUNK]
        base = np.floor((points - low) / cell).astype(int)
        i = base[:, :1] + di
        j = base[:, 1:] + dj
        cx = low[0] + (i + 0.5) * cell
        cy = low[1] + (j + 0.5) * cell
        inside = (cx - points[:, :1]) ** 2 + (cy - points[:, 1:]) ** 2
        inside = inside <= samples.radius[a : a + _CHUNK, None] ** 2
        inside &= (i >= 0) & (i < shape[0]) & (j >= 0) & (j < shape[1])
        rows, cols = np.nonzero(inside)
        cells_out.append(i[rows, cols] * shape[1] + j[rows, cols])
        owners_out.append(rows + a)
    return np.concatenate(cells_out), np.concatenate(owners_out)


def _mean(cells: np.ndarray, values: np.ndarray, size: int) -> np.ndarray:
    """Per-cell mean of the finite ``values`` (NaN where none)."""
    known = np.isfinite(values)
    total = np.bincount(cells[known], values[known], minlength=size)
    count = np.bincount(cells[known], minlength=size)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / count, np.nan)


def _window(values: np.ndarray, covered: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian-weighted mean of ``values`` over the covered cells (normalised
    convolution, ``sigma`` in cells); NaN where uncovered."""
    known = covered & np.isfinite(values)
    total = ndimage.gaussian_filter(np.where(known, values, 0.0), sigma, mode="constant")
    weight = ndimage.gaussian_filter(known.astype(float), sigma, mode="constant")
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(covered & (weight > 1e-9), total / weight, np.nan)


def _spacing(samples: _Samples, neighbours: int = 64) -> np.ndarray:
    """Distance (m,) from every sample to the nearest sample of another road (NaN when
    none is among its ``neighbours`` nearest samples)."""
    tree = cKDTree(samples.points)
    out = np.full(len(samples.points), np.nan)
    count = min(neighbours, len(samples.points))
    for a in range(0, len(samples.points), _CHUNK):
        distance, index = tree.query(samples.points[a : a + _CHUNK], k=count)
        distance, index = distance.reshape(len(distance), -1), index.reshape(len(index), -1)
        other = samples.road[index] != samples.road[a : a + _CHUNK, None]
        found = other.any(axis=1)
        first = np.argmax(other, axis=1)
        out[a : a + _CHUNK] = np.where(found, distance[np.arange(len(first)), first], np.nan)
    return out
