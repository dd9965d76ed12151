"""The solver against the independent check: accuracy, order, stops and refusals."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fabkit.design.check import check_design
from fabkit.design.design import Design
from fabkit.design.solver import REASONS, solve
from fabkit.errors import FabkitError
from fabkit.problem.spec import build_spec
from tests.conftest import EXAMPLES


def solved(table: dict, **solver):
    table["solver"].update(solver)
    return solve(build_spec(table, EXAMPLES))


def reasons(solution) -> set[str]:
    return {s.reason for s in solution.stops}


@pytest.mark.slow
def test_fig1_passes_check_at_step_one_twentieth(fig1):
    solution = solved(fig1, step=0.05, diagonals=60)
    report = check_design(solution.design)
    assert report.passed, report.table()
    for surface in report.surfaces:
        assert surface.points > 300
        assert surface.isometry.median <= 1e-3 and surface.isometry.p95 <= 1e-2
        assert surface.curvature.median <= 1e-2


def isometry_medians(fig1: dict, steps: tuple[float, ...], reach: float, **solver) -> np.ndarray:
    """Each surface's isometry median (check region 0.5) of Fig. 1 solved at each of
    ``steps`` with diagonals reaching ``reach`` (design units): shape (steps, surfaces)."""
    medians = []
    for step in steps:
        table = json.loads(json.dumps(fig1))
        design = solved(table, step=step, diagonals=int(round(reach / step)), **solver).design
        report = check_design(design, region=0.5)
        medians.append([s.isometry.median for s in report.surfaces])
    return np.array(medians)


def observed_orders(errors: np.ndarray) -> np.ndarray:
    """The orders of convergence between successive errors of steps halved each time."""
    return np.log2(errors[:-1] / errors[1:])


@pytest.mark.slow
def test_fig1_observed_order(fig1):
    orders = observed_orders(isometry_medians(fig1, (0.1, 0.05, 0.025), 1.5))
    assert np.all(orders >= 1.8), orders


@pytest.mark.slow
def test_plain_march_is_second_order(fig1):
    """Without Richardson extrapolation, quadrant (-1, 1) converges at order 2."""
    steps = (0.05, 0.025, 0.0125)
    medians = isometry_medians(fig1, steps, 0.8, extrapolate=False, quadrants=[[-1, 1]])
    orders = observed_orders(medians.max(axis=1))
    assert np.all(orders >= 1.8), orders


@pytest.mark.slow
def test_fig3_passes_check(fig3):
    solution = solved(fig3, step=0.1, diagonals=40)
    report = check_design(solution.design)
    assert report.passed, report.table()


def test_design_contract_shapes_and_nan_outside(fig1, tmp_path):
    design = solved(fig1, step=0.1, diagonals=20).design
    path = tmp_path / "design.npz"
    design.save(path)
    loaded = Design.load(path)
    nu = len(loaded.u)
    assert loaded.valid.shape == (nu, nu) and loaded.r.shape == (3, nu, nu, 2)
    assert loaded.eps.shape == (1, nu, nu) and loaded.stimuli.shape == (3, 1)
    assert 0.0 in loaded.u and loaded.valid[nu // 2, nu // 2]
    assert np.isnan(loaded.alpha[~loaded.valid]).all()
    assert np.isfinite(loaded.r[:, loaded.valid]).all()
    with np.load(path, allow_pickle=False) as data:
        assert json.loads(str(data["spec"]))["solver"]["step"] == 0.1
    g = np.array([[1.0, 0.0], [0.0, 1.0]])
    n0 = loaded.n[0][loaded.valid]
    assert np.allclose(np.einsum("pi,ij,pj->p", n0, g, n0), 1.0)


def test_one_quadrant(fig1):
    design = solved(fig1, step=0.1, diagonals=10, quadrants=[[1, 1]]).design
    u, v = np.meshgrid(design.u, design.v, indexing="ij")
    assert design.valid.any() and not design.valid[(u < 0) | (v < 0)].any()


def test_stop_strain_alpha_beta(fig1):
    found = reasons(solved(fig1, step=0.05, diagonals=60))
    assert REASONS[5] in found  # strain
    assert any(r.startswith("alpha <= 0") for r in found)
    assert any(r.startswith("beta <= 0") for r in found)


def test_stop_removes_only_its_domain_of_influence(fig1):
    design = solved(fig1, step=0.05, diagonals=60, quadrants=[[1, 1]]).design
    valid = design.valid[60:, 60:]
    for i in range(valid.shape[0]):
        for j in range(valid.shape[1]):
            if not valid[i, j] and i + j <= 60:
                # a point is lost only if it or a point it depends on failed, so the lost
                # set is a union of quarter-planes: its upper-right neighbours are lost too
                if i + 1 < valid.shape[0]:
                    assert not valid[i + 1, j]
                if j + 1 < valid.shape[1]:
                    assert not valid[i, j + 1]
    # and a diagonal is not cut as a whole: some diagonal has lost and kept points
    diagonals = [valid[np.arange(d + 1), d - np.arange(d + 1)] for d in range(1, 40)]
    assert any(row.any() and not row.all() for row in diagonals)


def test_stop_lambda_nonpositive(fig1):
    fig1["material"]["lambda2"] = "1 + L*eps"
    fig1["initial"]["eps"] = ["-0.3"]
    fig1["initial"]["slope"] = ["1"]
    fig1["solver"]["max_strain"] = 100.0
    assert REASONS[4] in reasons(solved(fig1, step=0.05, diagonals=20))


def test_stop_leaving_chart_names_surface(fig1):
    fig1["surfaces"][2]["geometry"]["domain"] = [-0.2, 0.2, -0.2, 0.2]
    stops = solved(fig1, step=0.05, diagonals=20).stops
    assert any(s.reason.startswith("target point left") and s.surface == "bump" for s in stops)


def test_stop_non_finite(fig1):
    fig1["surfaces"][2]["geometry"]["z"] = "sqrt(1.1 - x)"
    fig1["surfaces"][2]["start"] = [1.099, 0.0]
    assert REASONS[1] in reasons(solved(fig1, step=0.05, diagonals=20))


def test_stop_isotropic_point(fig1):
    fig1["material"]["lambda1"] = "exp(L*eps)"
    fig1["material"]["lambda2"] = "exp(L/2)"
    fig1["initial"]["eps"] = ["0.6 - t"]
    fig1["initial"]["slope"] = ["0"]
    fig1["initial"]["v_curve"] = ["0", "t"]
    assert REASONS[6] in reasons(solved(fig1, step=0.05, diagonals=10))


@pytest.mark.slow
def test_stop_no_neighbours(fig3):
    assert REASONS[9] in reasons(solved(fig3, step=0.1, diagonals=40))


def test_stop_det_m_near_zero(fig3):
    """eps1 = 0 with eps2 != 0 is not isotropic, yet the sphere, face and flat rows of M
    become dependent there (the supplement's word of caution)."""
    fig3["initial"]["eps"] = ["0.1 - t", "1/2"]
    stops = solved(fig3, step=0.05, diagonals=6).stops
    assert any(s.reason == REASONS[7] and abs(s.u - 0.1) < 1e-9 and s.v == 0 for s in stops)


def test_refuse_det_m_zero_at_start(fig1):
    fig1["surfaces"][2]["stimulus"] = [1]
    with pytest.raises(FabkitError, match="det M = 0 at the start point"):
        solved(fig1, step=0.1, diagonals=5)


def test_refuse_isotropic_start(fig1):
    fig1["material"]["lambda1"] = "exp(L*eps)"
    fig1["material"]["lambda2"] = "exp(L/2)"
    fig1["initial"]["v_curve"] = ["0", "t"]
    with pytest.raises(FabkitError, match="isotropic"):
        solved(fig1, step=0.1, diagonals=5)


def test_refuse_inconsistent_initial_data(fig1):
    fig1["initial"]["eps"] = ["5"]
    with pytest.raises(FabkitError, match="inconsistent initial data.*strain"):
        solved(fig1, step=0.1, diagonals=5)


@pytest.mark.slow
def test_cli_solve_and_check(run_cli, tmp_path):
    out = tmp_path / "run" / "design.npz"
    code, text, _ = run_cli(
        "solve", EXAMPLES / "two_shapes.toml", "--out", out, "--diagonals", "40"
    )
    assert code == 0 and "valid points" in text
    summary = json.loads(out.with_suffix(".json").read_text())
    assert summary["valid_points"] > 500 and summary["check"]["passed"]
    assert set(summary["area_design_units2"]) == {"flat", "sphere", "bump"}
    assert summary["stop_counts"]
    code, text, _ = run_cli("check", out)
    assert code == 0 and "sphere" in text
    code, text, _ = run_cli("check", out, "--json")
    assert json.loads(text)["passed"]
    code, _, _ = run_cli("check", out, "--isometry-median", "1e-9")
    assert code == 1


def test_cli_bad_spec_leaves_no_design(run_cli, tmp_path):
    spec = tmp_path / "bad.toml"
    text = (EXAMPLES / "two_shapes.toml").read_text().replace("stimulus = [2]", "stimulus = [1]")
    spec.write_text(text)
    out = tmp_path / "design.npz"
    code, _, err = run_cli("solve", spec, "--out", out)
    assert code == 2 and "det M = 0" in err and err.count("\n") == 1
    assert list(tmp_path.iterdir()) == [spec]


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (None, "does not exist"),
        (b"not a zip", "cannot read design file"),
        ("npz-missing-keys", "not a fabkit design file"),
    ],
)
def test_cli_check_bad_design(run_cli, tmp_path, content, message):
    path = tmp_path / "design.npz"
    if content == "npz-missing-keys":
        np.savez(path, u=np.zeros(3))
    elif content is not None:
        path.write_bytes(content)
    code, _, err = run_cli("check", path)
    assert code == 2 and message in err and err.count("\n") == 1
