"""The searches of docs/optimise.md's "Measured" table: one search of a figure's spec on the
local pool, printing what the table gives (the objective of the spec as given and of the
best, their ratio, budget, evaluations, seconds) and the best spec's check when solved again
on its own grid (worst isometry and curvature residual medians, 95th percentile).

With ``--acceptance`` a candidate counts only if its check passes issue 21's acceptance,
residual medians <= 1e-3 for the curvature too (:data:`fabkit.optimise.objective.ACCEPTANCE`;
the check's default allows the curvature's median 1e-2).

    python benchmarks/optimise_figures.py benchmarks/optimise/fig3.toml --popsize 2 \\
        --generations 8 --seed 0 --acceptance --out out/fig3/best.toml
"""

from __future__ import annotations

import argparse

from fabkit.design.check import Tolerances
from fabkit.optimise.objective import ACCEPTANCE
from fabkit.optimise.run import Job, optimise
from fabkit.optimise.search import Budget

ISOMETRY = ("length_u", "length_v", "angle")
"""The check's isometry residuals."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("spec")
    parser.add_argument("--out", required=True, help="the best spec (.toml); files beside it")
    parser.add_argument("--generations", type=int, default=8)
    parser.add_argument("--popsize", type=int, default=2)
    parser.add_argument("--batch", type=int, default=8)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=0, help="0: every core")
    parser.add_argument("--acceptance", action="store_true", help="medians <= 1e-3")
    args = parser.parse_args()
    budget = Budget(args.generations, args.popsize, args.seed, args.batch)
    tolerances = ACCEPTANCE if args.acceptance else Tolerances()
    job = Job(args.spec, args.out, tolerances=tolerances, budget=budget, workers=args.workers)
    summary = optimise(job, report=lambda line: print(line, flush=True)).summary
    start, best, again = summary["start"], summary["best"], summary["best_solved_again"]
    print(f"{args.spec}: {budget}, check tolerances {summary['check_tolerances']}")
    print(f"  spec as given {start['value']:.4g} ({start['points']} points)")
    print(f"  best {best['value']:.4g} ({best['points']} points), ratio {summary['ratio']:.3g}")
    print(
        f"  {summary['evaluations']} evaluations, {summary['seconds']:.0f} s, "
        f"{summary['evaluations_per_second']:.2f}/s on {summary['pool']['workers']} workers"
    )
    print(
        f"  best solved again: value {again['value']:.4g}, check passed {again['check']['passed']}"
    )
    for surface in again["check"]["surfaces"]:
        isometry = [surface[key] for key in ISOMETRY]
        print(
            f"    {surface['name']}: isometry median {max(r['median'] for r in isometry):.2e}, "
            f"p95 {max(r['p95'] for r in isometry):.2e}, "
            f"curvature median {surface['curvature']['median']:.2e}"
        )


if __name__ == "__main__":
    main()
