"""Work bounds: densities, the supplement's closed forms, direct integration, the CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fabkit.design.solver import solve
from fabkit.errors import FabkitError
from fabkit.mechanics.energy import (
    HomogeneousSheet,
    baromorph_energy,
    cycle_closed_form,
    cycle_energy,
    cycle_stretches,
    design_work,
    neo_hookean_density,
    small_strain_density,
    work_bound,
)
from fabkit.problem.spec import build_spec
from tests.conftest import ROOT, example_table

YOUNGS, POISSON, THICKNESS, EPS = 2.5, 0.45, 0.1, 0.4


def integrate_polar(lambda1, lambda2, density=small_strain_density, radius=1.5, cells=40):
    """Direct integration over a disc in polar material coordinates on a square grid.

    v is the radius (beta = 1) and u = c theta a scaled angle, so that u's step equals
    v's and [0, 2 pi] is covered exactly; then alpha = v / c.
    """
    step = radius / cells
    count = round(2 * np.pi / step)
    scale = count * step / (2 * np.pi)
    uu, vv = np.meshgrid(step * np.arange(count + 1), step * np.arange(cells + 1), indexing="ij")
    valid = np.ones_like(uu, dtype=bool)
    return work_bound(
        vv / scale,
        np.ones_like(vv),
        lambda1,
        lambda2,
        valid,
        step,
        YOUNGS,
        POISSON,
        THICKNESS,
        density,
    )


def sheet() -> HomogeneousSheet:
    """The disc of radius 1.5 that integrate_polar integrates over."""
    return HomogeneousSheet(np.pi * 1.5**2, YOUNGS, POISSON, THICKNESS)


def test_baromorph_closed_form_matches_direct_integration():
    for pressure in (0.3, 1.0, 2.5):
        direct = integrate_polar(1.0, 1.0 + pressure * EPS)
        closed = baromorph_energy(EPS, pressure, sheet())
        assert direct == pytest.approx(closed, rel=1e-6)


@pytest.mark.parametrize("stage", [1, 2, 3])
@pytest.mark.parametrize("density", [small_strain_density, neo_hookean_density])
def test_cycle_stages_match_direct_integration(stage, density):
    for t in (0.25, 0.5, 1.0):
        lambda1, lambda2 = cycle_stretches(stage, t, EPS)
        direct = integrate_polar(float(lambda1), float(lambda2), density)
        formula = cycle_energy(stage, t, EPS, sheet(), density)
        assert direct == pytest.approx(float(formula), rel=1e-6)


@pytest.mark.parametrize("stage", [1, 3])
def test_supplement_closed_forms_of_stages_one_and_three(stage):
    t = np.linspace(0, 1, 11)
    closed = cycle_closed_form(stage, t, EPS, sheet())
    density = cycle_energy(stage, t, EPS, sheet())
    assert np.allclose(closed, density, rtol=1e-12, atol=0)
    with pytest.raises(FabkitError):
        cycle_closed_form(2, t, EPS, sheet())


def test_cycle_is_closed_and_continuous():
    ends = [cycle_stretches(stage, t, EPS) for stage, t in ((1, 1), (2, 0), (2, 1), (3, 0))]
    assert np.allclose(ends[0], ends[1]) and np.allclose(ends[2], ends[3])
    assert np.allclose(cycle_stretches(1, 0, EPS), 1) and np.allclose(cycle_stretches(3, 1, EPS), 1)


def test_neo_hookean_agrees_with_small_strain_to_quadratic_order():
    for strain in (1e-2, 1e-3):
        for stretches in ((1 + strain, 1.0), (1 + strain, 1 - 0.5 * strain)):
            small = small_strain_density(*map(np.asarray, stretches), YOUNGS, 0.5)
            neo = neo_hookean_density(*map(np.asarray, stretches), YOUNGS, 0.5)
            assert neo / small == pytest.approx(1, abs=10 * strain)


@pytest.mark.slow
def test_fig1_design_work_bounds():
    table = example_table("two_shapes.toml")
    table["solver"].update(diagonals=60)
    design = solve(build_spec(table, ROOT)).design
    flat, sphere, bump = design_work(design, YOUNGS, POISSON, THICKNESS)
    assert flat.small_strain == 0 and flat.neo_hookean == 0
    assert flat.target_area == pytest.approx(flat.flat_area)
    assert 0 < sphere.small_strain < bump.small_strain  # lambda2 grows with the stimulus
    # lambda1 = 1 here, so the bound is the baromorph integrand with exp(L eps) - 1 for L eps
    assert sphere.target_area > flat.flat_area


@pytest.mark.slow
def test_energy_cli_writes_the_cycle_plot(run_cli, tmp_path):
    plot = tmp_path / "fig4d.png"
    code, out, _ = run_cli("energy", "--cycle", plot, "--epsilon", "0.5", "--json")
    assert code == 0 and plot.stat().st_size > 10_000
    rows = json.loads(out)["cycle"]
    assert [row["stage"] for row in rows] == [1, 2, 3]
    assert rows[0]["small_strain_end"] == pytest.approx(rows[1]["small_strain_start"])
    code, _, err = run_cli("energy")
    assert code == 2 and "design file" in err
