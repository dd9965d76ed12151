"""Evaluations per second of ``fabkit optimise`` on a local process pool and on a Dask
LocalCluster, with 1 and 2 workers, on the same search (the same seed: every run must find
the same best, which this script checks).

The search is benchmarks/optimise/fig1.toml (Fig. 1, its initial data and targets'
placements as 13 parameters) with a small budget; each run writes into a fresh temporary
folder. Prints one table row per pool: workers, evaluations computed, wall seconds of the
search (the pool's start-up excluded), evaluations per second, best objective.

    python benchmarks/optimise.py [--generations 2] [--popsize 2] [--spec FILE]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from fabkit.optimise.run import Job, optimise
from fabkit.optimise.search import Budget

HERE = Path(__file__).resolve().parent
POOLS = (
    ("local", None, 1),
    ("local", None, 2),
    ("dask local", "local", 1),
    ("dask local", "local", 2),
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spec", default=str(HERE / "optimise" / "fig1.toml"))
    parser.add_argument("--generations", type=int, default=2)
    parser.add_argument("--popsize", type=int, default=2)
    parser.add_argument("--batch", type=int, default=4)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    budget = Budget(args.generations, args.popsize, args.seed, args.batch)
    print(f"{args.spec}: {budget}")
    print(f"{'pool':<12} {'workers':>7} {'evaluations':>11} {'seconds':>8} {'eval/s':>7}  best")
    bests = set()
    for name, dask, workers in POOLS:
        with tempfile.TemporaryDirectory() as folder:
            out = str(Path(folder) / "best.toml")
            job = Job(args.spec, out, budget=budget, workers=workers, dask=dask)
            summary = optimise(job).summary
        bests.add(tuple(summary["best"]["parameters"].values()))
        print(
            f"{name:<12} {workers:>7} {summary['computed']:>11} {summary['seconds']:>8.1f} "
            f"{summary['evaluations_per_second']:>7.2f}  {summary['best']['value']:.6g}",
            flush=True,
        )
    print(f"same best on every pool: {len(bests) == 1}")


if __name__ == "__main__":
    main()
