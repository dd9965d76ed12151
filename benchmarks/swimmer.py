"""Swimmer figures: Stokes validations refined, and the example's displacement per cycle
with its convergence in the Stokeslet points, the regularisation, the stations and the
elastic mesh; loop scaling, symmetry and timing.

    python benchmarks/swimmer.py            # about 10 minutes on 2 cores
    python benchmarks/swimmer.py --quick    # coarser, about 2 minutes
    python benchmarks/swimmer.py --full     # adds 4189 Stokeslet points (2 GB, slow)
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np

from fabkit.swimmer.cycle import POINT_ORDER, Stroke, run_stroke
from fabkit.swimmer.motion import swim
from fabkit.swimmer.spec import SwimmerSpec, load_swimmer
from fabkit.swimmer.stokes import Stokes, default_epsilon, disc_points, sphere_points

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "swimmer.toml"
CYCLE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 0.0]])


def sphere_drag(counts: list[int]) -> None:
    print("sphere drag / 6 pi mu a U - 1   (eps = 0.35 x spacing)")
    for count in counts:
        stokes = Stokes.of(sphere_points(count), default_epsilon(4 * np.pi, count))
        print(f"  {count:5d} points   {stokes.resistance[0, 0] / (6 * np.pi) - 1:+.4f}")


def disc_drag(rings: list[int]) -> None:
    print("disc drag: broadside / 16 mu a U - 1, edgewise / (32/3) mu a U - 1")
    for ring in rings:
        flat = disc_points(1.0, ring)
        points = np.column_stack([flat, np.zeros(len(flat))])
        stokes = Stokes.of(points, default_epsilon(np.pi, len(points)))
        broadside = stokes.resistance[2, 2] / 16 - 1
        edgewise = stokes.resistance[0, 0] / (32 / 3) - 1
        print(f"  {len(points):5d} points   {broadside:+.4f}   {edgewise:+.4f}")


def three_spheres(radius: float, count: int, per_leg: int = 4) -> float:
    """Relative error of the three-sphere swimmer against Golestanian & Ajdari (2008)."""
    corners = np.array([[1.0, 1.0], [1.2, 1.0], [1.2, 1.2], [1.0, 1.2], [1.0, 1.0]])
    ball = sphere_points(count, radius)
    shapes = []
    for start, end in zip(corners[:-1], corners[1:], strict=True):
        for t in np.arange(per_leg) / per_leg:
            l1, l2 = start + t * (end - start)
            shapes.append(np.concatenate([ball, ball + [l1, 0, 0], ball + [l1 + l2, 0, 0]]))
    shapes.append(shapes[0])
    displacement = swim(shapes, default_epsilon(4 * np.pi * radius**2, count)).displacement[0]
    nodes, weights = np.polynomial.legendre.leggauss(20)
    expected = 0.0
    for start, end in zip(corners[:-1], corners[1:], strict=True):
        l1, l2 = (start[:, None] + np.outer(end - start, (nodes + 1) / 2)).reshape(2, -1)
        rate = (2 * l1**2 - l2**2) * (end - start)[0] + (l1**2 - 2 * l2**2) * (end - start)[1]
        expected += radius * np.sum(weights / 2 * rate / (6 * l1 * l2 * (l1 + l2)))
    return displacement / expected - 1


def axial(stroke: Stroke) -> float:
    return float(stroke.displacement[2])


def with_hydrodynamics(spec: SwimmerSpec, **changes) -> SwimmerSpec:
    hydro = dataclasses.replace(spec.hydrodynamics, **changes)
    return dataclasses.replace(spec, hydrodynamics=hydro)


def point_convergence(stroke: Stroke, rings: list[int], ratios: list[float]) -> None:
    print("displacement per cycle / R against Stokeslet rings (points), by eps / spacing")
    for ratio in ratios:
        base = dataclasses.replace(
            stroke, spec=with_hydrodynamics(stroke.spec, epsilon_ratio=ratio)
        )
        values, counts = [], []
        for ring in rings:
            started = time.perf_counter()
            refined = base.refined(ring)
            values.append(axial(refined))
            counts.append(len(refined.sheet.stokes))
            print(
                f"  ratio {ratio:.2f}  rings {ring:3d}  {counts[-1]:5d} points  "
                f"{values[-1]:+.6f}  ({time.perf_counter() - started:.1f} s)",
                flush=True,
            )
        if len(values) >= 3:
            steps = np.sqrt(1.0 / np.array(counts[-3:]))
            ratio_observed = (values[-3] - values[-2]) / (values[-2] - values[-1])
            orders = np.linspace(0.2, 2.0, 181)
            predicted = [
                (steps[0] ** p - steps[1] ** p) / (steps[1] ** p - steps[2] ** p) for p in orders
            ]
            order = orders[int(np.argmin(np.abs(np.array(predicted) - ratio_observed)))]
            gain = (steps[1] / steps[2]) ** POINT_ORDER
            extrapolated = values[-1] + (values[-1] - values[-2]) / (gain - 1)
            print(
                f"  observed order {order:.2f} (last three); Richardson with order "
                f"{POINT_ORDER}: {extrapolated:+.6f}"
            )


def station_convergence(spec: SwimmerSpec, per_leg: list[int]) -> None:
    print("displacement per cycle / R against stations per leg (shapes simulated anew)")
    for count in per_leg:
        stroke = run_stroke(spec.with_path(CYCLE, count))
        print(f"  {count:3d} per leg  {axial(stroke):+.6f}  {stroke.shapes.seconds:.1f} s shapes")


def mesh_convergence(spec: SwimmerSpec, rings: list[int]) -> None:
    print("displacement per cycle / R against the elastic mesh (rings; about 6 rings^2 faces)")
    for ring in rings:
        mechanics = dataclasses.replace(spec.mechanics, rings=ring)
        stroke = run_stroke(dataclasses.replace(spec, mechanics=mechanics))
        flags = stroke.shapes.converged
        print(
            f"  rings {ring:3d}  {len(stroke.sheet.points):5d} vertices  {axial(stroke):+.6f}  "
            f"converged {flags.sum()}/{len(flags)}  {stroke.shapes.seconds:.1f} s shapes"
        )


def loop_scaling(spec: SwimmerSpec) -> None:
    print("loop size: displacement per cycle / R and ratio to the loop twice as large")
    previous = None
    for scale in (1.0, 0.5, 0.25):
        value = axial(run_stroke(spec.with_path(scale * CYCLE)))
        ratio = "" if previous is None else f"  ratio {value / previous:.3f}"
        print(f"  loop x {scale:4.2f}  {value:+.6f}{ratio}")
        previous = value


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="coarser, about 2 minutes")
    parser.add_argument("--full", action="store_true", help="add 4189 Stokeslet points")
    args = parser.parse_args()
    quick = args.quick

    sphere_drag([200, 400, 800] if quick else [200, 400, 800, 1600, 3200])
    disc_drag([10, 14, 20] if quick else [10, 14, 20, 28])
    print("three-sphere swimmer against Golestanian & Ajdari (L = 1, loop 0.2 x 0.2)")
    for radius, count in [(0.02, 200), (0.01, 200)] + ([] if quick else [(0.01, 400)]):
        error = three_spheres(radius, count)
        print(f"  a = {radius:.2f}, {count} points per sphere: {error:+.4f}")

    spec = load_swimmer(EXAMPLE)
    started = time.perf_counter()
    stroke = run_stroke(spec)
    elapsed = time.perf_counter() - started
    drift = np.hypot(*stroke.displacement[:2])
    print(
        f"example: {axial(stroke):+.6f} R per cycle ({len(stroke.path.stimuli)} shapes, "
        f"{len(stroke.sheet.stokes)} points), one cycle {elapsed:.1f} s "
        f"(shapes {stroke.shapes.seconds:.1f} s, flow {stroke.seconds:.1f} s)"
    )
    print(
        f"  sideways drift {drift:.2e} R, rotation {np.linalg.norm(stroke.rotation):.2e} rad, "
        f"all shapes converged: {bool(stroke.shapes.converged.all())}"
    )
    coarse_shapes = run_stroke(spec.with_path(CYCLE, 3))
    rings = [10, 14, 20] if quick else [10, 14, 20, 28] + ([36] if args.full else [])
    point_convergence(coarse_shapes, rings, [0.35] if quick else [0.25, 0.35, 0.5])
    station_convergence(spec, [3, 6] if quick else [3, 6, 12])
    mesh_convergence(spec, [8, 12] if quick else [8, 12, 16])
    loop_scaling(spec)


if __name__ == "__main__":
    main()
