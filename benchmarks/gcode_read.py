"""Reading a G-code file before it is sent: issue 36's figures, printed against its targets.

Makes two files: Fig. 1 as the README's main command prints it (``fabkit run
examples/two_shapes.toml --layers 2``, its G-code only: ``--no-verify``) and a raster of
1,000,000 print moves on ``marlin_generic`` (benchmarks/gcode_write.py's). Prints

1. on Fig. 1's file: reading it into commands, and reading + pre-flight check + duration
   plan (:func:`fabkit.link.host.job.prepare_job`, what ``fabkit send`` does before the
   first byte), in lines/s; PyPI ``gcodeparser``'s reading alone of the same file, and
   the ratio (issue 36's target: >= 5x gcodeparser's reading, and >= 20x the code of
   commit a86dfed, whose time this script does not rerun: the issue measured 5.6 s of
   check and 4.7 s of estimate on a 31,882-line file);
2. ``fabkit send --dry-run`` on the 1,000,000-line file in a process of its own: wall time
   and peak memory (targets <= 5 s, <= 1 GB);
3. the emulator at ``time_scale=0`` (``sim://marlin?baud=0&time_scale=0``) on Fig. 1's
   file, through the whole protocol: lines/s, the best of ``--repeat`` sends (target
   >= 50,000); and, for scale, the same sends against a firmware that answers each
   move line ``ok`` without checking, parsing, moving or tracing it: the host and the
   port alone.

    python benchmarks/gcode_read.py [--repeat 3] [--lines 1000000]
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from common import repeat_runs, timing_arguments
from gcode_write import raster

from fabkit.cli import main as fabkit
from fabkit.gcode.read import read_job_bytes
from fabkit.link.emulator.marlin import MarlinFirmware
from fabkit.link.host.job import job_machine, prepare_job
from fabkit.link.host.send import send_file
from fabkit.machines import load_machine
from fabkit.writers.gcode import GcodeOptions, write_gcode

GCODEPARSER_RATIO = 5.0
DRY_RUN_SECONDS = 5.0
DRY_RUN_BYTES = 1024**3
EMULATOR_LINES_S = 50_000.0


def fig1_file(folder: Path) -> Path:
    """The README's main command's G-code (two layers), written into ``folder``."""
    out = folder / "fig1"
    args = ["run", "examples/two_shapes.toml", "--layers", "2", "--no-verify", "--out", str(out)]
    if fabkit(args) != 0:
        raise SystemExit("fabkit run failed")
    return out / "sheet.gcode"


def raster_file(folder: Path, moves: int) -> Path:
    """``moves`` print moves on marlin_generic, relative E."""
    path = folder / "raster.gcode"
    machine = load_machine("marlin_generic")
    write_gcode(raster(moves), machine, path, GcodeOptions(e_mode="relative"))
    return path


def verdict(holds: bool) -> str:
    return "meets it" if holds else "MISSES it"


def reading(path: Path, repeat: int) -> None:
    """Section 1: fabkit's reading, check and plan against gcodeparser's reading."""
    lines = path.read_bytes().count(b"\n")
    read = repeat_runs(lambda: read_job_bytes(path), repeat)
    choice = job_machine(path, None, "marlin_generic")
    prepared = repeat_runs(lambda: prepare_job(path, choice), repeat)
    print(f"1. {path.name}: {lines:,} lines")
    print(f"   read into commands: {read.best:.2f} s ({lines / read.best:,.0f} lines/s)")
    print(
        f"   read + check + plan: {prepared.best:.2f} s ({lines / prepared.best:,.0f} lines/s, "
        f"{prepared.result.plan.moves:,} moves)"
    )
    try:
        from gcodeparser import parse_gcode_lines
    except ImportError:
        print("   gcodeparser is not installed (pip install gcodeparser): no ratio")
        return
    text = path.read_text()
    theirs = repeat_runs(lambda: list(parse_gcode_lines(text)), repeat)
    ratio = theirs.best / prepared.best
    print(
        f"   gcodeparser reading alone: {theirs.best:.2f} s ({lines / theirs.best:,.0f} "
        f"lines/s); fabkit's read + check + plan is {ratio:.2f}x as fast "
        f"(target >= {GCODEPARSER_RATIO:g}x: {verdict(ratio >= GCODEPARSER_RATIO)})"
    )


PEAK = (
    "import re, sys\n"
    "from fabkit.cli import main\n"
    "code = main(sys.argv[1:])\n"
    "status = open('/proc/self/status').read()\n"
    "print(re.search(r'VmHWM:\\s*(\\d+)', status).group(1), file=sys.stderr)\n"
    "raise SystemExit(code)\n"
)
"""A child that runs a fabkit command and prints its own peak memory (kB, Linux's VmHWM)
last on stderr (getrusage's maxrss survives exec on Linux: it would count this process's
memory, the raster's, as the child's)."""


def dry_run(path: Path) -> None:
    """Section 2: ``fabkit send --dry-run`` in a child process, its wall time and memory."""
    lines = path.read_bytes().count(b"\n")
    command = [sys.executable, "-c", PEAK, "send", str(path), "--dry-run"]
    started = time.perf_counter()
    child = subprocess.run(
        command + ["--machine", "marlin_generic"], check=True, capture_output=True, text=True
    )
    wall = time.perf_counter() - started
    peak = int(child.stderr.split()[-1]) * 1024  # kB on Linux
    print(f"2. send --dry-run on {lines:,} lines: {wall:.1f} s, peak memory {peak / 1e9:.2f} GB")
    print(
        f"   targets <= {DRY_RUN_SECONDS:g} s ({verdict(wall <= DRY_RUN_SECONDS)}) and "
        f"<= 1 GB ({verdict(peak <= DRY_RUN_BYTES)})"
    )


def emulator(path: Path, repeat: int) -> None:
    """Section 3: the whole file through the emulator's protocol at time_scale=0, the best
    of ``repeat`` sends (the send's own figure, from its handshake to the last ``ok``);
    then the same against a firmware that only answers (:func:`_answering_only`)."""
    report = _best_send(path, repeat)
    rate = report.lines_per_s
    print(
        f"3. emulator, sim://marlin?baud=0&time_scale=0: {report.job_lines:,} lines in "
        f"{report.elapsed_s:.2f} s (best of {repeat}), {rate:,.0f} lines/s "
        f"(target >= {EMULATOR_LINES_S:,.0f}: {verdict(rate >= EMULATOR_LINES_S)})"
    )
    with _answering_only():
        bound = _best_send(path, repeat)
    print(
        f"   the host and the port alone (a firmware that answers each move line ok, "
        f"unchecked, unparsed, unmoved, untraced): {bound.elapsed_s:.2f} s, "
        f"{bound.lines_per_s:,.0f} lines/s"
    )


def _best_send(path: Path, repeat: int):
    reports = [
        send_file(path, "sim://marlin?baud=0&time_scale=0", show_progress=False)
        for _ in range(repeat)
    ]
    return min(reports, key=lambda r: r.elapsed_s)


@contextmanager
def _answering_only() -> Iterator[None]:
    """The emulated Marlin's quick path for move lines replaced, for the ``with`` block, by
    one that takes whatever arrives without a command word (the job's G0/G1 lines; the
    handshake's M110, M115 and M105 take the general path) and answers each line ``ok``."""
    real = MarlinFirmware.take_moves

    def answer(firmware: MarlinFirmware, data: bytes, t: float) -> bool:
        if firmware.queue or b"M" in data:
            return False
        lines = data.count(b"\n")
        firmware.last_n += lines
        firmware.out.raw(firmware.ok_bytes * lines, t)
        return True

    MarlinFirmware.take_moves = answer
    try:
        yield
    finally:
        MarlinFirmware.take_moves = real


def main() -> None:
    parser = timing_arguments(__doc__, repeat=3)
    parser.add_argument("--lines", type=int, default=1_000_000, help="moves of the raster")
    args = parser.parse_args()
    folder = Path(tempfile.mkdtemp(prefix="fabkit-bench-"))
    fig1 = fig1_file(folder)
    big = raster_file(folder, args.lines)
    reading(fig1, args.repeat)
    dry_run(big)
    emulator(fig1, args.repeat)


if __name__ == "__main__":
    main()
