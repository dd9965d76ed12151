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
  domain and for ``fabkit simulate``'s default part (without the regions under 4 bending
  lengths across), each cell as designed and split 2 x 2;
* a 20k-triangle cone (one ramp step): wall time against the 60 s budget;
* work bounds: baromorph and cycle closed forms against direct integration;
* with ``--wavy`` only: can the Fig. 3 wavy sheet be reached at all? From every start
  (dome, saddle, a 5 % pre-bias of the target's lowest modes, the quasi-static path flat
  -> sphere -> face -> wavy, the target itself), at several thicknesses and meshes, under
  the designed metric and under the target's own (its chord lengths: the target then
  carries no stretching energy): distance, strain, and the stretching and bending
  energies of the shape reached and of the target (docs/mechanics.md).

    python benchmarks/simulate.py [--skip-large] [--wavy [--quick]]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from fabkit.design.solver import solve
from fabkit.field.part import simulation_part
from fabkit.mechanics.compare import align, compare, integrated_curvature, target_points
from fabkit.mechanics.energy import (
    HomogeneousSheet,
    baromorph_energy,
    cycle_closed_form,
    cycle_energy,
    cycle_stretches,
    work_bound,
)
from fabkit.mechanics.mesh import DesignMesh, design_mesh, disc_mesh
from fabkit.mechanics.metric import edge_lengths, metric_from_director, metric_from_lengths
from fabkit.mechanics.shell import Sheet, build_shell
from fabkit.mechanics.simulate import (
    SEEDS,
    DesignSimulation,
    Settings,
    design_metrics,
    diameter,
    seeded,
    simulate,
    simulate_design,
    stimulus_metrics,
)
from fabkit.problem.spec import load_spec

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
ALONG, ACROSS = 0.8, 0.8**-0.5


def director_case(
    rings: int, field, seed: str, steps: int = Settings.steps
) -> tuple[float, object, int]:
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
        curvature, result, faces = director_case(20, field, seed)
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
    for trim, refine in ((0, 1), (None, 1), (None, 2)):
        part, _ = simulation_part(design, thickness, trim)
        for surface in (1, 2):
            simulation = simulate_design(design, surface, thickness, part=part, refine=refine)
            report = compare(design, simulation)
            domain = "whole domain" if trim == 0 else "default part"
            print(
                f"  {report.name:7} {domain:13} refine {refine}, {report.triangles} triangles: "
                f"RMS {100 * report.rms:.2f} %, max {100 * report.max:.2f} % of "
                f"{report.size:.3g}; strain median {report.strain_median:.1e}; "
                f"{report.iterations} iterations, converged {report.converged}, "
                f"{report.seconds:.1f} s"
            )


FIG3_PATH = ((0.5, 0.0), (2.0, 0.0), (0.0, 2.0))
"""Fig. 3's stimuli in order, from the flat sheet (0, 0): sphere, face, wavy."""


@dataclass(frozen=True)
class Case:
    """The wavy sheet's mesh at one thickness: flat points, triangles, the designed and
    the target's own (chord-length) metrics, the target points, where the design's own
    grid points are (compared there), and the material grid mesh."""

    mesh: DesignMesh
    designed: np.ndarray
    chords: np.ndarray
    target: np.ndarray
    thickness: float
    size: float = 1.0


def split_energy(points, triangles, metrics, thickness, positions) -> tuple[float, float]:
    """(stretching, bending) energy of ``positions``: a single layer's energy is h S + h^3 B,
    so two thicknesses separate them."""
    sheet = Sheet.build(points, triangles)
    one = build_shell(sheet, metrics[None], thickness, 0.5).energy(positions)
    two = build_shell(sheet, metrics[None], 2 * thickness, 0.5).energy(positions)
    bending = (two - 2 * one) / 6
    return one - bending, bending


def low_mode_seed(points: np.ndarray, target: np.ndarray, height: float) -> np.ndarray:
    """The flat sheet lifted by the target's lowest shape modes, ``height`` x its radius high:
    the target's height over the flat sheet (after the best rigid alignment) fitted by a
    cubic in the flat coordinates. A lab can pre-bias the buckling this way (a mould, a
    pre-curved substrate); it is not the target, only its first few modes, 5 % high."""
    flat = np.column_stack([points, np.zeros(len(points))])
    lifted = align(target, flat, mirror=False).aligned[:, 2]
    x, y = ((points - points.mean(0)) / np.ptp(points, axis=0).max()).T
    basis = np.column_stack([x**i * y**j for i in range(4) for j in range(4 - i)])
    smooth = basis @ np.linalg.lstsq(basis, lifted, rcond=None)[0]
    radius = np.max(np.linalg.norm(points - points.mean(0), axis=1))
    return np.column_stack([points, height * radius * smooth / np.max(np.abs(smooth))])


def wavy_case(design, part, refine: int, thickness: float) -> Case:
    mesh = design_mesh(design, part, refine)
    designed = design_metrics(design, mesh, 3)
    probe = DesignSimulation(3, "wavy", mesh, designed, thickness, None)
    target = target_points(design, probe)
    start, end = mesh.triangles[:, [1, 2, 0]], mesh.triangles[:, [2, 0, 1]]
    chords = metric_from_lengths(
        mesh.points, mesh.triangles, np.linalg.norm(target[end] - target[start], axis=-1)
    )
    return Case(mesh, designed, chords, target, thickness)


def wavy_run(design, case: Case, start: str, metric: str) -> None:
    """One row of the wavy study: the sheet from ``start`` under the ``metric`` metrics."""
    mesh, thickness = case.mesh, case.thickness
    metrics = case.designed if metric == "designed" else case.chords
    made = stimulus_metrics(design, mesh, np.zeros(2))
    settings = Settings(max_iterations=400)
    started = time.perf_counter()
    if start == "target":  # relax from the target itself
        result = simulate(
            mesh.points,
            mesh.triangles,
            metrics,
            thickness,
            settings=replace(settings, steps=1),
            initial=case.target,
            start_metrics=metrics,
        )
    elif start == "path":  # flat -> sphere -> face -> wavy, each leg along the slow ramp
        x, previous, iterations = seeded(mesh.points, settings), made, 0
        for stimulus in FIG3_PATH:
            leg = stimulus_metrics(design, mesh, np.array(stimulus))
            if stimulus == FIG3_PATH[-1]:
                leg = metrics
            result = simulate(
                mesh.points,
                mesh.triangles,
                leg,
                thickness,
                settings=settings,
                initial=x,
                start_metrics=previous,
            )
            x, previous, iterations = result.positions, leg, iterations + result.iterations
        result = replace(result, iterations=iterations)
    else:
        initial = None
        if start == "low modes":
            initial = low_mode_seed(mesh.points, case.target, settings.seed_height)
        result = simulate(
            mesh.points,
            mesh.triangles,
            metrics,
            thickness,
            settings=replace(settings, seed=start if start in SEEDS else "dome"),
            initial=initial,
            start_metrics=made,
        )
    seconds = time.perf_counter() - started
    simulation = DesignSimulation(3, "wavy", mesh, metrics, thickness, result)
    report = compare(design, simulation)
    reached = split_energy(mesh.points, mesh.triangles, metrics, thickness, result.positions)
    target = split_energy(mesh.points, mesh.triangles, metrics, thickness, case.target)
    print(
        f"  {100 * thickness / case.size:5.2f} {mesh.refine:6d} {len(mesh.triangles):6d} "
        f"{metric:8} {start:9} {100 * report.rms:6.2f} {100 * report.max:6.2f} "
        f"{str(report.converged):5} {report.iterations:5d} {report.strain_median:8.1e} "
        f"{reached[0]:9.2e} {reached[1]:9.2e} {target[0]:9.2e} {target[1]:9.2e} "
        f"{seconds:6.1f}",
        flush=True,
    )


def wavy_study(quick: bool) -> None:
    """Can the Fig. 3 wavy sheet be reached? Every start, thickness and mesh (docs)."""
    design = solve(load_spec(EXAMPLES / "three_shapes.toml")).design
    size = diameter(design_mesh(design).points)
    print(
        "Fig. 3 wavy sheet (examples/three_shapes.toml): distance to the target / patch size, "
        "energies (Y x design units^3) of the shape reached and of the target under the same "
        "metric, stretching and bending; h as % of the flat sheet's diameter "
        f"({size:.3g}; one 0.3 mm layer at 60 mm is 0.5 %)"
    )
    print(
        "      h refine  faces metric   start       RMS    max conv   iter   strain "
        "  reach S   reach B  target S  target B      s"
    )
    rows = [(0.01, 1), (0.005, 1), (0.0025, 1), (0.01, 2)]
    starts = ("dome", "saddle", "low modes", "path", "target")
    if quick:
        rows, starts = [(0.01, 1)], ("dome", "target")
    for fraction, refine in rows:
        part, thickness = simulation_part(design, fraction * size)
        case = wavy_case(design, part, refine, thickness)
        case = replace(case, size=size)
        for start in starts:
            wavy_run(design, case, start, "designed")
        for start in ("dome", "target"):
            wavy_run(design, case, start, "chords")


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
    sheet = HomogeneousSheet(area, youngs, poisson, thickness)

    def direct(l1, l2):
        return work_bound(alpha, np.ones_like(vv), l1, l2, valid, step, youngs, poisson, thickness)

    worst = 0.0
    for pressure in np.linspace(0.1, 2, 8):
        closed = baromorph_energy(eps, pressure, sheet)
        worst = max(worst, abs(direct(1.0, 1 + pressure * eps) / closed - 1))
    print(f"energy: baromorph closed form vs direct integration, worst relative {worst:.1e}")
    for stage in (1, 2, 3):
        worst = 0.0
        for t in np.linspace(0.05, 0.95, 10):  # stage 3 ends at zero energy
            l1, l2 = cycle_stretches(stage, t, eps)
            formula = cycle_energy(stage, t, eps, sheet)
            if stage != 2:
                formula = cycle_closed_form(stage, t, eps, sheet)
            worst = max(worst, abs(direct(float(l1), float(l2)) / float(formula) - 1))
        source = "closed form" if stage != 2 else "homogeneous formula"
        print(f"  cycle stage {stage}: {source} vs direct integration, worst relative {worst:.1e}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--skip-large", action="store_true", help="skip the 20k-triangle run")
    parser.add_argument(
        "--wavy", action="store_true", help="only the Fig. 3 wavy study (about 15 min)"
    )
    parser.add_argument("--quick", action="store_true", help="with --wavy: two rows only")
    args = parser.parse_args()
    started = time.perf_counter()
    if args.wavy:
        wavy_study(args.quick)
        print(f"total {time.perf_counter() - started:.0f} s")
        return
    energy()
    validation()
    figure1()
    if not args.skip_large:
        large()
    print(f"total {time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()
