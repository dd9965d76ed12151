"""Fig. 1's run, today against an earlier revision, in one run.

``fabkit run examples/two_shapes.toml --out OUT --send "sim://marlin?baud=0&time_scale=0"``
(the README's main command in one layer, as earlier revisions print it: today's code gets
``--layers 1``, which they do not know, since it prints two layers when not told) runs
as ``python -m fabkit`` in a fresh process (interpreter start included), from a folder
outside the repository, alternately with this checkout's code and with the code
of ``--base`` (checked out into a temporary git worktree and put first on PYTHONPATH),
``-n`` times each, after one untimed run of each (it fills the caches both would have on
a second run: compiled solver kernels, the operating system's file cache). Alternating
spreads any change of the machine's load over both. It prints each run's wall time, the
medians, and their ratio against its goal (:data:`GOALS`: issue 20 asks <= 60 % of
16092b9, issue 36 <= 45 % of a86dfed).

    python benchmarks/run.py [--base 16092b9] [-n 5]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SPEC = ROOT / "examples" / "two_shapes.toml"
SEND = "sim://marlin?baud=0&time_scale=0"
BASE = "16092b9"
"""The last commit before issue 20's values-between-stages work."""
GOALS = {"16092b9": "<= 60 %, issue 20", "a86dfed": "<= 45 %, issue 36"}
"""The ratio each base was given as a goal."""
ONE_LAYER = ("--layers", "1")
"""Today's option for the one layer the bases print."""


def timed_run(code: Path, out: Path, layers: tuple[str, ...] = ()) -> float:
    """Wall time (s) of the README command with the package at ``code`` (``layers``: the
    option that asks for one layer, where the code knows it)."""
    command = [sys.executable, "-m", "fabkit", "run", str(SPEC), "--out", str(out)]
    command += ["--send", SEND, *layers]
    env = {**os.environ, "PYTHONPATH": str(code)}
    started = time.perf_counter()
    subprocess.run(command, cwd=out.parent, env=env, check=True, capture_output=True)
    return time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", default=BASE, help="the earlier revision (git)")
    parser.add_argument("-n", type=int, default=5, help="runs of each")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="fabkit-bench-run-") as folder:
        base = Path(folder) / "base"
        subprocess.run(
            ["git", "-C", str(ROOT), "worktree", "add", "--detach", "-q", str(base), args.base],
            check=True,
        )
        try:
            runs = (("base", base, ()), ("today", ROOT, ONE_LAYER))
            for name, code, layers in runs:
                timed_run(code, Path(folder) / f"out-{name}-warm", layers)
            times: dict[str, list[float]] = {"base": [], "today": []}
            for k in range(args.n):
                for name, code, layers in runs:
                    seconds = timed_run(code, Path(folder) / f"out-{name}-{k}", layers)
                    times[name].append(seconds)
                    print(f"  {name:<6} run {k + 1}: {seconds:.2f} s", flush=True)
        finally:
            subprocess.run(
                ["git", "-C", str(ROOT), "worktree", "remove", "--force", str(base)], check=True
            )
    old, new = (statistics.median(times[name]) for name in ("base", "today"))
    print(f"base {args.base}: median {old:.2f} s over {args.n} runs")
    print(f"today: median {new:.2f} s over {args.n} runs")
    goal = GOALS.get(args.base, "none for this base")
    print(f"today / base: {100 * new / old:.0f} % (goal: {goal})")


if __name__ == "__main__":
    main()
