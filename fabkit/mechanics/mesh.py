"""Triangle meshes of the flat sheet: the design's (u, v) grid, discs, topology, mesh files.

Flat-sheet points are (V, 2) arrays in design units; triangles (F, 3) vertex indices,
counter-clockwise on the flat sheet (so the initial normal is +z). The hinge topology
(interior edges with their two opposite vertices) is what the bending energy needs.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import Delaunay

from fabkit.design.design import Design
from fabkit.design.patches import MESH_FORMATS
from fabkit.errors import FabkitError
from fabkit.field.part import Part, solved_cells
from fabkit.files.atomic import atomic_path


@dataclass(frozen=True)
class DesignMesh:
    """The solved flat domain of a design as a triangle mesh.

    ``points`` (V, 2) flat-sheet positions; ``triangles`` (F, 3) counter-clockwise;
    ``grid`` (V, 2) int, every vertex's index (i, j) on the design grid refined ``refine``
    times, so vertex k sits at material coordinates (u, v) = (u[0], v[0]) + step
    grid[k] / refine. With ``refine`` = 1 the vertices are the design's grid points and
    vertex k corresponds to r_s[i, j] on every surface s; otherwise :meth:`sample`
    interpolates the design's fields at the vertices.
    """

    points: np.ndarray
    triangles: np.ndarray
    grid: np.ndarray
    refine: int = 1

    @property
    def nodes(self) -> np.ndarray:
        """Boolean mask (V,) of the vertices that are points of the design's own grid."""
        return np.all(self.grid % self.refine == 0, axis=1)

    def sample(self, field: np.ndarray) -> np.ndarray:
        """A design field (nu, nv, ...) at the vertices (V, ...), bilinear in (u, v).

        Exact at the design's grid points; inside a grid cell only the cell's four corners
        are used (a solved cell's corners are all solved).
        """
        field = np.asarray(field)
        low = np.minimum(self.grid // self.refine, np.array(field.shape[:2]) - 2)
        fraction = self.grid / self.refine - low
        total = np.zeros((len(self.grid), *field.shape[2:]))
        for di, dj in ((0, 0), (1, 0), (0, 1), (1, 1)):
            weight = np.abs(1 - di - fraction[:, 0]) * np.abs(1 - dj - fraction[:, 1])
            value = field[low[:, 0] + di, low[:, 1] + dj]
            weight = weight.reshape(-1, *([1] * (value.ndim - 1)))
            total += weight * np.where(weight > 0, value, 0.0)
        return total


@dataclass(frozen=True)
class Topology:
    """Edge structure of a triangle mesh.

    ``hinges`` (H, 4): interior edges as (p, q, a, b) with p -> q a counter-clockwise edge
    of face A = (p, q, a) and q -> p one of face B = (q, p, b).
    ``face_hinges`` (F, 3): the hinge on the edge opposite vertex i of each face, -1 on
    the boundary. ``flaps`` (F, 3): the vertex across that edge, -1 on the boundary.
    """

    hinges: np.ndarray
    face_hinges: np.ndarray
    flaps: np.ndarray


def design_mesh(design: Design, part: Part | None = None, refine: int = 1) -> DesignMesh:
    """Triangulate the solved grid cells of ``design`` (two triangles per cell).

    With ``part`` (:class:`~fabkit.field.part.Part`), only the cells whose centre lies in the
    part are kept (the part's trim removes regions too narrow for the sheet's thickness:
    a ribbon a few bending lengths wide bends freely whatever its metric). With ``refine``
    = n > 1 every solved cell is split into n x n sub-cells, uniform in material
    coordinates, each kept when its own centre lies in the part; the new vertices' flat
    positions interpolate the design's flat sheet r[0] bilinearly (they only chart the
    sheet: its reference metric comes from the designed metric in (u, v), see
    :func:`~fabkit.mechanics.simulate.design_metrics`).
    """
    if refine < 1:
        raise FabkitError(f"refine must be a positive integer, got {refine}")
    fine = np.kron(solved_cells(design), np.ones((refine, refine), dtype=bool))
    i, j = np.nonzero(fine)
    corners = np.stack([(i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)], axis=1)  # (2, 4, F)
    if part is not None and len(i):
        probe = DesignMesh(
            np.zeros((4 * len(i), 2)), np.zeros((0, 3), int), corners.reshape(2, -1).T, refine
        )
        centres = probe.sample(np.nan_to_num(design.r[0])).reshape(4, len(i), 2).mean(axis=0)
        keep = part.contains(centres)
        i, j, corners = i[keep], j[keep], corners[:, :, keep]
    if len(i) == 0:
        raise FabkitError("the design has no solved grid cell to simulate (in the part)")
    flat = corners.reshape(2, -1)
    grid, inverse = np.unique(flat.T, axis=0, return_inverse=True)
    a, b, c, d = inverse.reshape(4, -1)
    triangles = np.concatenate([np.stack([a, b, c], -1), np.stack([a, c, d], -1)])
    mesh = DesignMesh(np.zeros((len(grid), 2)), triangles, grid, refine)
    points = mesh.sample(design.r[0])
    return DesignMesh(points, counter_clockwise(points, triangles), grid, refine)


def disc_mesh(radius: float, rings: int) -> tuple[np.ndarray, np.ndarray]:
    """A disc of ``radius`` meshed by ``rings`` concentric rings of 6 k points (k = 1..rings).

    Returns points (V, 2) with the centre as vertex 0, and about 6 rings^2 triangles.
    """
    points = [np.zeros((1, 2))]
    for ring in range(1, rings + 1):
        angle = (np.arange(6 * ring) + 0.5 * (ring % 2)) * 2 * np.pi / (6 * ring)
        points.append(radius * ring / rings * np.stack([np.cos(angle), np.sin(angle)], -1))
    points = np.concatenate(points)
    return points, counter_clockwise(points, Delaunay(points).simplices)


def counter_clockwise(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """``triangles`` with each row reordered to be counter-clockwise on the flat sheet."""
    triangles = np.array(triangles, dtype=np.int64)
    a, b, c = (points[triangles[:, k]] for k in range(3))
    signed = (b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0]
    flip = signed < 0
    triangles[flip] = triangles[flip][:, [0, 2, 1]]
    return triangles


def topology(triangles: np.ndarray) -> Topology:
    """Hinges, face-to-hinge map and flap vertices of a consistently oriented mesh.

    Raises :class:`FabkitError` for a non-manifold edge (shared by three or more faces)
    or inconsistent orientation.
    """
    faces = len(triangles)
    # Edge i of a face is opposite vertex i: it runs from vertex i+1 to vertex i+2.
    start = triangles[:, [1, 2, 0]].ravel()
    end = triangles[:, [2, 0, 1]].ravel()
    low, high = np.minimum(start, end), np.maximum(start, end)
    order = np.lexsort((high, low))
    same = (low[order][1:] == low[order][:-1]) & (high[order][1:] == high[order][:-1])
    first, second = order[:-1][same], order[1:][same]
    if np.any(np.bincount(np.concatenate([first, second]), minlength=3 * faces) > 1):
        raise FabkitError("mesh: an edge is shared by more than two triangles")
    if np.any(start[first] == start[second]):
        raise FabkitError("mesh: triangles are not consistently oriented")
    face_a = np.where(start[first] < end[first], first, second)
    face_b = np.where(start[first] < end[first], second, first)
    opposite = triangles.ravel()
    hinges = np.stack([start[face_a], end[face_a], opposite[face_a], opposite[face_b]], -1)
    face_hinges = np.full(3 * faces, -1)
    flaps = np.full(3 * faces, -1)
    count = np.arange(len(hinges))
    face_hinges[face_a], face_hinges[face_b] = count, count
    flaps[face_a], flaps[face_b] = opposite[face_b], opposite[face_a]
    return Topology(hinges, face_hinges.reshape(faces, 3), flaps.reshape(faces, 3))


def save_mesh(
    path: str | Path,
    positions: np.ndarray,
    triangles: np.ndarray,
    vertex_values: Mapping[str, np.ndarray] | None = None,
) -> None:
    """Write a 3D mesh as PLY, STL, GLB or OBJ (chosen by the suffix), atomically.

    ``vertex_values``: named values (V,) per vertex, written as vertex properties of a PLY
    (the other formats have no place for them)."""
    import trimesh

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in MESH_FORMATS:
        raise FabkitError(f"{path}: mesh format must be one of {', '.join(MESH_FORMATS)}")
    mesh = trimesh.Trimesh(positions, triangles, process=False)
    for name, values in (vertex_values or {}).items():
        mesh.vertex_attributes[name] = np.asarray(values, dtype=float)
    with atomic_path(path) as tmp:
        mesh.export(tmp, file_type=suffix.lstrip("."))
