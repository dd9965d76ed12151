"""The part (issue 17) of Fig. 1 and Fig. 3, 60 mm long: its figures, and docs/part.md's pictures.

    python benchmarks/part.py [--pictures docs/images]

Solves examples/two_shapes.toml and examples/three_shapes.toml, cuts each part as
``fabkit run`` does for the default printer (marlin_diw_pneumatic: road width 0.41 mm,
layer 0.3 mm) at 60 mm, and prints per figure: the kept area and what each step removed,
the share of the part an opening with a disc of radius 2 road widths removes, the largest
turn of the outline over one road width (degrees), the area outside the solved cells,
and the time to cut the part. With ``--pictures DIR`` it draws, before and after, the
union of the solved grid cells (what was printed before the part) against the part, the
whole sheet and a close-up of an edge, and a part cut to a user outline.
"""

from __future__ import annotations

import argparse
import sys
import textwrap
import time
from pathlib import Path

import matplotlib

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import shapely  # noqa: E402
import shapely.affinity  # noqa: E402

from fabkit.design.design import Design  # noqa: E402
from fabkit.design.solver import solve  # noqa: E402
from fabkit.field.part import (  # noqa: E402
    Part,
    PartOptions,
    margin_outline,
    part_of_size,
    solved_region,
)
from fabkit.machines import load_machine  # noqa: E402
from fabkit.problem.spec import load_spec  # noqa: E402
from tests.test_part import opened_share, turn_over  # noqa: E402

SIZE_MM = 60.0
FIGURES = {"Fig. 1": "two_shapes.toml", "Fig. 3": "three_shapes.toml"}
CLOSE_UPS = {"Fig. 1": (-20.0, 8.5, 5.0), "Fig. 3": (45.0, 16.3, 6.0)}
"""Centre x, y and half-width (mm) of each close-up."""
USER_OUTLINE = "ellipse:22,11"


def cut(design: Design, outline: str | None = None) -> tuple[Part, float]:
    """The part as fabkit run cuts it at 60 mm on the default printer, and the seconds."""
    process = load_machine("marlin_diw_pneumatic").process
    started = time.perf_counter()
    solved = solved_region(design)
    options = PartOptions(
        outline=outline, road_width_mm=process.road_width_mm, thickness_mm=process.layer_height_mm
    )
    part = part_of_size(design, SIZE_MM, options, solved)
    return part, time.perf_counter() - started


def figures(name: str, part: Part, seconds: float) -> None:
    road = load_machine("marlin_diw_pneumatic").process.road_width_mm
    outline = part.outline_mm()
    outside = part.outline.difference(part.solved).area / part.solved.area
    print(f"{name}: {part.summary()}")
    print(
        f"  opening (disc of radius 2 road widths) removes "
        f"{100 * opened_share(outline, 2 * road):.4f} %; largest turn over a road "
        f"width {turn_over(outline, road, road / 8).max():.1f} deg; outside the solved cells "
        f"{100 * outside:.1e} %; cut in {seconds:.2f} s"
    )


def _draw(axes, geometry: shapely.Geometry, scale: float, **style) -> None:
    geometry = shapely.affinity.scale(geometry, scale, scale, origin=(0, 0))
    for polygon in shapely.get_parts(geometry):
        for ring in (polygon.exterior, *polygon.interiors):
            xy = np.asarray(ring.coords)
            axes.plot(xy[:, 0], xy[:, 1], **style)


def _fill(axes, geometry: shapely.Geometry, scale: float, colour: str) -> None:
    geometry = shapely.affinity.scale(geometry, scale, scale, origin=(0, 0))
    for polygon in shapely.get_parts(geometry):
        axes.fill(*np.asarray(polygon.exterior.coords).T, color=colour, lw=0)
        for ring in polygon.interiors:
            axes.fill(*np.asarray(ring.coords).T, color="white", lw=0)


def picture(name: str, design: Design, part: Part, path: Path) -> None:
    """The solved cells (grey) against the part (blue, black outline): the whole sheet and
    a close-up with the grid points and the margin contour (dashed)."""
    scale = float(part.mm_per_unit)
    figure, (whole, close) = plt.subplots(1, 2, figsize=(9, 4.4))
    for axes in (whole, close):
        _fill(axes, part.solved, scale, "0.82")
        _fill(axes, part.outline, scale, "#9ecae1")
        _draw(axes, part.solved, scale, color="0.35", lw=0.8)
        _draw(axes, part.outline, scale, color="black", lw=1.3)
        axes.set_aspect("equal")
        axes.set_xlabel("x (mm)")
    _draw(close, margin_outline(design), scale, color="tab:red", lw=0.9, ls="--")
    points = design.r[0][design.valid] * scale
    close.plot(points[:, 0], points[:, 1], ".", color="0.3", ms=2.5)
    x, y, half = CLOSE_UPS[name]
    close.set_xlim(x - half, x + half)
    close.set_ylim(y - half, y + half)
    whole.plot(
        [x - half, x + half, x + half, x - half, x - half],
        [y - half, y - half, y + half, y + half, y - half],
        color="tab:red",
        lw=0.8,
    )
    whole.set_ylabel("y (mm)")
    whole.set_title(f"{name}: solved cells (grey), the part (blue)", fontsize=10)
    close.set_title("close-up: grid points, margin contour (red, dashed)", fontsize=10)
    figure.suptitle(textwrap.fill(part.summary(), 110), fontsize=8)
    figure.tight_layout()
    figure.savefig(path, dpi=80)
    plt.close(figure)


def outline_picture(design: Design, part: Part, path: Path) -> None:
    """A part cut to a user outline: the solved cells, the outline, the part."""
    scale = float(part.mm_per_unit)
    figure, axes = plt.subplots(figsize=(5.5, 4.4))
    _fill(axes, part.solved, scale, "0.82")
    _fill(axes, part.outline, scale, "#9ecae1")
    _draw(axes, part.outline, scale, color="black", lw=1.3)
    _draw(axes, part.rules.outline, scale, color="tab:red", lw=0.9, ls="--")
    axes.set_aspect("equal")
    axes.set_xlabel("x (mm)")
    axes.set_ylabel("y (mm)")
    axes.set_title(f"--outline {USER_OUTLINE} (red, dashed): the part (blue)", fontsize=10)
    figure.suptitle(textwrap.fill(part.summary(), 80), fontsize=7)
    figure.tight_layout()
    figure.savefig(path, dpi=80)
    plt.close(figure)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pictures", type=Path, help="write the pictures into this folder")
    args = parser.parse_args()
    for name, example in FIGURES.items():
        design = solve(load_spec(ROOT / "examples" / example)).design
        part, seconds = cut(design)
        figures(name, part, seconds)
        if args.pictures is not None:
            args.pictures.mkdir(parents=True, exist_ok=True)
            stem = example.removesuffix(".toml")
            picture(name, design, part, args.pictures / f"part_{stem}.png")
            if name == "Fig. 3":
                user, seconds = cut(design, USER_OUTLINE)
                figures(f"{name} --outline {USER_OUTLINE}", user, seconds)
                outline_picture(design, user, args.pictures / "part_outline.png")


if __name__ == "__main__":
    main()
