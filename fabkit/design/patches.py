"""The solved patches as triangle meshes: on the flat sheet and on every target in 3D."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from fabkit.design.design import Design
from fabkit.errors import FabkitError
from fabkit.files.atomic import atomic_path, check_name, inside
from fabkit.problem.spec import Target

MESH_FORMATS = (".ply", ".stl", ".glb", ".obj")
MESH_TYPES = tuple(suffix.lstrip(".") for suffix in MESH_FORMATS)
"""The mesh file types by name, as ``--mesh-format`` takes them."""


def grid_triangles(valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Triangulate the solved grid cells.

    Returns ``(points, triangles)``: ``points`` (V, 2) int grid indices (i, j) of the
    vertices used, ``triangles`` (F, 3) indices into ``points``; every grid cell whose
    four corners are solved gives two triangles, counter-clockwise in (u, v).
    """
    cells = valid[:-1, :-1] & valid[1:, :-1] & valid[:-1, 1:] & valid[1:, 1:]
    i, j = np.nonzero(cells)
    corners = np.stack([(i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)], axis=1)  # (2, 4, F)
    used = np.zeros_like(valid)
    for k in range(4):
        used[corners[0, k], corners[1, k]] = True
    index = np.full(valid.shape, -1)
    points = np.argwhere(used)
    index[points[:, 0], points[:, 1]] = np.arange(len(points))
    a, b, c, d = (index[corners[0, k], corners[1, k]] for k in range(4))
    triangles = np.concatenate([np.stack([a, b, c], -1), np.stack([a, c, d], -1)])
    return points, triangles


def patch_mesh(design: Design, surface: int) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) and triangles (F, 3) of the patch on surface ``surface`` in 3D.

    Surface 0 is the flat sheet (z = 0). A surface given only by its metric has no
    embedding and is refused.
    """
    spec = design.problem
    target = spec.targets[surface]
    points, triangles = grid_triangles(design.valid)
    chart = design.r[surface][points[:, 0], points[:, 1]]
    vertices = target.surface.embed(chart)
    if vertices is None:
        raise FabkitError(f"surface '{target.name}' is intrinsic (metric only): no 3D mesh")
    return vertices, triangles


def write_patch_mesh(design: Design, surface: int, path: str | Path) -> None:
    """Write the patch on one surface as PLY, STL, GLB or OBJ (chosen by the suffix)."""
    import trimesh

    path = Path(path)
    if path.suffix.lower() not in MESH_FORMATS:
        raise FabkitError(f"{path}: mesh format must be one of {', '.join(MESH_FORMATS)}")
    vertices, triangles = patch_mesh(design, surface)
    if len(triangles) == 0:
        raise FabkitError("the design has no solved grid cell to mesh")
    mesh = trimesh.Trimesh(vertices, triangles, process=False)
    with atomic_path(path) as tmp:
        mesh.export(tmp, file_type=path.suffix.lower().lstrip("."))


def patch_paths(
    targets: Sequence[Target], folder: str | Path, mesh_format: str = "ply"
) -> list[tuple[int, Path]]:
    """(surface index, mesh file) of every target with a 3D embedding, in ``folder``.

    Files are ``folder / f"{index}_{name}.{mesh_format}"``; a name that could not
    safely be part of a file name (:func:`fabkit.files.atomic.check_name`), or a file that would
    land outside ``folder``, is a one-line error, so callers check before any work.
    """
    paths = []
    for index, target in enumerate(targets):
        if target.surface.embed(target.start[None]) is not None:
            name = check_name(target.name, f"surfaces[{index}].name")
            paths.append((index, inside(folder, f"{index}_{name}.{mesh_format}")))
    return paths


def write_patch_meshes(design: Design, folder: str | Path, mesh_format: str = "ply") -> list[Path]:
    """Write the patch on every surface with a 3D embedding (see :func:`patch_paths`);
    returns the paths written. Surfaces given only by their metric are skipped."""
    paths = patch_paths(design.problem.targets, folder, mesh_format)
    for index, path in paths:
        write_patch_mesh(design, index, path)
    return [path for _, path in paths]
