"""``fabkit verify`` on Fig. 3 at 60 mm: its time, stage by stage, and its figures.

    python benchmarks/verify.py [--out DIR] [--reference] [--layers K]

Solves examples/three_shapes.toml, plans it for the default two-ink DIW printer
(marlin_diw_pneumatic: eps1 as the print speed, eps2 as the share of the second ink) at
60 mm and writes the G-code (unless ``--out`` already holds them), then reads the G-code
back with ``fabkit verify`` and prints the time of each stage (reading the G-code, the
grid of the sheet, the comparison with the design, each forward simulation) against the
goal of 30 s, and the figures: coverage, director error, each feature's error, and the
distance of the sheet as fabricated to each target (``--reference``: and of the sheet
as designed, on the same mesh). ``--layers 2`` (the layered sheet of ``fabkit run
--layers 2``: every layer read back, the stacked sheet simulated) has a goal of 60 s.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from fabkit.run.inputs import RunOptions
from fabkit.run.pipeline import run_pipeline
from fabkit.verify import as_fabricated, machine_file
from fabkit.verify.machine_file import VerifyOptions, verify

ROOT = Path(__file__).resolve().parent.parent
GOAL_S = 30.0
LAYERED_GOAL_S = 60.0


class _Timed:
    """Wraps a function of a module and adds up the time spent in it."""

    def __init__(self, module, name: str) -> None:
        self.module, self.name = module, name
        self.function = getattr(module, name)
        self.seconds = 0.0
        setattr(module, name, self)

    def __call__(self, *args, **kwargs):
        start = time.perf_counter()
        try:
            return self.function(*args, **kwargs)
        finally:
            self.seconds += time.perf_counter() - start

    def restore(self) -> None:
        setattr(self.module, self.name, self.function)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("/tmp/fabkit-bench-verify"))
    parser.add_argument("--reference", action="store_true")
    parser.add_argument("--layers", type=int, default=1)
    args = parser.parse_args()
    out = args.out / f"layers{args.layers}"
    if not (out / "sheet.gcode").is_file():
        spec = ROOT / "examples" / "three_shapes.toml"
        options = RunOptions(str(spec), str(out), verify=False, layers=args.layers)
        run_pipeline(options, say=lambda _: None)
    names = {
        "read_gcode": "read the G-code",
        "rasterise": "grid of the sheet",
        "_flat_field": "the design on the sheet",
        "feature_errors": "features read back",
        "simulate_sheet": "simulations",
    }
    where = {"simulate_sheet": as_fabricated}  # the module that calls it; else machine_file
    stages = [_Timed(where.get(name, machine_file), name) for name in names]
    try:
        start = time.perf_counter()
        options = VerifyOptions(reference=args.reference)
        result = verify(out / "design.npz", out / "sheet.gcode", options)
        total = time.perf_counter() - start
    finally:
        for stage in stages:
            stage.restore()
    print(result.table())
    print()
    for stage in stages:
        print(f"{names[stage.name]:>26}: {stage.seconds:6.1f} s")
    rest = total - sum(stage.seconds for stage in stages)
    print(f"{'the rest (director, ...)':>26}: {rest:6.1f} s")
    goal = GOAL_S if args.layers == 1 else LAYERED_GOAL_S
    print(f"{'total':>26}: {total:6.1f} s (goal {goal:g} s, {args.layers} layer(s))")
    for target in result.targets:
        label = f"simulation {target.target}"
        print(f"{label:>26}: {target.seconds:6.1f} s, {target.triangles} triangles")


if __name__ == "__main__":
    main()
