"""Forward simulation figures: validation cases, the Fig. 1 design, 20k triangles, energy.

Prints, for each case, the measured error, Newton iterations and wall time:

* azimuthal director (cone) and radial director (anticone) on a 2.4k-triangle disc,
  h/R = 1e-3: integrated Gaussian curvature against 2 pi (1 - l_par/l_perp) and
  -2 pi (l_perp/l_par - 1);
* spherical cap from the metric (2 / (1 + r^2))^2 I on r <= 0.7, 2.4k triangles,
  h/R = 3e-3: largest pointwise distance after alignment / R (bounds the Hausdorff
  distance) and RMS / R;
* the Fig. 1 design (examples/two_shapes.toml) at thickness 1 % of its flat size under
  stimuli 1 and 2: RMS and max distance to the targets / patch size, for the whole solved
  domain and without the arms (regions under 9 cells, 0.45 in (u, v), across), each cell
  as designed and split 2 x 2;
* a 20k-triangle cone (one ramp step): wall time against the 60 s budget;
* work bounds: baromorph and cycle closed forms against direct integration.

    python benchmarks/simulate.py [--skip-large]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from fabkit.design.solver import solve
from fabkit.mechanics.compare import align, compare, integrated_curvature
from fabkit.mechanics.energy import (
    baromorph_energy,
    cycle_closed_form,
    cycle_energy,
    cycle_stretches,
    work_bound,
)
from fabkit.mechanics.mesh import design_mesh, disc_mesh
from fabkit.mechanics.metric import edge_lengths, metric_from_director, metric_from_lengths
from fabkit.mechanics.simulate import Settings, diameter, simulate, simulate_design
from fabkit.problem.spec import load_spec

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
ALONG, ACROSS = 0.8, 0.8**-0.5


def director_case(rings: int, field, seed: str, steps: int) -> tuple[float, object, int]:
    points, triangles = disc_mesh(1.0, rings)

    def metric(p):
        shape = p.shape[:-1]
        return metric_from_director(field(p), np.full(shape, ALONG), np.full(shape, ACROSS))

    metrics = metric_from_lengths(points, triangles, edge_lengths(points, triangles, metric))
    settings = Settings(steps=steps, seed=seed, max_iterations=400)
    result = simulate(points, triangles, metrics, 1e-3, settings=settings)
    return integrated_curvature(result.positions, triangles), result, len(triangles)


def validation() -> None:
    print("validation (disc of radius R = 1, lambda_par = 0.8, lambda_perp = 0.8^-1/2)")
    cases = (  # integrated K = 2 pi (1 - circumference / (2 pi radius)) in the target
        ("cone", lambda p: np.stack([-p[..., 1], p[..., 0]], -1), "dome", ALONG / ACROSS),
        ("anticone", lambda p: p, "saddle", ACROSS / ALONG),
    )
    for name, field, seed, ratio in cases:
        curvature, result, faces = director_case(20, field, seed, 2)
        exact = 2 * np.pi * (1 - ratio)
        print(
            f"  {name:9} {faces} triangles, h/R 1e-3: integrated K {curvature:.5f}, exact "
            f"{exact:.5f}, error {100 * (curvature / exact - 1):+.3f} %; "
            f"{result.iterations} iterations, {result.seconds:.1f} s"
        )
    points, triangles = disc_mesh(1.0, 20)
    points = 0.7 * points

    def cap_metric(p):
        scale = 2 / (1 + np.sum(p**2, -1))
        return scale[..., None, None] ** 2 * np.eye(2)

    metrics = metric_from_lengths(points, triangles, edge_lengths(points, triangles, cap_metric))
    result = simulate(points, triangles, metrics, 3e-3)
    r2 = np.sum(points**2, 1)[:, None]
    cap = np.concatenate([2 * points / (1 + r2), (1 - r2) / (1 + r2)], 1)
    alignment = align(result.positions, cap)
    print(
        f"  cap       {len(triangles)} triangles, h/R 3e-3: max distance / R "
        f"{100 * alignment.max:.3f} %, RMS / R {100 * alignment.rms:.3f} %; "
        f"{result.iterations} iterations, {result.seconds:.1f} s"
    )


def figure1() -> None:
    design = solve(load_spec(EXAMPLES / "two_shapes.toml")).design
    thickness = 0.01 * diameter(design_mesh(design).points)
    print(f"Fig. 1 design, thickness {thickness:.4f} (1 % of the flat sheet's diameter)")
    for trim, refine, iterations in ((0, 1, 1000), (9, 1, 100), (9, 2, 100)):
        settings = Settings(max_iterations=iterations)  # the whole domain creeps for long
        for surface in (1, 2):
            simulation = simulate_design(
                design, surface, thickness, settings=settings, trim=trim, refine=refine
            )
            report = compare(design, simulation)
            domain = "whole domain" if trim == 0 else f"trim {trim}"
            print(
                f"  {report.name:7} {domain:13} refine {refine}, {report.triangles} triangles: "
                f"RMS {100 * report.rms:.2f} %, max {100 * report.max:.2f} % of "
                f"{report.size:.3g}; strain median {report.strain_median:.1e}; "
                f"{report.iterations} iterations, converged {report.converged}, "
                f"{report.seconds:.1f} s"
            )


def large() -> None:
    curvature, result, faces = director_case(
        58, lambda p: np.stack([-p[..., 1], p[..., 0]], -1), "dome", 1
    )
    exact = 2 * np.pi * (1 - ALONG / ACROSS)
    verdict = "within" if result.seconds <= 60 else "OVER"
    print(
        f"large: cone, {faces} triangles, one ramp step: {result.seconds:.1f} s ({verdict} the "
        f"60 s budget), {result.iterations} iterations; integrated K error "
        f"{100 * (curvature / exact - 1):+.2f} %"
    )


def energy() -> None:
    youngs, poisson, thickness, eps, radius, cells = 1.0, 0.45, 0.01, 0.5, 1.0, 40
    step = radius / cells
    count = round(2 * np.pi / step)
    uu, vv = np.meshgrid(step * np.arange(count + 1), step * np.arange(cells + 1), indexing="ij")
    alpha, valid, area = vv * 2 * np.pi / (count * step), np.ones_like(uu, bool), np.pi * radius**2

    def direct(l1, l2):
        return work_bound(alpha, np.ones_like(vv), l1, l2, valid, step, youngs, poisson, thickness)

    worst = 0.0
    for pressure in np.linspace(0.1, 2, 8):
        closed = baromorph_energy(eps, pressure, area, youngs, poisson, thickness)
        worst = max(worst, abs(direct(1.0, 1 + pressure * eps) / closed - 1))
    print(f"energy: baromorph closed form vs direct integration, worst relative {worst:.1e}")
    for stage in (1, 2, 3):
        worst = 0.0
        for t in np.linspace(0.05, 0.95, 10):  # stage 3 ends at zero energy
            l1, l2 = cycle_stretches(stage, t, eps)
            formula = cycle_energy(stage, t, eps, area, youngs, poisson, thickness)
            if stage != 2:
                formula = cycle_closed_form(stage, t, eps, area, youngs, poisson, thickness)
            worst = max(worst, abs(direct(float(l1), float(l2)) / float(formula) - 1))
        source = "closed form" if stage != 2 else "homogeneous formula"
        print(f"  cycle stage {stage}: {source} vs direct integration, worst relative {worst:.1e}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--skip-large", action="store_true", help="skip the 20k-triangle run")
    args = parser.parse_args()
    started = time.perf_counter()
    energy()
    validation()
    figure1()
    if not args.skip_large:
        large()
    print(f"total {time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()
