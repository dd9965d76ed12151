"""``fabkit simulate design.npz --stimulus NAME|INDEX``: the sheet's shape at a stimulus.

The sheet is the printed one ``fabkit run`` makes of the design: its part at ``--size``
(mm, default 60) for the machine's process, as thick as the design's layers of the
process's layer height; its part line and its verdict's figures are the run's.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from fabkit.commands import add_command, add_length, add_machine, add_process, chosen_process
from fabkit.design.design import Design
from fabkit.design.patches import MESH_FORMATS
from fabkit.errors import FabkitError
from fabkit.field.part import DEFAULT_SIZE_MM, Part, PartRequest
from fabkit.mechanics.compare import Comparison, compare
from fabkit.mechanics.mesh import save_mesh
from fabkit.mechanics.simulate import (
    EQUAL_STEPS,
    SEEDS,
    SLOW_STEPS,
    Settings,
    ramp_words,
    simulate_design,
    surface_index,
)
from fabkit.mechanics.verdict import FORM_TOLERANCE, Shape, StartEnd
from fabkit.progress import ProgressBar, add_progress


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = add_command(subparsers, "simulate")
    parser.add_argument("design", help="design file (.npz) written by fabkit solve")
    parser.add_argument(
        "--stimulus", required=True, help="surface name or index whose stimulus to apply"
    )
    sheet = parser.add_argument_group("the printed sheet (as fabkit run makes it)")
    add_length(sheet, "--size", "the part's longest side (default 60, as fabkit run)")
    add_machine(
        sheet, "machine profile whose process makes the sheet (default: marlin_diw_pneumatic)"
    )
    add_process(sheet, "TOML whose [process] replaces the machine's")
    add_length(
        sheet,
        "--thickness",
        "sheet thickness (default: the design's layers times the process's layer height)",
    )
    parser.add_argument("--poisson", type=float, default=0.5, help="Poisson ratio (default 0.5)")
    defaults = Settings()
    parser.add_argument(
        "--steps",
        type=int,
        default=defaults.steps,
        help=f"ramp steps (default: {SLOW_STEPS} for a sheet with natural curvature, its "
        "share of the stimulus growing geometrically from --first-step to 1; "
        f"{EQUAL_STEPS} equal steps without)",
    )
    parser.add_argument(
        "--first-step",
        type=float,
        default=defaults.first_step,
        help="the stimulus's share at the first ramp step of a sheet with natural curvature "
        "(default 1/256)",
    )
    parser.add_argument(
        "--max-iterations",
        type=int,
        default=defaults.max_iterations,
        help="Newton iterations per ramp step (default %(default)s)",
    )
    parser.add_argument(
        "--seed",
        choices=SEEDS,
        default=defaults.seed,
        help="the start: the flat sheet lifted 5 %% of its radius by this shape (a verdict "
        "uses all of them)",
    )
    parser.add_argument(
        "--trim",
        type=float,
        metavar="N",
        help="simulate the part without the regions narrower than N bending lengths "
        "sqrt(thickness R) (default 4; 0: no trim; docs/part.md)",
    )
    parser.add_argument(
        "--refine",
        type=int,
        default=1,
        help="split every grid cell into REFINE x REFINE sub-cells (default 1)",
    )
    parser.add_argument("--out", type=Path, help="mesh of the result, mm (.ply, .stl, .glb, .obj)")
    parser.add_argument("--json", action="store_true", help="print the comparison as JSON")
    add_progress(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.out is not None and args.out.suffix.lower() not in MESH_FORMATS:
        raise FabkitError(f"--out {args.out}: mesh format must be one of {', '.join(MESH_FORMATS)}")
    design = Design.load(args.design)
    surface = surface_index(design, args.stimulus)
    settings = Settings(
        steps=args.steps,
        first_step=args.first_step,
        seed=args.seed,
        max_iterations=args.max_iterations,
    )
    part, thickness = _printed(design, args)
    bar = ProgressBar("simulating", force=args.progress)
    try:
        simulation = simulate_design(
            design,
            surface,
            thickness,
            args.poisson,
            settings,
            part,
            args.refine,
            progress=bar,
        )
    finally:
        bar.close()
    report = compare(design, simulation)
    alone = _this_start(report, settings.seed, part.mm_per_unit)
    if args.out is not None:
        mm = simulation.result.positions * part.mm_per_unit
        save_mesh(args.out, mm, simulation.mesh.triangles)
    used = {
        "seed": settings.seed,
        "path": f"flat sheet as made -> the stimulus, {ramp_words(settings)}",
        "solver": "damped Newton (exact Hessian, Levenberg-Marquardt)",
        "thickness_mm": thickness * part.mm_per_unit,
        "mm_per_unit": part.mm_per_unit,
    }
    if args.json:
        figures = {**report.to_dict(), "part": part.to_dict(), **used}
        print(json.dumps({**figures, "this_start": alone.to_dict()}, indent=2))
    else:
        print(part.summary())
        print(report.table(part.mm_per_unit))
        print(f"  started flat with a {used['seed']} seed; path {used['path']}")
        print(
            f"  from this start alone (a verdict takes all six: fabkit check, fabkit run): "
            f"{alone.line()}"
        )
        if not simulation.result.converged:
            print(
                f"  not converged: Newton stopped at {settings.max_iterations} iterations per "
                "ramp step with the sheet still moving; raise --max-iterations"
            )
        if args.out is not None:
            print(f"wrote {args.out}")
    return 0


def _printed(design: Design, args: argparse.Namespace) -> tuple[Part, float]:
    """The part ``fabkit run`` prints of ``design`` at ``--size`` for the process, and the
    sheet's thickness (design units)."""
    from fabkit.run.solve import design_part

    size = DEFAULT_SIZE_MM if args.size_mm is None else args.size_mm
    for option, value in (("--size", size), ("--thickness", args.thickness_mm)):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise FabkitError(f"{option} {value:g}: expected a positive finite length (mm)")
    process = chosen_process(args)
    request = PartRequest(trim=args.trim)
    part = design_part(design, size, process, design.layers, request, args.thickness_mm)
    return part, part.rules.thickness  # the thickness the part was cut for


def _this_start(report: Comparison, seed: str, mm_per_unit: float) -> Shape:
    """The verdict's words and limit applied to this one start (a verdict takes every
    start of :data:`~fabkit.mechanics.simulate.STARTS`)."""
    end = StartEnd.of(seed, report)
    diameter_mm = report.size * mm_per_unit
    return Shape.of(report.name, (end,), FORM_TOLERANCE, report.seconds, diameter_mm)
