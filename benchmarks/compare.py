"""Comparing a scan with its target: issue 38's figure, printed against its target.

Makes a point cloud of ``--points`` points (default 200,000) from the sheet as fabricated
that tests/data/compare_run holds (``fabkit run examples/two_shapes.toml --layers 2``'s
sphere): turned and moved at random, in m, with Gaussian noise of 0.2 mm. Prints
``fabkit compare`` on it in a process of its own: wall time and peak memory (target
<= 10 s), and the verdict's lines.

    python benchmarks/compare.py [--points 200000]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh
from gcode_read import PEAK, verdict

RUN = Path(__file__).resolve().parent.parent / "tests" / "data" / "compare_run"
SECONDS = 10.0
NOISE_MM = 0.2


def scan_file(folder: Path, points: int) -> Path:
    """The scan: ``points`` points on the sphere's sheet, posed at random, in m."""
    sheet = trimesh.load(RUN / "as_fabricated" / "sphere.ply", process=False)
    rng = np.random.default_rng(38)
    cloud, _ = trimesh.sample.sample_surface(sheet, points, seed=38)
    cloud = cloud + rng.normal(scale=NOISE_MM, size=cloud.shape)
    turn, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    cloud = cloud @ (turn * np.sign(np.linalg.det(turn))).T + rng.normal(scale=50.0, size=3)
    path = folder / "scan.ply"
    trimesh.PointCloud(cloud / 1000).export(path)
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=200_000, help="points of the scan")
    args = parser.parse_args()
    folder = Path(tempfile.mkdtemp(prefix="fabkit-bench-"))
    scan = scan_file(folder, args.points)
    command = [sys.executable, "-c", PEAK, "compare", str(scan), str(RUN), "--target", "sphere"]
    command += ["--units", "m", "--out", str(folder / "out")]
    started = time.perf_counter()
    child = subprocess.run(command, check=True, capture_output=True, text=True)
    wall = time.perf_counter() - started
    peak = int(child.stderr.split()[-1]) * 1024  # kB on Linux
    print(f"fabkit compare on a scan of {args.points:,} points: {wall:.1f} s (the whole process)")
    print(f"   peak memory {peak / 1e6:.0f} MB")
    print(f"   target <= {SECONDS:g} s: {verdict(wall <= SECONDS)}")
    for line in child.stdout.splitlines():
        print(f"   {line}")


if __name__ == "__main__":
    main()
