"""``fabkit energy``: bounds on the work a design can do, and the Fig. 4d cycle."""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import asdict
from pathlib import Path

from fabkit.commands import add_command
from fabkit.errors import FabkitError


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = add_command(subparsers, "energy")
    parser.add_argument("design", nargs="?", help="design file (.npz) written by fabkit solve")
    parser.add_argument("--youngs", type=float, default=1.0, help="Young's modulus (default 1)")
    parser.add_argument("--poisson", type=float, default=0.5, help="Poisson ratio (default 0.5)")
    parser.add_argument(
        "--thickness", type=float, default=1.0, help="sheet thickness (design units; default 1)"
    )
    parser.add_argument("--cycle", type=Path, help="also write the Fig. 4d cycle plot to this .png")
    parser.add_argument(
        "--epsilon", type=float, default=0.5, help="eps of the homogeneous cycle sheet"
    )
    parser.add_argument("--area", type=float, default=1.0, help="flat area A0 of the cycle sheet")
    parser.add_argument("--json", action="store_true", help="print the results as JSON")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from fabkit.design.design import Design
    from fabkit.mechanics.energy import (
        cycle_table,
        describe_cycle,
        describe_work,
        design_work,
        plot_cycle,
    )

    if args.design is None and args.cycle is None:
        raise FabkitError("give a design file, --cycle PLOT.png, or both")
    if args.cycle is not None:
        if not (math.isfinite(args.epsilon) and args.epsilon > -1 and args.epsilon != 0):
            raise FabkitError(
                f"--epsilon {args.epsilon:g}: expected a finite non-zero number above -1 "
                "(the stretches are 1 + Lambda eps)"
            )
        if not (math.isfinite(args.area) and args.area > 0):
            raise FabkitError(f"--area {args.area:g}: expected a positive finite number")
    output = {}
    if args.design is not None:
        work = design_work(Design.load(args.design), args.youngs, args.poisson, args.thickness)
        output["surfaces"] = [asdict(item) for item in work]
        if not args.json:
            print(describe_work(work))
    if args.cycle is not None:
        rows = cycle_table(args.epsilon, args.area, args.youngs, args.poisson, args.thickness)
        plot_cycle(args.cycle, args.epsilon, args.area, args.youngs, args.poisson, args.thickness)
        output["cycle"] = [asdict(row) for row in rows]
        if not args.json:
            print(describe_cycle(rows))
            print(f"wrote {args.cycle}")
    if args.json:
        print(json.dumps(output, indent=2))
    return 0
