"""Solver speed on the paper's grids: Fig. 1 (step 1/20, 200 diagonals, four quadrants)
and Fig. 3 (step 1/10, 100 diagonals, four quadrants).

Prints wall time (best and median of several runs), valid points, points per second,
the check's worst median isometry residual, and the ratio to the published 49.8 s
(Mathematica, Fig. 1, four quadrants in parallel on the authors' machine).

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
    report = check_design(design)
    worst = max(s.isometry.median for s in report.surfaces)
    settings = spec.solver
    print(
        f"{name}: step {settings.step:g}, {settings.diagonals} diagonals, "
        f"{len(settings.quadrants)} quadrants, Richardson {settings.extrapolate}"
    )
    print(f"  wall time  best {best:.3f} s, median {median:.3f} s over {repeat} runs")
    print(f"  valid points {points}, {points / best:,.0f} points/s")
    print(f"  worst median isometry residual {worst:.2e}, check passed: {report.passed}")
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
