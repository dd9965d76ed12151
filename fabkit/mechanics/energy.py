"""Bounds on the work a sheet can do: the frustrated energy if held flat (supplement).

A sheet prevented from deforming keeps the flat metric g = diag(alpha^2, beta^2) in
material coordinates while its reference metric becomes
abar = diag((lambda1 alpha)^2, (lambda2 beta)^2). The stored stretching energy bounds
the work it can do on its surroundings:

    E = h  iint_target  W(lambda1, lambda2) dA,    dA = lambda1 lambda2 alpha beta du dv,

with the small-strain density (non-Euclidean plates)

    W = Y / (8 (1 - nu^2)) [ (1 - nu) ((1 - 1/l1^2)^2 + (1 - 1/l2^2)^2)
                              + nu (1/l1^2 + 1/l2^2 - 2)^2 ]

or the incompressible neo-Hookean density for large strains

    W = Y / (4 (1 + nu)) (1/l1^2 + 1/l2^2 + l1^2 l2^2 - 3) / (l1 l2).

Energies are in units of Young's modulus Y x length^3 when Y, h and lengths are given
in consistent units (e.g. Pa, m -> J). The closed forms of the supplement (the
homogeneous baromorph lambda1 = 1, lambda2 = 1 + Lambda eps, and the three stages of
the Fig. 4d cycle (0,0) -> (1,0) -> (1,1) -> (0,0)) are here too, with the plot.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fabkit.design.design import Design
from fabkit.design.summary import realised_areas
from fabkit.errors import FabkitError
from fabkit.figures import AREA_UNIT, cell_integral
from fabkit.files.atomic import atomic_path

Density = Callable[[np.ndarray, np.ndarray, float, float], np.ndarray]


def small_strain_density(
    lambda1: np.ndarray, lambda2: np.ndarray, youngs: float, poisson: float
) -> np.ndarray:
    """Small-strain stretching energy per unit target area and thickness (units of Y)."""
    a, b = 1 - 1 / lambda1**2, 1 - 1 / lambda2**2
    return (
        youngs / (8 * (1 - poisson**2)) * ((1 - poisson) * (a**2 + b**2) + poisson * (a + b) ** 2)
    )


def neo_hookean_density(
    lambda1: np.ndarray, lambda2: np.ndarray, youngs: float, poisson: float
) -> np.ndarray:
    """Incompressible neo-Hookean energy per unit target area and thickness (units of Y)."""
    product = lambda1 * lambda2
    return (
        youngs / (4 * (1 + poisson)) * (1 / lambda1**2 + 1 / lambda2**2 + product**2 - 3) / product
    )


DENSITIES: dict[str, Density] = {
    "small_strain": small_strain_density,
    "neo_hookean": neo_hookean_density,
}


def _check(youngs: float, poisson: float, thickness: float) -> None:
    if not youngs > 0:
        raise FabkitError("Young's modulus must be positive")
    if not -1 < poisson <= 0.5:
        raise FabkitError("Poisson ratio must lie in (-1, 0.5]")
    if not thickness > 0:
        raise FabkitError("thickness must be positive")


def work_bound(
    alpha: np.ndarray,
    beta: np.ndarray,
    lambda1: np.ndarray,
    lambda2: np.ndarray,
    valid: np.ndarray,
    step: float,
    youngs: float,
    poisson: float,
    thickness: float,
    density: Density = small_strain_density,
) -> float:
    """h iint W(lambda1, lambda2) lambda1 lambda2 alpha beta du dv on a material grid.

    All fields (nu, nv); ``valid`` marks the points to use, ``step`` the grid step.
    """
    _check(youngs, poisson, thickness)
    with np.errstate(all="ignore"):
        integrand = density(lambda1, lambda2, youngs, poisson) * lambda1 * lambda2 * alpha * beta
    valid = valid & np.isfinite(integrand)
    return thickness * cell_integral(np.where(valid, integrand, 0.0), valid, step)


@dataclass(frozen=True)
class SurfaceWork:
    """Work bounds of a design at one surface's stimulus.

    Areas in design units^2 (flat sheet and target), energies in Y x design units^3.
    """

    name: str
    stimulus: tuple[float, ...]
    flat_area: float
    target_area: float
    small_strain: float
    neo_hookean: float


def design_work(
    design: Design, youngs: float, poisson: float, thickness: float
) -> tuple[SurfaceWork, ...]:
    """Work bounds of ``design`` at every surface's stimulus (surface 0 gives zero)."""
    _check(youngs, poisson, thickness)
    spec = design.problem
    valid, step = design.valid, design.step
    alpha, beta = np.where(valid, design.alpha, 0.0), np.where(valid, design.beta, 0.0)
    eps = np.where(valid[None], design.eps, 0.0)
    response = spec.material.response(eps, design.stimuli)
    areas = realised_areas(design)  # the areas design.json and fabkit solve print
    flat_area = areas[spec.targets[0].name]
    results = []
    for index, target in enumerate(spec.targets):
        l1, l2 = response.lambda1[index], response.lambda2[index]
        energies = [
            work_bound(alpha, beta, l1, l2, valid, step, youngs, poisson, thickness, density)
            for density in DENSITIES.values()
        ]
        area = areas[target.name]
        results.append(SurfaceWork(target.name, target.stimulus, flat_area, area, *energies))
    return tuple(results)


def describe_work(results: tuple[SurfaceWork, ...]) -> str:
    """A table of :func:`design_work` results."""
    lines = [
        f"{'surface':12} {'stimulus':>12} {'flat area':>10} {'target area':>12} "
        f"{'E small-strain':>15} {'E neo-Hookean':>15}"
    ]
    for item in results:
        stimulus = ",".join(f"{s:g}" for s in item.stimulus)
        lines.append(
            f"{item.name:12} {stimulus:>12} {item.flat_area:10.4g} {item.target_area:12.4g} "
            f"{item.small_strain:15.6g} {item.neo_hookean:15.6g}"
        )
    lines.append(
        f"areas over the solved cells in {AREA_UNIT} (as design.json); energies in "
        "Young's modulus x design units^3"
    )
    return "\n".join(lines)


@dataclass(frozen=True)
class HomogeneousSheet:
    """The sheet of the supplement's closed forms and of the Fig. 4d cycle: flat area A0
    (length^2), Young's modulus Y, Poisson ratio nu and thickness h (length)."""

    area: float
    youngs: float
    poisson: float
    thickness: float


def baromorph_energy(eps: float, pressure: np.ndarray, sheet: HomogeneousSheet) -> np.ndarray:
    """Closed form for a homogeneous baromorph, lambda1 = 1, lambda2 = 1 + Lambda eps:

    E = h A0 Y / (8 (1 - nu^2)) eps^2 Lambda^2 (2 + Lambda eps)^2 / (1 + Lambda eps)^3,
    with A0 the flat sheet's area (small-strain density).
    """
    x = np.asarray(pressure, dtype=float) * eps
    h, area, youngs, poisson = sheet.thickness, sheet.area, sheet.youngs, sheet.poisson
    return h * area * youngs / (8 * (1 - poisson**2)) * x**2 * (2 + x) ** 2 / (1 + x) ** 3


CYCLE = ((0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 0.0))
"""Fig. 4d: the corners (Lambda1, Lambda2) of the three-stage cycle, joined by straight lines."""


def cycle_stretches(stage: int, t: np.ndarray, eps: float) -> tuple[np.ndarray, np.ndarray]:
    """lambda1 (along u) and lambda2 (along v) at fraction t in [0, 1] of stage 1, 2 or 3.

    The reference metric is (1 + Lambda2 eps)^2 v^2 du^2 + (1 + Lambda1 eps)^2 dv^2 on
    the flat metric v^2 du^2 + dv^2, so lambda1 = 1 + Lambda2 eps, lambda2 = 1 + Lambda1 eps.
    """
    if stage not in (1, 2, 3):
        raise FabkitError(f"cycle stage must be 1, 2 or 3, got {stage}")
    start, end = np.array(CYCLE[stage - 1]), np.array(CYCLE[stage])
    t = np.asarray(t, dtype=float)
    stimulus1 = start[0] + t * (end[0] - start[0])
    stimulus2 = start[1] + t * (end[1] - start[1])
    return 1 + stimulus2 * eps, 1 + stimulus1 * eps


def cycle_energy(
    stage: int,
    t: np.ndarray,
    eps: float,
    sheet: HomogeneousSheet,
    density: Density = small_strain_density,
) -> np.ndarray:
    """Energy bound at fraction t of a cycle stage for a homogeneous sheet of flat area A0:
    h A0 W(lambda1, lambda2) lambda1 lambda2 (the stretches are uniform)."""
    l1, l2 = cycle_stretches(stage, t, eps)
    return sheet.thickness * sheet.area * density(l1, l2, sheet.youngs, sheet.poisson) * l1 * l2


def cycle_closed_form(stage: int, t: np.ndarray, eps: float, sheet: HomogeneousSheet) -> np.ndarray:
    """The supplement's small-strain closed forms: stage 1 is the baromorph with
    Lambda = Lambda1; stage 3 (lambda1 = lambda2 = 1 + Lambda eps) is
    h A0 Y eps^2 Lambda^2 (2 + Lambda eps)^2 / (4 (1 - nu) (1 + Lambda eps)^2).
    The supplement gives none for stage 2."""
    l1, l2 = cycle_stretches(stage, t, eps)
    if stage == 1:
        return baromorph_energy(eps, (l2 - 1) / eps, sheet)
    if stage == 3:
        x = l1 - 1
        h, area, youngs, poisson = sheet.thickness, sheet.area, sheet.youngs, sheet.poisson
        return h * area * youngs * x**2 * (2 + x) ** 2 / (4 * (1 - poisson) * (1 + x) ** 2)
    raise FabkitError("the supplement gives closed forms for cycle stages 1 and 3 only")


@dataclass(frozen=True)
class CycleStage:
    """One stage of the cycle: stimuli at its ends and the energy bounds there
    (Y x length^3), small-strain and neo-Hookean."""

    stage: int
    start: tuple[float, float]
    end: tuple[float, float]
    small_strain_start: float
    small_strain_end: float
    neo_hookean_start: float
    neo_hookean_end: float


def cycle_table(
    eps: float, area: float, youngs: float, poisson: float, thickness: float
) -> tuple[CycleStage, ...]:
    """The numbers behind Fig. 4d: energy bounds at both ends of each stage."""
    _check(youngs, poisson, thickness)
    sheet = HomogeneousSheet(area, youngs, poisson, thickness)
    rows = []
    for stage in (1, 2, 3):
        values = [
            float(cycle_energy(stage, t, eps, sheet, density))
            for density in DENSITIES.values()
            for t in (0.0, 1.0)
        ]
        rows.append(CycleStage(stage, CYCLE[stage - 1], CYCLE[stage], *values))
    return tuple(rows)


def describe_cycle(rows: tuple[CycleStage, ...]) -> str:
    """A table of :func:`cycle_table` rows."""
    lines = [f"{'stage':6} {'from':>10} {'to':>10} {'small-strain':>27} {'neo-Hookean':>27}"]
    for row in rows:
        lines.append(
            f"{row.stage:<6} {str(row.start):>10} {str(row.end):>10} "
            f"{row.small_strain_start:12.6g} -> {row.small_strain_end:<12.6g}"
            f"{row.neo_hookean_start:12.6g} -> {row.neo_hookean_end:<12.6g}"
        )
    return "\n".join(lines)


def plot_cycle(
    path: str | Path,
    eps: float,
    area: float,
    youngs: float,
    poisson: float,
    thickness: float,
    samples: int = 101,
) -> None:
    """Fig. 4d as a PNG: energy bound along the three stages (both densities)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    _check(youngs, poisson, thickness)
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise FabkitError(f"{path}: the cycle plot is written as .png")
    sheet = HomogeneousSheet(area, youngs, poisson, thickness)
    t = np.linspace(0.0, 1.0, samples)
    figure, axes = plt.subplots(figsize=(6, 3.6), layout="constrained")
    for (label, density), style in zip(DENSITIES.items(), ("-", "--"), strict=True):
        for stage in (1, 2, 3):
            energy = cycle_energy(stage, t, eps, sheet, density)
            axes.plot(
                stage - 1 + t,
                energy,
                style,
                color=f"C{stage - 1}",
                label=f"{label.replace('_', '-')}" if stage == 1 else None,
            )
    for stage, name in enumerate(("I: (0,0)->(1,0)", "II: (1,0)->(1,1)", "III: (1,1)->(0,0)")):
        axes.text(stage + 0.5, 0.02, name, ha="center", transform=axes.get_xaxis_transform())
    axes.set_xticks([0, 1, 2, 3])
    axes.set_xlabel("cycle coordinate (stage)")
    axes.set_ylabel("work bound E  [Y x length$^3$]")
    axes.set_title(f"Fig. 4d: frustrated energy along the cycle (eps = {eps:g})")
    axes.legend(title="density (line style)")
    with atomic_path(path) as tmp:
        figure.savefig(tmp, dpi=120)
    plt.close(figure)
