"""``fabkit simulate design.npz --stimulus NAME|INDEX``: the sheet's shape at a stimulus."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from fabkit.commands import add_command
from fabkit.design.design import Design
from fabkit.design.patches import MESH_FORMATS
from fabkit.errors import FabkitError
from fabkit.field.part import simulation_part
from fabkit.mechanics.compare import Comparison, compare
from fabkit.mechanics.mesh import save_mesh
from fabkit.mechanics.simulate import SEEDS, Settings, simulate_design, surface_index
from fabkit.mechanics.verdict import FORM_TOLERANCE, Shape, StartEnd
from fabkit.progress import ProgressBar, add_progress


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = add_command(subparsers, "simulate")
    parser.add_argument("design", help="design file (.npz) written by fabkit solve")
    parser.add_argument(
        "--stimulus", required=True, help="surface name or index whose stimulus to apply"
    )
    parser.add_argument(
        "--thickness",
        type=float,
        help="sheet thickness (design units; default 1 %% of the solved flat domain's diameter)",
    )
    parser.add_argument("--poisson", type=float, default=0.5, help="Poisson ratio (default 0.5)")
    defaults = Settings()
    parser.add_argument(
        "--steps", type=int, default=defaults.steps, help="ramp steps (default %(default)s)"
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
    parser.add_argument("--out", type=Path, help="mesh of the result (.ply, .stl, .glb, .obj)")
    parser.add_argument("--json", action="store_true", help="print the comparison as JSON")
    add_progress(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.out is not None and args.out.suffix.lower() not in MESH_FORMATS:
        raise FabkitError(f"--out {args.out}: mesh format must be one of {', '.join(MESH_FORMATS)}")
    design = Design.load(args.design)
    surface = surface_index(design, args.stimulus)
    settings = Settings(steps=args.steps, seed=args.seed, max_iterations=args.max_iterations)
    part, thickness = simulation_part(design, args.thickness, args.trim)
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
    alone = _this_start(report, settings.seed)
    if args.out is not None:
        save_mesh(args.out, simulation.result.positions, simulation.mesh.triangles)
    used = {
        "seed": settings.seed,
        "path": f"flat sheet as made -> the stimulus, {settings.steps} ramp steps",
        "solver": "damped Newton (exact Hessian, Levenberg-Marquardt)",
    }
    if args.json:
        figures = {**report.to_dict(), "part": part.to_dict(), **used}
        print(json.dumps({**figures, "this_start": alone.to_dict()}, indent=2))
    else:
        print(part.summary())
        print(report.table())
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


def _this_start(report: Comparison, seed: str) -> Shape:
    """The verdict's words and limit applied to this one start (a verdict takes every
    start of :data:`~fabkit.mechanics.simulate.STARTS`)."""
    end = StartEnd.of(seed, report)
    return Shape.of(report.name, (end,), FORM_TOLERANCE, report.seconds)
