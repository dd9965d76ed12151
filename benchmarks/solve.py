"""Solver speed on the paper's grids: Fig. 1 (step 1/20, 200 diagonals, four quadrants)
and Fig. 3 (step 1/10, 100 diagonals, four quadrants).

Prints wall time (best and median of several runs), valid points, points per second, the
check's worst median and 95th percentile isometry residual and worst median curvature
residual, the share of the solved points that error control keeps (solver.tolerance), and
the ratio to the published 49.8 s (Mathematica, Fig. 1, four quadrants in parallel on the
authors' machine). Issue 21 asks for 30,000 points per second on Fig. 1.

Then the batched solve a search uses (:func:`fabkit.design.solver.solve_batch`, designs
cropped to their solved points): ``--batch`` candidates of the same figure whose initial
eps differ (0.45 to 0.55), marched together (8 is what ``fabkit optimise`` solves per
task by default); it prints the wall time per candidate and the valid points per second
over the batch, and checks that every candidate's design is the one the single solve
gives it (valid points and eps bitwise equal).

Every rate is given per second of wall time and per second of CPU time of this process
(``time.process_time``): on a machine shared with other jobs the second moves less with
their load. The solver's compiled kernels (numba) are compiled, or loaded from their
cache, before the first timed run; the seconds that takes are printed first.

    python benchmarks/solve.py [--repeat 5] [--batch 8 64]
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from common import repeat_runs, timing_arguments

from fabkit.design.check import check_design
from fabkit.design.solver import solve, solve_batch
from fabkit.problem.spec import Spec, load_spec, spec_from_json

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
PUBLISHED_FIG1_SECONDS = 49.8
NO_CONTROL = 1e9
"""A tolerance no error estimate reaches: every solved point is kept."""


def measure(name: str, repeat: int) -> None:
    spec = load_spec(EXAMPLES / name)
    runs = repeat_runs(lambda: solve(spec), repeat)
    design, best = runs.result.design, runs.best
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
    print(f"  wall time  best {best:.3f} s, median {runs.median:.3f} s over {repeat} runs")
    print(
        f"  valid points {points}, {points / best:,.0f} points/s wall, "
        f"{points / runs.best_cpu:,.0f} points/CPU-s"
    )
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


def with_eps(spec: Spec, eps: float) -> Spec:
    """The spec with every initial eps the constant ``eps``."""
    table = json.loads(spec.to_json())
    table["initial"]["eps"] = [str(eps)] * len(table["initial"]["eps"])
    return spec_from_json(json.dumps(table))


def measure_batch(name: str, batch: int, repeat: int) -> None:
    spec = load_spec(EXAMPLES / name)
    specs = [with_eps(spec, e) for e in np.linspace(0.45, 0.55, batch)]
    runs = repeat_runs(lambda: solve_batch(specs, crop=True), repeat)
    designs = [s.design for s in runs.result]
    best = runs.best
    points = sum(int(d.valid.sum()) for d in designs)
    alone = [solve(s).design for s in (specs[0], specs[-1])]
    same = all(
        int(a.valid.sum()) == int(b.valid.sum())
        and np.array_equal(np.sort(a.eps[:, a.valid].ravel()), np.sort(b.eps[:, b.valid].ravel()))
        for a, b in zip(alone, (designs[0], designs[-1]), strict=True)
    )
    print(
        f"  batch of {batch} (eps 0.45-0.55): best {best:.3f} s, {1000 * best / batch:.1f} ms "
        f"per candidate, {points} valid points, {points / best:,.0f} points/s wall, "
        f"{points / runs.best_cpu:,.0f} points/CPU-s; designs equal to single solves: {same}"
    )


def main() -> None:
    parser = timing_arguments(__doc__, repeat=5)
    parser.add_argument(
        "--batch", type=int, nargs="+", default=[8, 64], help="candidates per batch"
    )
    args = parser.parse_args()
    first = repeat_runs(
        lambda: solve(load_spec(EXAMPLES / "two_shapes.toml").with_solver(diagonals=4))
    )
    print(
        f"kernels compiled or loaded, first small solve: {first.best:.2f} s wall, "
        f"{first.best_cpu:.2f} CPU-s"
    )
    for name in ("two_shapes.toml", "three_shapes.toml"):
        measure(name, args.repeat)
        for batch in args.batch:
            measure_batch(name, batch, max(1, args.repeat // 2))


if __name__ == "__main__":
    main()
