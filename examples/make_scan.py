"""Make ``examples/data/sphere_scan.ply``: a stand-in for a scan of Fig. 1's printed sphere.

No printed sheet was scanned for this repository; this is what a scanner would give of
the sheet as fabricated that ``fabkit run examples/two_shapes.toml --layers 2`` simulates
under the sphere's stimulus (its mesh in tests/data/compare_run/as_fabricated/sphere.ply):
a point cloud of 8,000 points on its surface with Gaussian noise of 0.2 mm, the fifth of
it farthest along one side cut away (a scanner that missed it), turned and moved at
random and written in metres (as many scanners do). ``fabkit compare`` reads it with
``--units m`` (docs/compare.md).

Run from the repository root: ``python examples/make_scan.py`` (deterministic).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

ROOT = Path(__file__).resolve().parent.parent
SHEET = ROOT / "tests" / "data" / "compare_run" / "as_fabricated" / "sphere.ply"
SCAN = ROOT / "examples" / "data" / "sphere_scan.ply"
POINTS = 8_000
NOISE_MM = 0.2
CUT = 0.2
"""The share of the points cut away."""


def scan_points(seed: int = 1) -> np.ndarray:
    """The scan's points (m): on the sheet, noisy, a fifth cut away, posed at random."""
    rng = np.random.default_rng(seed)
    sheet = trimesh.load(SHEET, process=False)
    points, _ = trimesh.sample.sample_surface(sheet, round(POINTS / (1 - CUT)), seed=seed)
    points = points + rng.normal(scale=NOISE_MM, size=points.shape)
    side = points @ rng.normal(size=3)
    points = points[side > np.quantile(side, CUT)]
    turn, upper = np.linalg.qr(rng.normal(size=(3, 3)))
    turn = turn * np.sign(np.diag(upper))
    turn[:, 0] *= np.sign(np.linalg.det(turn))  # a rotation, not a mirror image
    return (points @ turn.T + rng.normal(scale=100.0, size=3)) / 1000


def main() -> None:
    SCAN.write_bytes(trimesh.PointCloud(scan_points()).export(file_type="ply"))
    print(f"wrote {SCAN.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
