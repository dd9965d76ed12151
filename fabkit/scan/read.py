"""Reading a scan of a printed sheet: the file, its units, and the points to measure.

A scan is a mesh or a point cloud in PLY, STL, OBJ, OFF or GLB (read by trimesh). Its
lengths are scaled to mm by its ``units``; its extent must be plausible for the target it
is compared with (:func:`check_extent`), else the units are likely wrong. The scan is
measured at no more than :data:`MAX_POINTS` points (so that a scan of millions of points
takes bounded time and memory): a mesh at points spread evenly over its surface (by
area, so that a scanner's dense and sparse regions weigh as the surface does), a point
cloud at its own points, a seeded random choice of them when there are more.
"""

from __future__ import annotations

import io
import logging
import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fabkit.errors import FabkitError
from fabkit.files.npzfile import check_magnitude
from fabkit.files.readfile import read_limited
from fabkit.limits import SCAN_BYTES
from fabkit.scan.align import area_samples

SCAN_TYPES = ("ply", "stl", "obj", "off", "glb")
"""The file types a scan may be, by suffix."""
UNITS = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "in": 25.4}
"""mm per unit of a scan's lengths, by the name ``--units`` takes."""
MAX_POINTS = 20_000
"""Most points a scan is measured at."""
EXTENT_RANGE = (0.3, 3.0)
"""A scan's extent (its bounding box's diagonal) divided by the target's must lie in this
range; outside it the scan is refused (its units are likely wrong)."""
SEED = 0
"""The seed of the random choice of the points measured (the same scan, the same figures)."""


@dataclass(frozen=True, eq=False)
class Scan:
    """A scan in mm. ``vertices_mm`` (V, 3) and ``faces`` (F, 3) as in the file (F = 0 for
    a point cloud); ``points_mm`` (n, 3), n <= :data:`MAX_POINTS`: where the scan is
    measured; ``sampling``: how those points were chosen, in words; ``units``: the unit
    the file's lengths were read in."""

    name: str
    vertices_mm: np.ndarray
    faces: np.ndarray
    points_mm: np.ndarray
    sampling: str
    units: str = "mm"

    @property
    def extent_mm(self) -> float:
        """The diagonal of the scan's bounding box (mm)."""
        return float(np.linalg.norm(np.ptp(self.vertices_mm, axis=0)))


def read_scan(path: str | Path, units: str = "mm", points: int = MAX_POINTS) -> Scan:
    """The scan in ``path`` in mm (its lengths in ``units``, a key of :data:`UNITS`),
    measured at no more than ``points`` points. An unreadable, empty or non-finite scan is
    a one-line :class:`~fabkit.errors.FabkitError`."""
    path = Path(path)
    if units not in UNITS:
        raise FabkitError(f"--units {units}: expected one of {', '.join(UNITS)}")
    vertices, faces = _load(path)
    bad = int(np.count_nonzero(~np.isfinite(vertices).all(axis=1)))
    if bad:
        raise FabkitError(
            f"{path.name}: {bad} of {len(vertices)} vertices are not finite numbers (NaN or "
            "inf): remove them in the scanning software and export again"
        )
    check_magnitude(vertices, "vertices", path.name)
    vertices = vertices * UNITS[units]
    measured, sampling = _measured_points(vertices, faces, points)
    if len(np.unique(measured.round(9), axis=0)) < 4:
        raise FabkitError(f"{path.name}: fewer than 4 distinct points: nothing to compare")
    return Scan(path.name, vertices, faces, measured, sampling, units)


def _load(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The vertices (V, 3) and faces (F, 3) of the file (a scene's geometries joined).

    The file (at most :data:`~fabkit.limits.SCAN_BYTES`) is handed to trimesh as bytes
    without a name, so that no other file it names is opened (an OBJ's material library,
    a texture), with trimesh's warnings and log lines held back (one line on stderr)."""
    import trimesh

    if not path.exists():
        raise FabkitError(f"{path}: no such file")
    kind = path.suffix.lower().lstrip(".")
    if kind not in SCAN_TYPES:
        raise FabkitError(f"{path.name}: a scan must be one of {', '.join(SCAN_TYPES)}")
    data = read_limited(path, "scan", SCAN_BYTES)
    logger = logging.getLogger("trimesh")
    disabled, logger.disabled = logger.disabled, True
    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            loaded = trimesh.load(io.BytesIO(data), file_type=kind, process=False)
            if isinstance(loaded, trimesh.Scene):
                loaded = loaded.to_geometry() if loaded.geometry else None
            vertices = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=float)
            faces = getattr(loaded, "faces", None)
            faces = np.asarray(np.zeros((0, 3)) if faces is None else faces, dtype=np.int64)
    # trimesh's loaders raise many exception types on corrupt input; all of them mean the
    # same to the user
    except Exception as exc:  # noqa: BLE001
        reason = (str(exc).splitlines() or [type(exc).__name__])[0][:120]
        raise FabkitError(f"{path.name}: cannot read the scan ({reason})") from None
    finally:
        logger.disabled = disabled
    if vertices.ndim != 2 or vertices.shape[1:] != (3,) or len(vertices) == 0:
        raise FabkitError(f"{path.name}: the scan holds no points (an empty or damaged file?)")
    if faces.ndim != 2 or faces.shape[1:] != (3,):
        faces = np.zeros((0, 3), dtype=np.int64)
    if len(faces) and (faces.min() < 0 or faces.max() >= len(vertices)):
        raise FabkitError(f"{path.name}: its faces name vertices it does not hold (damaged?)")
    return vertices, faces


def _measured_points(vertices: np.ndarray, faces: np.ndarray, count: int) -> tuple[np.ndarray, str]:
    """The points a scan is measured at (module docstring), and how they were chosen."""
    rng = np.random.default_rng(SEED)
    if len(faces):
        corners = vertices[faces]
        areas = 0.5 * np.linalg.norm(
            np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1
        )
        if areas.sum() > 0:
            points, _ = area_samples(corners, areas, count, rng)
            return points, f"{count} points spread evenly over its {len(faces)} triangles"
    if len(vertices) <= count:
        return vertices, f"all its {len(vertices)} points"
    chosen = np.sort(rng.choice(len(vertices), size=count, replace=False))
    return vertices[chosen], f"{count} of its {len(vertices)} points (a seeded random choice)"


def check_extent(scan: Scan, target_extent_mm: float, target: str, units: str) -> None:
    """Refuse a scan whose extent is implausible beside the target's (both bounding-box
    diagonals, mm): outside :data:`EXTENT_RANGE` times it, naming the units that would
    fit, if any."""
    low, high = EXTENT_RANGE
    ratio = scan.extent_mm / target_extent_mm
    if low <= ratio <= high:
        return
    raw = scan.extent_mm / UNITS[units]
    fits = [name for name, mm in UNITS.items() if low <= raw * mm / target_extent_mm <= high]
    fits = [name for name in fits if name != units]
    hint = f"is it in {fits[0]}? (--units {fits[0]})" if fits else "is it a scan of this part?"
    raise FabkitError(
        f"{scan.name}: extent {_mm(scan.extent_mm)} mm (in {units}) is implausible for the "
        f"target {target} (extent {_mm(target_extent_mm)} mm): {hint}"
    )


def _mm(value: float) -> str:
    """A length for a message: three significant digits."""
    return f"{value:.3g}" if math.isfinite(value) else str(value)
