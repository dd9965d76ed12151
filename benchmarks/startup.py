"""Start-up time of the quick commands: median wall time of each over N fresh processes.

Each command runs as ``python -m fabkit ...`` in its own process (what a user waits for
when typing it, the interpreter's start included), N times; the median and the slowest
are printed against the goal (0.5 s). The ``send`` rows check and estimate a small G-code
file written here (``--dry-run``: no port).

    python benchmarks/startup.py [-n 7]
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

GOAL_S = 0.5
ROOT = Path(__file__).resolve().parent.parent
SPEC = ROOT / "examples" / "two_shapes.toml"
GCODE = """; a small job for the start-up benchmark
G21
G90
G28
G1 Z5 F240
G1 X10 Y10 F3000
G1 X40 Y10 F1200
G1 X40 Y40
G1 X10 Y40
G1 X10 Y10
M84
"""


def commands(gcode: Path) -> list[list[str]]:
    """The commands timed: the ones the CLI promises to start at once."""
    return [
        ["--version"],
        ["--help"],
        ["machines"],
        ["spec", str(SPEC)],
        ["send", "--help"],
        ["send", str(gcode), "--dry-run", "--machine", "marlin_generic"],
    ]


def wall_times(args: list[str], repeats: int) -> list[float]:
    """Wall time (s) of ``python -m fabkit ARGS`` in ``repeats`` fresh processes."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        process = subprocess.run(
            [sys.executable, "-m", "fabkit", *args], capture_output=True, text=True, check=False
        )
        times.append(time.perf_counter() - start)
        if process.returncode != 0:
            raise SystemExit(f"fabkit {' '.join(args)} failed: {process.stderr.strip()}")
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-n", type=int, default=7, help="processes per command (default 7)")
    repeats = parser.parse_args().n
    with tempfile.TemporaryDirectory() as folder:
        gcode = Path(folder) / "job.gcode"
        gcode.write_text(GCODE, encoding="utf-8")
        python = [sys.executable, "-c", "pass"]
        bare = statistics.median(_times(python, repeats))
        print(f"python itself (no fabkit): median {bare:.3f} s")
        print(f"{'command':<52} {'median s':>9} {'max s':>7}  goal {GOAL_S} s")
        worst = 0.0
        for args in commands(gcode):
            times = wall_times(args, repeats)
            median = statistics.median(times)
            worst = max(worst, median)
            shown = " ".join(Path(a).name if "/" in a else a for a in args)
            mark = "ok" if median <= GOAL_S else "SLOW"
            print(f"fabkit {shown:<45} {median:9.3f} {max(times):7.3f}  {mark}")
    print(f"slowest median {worst:.3f} s: {'all within' if worst <= GOAL_S else 'over'} the goal")


def _times(command: list[str], repeats: int) -> list[float]:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        subprocess.run(command, capture_output=True, check=False)
        times.append(time.perf_counter() - start)
    return times


if __name__ == "__main__":
    main()
