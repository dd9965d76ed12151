"""The README's main command, today against an earlier revision, in one run.

Each revision runs the main command its own README gives (``fabkit run
examples/two_shapes.toml ... --send "sim://marlin?baud=0&time_scale=0"``, read from the
README at that revision: a86dfed's says ``--layers 2``, today's chooses two layers itself
and judges every target from six starts) as ``python -m fabkit`` in a fresh process
(interpreter start included), from a folder outside the repository, alternately with this
checkout's code and with the code of ``--base`` (checked out into a temporary git worktree
and put first on PYTHONPATH), ``-n`` times each, after one untimed run of each (it fills
the caches both would have on a second run: compiled solver kernels, kept simulations, the
operating system's file cache). Alternating spreads any change of the machine's load over
both. ``--one-layer`` runs both in one layer instead (today's code gets ``--layers 1``;
the measure earlier notes quoted). It prints each run's wall time, the medians, and their
ratio against its goal (:data:`GOALS`: issue 20 asks <= 60 % of 16092b9, issue 36 <= 45 %
of a86dfed).

    python benchmarks/run.py [--base 16092b9] [-n 5] [--one-layer]
"""

from __future__ import annotations

import argparse
import os
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BASE = "16092b9"
"""The last commit before issue 20's values-between-stages work."""
GOALS = {"16092b9": "<= 60 %, issue 20", "a86dfed": "<= 45 %, issue 36"}
"""The ratio each base was given as a goal."""
INSTALL = "pip install -e . && "
"""What precedes the main command on the README's quickstart line."""


def readme_command(revision: str | None) -> list[str]:
    """The arguments after ``fabkit`` of the README's main command at ``revision`` (None:
    the working tree), with ``--out out`` left for :func:`timed_run` to replace."""
    if revision is None:
        readme = (ROOT / "README.md").read_text(encoding="utf-8")
    else:
        show = ["git", "-C", str(ROOT), "show", f"{revision}:README.md"]
        readme = subprocess.run(show, check=True, capture_output=True, text=True).stdout
    line = next(line for line in readme.splitlines() if line.startswith(INSTALL + "fabkit run"))
    return shlex.split(line.removeprefix(INSTALL))[1:]


def one_layer(arguments: list[str], today: bool) -> list[str]:
    """``arguments`` printing one layer: no ``--layers K``, and today's ``--layers 1``."""
    kept = [a for k, a in enumerate(arguments) if "--layers" not in arguments[k - 1 : k + 1]]
    return kept + (["--layers", "1"] if today else [])


def timed_run(code: Path, out: Path, arguments: list[str]) -> float:
    """Wall time (s) of ``fabkit ARGUMENTS`` (its ``--out`` set to ``out``) with the
    package at ``code``, run from ``out``'s folder."""
    at = arguments.index("--out") + 1
    command = [sys.executable, "-m", "fabkit", *arguments[:at], str(out), *arguments[at + 1 :]]
    command = [a.replace("examples/", f"{ROOT}/examples/", 1) for a in command]
    env = {**os.environ, "PYTHONPATH": str(code)}
    started = time.perf_counter()
    subprocess.run(command, cwd=out.parent, env=env, check=True, capture_output=True)
    return time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", default=BASE, help="the earlier revision (git)")
    parser.add_argument("-n", type=int, default=5, help="runs of each")
    parser.add_argument("--one-layer", action="store_true", help="both in one layer")
    args = parser.parse_args()
    commands = {"base": readme_command(args.base), "today": readme_command(None)}
    if args.one_layer:
        commands = {name: one_layer(c, name == "today") for name, c in commands.items()}
    for name, command in commands.items():
        print(f"{name}: fabkit {shlex.join(command)}")
    with tempfile.TemporaryDirectory(prefix="fabkit-bench-run-") as folder:
        base = Path(folder) / "base"
        subprocess.run(
            ["git", "-C", str(ROOT), "worktree", "add", "--detach", "-q", str(base), args.base],
            check=True,
        )
        try:
            runs = (("base", base), ("today", ROOT))
            for name, code in runs:
                timed_run(code, Path(folder) / f"out-{name}-warm", commands[name])
            times: dict[str, list[float]] = {"base": [], "today": []}
            for k in range(args.n):
                for name, code in runs:
                    seconds = timed_run(code, Path(folder) / f"out-{name}-{k}", commands[name])
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
