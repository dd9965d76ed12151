"""Toolpath speed and fill quality figures.

    python benchmarks/toolpath.py [--repeat 3] [--design design.npz]

1. Speed: a 100 x 100 mm sheet at w = 0.4 mm (about 25 m of path) for three director
   fields: stripe solve, line extraction/trimming/extension/gap filling, ordering, and
   their total (best of ``--repeat`` runs; the bound is 5 s).
2. Quality (Vector Slicer's definitions, raster w/10): radial and azimuthal 20 mm discs and
   a +1/2 defect in a 20 mm square at w = 0.2 mm; with ``--design``, that design scaled to
   60 mm at w = 0.4 mm (the Fig. 1 acceptance case: ``fabkit solve
   examples/two_shapes.toml --out design.npz``). The bounds are 3 % / 3 % / 3 degrees.
"""

from __future__ import annotations

import time

from common import timing_arguments

from fabkit.field.design_field import field_from_design
from fabkit.field.flat import field_from_expression
from fabkit.field.outlines import parse_shape
from fabkit.toolpath.lines import (
    PIN_MARGIN,
    LineSettings,
    lines_from_pattern,
    polyline_length,
    print_lines,
)
from fabkit.toolpath.order import order_lines
from fabkit.toolpath.quality import measure_quality
from fabkit.toolpath.stripes import solve_stripes

SHEET_FIELDS = {
    "uniform": "0.3",
    "bend": "0.3 + 0.02*x",
    "spiral (+1 defect)": "phi + pi/4",
}
PATTERNS = {
    "radial disc 20 mm": ("arctan2(y, x)", "disc:10"),
    "azimuthal disc 20 mm": ("phi + pi/2", "disc:10"),
    "+1/2 defect, 20 mm square": ("phi/2", "square:20"),
}


def time_sheet(theta: str, w: float, repeats: int) -> tuple[list[float], float]:
    """Best-of-``repeats`` times (s) of solve, lines, order and total, and the path (m)."""
    field = field_from_expression(theta, parse_shape("square:100"))
    settings = LineSettings()
    best = [float("inf")] * 4
    for _ in range(repeats):
        start = time.perf_counter()
        pattern = solve_stripes(field, w, (settings.end_inset + PIN_MARGIN) * w, settings.stripes)
        solved = time.perf_counter()
        lines = lines_from_pattern(pattern, field, w, settings)
        extracted = time.perf_counter()
        order_lines(lines)
        ordered = time.perf_counter()
        laps = [solved - start, extracted - solved, ordered - extracted, ordered - start]
        best = [min(b, lap) for b, lap in zip(best, laps, strict=True)]
    return best, sum(polyline_length(line) for line in lines) / 1000


def quality_row(name: str, field, w: float) -> str:
    start = time.perf_counter()
    (lines,) = print_lines(field, w)
    generated = time.perf_counter()
    quality = measure_quality(lines, w, field, w)
    measured = time.perf_counter()
    return (
        f"{name:28s} w={w:.1f}  empty {100 * quality.empty_fraction:5.2f} %  overlap "
        f"{100 * quality.mean_overlap:5.2f} %  angle {quality.mean_angle_error_deg:5.2f} deg  "
        f"paths {quality.paths:4d}  ({generated - start:.2f} s lines, "
        f"{measured - generated:.2f} s metrics)"
    )


def main() -> None:
    parser = timing_arguments(__doc__, repeat=3)
    parser.add_argument("--design", help="a design.npz to scale to 60 mm (Fig. 1)")
    args = parser.parse_args()
    print(f"100 x 100 mm sheet, w = 0.4 mm (best of {args.repeat}):")
    for name, theta in SHEET_FIELDS.items():
        (solve, lines, order, total), metres = time_sheet(theta, 0.4, args.repeat)
        print(
            f"  {name:20s} solve {solve:.2f} s  lines {lines:.2f} s  order {order:.2f} s  "
            f"total {total:.2f} s  ({metres:.1f} m of path)"
        )
    print("fill quality:")
    for name, (theta, shape) in PATTERNS.items():
        print("  " + quality_row(name, field_from_expression(theta, parse_shape(shape)), 0.2))
    if args.design:
        print("  " + quality_row("design at 60 mm", field_from_design(args.design, 60.0), 0.4))


if __name__ == "__main__":
    main()
