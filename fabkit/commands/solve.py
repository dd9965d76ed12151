"""``fabkit solve SPEC --out design.npz``: solve the inverse-design problem."""

from __future__ import annotations

import argparse
from pathlib import Path

from fabkit import commands
from fabkit.commands import add_command
from fabkit.design.design import MAX_LAYERS
from fabkit.errors import FabkitError
from fabkit.field.part import DEFAULT_SIZE_MM
from fabkit.machines import DEFAULT_MACHINE
from fabkit.process import Process
from fabkit.progress import add_progress


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = add_command(subparsers, "solve")
    parser.add_argument("spec", help="spec file (TOML)")
    parser.add_argument("--out", default="design.npz", help="design file to write (.npz)")
    parser.add_argument("--step", type=float, help="grid step in u and v (design units)")
    parser.add_argument("--diagonals", type=int, help="diagonals to march per quadrant")
    parser.add_argument("--quadrants", type=parse_quadrants, help='"all" or signs like "1,1;-1,1"')
    layers = parser.add_argument_group("a layered sheet (as fabkit run --layers)")
    layers.add_argument(
        "--layers",
        type=int,
        default=1,
        help="make the design of this many layers (>= 2) of the machine's layer height, "
        "programmed with the curvature of the targets its metric alone misses (default 1)",
    )
    commands.add_machine(
        layers, f"the printer the layers are for (default {DEFAULT_MACHINE}; see fabkit machines)"
    )
    commands.add_process(layers, "TOML whose [process] table replaces the machine's")
    commands.add_length(
        layers,
        "--size",
        "longest side of the part, mm, as fabkit run --size (default %(default)g)",
        default=DEFAULT_SIZE_MM,
    )
    add_progress(parser)
    parser.set_defaults(func=run)


def parse_quadrants(text: str) -> list[list[int]]:
    if text == "all":
        return [[1, 1], [-1, 1], [-1, -1], [1, -1]]
    try:
        return [[int(s) for s in pair.split(",")] for pair in text.split(";")]
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected "all" or "1,1;-1,1", got {text!r}') from None


def run(args: argparse.Namespace) -> int:
    from fabkit.design.summary import describe, solve_to_file
    from fabkit.problem.spec import load_spec

    out = Path(args.out)
    if out.suffix != ".npz":
        raise FabkitError(f"--out {out}: a design file must end in .npz")
    spec = load_spec(args.spec).with_solver(
        step=args.step, diagonals=args.diagonals, quadrants=args.quadrants
    )
    if not 1 <= args.layers <= MAX_LAYERS:
        raise FabkitError(f"--layers {args.layers}: expected 1 to {MAX_LAYERS} layers")
    process = None
    if args.layers > 1:
        process = _process(args)
    solved = solve_to_file(spec, out, progress=args.progress)
    print(describe(solved.summary, solved.check))
    if process is not None:
        from fabkit.run.solve import LayerRequest, design_part, layer_design

        design = solved.solution.design
        part = design_part(design, args.size_mm, process, args.layers)
        design = layer_design(design, LayerRequest(args.layers, process, part)).design
        design.save(out)
    print(f"wrote {out} and {out.with_suffix('.json')}")
    return 0


def _process(args: argparse.Namespace) -> Process:
    """The process the layers are made for: --process, else the machine's."""
    process = commands.chosen_process(args)
    if process is None:
        machine = args.machine or DEFAULT_MACHINE
        raise FabkitError(f"--layers: machine {machine} has no process to print layers with")
    return process
