"""Solver speed on the paper's grids: Fig. 1 (step 1/20, 200 diagonals, four quadrants)
and Fig. 3 (step 1/10, 100 diagonals, four quadrants).

Prints wall time (best and median of several runs), valid points, points per second, the
check's worst median and 95th percentile isometry residual and worst median curvature
residual, the share of the solved points that error control keeps (solver.tolerance), and
the ratio to the published 49.8 s (Mathematica, Fig. 1, four quadrants in parallel on the
authors' machine). Issue 21 asks for 30,000 points per second on Fig. 1.

    python benchmarks/solve.py [--repeat 5]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

from fabkit.design.check import check_design
from fabkit.design.solver import solve
from fabkit.spec import load_spec

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
PUBLISHED_FIG1_SECONDS = 49.8
NO_CONTROL = 1e9
"""A tolerance no error estimate reaches: every solved point is kept."""


def measure(name: str, repeat: int) -> None:
    spec = load_spec(EXAMPLES / name)
    times, solution = [], None
    for _ in range(repeat):
        started = time.perf_counter()
        solution = solve(spec)
        times.append(time.perf_counter() - started)
    design = solution.design
    best, median = min(times), statistics.median(times)
    points = int(design.valid.sum())
    solved = int(solve(spec.with_solver(tolerance=NO_CONTROL)).design.valid.sum())
    report = check_design(design)
    isometry = max(s.isometry.median for s in report.surfaces)
    p95 = max(s.isometry.p95 for s in report.surfaces)
    curvature = max(s.curvature.median for s in report.surfaces)
    settings = spec.solver
    print(
        f"{name}: step {settings.step:g}, {settings.diagonals} diagonals, "
        f"{len(settings.quadrants)} quadrants, Richardson {settings.extrapolate}, "
        f"tolerance {settings.tolerance:g}"
    )
    print(f"  wall time  best {best:.3f} s, median {median:.3f} s over {repeat} runs")
    print(f"  valid points {points}, {points / best:,.0f} points/s")
    print(f"  kept {points} of {solved} solved points ({points / solved:.0%})")
    print(
        f"  check: worst isometry median {isometry:.2e}, p95 {p95:.2e}, "
        f"curvature median {curvature:.2e}, passed: {report.passed}"
    )
    if name == "two_shapes.toml":
        print(
            f"  ratio to the published {PUBLISHED_FIG1_SECONDS} s: "
            f"{PUBLISHED_FIG1_SECONDS / best:.0f}x faster"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    for name in ("two_shapes.toml", "three_shapes.toml"):
        measure(name, args.repeat)


if __name__ == "__main__":
    main()
