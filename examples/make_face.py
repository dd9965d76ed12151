"""Generate the face-like mask of Fig. 3 as data files: ``examples/data/face.npy`` and ``face.stl``.

The paper's face data is not public; this is a stand-in of the same size: heights over
x in [-16, 16] (across the face) and y in [0, 40] (chin at the bottom, forehead at the
top), a few units high, built from smooth Gaussian features (a head dome, forehead,
brows, eye sockets, nose with tip and wings, cheeks, lips with the mouth line, chin), all
wider than about half a unit so that a sheet can follow them. The design of Fig. 3
starts on the nose at (0, 18) with director (0, 1) (up the face).

* ``face.npy``: float64 heights, 201 rows (y = 0 .. 40) x 161 columns (x = -16 .. 16),
  spacing 0.2; use it as
  ``geometry = { kind = "heightmap", file = "data/face.npy", extent = [-16, 16, 0, 40] }``.
* ``face.stl``: the same surface meshed on a coarser 0.5 grid (two triangles per cell,
  binary STL); use it as ``geometry = { kind = "mesh", file = "data/face.stl" }``.

Run from the repository root: ``python examples/make_face.py`` (deterministic; the test
suite checks that the shipped files match this script).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import trimesh

EXTENT = (-16.0, 16.0, 0.0, 40.0)
"""x0, x1, y0, y1 of the mask, as in Fig. 3."""
HEIGHTMAP_STEP = 0.2
MESH_STEP = 0.5
FEATURES = (
    # (height, x centre, y centre, x width, y width): one Gaussian bump or dent each.
    (5.0, 0.0, 21.0, 8.0, 12.0),  # head dome
    (1.0, 0.0, 33.0, 6.0, 4.0),  # forehead
    (0.6, -5.0, 28.0, 2.2, 0.9),  # brows
    (0.6, 5.0, 28.0, 2.2, 0.9),
    (-1.5, -5.0, 25.0, 2.0, 1.6),  # eye sockets
    (-1.5, 5.0, 25.0, 2.0, 1.6),
    (1.6, 0.0, 21.0, 1.1, 4.0),  # nose bridge
    (1.0, 0.0, 17.0, 1.2, 1.3),  # nose tip
    (0.5, -1.8, 16.0, 0.8, 0.9),  # nose wings
    (0.5, 1.8, 16.0, 0.8, 0.9),
    (0.8, -6.5, 17.0, 3.0, 3.5),  # cheeks
    (0.8, 6.5, 17.0, 3.0, 3.5),
    (0.6, 0.0, 11.8, 2.6, 0.8),  # upper lip
    (0.7, 0.0, 9.6, 2.3, 0.8),  # lower lip
    (-0.3, 0.0, 10.8, 2.8, 0.6),  # mouth line
    (0.9, 0.0, 5.5, 2.8, 2.0),  # chin
)


def face_height(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Height of the mask at (x, y) (arrays of one shape, design units)."""
    z = np.zeros(np.broadcast(x, y).shape)
    for height, cx, cy, wx, wy in FEATURES:
        z += height * np.exp(-((x - cx) ** 2) / (2 * wx**2) - (y - cy) ** 2 / (2 * wy**2))
    return z


def grid(step: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Node coordinates and heights (ny, nx) over EXTENT at the given step."""
    x0, x1, y0, y1 = EXTENT
    x = np.linspace(x0, x1, int(round((x1 - x0) / step)) + 1)
    y = np.linspace(y0, y1, int(round((y1 - y0) / step)) + 1)
    xx, yy = np.meshgrid(x, y)
    return xx, yy, face_height(xx, yy)


def grid_mesh(xx: np.ndarray, yy: np.ndarray, zz: np.ndarray) -> trimesh.Trimesh:
    """Two triangles per grid cell, counter-clockwise seen from +z."""
    ny, nx = zz.shape
    vertices = np.stack([xx.ravel(), yy.ravel(), zz.ravel()], axis=-1)
    index = np.arange(ny * nx).reshape(ny, nx)
    a, b = index[:-1, :-1].ravel(), index[:-1, 1:].ravel()
    c, d = index[1:, 1:].ravel(), index[1:, :-1].ravel()
    faces = np.concatenate([np.stack([a, b, c], -1), np.stack([a, c, d], -1)])
    return trimesh.Trimesh(vertices, faces, process=False)


def main(folder: Path) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    np.save(folder / "face.npy", grid(HEIGHTMAP_STEP)[2])
    grid_mesh(*grid(MESH_STEP)).export(folder / "face.stl")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parent / "data")
