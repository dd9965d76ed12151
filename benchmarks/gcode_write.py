"""G-code writing speed: 1,000,000 print moves with fabkit's writer, and mecode on the same
moves in the same run.

The job is a raster of wavy roads (1000 roads of 1000 segments, 0.1 mm apart, eps-like
varying speeds) on ``marlin_generic`` with relative E. fabkit's time is everything from
the toolpath to the file on disk: placement, travels, checks against the profile, E from
the volumes, formatting and the atomic write. mecode (``pip install mecode``; imported
only here) writes the very same G1 lines, with the E and F values fabkit computed handed
to it, so it does only the formatting and writing. Prints wall and CPU time (best of
``--repeat``), lines per second and the ratio; the targets are <= 3 s and >= 10x.

    python benchmarks/gcode_write.py [--moves 1000000] [--repeat 3] [--no-mecode]
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
from common import repeat_runs, timing_arguments

from fabkit.machines import load_machine
from fabkit.toolpath import PRINT, TRAVEL, Layer, Move, Toolpath
from fabkit.writers.gcode import GcodeOptions, write_gcode

TARGET_SECONDS = 3.0
TARGET_RATIO = 10.0
SEGMENTS_PER_ROAD = 1000
SPEED = "print_speed_mm_s"
"""The channel the raster's varying speeds are encoded in."""


def raster(moves: int) -> Toolpath:
    """``moves`` print segments: roads of 1000 segments along x, serpentine, 0.1 mm apart."""
    roads = max(1, moves // SEGMENTS_PER_ROAD)
    x = np.linspace(-50.0, 50.0, SEGMENTS_PER_ROAD + 1)
    result, last = [], None
    for k in range(roads):
        xs = x if k % 2 == 0 else x[::-1]
        y = -roads * 0.05 + 0.1 * k + 0.02 * np.sin(xs)
        xy = np.column_stack([xs, y])
        speed = 20.0 + 5.0 * np.cos(xs / 7.0 + k)
        if last is not None:
            hop = [last, xy[0]]
            result.append(Move.make(TRAVEL, hop, 0.2, 0.0, 120.0, 0.0, {SPEED: np.nan}))
        result.append(Move.make(PRINT, xy, 0.2, 0.45, speed, 1.0, {SPEED: speed}))
        last = xy[-1]
    return Toolpath((Layer(0.2, 0.2, tuple(result)),), {SPEED: "eps"})


def mecode_writer(toolpath: Toolpath, reference: Path, out: Path):
    """A function writing the same motion lines with mecode, or None if it is missing."""
    try:
        from mecode import G
    except ImportError:
        print("mecode is not installed (pip install mecode): no comparison")
        return None
    lines = [
        line.split(";")[0].split()
        for line in reference.read_text().splitlines()
        if line.startswith(("G0 ", "G1 "))
    ]
    words = [(ln[0], {w[0]: float(w[1:]) for w in ln[1:]}) for ln in lines]

    def run() -> None:
        g = G(outfile=str(out), print_lines=False, setup=False)
        g.absolute()
        for code, values in words:
            axes = {k.lower(): values[k] for k in "XYZ" if k in values}
            extra = {k: values[k] for k in "EF" if k in values}
            g.abs_move(rapid=code == "G0", **axes, **extra)
        g.teardown()

    return run


def main() -> None:
    parser = timing_arguments(__doc__, repeat=3)
    parser.add_argument("--moves", type=int, default=1_000_000)
    parser.add_argument("--no-mecode", action="store_true")
    args = parser.parse_args()

    machine = load_machine("marlin_generic")
    built = time.perf_counter()
    toolpath = raster(args.moves)
    built = time.perf_counter() - built
    folder = Path(tempfile.mkdtemp(prefix="fabkit-bench-"))
    out = folder / "fabkit.gcode"
    options = GcodeOptions(e_mode="relative")
    summary = write_gcode(toolpath, machine, out, options)
    fabkit = repeat_runs(lambda: write_gcode(toolpath, machine, out, options), args.repeat)
    wall, cpu = fabkit.best, fabkit.best_cpu
    lines, size = summary.motion_lines, out.stat().st_size
    print(
        f"toolpath: {args.moves:,} print segments in {toolpath.print_length_mm:,.0f} mm "
        f"(built in {built:.2f} s)"
    )
    print(
        f"fabkit : {wall:.2f} s wall, {cpu:.2f} s CPU (best of {args.repeat}); "
        f"{lines:,} motion lines, {size / 1e6:.1f} MB, {lines / wall:,.0f} lines/s; "
        f"target <= {TARGET_SECONDS:g} s: {'met' if wall <= TARGET_SECONDS else 'MISSED'}"
    )
    if args.no_mecode:
        return
    run = mecode_writer(toolpath, out, folder / "mecode.gcode")
    if run is None:
        return
    mecode = repeat_runs(run)
    m_wall, m_cpu = mecode.best, mecode.best_cpu
    m_size = (folder / "mecode.gcode").stat().st_size
    ratio = m_wall / wall
    print(
        f"mecode : {m_wall:.2f} s wall, {m_cpu:.2f} s CPU (same {lines:,} lines, "
        f"{m_size / 1e6:.1f} MB)"
    )
    print(
        f"ratio  : {ratio:.1f}x wall, {m_cpu / cpu:.1f}x CPU; target >= {TARGET_RATIO:g}x: "
        f"{'met' if ratio >= TARGET_RATIO else 'MISSED'}"
    )


if __name__ == "__main__":
    main()
