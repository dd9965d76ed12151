"""Triangle meshes from ``.stl``, ``.obj`` and ``.ply`` files, resampled on a height grid.

``read_mesh`` reads a mesh safely (no other file it names is opened); ``mesh_grid``
refuses a mesh that is not a height field over its chart plane and resamples it as a
:class:`~fabkit.problem.surfaces.grids.HeightGrid`: at its own vertices when they form a
regular lattice, otherwise at its mean vertex spacing with local quadratic fits. The mesh
surface that uses them is in :mod:`fabkit.problem.surfaces.data`.
"""

from __future__ import annotations

import contextlib
import io
import logging
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fabkit.errors import FabkitError
from fabkit.files.npzfile import check_magnitude
from fabkit.files.readfile import read_limited
from fabkit.limits import MESH_BYTES, MESH_FACES, RASTER_HITS
from fabkit.problem.surfaces.grids import MAX_SIDE, MIN_SIDE, HeightGrid

MESH_MAX_SIDE = 1024
"""Most nodes per side when resampling an irregular mesh."""
QUADRATIC_NEIGHBOURS = 16
"""Vertices in each local quadratic fit when resampling an irregular mesh."""
MESH_FORMATS = (".stl", ".obj", ".ply")


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
