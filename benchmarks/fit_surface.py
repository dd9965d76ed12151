"""Data targets: fit time, evaluation time and K accuracy.

Prints

* the time to fit a 1000 x 1000 height map (Fig. 1's bump, clean and with 1 % noise, and
  with a hole), cold (first fit of that size: includes the eigen-decompositions, which
  are cached per grid size) and warm (best of the rest);
* the time of one ``geometry`` call (metric, Christoffel symbols and K) at 100 000 points,
  best and median of several runs;
* the median relative error of K over the interior (>= 5 cells from the border, where
  |K| >= 10 % of max |K|) for the bump and the wavy sheet sampled 200 x 200 as a height
  map, as an STL mesh, and as a height map with 1 % Gaussian noise.

    python benchmarks/fit_surface.py [--repeat 5]
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import trimesh
from common import repeat_runs, timing_arguments

from fabkit.problem.surfaces import build_surface
from fabkit.problem.surfaces.fit import fit_grid

CASES = {
    "bump": ("exp(-(x**2 + y**2/4))", (-4.0, 4.0, -6.0, 6.0)),
    "wavy": ("sin(x)*sin(y/4)", (-8.0, 8.0, -12.0, 12.0)),
}
"""Fig. 1's bump and Fig. 3's wavy sheet, with the domains they are sampled on."""


def analytic(expression: str):
    return build_surface("analytic", {"kind": "graph", "z": expression}, "benchmark")


def sample(expression: str, extent: tuple[float, ...], n: int):
    """Node coordinates and heights (n, n) of z = expression over extent."""
    xx, yy = np.meshgrid(np.linspace(*extent[:2], n), np.linspace(*extent[2:], n))
    return xx, yy, analytic(expression).embed(np.stack([xx, yy], -1))[..., 2]


def fit_times(repeat: int) -> None:
    expression, extent = CASES["bump"]
    z = sample(expression, extent, 1000)[2]
    noisy = z + 0.01 * np.ptp(z) * np.random.default_rng(0).standard_normal(z.shape)
    holed = z.copy()
    holed[450:550, 400:550] = np.nan
    spacing = ((extent[1] - extent[0]) / 999, (extent[3] - extent[2]) / 999)
    print("fit of a 1000 x 1000 height map (bump):")
    for label, heights in (("clean", z), ("1 % noise", noisy), ("with a hole", holed)):
        times = repeat_runs(lambda h=heights: fit_grid(h, extent[::2], spacing), repeat).wall
        print(f"  {label:<12} first {times[0]:.2f} s, then best {min(times[1:] or times):.2f} s")


def evaluation_times(repeat: int) -> None:
    expression, extent = CASES["bump"]
    with tempfile.TemporaryDirectory() as folder:
        np.save(Path(folder) / "bump.npy", sample(expression, extent, 1000)[2])
        table = {"kind": "heightmap", "file": "bump.npy", "extent": list(extent)}
        surface = build_surface("bump", table, "benchmark", Path(folder))
    points = np.random.default_rng(1).uniform((-3.5, -5.5), (3.5, 5.5), (100_000, 2))
    runs = repeat_runs(lambda: surface.geometry(points), repeat)
    print(
        f"geometry (g, Gamma, K) at 100k points: best {runs.best:.3f} s, median {runs.median:.3f} s"
    )


def curvature_errors() -> None:
    print("median relative K error over the interior, 200 x 200 samples:")
    rng = np.random.default_rng(2)
    with tempfile.TemporaryDirectory() as name:
        folder = Path(name)
        for case, (expression, extent) in CASES.items():
            xx, yy, z = sample(expression, extent, 200)
            noisy = z + 0.01 * np.ptp(z) * rng.standard_normal(z.shape)
            np.save(folder / "clean.npy", z)
            np.save(folder / "noisy.npy", noisy)
            mesh = trimesh.Trimesh(
                np.stack([xx.ravel(), yy.ravel(), z.ravel()], -1), grid_faces(*z.shape)
            )
            mesh.export(folder / "clean.stl")
            tables = {
                "heightmap": {"kind": "heightmap", "file": "clean.npy", "extent": list(extent)},
                "stl": {"kind": "mesh", "file": "clean.stl"},
                "noisy heightmap": {
                    "kind": "heightmap",
                    "file": "noisy.npy",
                    "extent": list(extent),
                },
            }
            points = interior_points(extent, 200, rng)
            truth = analytic(expression).curvature(points)
            keep = np.abs(truth) >= 0.1 * np.abs(truth).max()
            for label, table in tables.items():
                surface = build_surface(case, table, "benchmark", folder)
                error = np.abs(surface.curvature(points[keep]) - truth[keep]) / np.abs(truth[keep])
                print(f"  {case} {label:<16} {np.median(error):8.2%}")


def grid_faces(ny: int, nx: int) -> np.ndarray:
    """Two triangles per cell of an (ny, nx) grid of vertices numbered row by row."""
    index = np.arange(ny * nx).reshape(ny, nx)
    a, b = index[:-1, :-1].ravel(), index[:-1, 1:].ravel()
    c, d = index[1:, 1:].ravel(), index[1:, :-1].ravel()
    return np.concatenate([np.stack([a, b, c], -1), np.stack([a, c, d], -1)])


def interior_points(extent: tuple[float, ...], n: int, rng) -> np.ndarray:
    """20 000 random points (20000, 2) at least 5 cells from the border of extent."""
    margin = 5 * np.array([extent[1] - extent[0], extent[3] - extent[2]]) / (n - 1)
    low = np.array([extent[0], extent[2]]) + margin
    high = np.array([extent[1], extent[3]]) - margin
    return rng.uniform(low, high, (20_000, 2))


def main() -> None:
    parser = timing_arguments(__doc__, repeat=5)
    args = parser.parse_args()
    fit_times(args.repeat)
    evaluation_times(args.repeat)
    curvature_errors()


if __name__ == "__main__":
    main()
