"""A simulated sheet drawn on the part's smooth outline, not on its grid cells' steps.

A simulation meshes the part by the design's grid cells whose centres lie in it
(:func:`~fabkit.mechanics.mesh.design_mesh`), so the edge of its mesh steps along the
cells. For pictures and mesh files the mesh is completed and cut on the part's outline:

1. the solved cells beside the mesh that the outline crosses are added; their new corners
   are carried by the deformation of the nearest simulated vertex (the sheet's local
   affine map, its gradient averaged over that vertex's triangles), and the target's
   points there are the target's own;
2. every triangle the outline crosses is cut along it and the piece inside triangulated;
   positions inside a triangle are interpolated linearly (barycentric coordinates).

The figures of a verdict are measured on the simulated mesh alone; this is only drawn.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely
from scipy import ndimage
from scipy.spatial import cKDTree

from fabkit.design.design import Design
from fabkit.field.part import solved_cells
from fabkit.mechanics.mesh import DesignMesh, counter_clockwise

ROUNDING = 1e-9
"""Points of the flat sheet closer than this share of its size are one vertex."""
SIMPLIFY = 0.03
"""The outline is simplified within this share of a grid cell's side before the cut (a
part's outline has many more points than the mesh: slivers, and their edges drawn dark)."""


@dataclass(frozen=True)
class OutlinedMesh:
    """A mesh of the part up to its outline: ``flat`` (V, 2) flat-sheet positions,
    ``sheet`` (V, 3) and ``target`` (V, 3) the simulated sheet and the target there, and
    ``triangles`` (F, 3), counter-clockwise on the flat sheet (design units)."""

    flat: np.ndarray
    sheet: np.ndarray
    target: np.ndarray
    triangles: np.ndarray


def on_outline(
    design: Design,
    mesh: DesignMesh,
    sheet: np.ndarray,
    target: np.ndarray,
    surface: int,
    outline: shapely.Geometry,
) -> OutlinedMesh:
    """``sheet`` and ``target`` (V, 3) at ``mesh``'s vertices (a mesh of ``design``'s grid
    cells, not refined) completed and cut on ``outline`` (flat-sheet coordinates), with
    surface ``surface``'s target points at the added corners (module docstring)."""
    flat, sheet, target, triangles = _with_cells_beside(design, mesh, sheet, target, surface)
    triangles = counter_clockwise(flat, triangles)
    corners = flat[triangles]
    side = np.median(np.linalg.norm(corners[:, 1] - corners[:, 0], axis=1))
    outline = shapely.simplify(outline, SIMPLIFY * side)
    polygons = shapely.polygons(corners)
    shapely.prepare(outline)
    inside = shapely.contains_properly(outline, polygons)
    crossing = ~inside & shapely.intersects(outline, polygons)
    pieces = [(flat, sheet, target, triangles[inside])]
    pieces += _cut(flat, sheet, target, triangles[crossing], polygons[crossing], outline)
    return _joined(pieces, scale=float(np.ptp(flat, axis=0).max()))


def _with_cells_beside(
    design: Design, mesh: DesignMesh, sheet: np.ndarray, target: np.ndarray, surface: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The mesh's vertices and triangles with every solved cell's missing halves added in
    its cells and the cells that touch them (flat, sheet, target, triangles): a cell the
    simulation left half (a face it could not make) is whole again; the added corners'
    sheet points carried by the nearest vertex's deformation, their target points the
    design's."""
    i, j, half = _missing_halves(solved_cells(design), mesh)
    a, b, c, d = (i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)
    lower, upper = np.stack([a, b, c]), np.stack([a, c, d])  # (3, 2, H)
    added = np.where(half == 0, lower, upper).transpose(2, 0, 1)  # (H, 3, 2)
    grid = np.concatenate([mesh.grid, added.reshape(-1, 2)])  # added: (H, 3, 2)
    grid, first, inverse = np.unique(grid, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.ravel()
    old = first < len(mesh.grid)  # grid points already meshed keep their positions
    new_grid = grid[~old]
    rs = design.r[surface][new_grid[:, 0], new_grid[:, 1]]
    flat = np.empty((len(grid), 2))
    points3 = np.empty((len(grid), 3))
    target3 = np.empty((len(grid), 3))
    kept = first[old]
    flat[old], points3[old], target3[old] = mesh.points[kept], sheet[kept], target[kept]
    flat[~old] = design.r[0][new_grid[:, 0], new_grid[:, 1]]
    target3[~old] = design.problem.targets[surface].surface.embed(rs)
    points3[~old] = _carried(mesh, sheet, new_grid)
    meshed = inverse[: len(mesh.grid)][mesh.triangles]
    triangles = np.concatenate([meshed, inverse[len(mesh.grid) :].reshape(-1, 3)])
    return flat, points3, target3, triangles


def _missing_halves(
    solved: np.ndarray, mesh: DesignMesh
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The halves (cell i, j and 0 for the triangle through corner (i + 1, j), 1 for the
    one through (i, j + 1)) of the solved cells in or beside the mesh's cells that the
    mesh lacks."""
    corners = mesh.grid[mesh.triangles]  # (F, 3, 2)
    cell = corners.min(axis=1)
    half = (corners == (cell + [0, 1])[:, None, :]).all(axis=-1).any(axis=-1).astype(int)
    present = np.zeros((*solved.shape, 2), dtype=bool)
    present[cell[:, 0], cell[:, 1], half] = True
    near = ndimage.binary_dilation(present.any(axis=-1), np.ones((3, 3), bool)) & solved
    return np.nonzero(near[..., None] & ~present)


def _carried(mesh: DesignMesh, sheet: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """The sheet (M, 3) at grid points ``grid`` (M, 2) off the mesh: the nearest vertex's
    position moved by its gradient (3, 2) in grid coordinates, the mean of its triangles'."""
    g = mesh.grid.astype(float)
    t = mesh.triangles
    edges = np.stack([g[t[:, 1]] - g[t[:, 0]], g[t[:, 2]] - g[t[:, 0]]], axis=-1)  # (F, 2, 2)
    spans = np.stack([sheet[t[:, 1]] - sheet[t[:, 0]], sheet[t[:, 2]] - sheet[t[:, 0]]], -1)
    gradients = spans @ np.linalg.inv(edges)  # (F, 3, 2)
    total = np.zeros((len(g), 3, 2))
    count = np.zeros(len(g))
    for k in range(3):
        np.add.at(total, t[:, k], gradients)
        np.add.at(count, t[:, k], 1.0)
    used = np.flatnonzero(count)  # a vertex no triangle uses has no gradient
    gradient = total[used] / count[used, None, None]
    _, nearest = cKDTree(g[used]).query(grid.astype(float))
    step = grid - g[used][nearest]
    return sheet[used][nearest] + np.einsum("mij,mj->mi", gradient[nearest], step)


def _cut(
    flat: np.ndarray,
    sheet: np.ndarray,
    target: np.ndarray,
    triangles: np.ndarray,
    polygons: np.ndarray,
    outline: shapely.Geometry,
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """The parts of ``triangles`` inside ``outline``, triangulated: per piece its points'
    flat, sheet and target positions (interpolated in the triangle it came from) and its
    triangles, indexing those points."""
    pieces = shapely.intersection(polygons, outline)
    cut = shapely.constrained_delaunay_triangles(pieces)
    parts, owner = shapely.get_parts(cut, return_index=True)
    if len(parts) == 0:
        return []
    corners = shapely.get_coordinates(parts).reshape(len(parts), 4, 2)[:, :3]  # closed rings
    source = triangles[owner]
    a, b, c = (flat[source[:, k]] for k in range(3))
    basis = np.stack([b - a, c - a], axis=-1)  # (P, 2, 2)
    local = np.linalg.solve(basis[:, None], (corners - a[:, None])[..., None])[..., 0]
    weights = np.concatenate([1 - local.sum(-1, keepdims=True), local], axis=-1)  # (P, 3, 3)

    def at(values: np.ndarray) -> np.ndarray:
        return np.einsum("pkw,pwd->pkd", weights, values[source]).reshape(-1, values.shape[1])

    points = corners.reshape(-1, 2)
    return [(points, at(sheet), at(target), np.arange(len(points)).reshape(-1, 3))]


def _joined(
    pieces: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]], scale: float
) -> OutlinedMesh:
    """One mesh of ``pieces`` (flat, sheet, target, triangles), their points that share a
    flat position merged, those no triangle uses dropped."""
    flats, sheets, targets, triangles, offset = [], [], [], [], 0
    for flat, sheet, target, faces in pieces:
        flats.append(flat)
        sheets.append(sheet)
        targets.append(target)
        triangles.append(faces + offset)
        offset += len(flat)
    flat = np.concatenate(flats)
    faces = np.concatenate(triangles)
    used = np.unique(faces)
    key = np.round(flat[used] / (ROUNDING * scale)).astype(np.int64)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    renumber = np.full(len(flat), -1)
    renumber[used] = inverse.ravel()
    keep = used[first]
    faces = renumber[faces]
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2])]
    faces = faces[faces[:, 0] != faces[:, 2]]
    points = flat[keep]
    return OutlinedMesh(
        points,
        np.concatenate(sheets)[keep],
        np.concatenate(targets)[keep],
        counter_clockwise(points, faces),
    )
