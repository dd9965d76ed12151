"""``fabkit swimmer SPEC --out DIR``: shapes along the cycle, net motion, plots, machine file."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from fabkit.commands import add_command, add_overwrite, in_out_folder
from fabkit.files.atomic import atomic_path
from fabkit.progress import ProgressBar, add_progress
from fabkit.swimmer.cycle import convergence, run_stroke
from fabkit.swimmer.fabricate import fabricate
from fabkit.swimmer.report import (
    describe,
    plot_cycle,
    plot_energy,
    plot_position,
    save_stroke,
    summary,
)
from fabkit.swimmer.spec import load_swimmer


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = add_command(subparsers, "swimmer")
    parser.add_argument("spec", help="swimmer spec (TOML), e.g. examples/swimmer.toml")
    parser.add_argument("--out", required=True, metavar="DIR", help="output folder")
    parser.add_argument("--stations", type=int, help="shapes per leg (overrides the spec)")
    parser.add_argument(
        "--no-convergence",
        action="store_true",
        help="skip the re-solves with half the stations and fewer Stokeslet points",
    )
    parser.add_argument("--no-fabricate", action="store_true", help="skip toolpath and G-code")
    add_overwrite(parser)
    add_progress(parser)
    parser.set_defaults(func=run)


@in_out_folder
def run(args: argparse.Namespace) -> int:
    spec = load_swimmer(args.spec)
    if args.stations is not None:
        spec = spec.with_path(spec.path, args.stations)
    out = Path(args.out)
    labels = ("shapes", "flow", "flow, fewer points", "flow, half the stations")
    bars: list[ProgressBar] = []
    for label in labels:  # each stage's clock starts when the one before it finished
        bars.append(ProgressBar(label, force=args.progress, after=bars[-1] if bars else None))
    try:
        stroke = run_stroke(spec, *bars[:2])
        converged = None if args.no_convergence else convergence(stroke, *bars[2:])
    finally:
        for bar in bars:
            bar.close()
    data = summary(stroke, converged)
    with atomic_path(out / "summary.json") as tmp:
        tmp.write_text(json.dumps(data, indent=2), encoding="utf-8")
    save_stroke(stroke, out / "stroke.npz")
    plot_cycle(stroke, out / "cycle.png")
    plot_position(stroke, out / "position.png")
    plot_energy(stroke, out / "energy.png")
    print(describe(data))
    names = ["summary.json", "stroke.npz", "cycle.png", "position.png", "energy.png"]
    if not args.no_fabricate:
        made = fabricate(spec, out)
        print("\n".join(made.lines))
        names += [path.name for path in made.files]
    print(f"wrote {', '.join(names)} in {out}")
    return 0
