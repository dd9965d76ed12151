"""Fill quality of print lines, with Vector Slicer's definitions, on a raster of w/10.

The domain is rasterised at ``pixel = w / 10`` (pixel centres). A print path covers the
pixels whose centre lies within half its road width of the path's centreline (round ends
and joins). ``hits`` of a pixel counts the *distinct* paths covering it. Then:

* ``empty_fraction``: domain pixels with no hit / domain pixels;
* ``mean_overlap``: mean of ``hits - 1`` over the domain pixels with at least one hit;
* ``mean_angle_error_deg``: mean |angle| between the path tangent and the director (mod
  180 degrees), weighted by printed length. Nothing is excluded near defects: the director
  is evaluated exactly where the path is, however close to the core (as Vector Slicer's
  metrics include the defect neighbourhood);
* ``paths``, ``print_length_mm``, ``travel_length_mm`` (``travel_between_lines_mm`` in
  :meth:`Quality.to_dict`: the straight travels from one line's end to the next's start).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from functools import lru_cache

import numba
import numpy as np
import shapely

from fabkit.field.flat import FlatField, director_angle

PIXELS_PER_WIDTH = 10


@dataclass(frozen=True)
class Quality:
    """Fill metrics of one layer (see the module docstring); lengths in mm."""

    empty_fraction: float
    mean_overlap: float
    mean_angle_error_deg: float
    paths: int
    print_length_mm: float
    travel_length_mm: float
    pixel_mm: float

    def to_dict(self) -> dict[str, float | int]:
        """The figures by name; ``travel_between_lines_mm``: the straight in-plane travels
        from one line's end to the next line's start (the G-code's non-printing moves add
        lifts and the moves to and from the sheet)."""
        data = asdict(self)
        data["travel_between_lines_mm"] = data.pop("travel_length_mm")
        data["pixel_mm"] = data.pop("pixel_mm")
        return data

    def summary(self) -> str:
        """One line, e.g. ``empty 1.2 %  overlap 0.8 %  angle 1.1 deg  ...`` (lengths in mm)."""
        return (
            f"empty {100 * self.empty_fraction:.2f} %  overlap {100 * self.mean_overlap:.2f} %  "
            f"angle {self.mean_angle_error_deg:.2f} deg  paths {self.paths}  "
            f"printing {self.print_length_mm:.1f} mm  travel between lines "
            f"{self.travel_length_mm:.1f} mm"
        )


def measure_quality(
    paths: list[np.ndarray],
    widths: list[np.ndarray] | float,
    flat: FlatField,
    road_width: float,
    travel_length_mm: float = 0.0,
) -> Quality:
    """Quality of print ``paths`` ((n, 2) polylines, mm) with per-vertex ``widths`` (mm) or
    one width, on ``flat``'s outline and director; raster pixel ``road_width / 10``."""
    pixel = road_width / PIXELS_PER_WIDTH
    grid = _raster(flat.outline, pixel)
    hits = np.zeros(grid.size, np.int32)
    owner = np.full(grid.size, -1, np.int64)
    angle_sum = length_sum = 0.0
    for index, path in enumerate(paths):
        width = widths if np.isscalar(widths) else widths[index]
        samples, radius, segment = _samples(path, np.broadcast_to(width, (len(path),)), pixel)
        grid.paint(samples, radius, index, hits, owner)
        if len(segment):
            middle = 0.5 * (samples[:-1] + samples[1:])
            tangent = np.arctan2(segment[:, 1], segment[:, 0])
            error = np.abs(director_angle(tangent - flat.theta(middle)))
            lengths = np.linalg.norm(segment, axis=1)
            angle_sum += float((error * lengths).sum())
            length_sum += float(lengths.sum())
    inside = grid.inside
    filled = inside & (hits > 0)
    return Quality(
        empty_fraction=float((inside & (hits == 0)).sum() / max(inside.sum(), 1)),
        mean_overlap=float((hits[filled] - 1).sum() / max(filled.sum(), 1)),
        mean_angle_error_deg=float(np.degrees(angle_sum / length_sum)) if length_sum else 0.0,
        paths=len(paths),
        print_length_mm=length_sum,
        travel_length_mm=float(travel_length_mm),
        pixel_mm=pixel,
    )


def _samples(
    path: np.ndarray, width: np.ndarray, pixel: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points along ``path`` at most one pixel apart, their radii, and the segments between."""
    segment = np.diff(path, axis=0)
    lengths = np.linalg.norm(segment, axis=1)
    parts = np.maximum(np.ceil(lengths / pixel).astype(int), 1)
    which = np.repeat(np.arange(len(segment)), parts)
    fraction = (np.arange(parts.sum()) - np.repeat(np.cumsum(parts) - parts, parts)) / parts[which]
    points = np.vstack([path[which] + fraction[:, None] * segment[which], path[-1:]])
    radius = 0.5 * np.concatenate(
        [width[which] + fraction * (width[which + 1] - width[which]), width[-1:]]
    )
    return points, radius, np.diff(points, axis=0)


@lru_cache(maxsize=2)
def _raster(outline: shapely.Geometry, pixel: float) -> _Raster:
    """The raster of ``outline`` at ``pixel`` (mm), made once for the layers of a plan
    that share their outline (each took 0.25 s on Fig. 1 at 60 mm)."""
    return _Raster.covering(outline, pixel)


@dataclass(frozen=True)
class _Raster:
    """Pixel centres ``(x0 + (i + 1/2) p, y0 + (j + 1/2) p)``; ``inside`` (nx * ny,) bool."""

    x0: float
    y0: float
    pixel: float
    nx: int
    ny: int
    inside: np.ndarray

    @classmethod
    def covering(cls, outline: shapely.Geometry, pixel: float) -> _Raster:
        low_x, low_y, high_x, high_y = outline.bounds
        nx = int(np.ceil((high_x - low_x) / pixel)) + 1
        ny = int(np.ceil((high_y - low_y) / pixel)) + 1
        xs = low_x + (np.arange(nx) + 0.5) * pixel
        ys = low_y + (np.arange(ny) + 0.5) * pixel
        shapely.prepare(outline)
        inside = np.zeros((nx, ny), bool)
        for start in range(0, nx, 256):  # rows in blocks: bounded memory
            block = np.meshgrid(xs[start : start + 256], ys, indexing="ij")
            inside[start : start + 256] = shapely.contains_xy(outline, *block)
        return cls(low_x, low_y, pixel, nx, ny, inside.ravel())

    @property
    def size(self) -> int:
        return self.nx * self.ny

    def paint(
        self, points: np.ndarray, radius: np.ndarray, path: int, hits: np.ndarray, owner: np.ndarray
    ) -> None:
        """Count ``path`` once in ``hits`` (size,) at every pixel whose centre lies within
        ``radius`` (m,) of one of its ``points`` (m, 2); ``owner`` (size,) holds the last
        path counted at each pixel."""
        _paint(points, radius, path, self.x0, self.y0, self.pixel, self.nx, self.ny, hits, owner)


@numba.njit(cache=True, error_model="numpy")
def _paint(points, radius, path, x0, y0, pixel, nx, ny, hits, owner):  # pragma: no cover
    """:meth:`_Raster.paint`, compiled: the numpy formulation it replaced gathered every
    (sample, pixel) pair of a window around each sample and took the distinct pixels, 0.6
    s of the two layers' quality on Fig. 1 at 60 mm; the same pixels, the same condition
    (tests/test_toolpath_quality.py)."""
    reach = int(math.ceil(radius.max() / pixel)) + 1 if len(radius) else 0
    for s in range(len(points)):
        x, y, r2 = points[s, 0], points[s, 1], radius[s] * radius[s]
        ci, cj = math.floor((x - x0) / pixel), math.floor((y - y0) / pixel)
        for i in range(max(ci - reach, 0), min(ci + reach + 1, nx)):
            dx = x0 + (i + 0.5) * pixel - x
            for j in range(max(cj - reach, 0), min(cj + reach + 1, ny)):
                dy = y0 + (j + 0.5) * pixel - y
                if dx * dx + dy * dy <= r2:
                    k = i * ny + j
                    if owner[k] != path:
                        owner[k] = path
                        hits[k] += 1
