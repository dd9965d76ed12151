"""The solve summary written beside a design file (``design.json``) and printed on screen."""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fabkit.design.check import CheckReport, ResidualMaps, check_maps, residual_maps
from fabkit.design.design import Design
from fabkit.design.solver import Solution, solve
from fabkit.errors import FabkitError
from fabkit.figures import AREA_UNIT, cell_integral
from fabkit.files.atomic import atomic_path
from fabkit.limits import DESIGN_NODES
from fabkit.problem.spec import Spec
from fabkit.progress import ProgressBar


def realised_areas(design: Design, spec: Spec | None = None) -> dict[str, float]:
    """Area of the solved patch on every surface (design units^2): alpha beta lambda1 lambda2
    integrated over the solved cells (:func:`fabkit.figures.cell_integral`); ``spec``: the
    design's spec when the caller has it, else the design's own."""
    spec = design.problem if spec is None else spec
    eps = np.where(design.valid, design.eps, 0.0)
    response = spec.material.response(eps, design.stimuli)
    valid = design.valid
    alpha, beta = np.where(valid, design.alpha, 0.0), np.where(valid, design.beta, 0.0)
    return {
        target.name: cell_integral(
            alpha * beta * response.lambda1[j] * response.lambda2[j], valid, design.step
        )
        for j, target in enumerate(spec.targets)
    }


def summary(solution: Solution, check: CheckReport) -> dict[str, Any]:
    """Solve time, grid, valid points, areas, stops and residuals as plain JSON data."""
    design = solution.design
    spec = design.problem
    stops = [
        {"reason": s.reason, "u": round(s.u, 12), "v": round(s.v, 12), "surface": s.surface}
        for s in solution.stops
    ]
    return {
        "solve_seconds": round(solution.seconds, 4),
        "grid": {
            "step": design.step,
            "diagonals": spec.solver.diagonals,
            "quadrants": [list(q) for q in spec.solver.quadrants],
            "shape": list(design.valid.shape),
            "extrapolate": spec.solver.extrapolate,
        },
        "valid_points": int(design.valid.sum()),
        "area_design_units2": realised_areas(design),
        "stop_counts": dict(Counter(s.reason for s in solution.stops)),
        "stops": stops,
        "check": check.to_dict(),
    }


@dataclass(frozen=True)
class Solved:
    """A solve written to disk: the solution, its check (and the residual maps it was
    computed from, for the pictures), and the summary data."""

    solution: Solution
    check: CheckReport
    summary: dict[str, Any]
    maps: tuple[ResidualMaps, ...]


def check_grid_size(spec: Spec) -> None:
    """Refuse solver settings whose design grid would exceed DESIGN_NODES: the design grid
    is (2 diagonals + 1) nodes each way, whichever quadrants are solved."""
    settings = spec.solver
    nu = nv = 2 * settings.diagonals + 1
    if nu * nv > DESIGN_NODES:
        raise FabkitError(
            f"solver.diagonals {settings.diagonals}: the design grid would be {nu} x {nv} = "
            f"{nu * nv} nodes, more than the limit of {DESIGN_NODES} a design file may hold; "
            "give fewer --diagonals (and a larger --step)"
        )


def solve_to_file(
    spec: Spec, out: str | Path, label: str = "solving", progress: bool = False
) -> Solved:
    """Solve with a progress bar (:mod:`fabkit.progress`: on a terminal, or if
    ``progress``), check, and write ``out`` (.npz) and its .json summary.

    A grid larger than a design file may hold (DESIGN_NODES) is refused before solving.
    """
    out = Path(out)
    check_grid_size(spec)
    bar = ProgressBar(label, force=progress)
    try:
        solution = solve(spec, progress=bar)
    finally:
        bar.close()
    design = solution.design.knowing(spec)
    maps = residual_maps(design)
    check = check_maps(maps)
    data = summary(solution, check)
    design.save(out)
    write_summary(out.with_suffix(".json"), data)
    return Solved(solution, check, data, maps)


def write_summary(path: str | Path, data: dict[str, Any]) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")


def checked_points(check: dict[str, Any]) -> str:
    """How many of the valid points the check uses (from a check report's data)."""
    counts = {s["name"]: s["checked_points"] for s in check["surfaces"]}
    each = (
        f"{next(iter(counts.values()))} per surface"
        if len(set(counts.values())) == 1
        else ", ".join(f"{name} {n}" for name, n in counts.items())
    )
    return (
        f"checked points: {each} (the valid points whose five-point stencils in u and v are "
        "all solved, alpha and beta >= 0.2)"
    )


def describe(data: dict[str, Any], check: CheckReport) -> str:
    """One screen of text for the terminal."""
    grid = data["grid"]
    lines = [
        f"solved in {data['solve_seconds']:.3f} s: {data['valid_points']} valid points on a "
        f"{grid['shape'][0]} x {grid['shape'][1]} grid (step {grid['step']:g}, "
        f"{'Richardson-extrapolated' if grid['extrapolate'] else 'second order'})",
        checked_points(data["check"]),
        f"area over the solved cells ({AREA_UNIT}): "
        + ", ".join(f"{k} {v:.4g}" for k, v in data["area_design_units2"].items()),
    ]
    if data["stop_counts"]:
        lines.append("stops:")
        first = {}
        for stop in data["stops"]:
            first.setdefault(stop["reason"], stop)
        for reason, count in data["stop_counts"].items():
            stop = first[reason]
            where = f" on {stop['surface']}" if stop["surface"] else ""
            at = f"u = {stop['u']:.3g}, v = {stop['v']:.3g}"
            lines.append(f"  {count:5d} x {reason}{where} (first at {at})")
    lines.append(check.table())
    return "\n".join(lines)
