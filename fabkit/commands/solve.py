"""``fabkit solve SPEC --out design.npz``: solve the inverse-design problem."""

from __future__ import annotations

import argparse
from pathlib import Path

from fabkit.commands import add_command
from fabkit.errors import FabkitError
from fabkit.progress import add_progress


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = add_command(subparsers, "solve")
    parser.add_argument("spec", help="spec file (TOML)")
    parser.add_argument("--out", default="design.npz", help="design file to write (.npz)")
    parser.add_argument("--step", type=float, help="grid step in u and v (design units)")
    parser.add_argument("--diagonals", type=int, help="diagonals to march per quadrant")
    parser.add_argument("--quadrants", type=parse_quadrants, help='"all" or signs like "1,1;-1,1"')
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
    from fabkit.design.report import describe, solve_to_file
    from fabkit.problem.spec import load_spec

    out = Path(args.out)
    if out.suffix != ".npz":
        raise FabkitError(f"--out {out}: a design file must end in .npz")
    spec = load_spec(args.spec).with_solver(
        step=args.step, diagonals=args.diagonals, quadrants=args.quadrants
    )
    solved = solve_to_file(spec, out, progress=args.progress)
    print(describe(solved.summary, solved.check))
    print(f"wrote {out} and {out.with_suffix('.json')}")
    return 0
