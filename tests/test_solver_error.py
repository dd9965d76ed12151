"""Error control (issue 17): every solved point's error estimate, kept in design.npz; points
over solver.tolerance dropped with their quarter-plane of influence and reported; and
`fabkit check` passing on the designs `fabkit solve` writes, hard cases included."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fabkit.design.check import check_design
from fabkit.design.design import Design
from fabkit.design.solver import REASONS, solve
from fabkit.errors import FabkitError
from fabkit.problem.spec import build_spec
from tests.conftest import EXAMPLES, coarse_design, example_table

ERROR_STOP = "error estimate beyond solver.tolerance"
NO_CONTROL = 1e9
"""A tolerance no estimate reaches: the solve as it was before error control."""

HARD = {
    # the u-curve is a circle of radius 1/3: b = 3, so alpha falls to 0 near v = 1/3
    "defect-near-start": (
        "two_shapes.toml",
        {"u_curve": ["sin(3*t)/3", "(1 - cos(3*t))/3"]},
        {"diagonals": 40},
    ),
    # the v-curve is a circle of radius 1/3: s = 3, so beta grows fast along u
    "fast-growth-of-beta": (
        "two_shapes.toml",
        {"v_curve": ["(1 - cos(3*t))/3", "sin(3*t)/3"]},
        {"diagonals": 40},
    ),
    # baromorph law lambda2 = 1 + P eps with a curved v-curve (radius 1/2)
    "baromorph": (
        "baromorph.toml",
        {"v_curve": ["(1 - cos(2*t))/2", "sin(2*t)/2"]},
        {"diagonals": 60},
    ),
    # Fig. 1 on a coarse grid: the march's error is large near the strain stops
    "fig1-coarse": ("two_shapes.toml", {}, {"step": 0.1, "diagonals": 20}),
}


def hard_table(name: str, **solver) -> dict:
    example, initial, settings = HARD[name]
    table = example_table(example)
    table["initial"].update(initial)
    table["solver"].update(settings, **solver)
    return table


def solved(table: dict, **solver):
    table["solver"].update(solver)
    return solve(build_spec(table, EXAMPLES))


@pytest.mark.slow
@pytest.mark.parametrize("name", HARD)
def test_hard_case_fails_check_without_error_control_and_passes_with_it(name):
    before = solved(hard_table(name, tolerance=NO_CONTROL))
    assert not check_design(before.design).passed
    assert ERROR_STOP not in {s.reason for s in before.stops}
    after = solved(hard_table(name))
    report = check_design(after.design)
    assert report.passed, report.table()
    assert ERROR_STOP in {s.reason for s in after.stops}
    kept = after.design.valid.sum() / before.design.valid.sum()
    assert 0.3 < kept < 1, kept
    # error control only removes points: what is kept is what was solved before
    assert not (after.design.valid & ~before.design.valid).any()
    same = after.design.valid
    assert np.array_equal(after.design.r[:, same], before.design.r[:, same])


def test_error_key_is_saved_and_loaded(fig1, tmp_path):
    design = solved(fig1, step=0.1, diagonals=20).design
    error = design.error
    assert error.shape == design.valid.shape
    assert np.isfinite(error[design.valid]).all() and np.isnan(error[~design.valid]).all()
    assert (error[design.valid] >= 0).all() and (error[design.valid] <= 1e-2).all()
    assert error[design.valid].max() > 0  # an estimate, not a placeholder
    path = tmp_path / "design.npz"
    design.save(path)
    with np.load(path, allow_pickle=False) as data:
        assert "error" in data.files
    assert np.array_equal(Design.load(path).error, error, equal_nan=True)


def test_error_estimate_is_second_order(fig1):
    """Halving the step divides the Richardson difference of a second-order march by ~4."""
    errors = []
    for step in (0.1, 0.05):
        table = json.loads(json.dumps(fig1))
        design = solved(table, step=step, diagonals=int(round(1.2 / step)), tolerance=1.0).design
        every = int(round(0.1 / step))
        centre = len(design.u) // 2
        window = slice(centre - 6 * every, centre + 6 * every + 1, every)  # |u|, |v| <= 0.6
        errors.append(np.where(design.valid, design.error, np.nan)[window, window])
    with np.errstate(invalid="ignore"):
        both = (errors[0] > 0) & (errors[1] > 0)  # not the origin, where both are exact
    assert both.sum() > 40
    ratio = np.median(errors[0][both] / errors[1][both])
    assert 3.0 < ratio < 5.5, ratio


@pytest.mark.slow
def test_tight_tolerance_stops_and_drops_quarter_planes(fig1):
    loose = solved(json.loads(json.dumps(fig1)), step=0.1, diagonals=20).design
    tight = solved(fig1, step=0.1, diagonals=20, tolerance=1e-3)
    design = tight.design
    assert not (design.valid & ~loose.valid).any() and design.valid.sum() < loose.valid.sum()
    assert (design.error[design.valid] <= 1e-3).all()
    stops = [s for s in tight.stops if s.reason == ERROR_STOP]
    assert stops and REASONS[10] == ERROR_STOP
    centre = len(design.u) // 2
    for stop in stops:
        i = centre + int(round(stop.u / design.step))
        j = centre + int(round(stop.v / design.step))
        assert loose.valid[i, j] and loose.error[i, j] > 1e-3
        # the stop's quarter-plane (away from the axes, within its quadrant) is dropped
        rows = slice(i, None) if stop.u >= 0 else slice(0, i + 1)
        cols = slice(j, None) if stop.v >= 0 else slice(0, j + 1)
        assert not design.valid[rows, cols].any()
        # and no other stop influences it: its solved neighbours towards the axes are kept
        for di, dj in ((-np.sign(stop.u), 0), (0, -np.sign(stop.v))):
            ni, nj = i + int(di), j + int(dj)
            if (ni, nj) != (i, j) and loose.valid[ni, nj]:
                assert design.valid[ni, nj], (stop, ni, nj)
    # every dropped point is over tolerance or in the quarter-plane of a stop
    lost = loose.valid & ~design.valid
    explained = loose.error > 1e-3
    for stop in stops:
        i = centre + int(round(stop.u / design.step))
        j = centre + int(round(stop.v / design.step))
        rows = slice(i, None) if stop.u >= 0 else slice(0, i + 1)
        cols = slice(j, None) if stop.v >= 0 else slice(0, j + 1)
        explained[rows, cols] = True
    assert not (lost & ~explained).any()


def test_tolerance_key(fig1):
    spec = build_spec(fig1, EXAMPLES)
    assert spec.solver.tolerance == 1e-2
    assert json.loads(spec.to_json())["solver"]["tolerance"] == 1e-2
    fig1["solver"]["tolerance"] = 0.05
    assert build_spec(fig1, EXAMPLES).with_solver(step=0.1).solver.tolerance == 0.05
    fig1["solver"]["tolerance"] = -1
    with pytest.raises(FabkitError, match="solver.tolerance"):
        build_spec(fig1, EXAMPLES)


@pytest.mark.slow
def test_extrapolate_false_keeps_the_step_h_march_with_its_estimate(fig1):
    richardson = solved(json.loads(json.dumps(fig1)), step=0.1, diagonals=20).design
    plain = solved(fig1, step=0.1, diagonals=20, extrapolate=False).design
    assert json.loads(plain.spec)["solver"]["extrapolate"] is False
    both = plain.valid & richardson.valid
    assert both.sum() > 100
    assert not np.allclose(plain.alpha[both], richardson.alpha[both], rtol=0, atol=1e-12)
    assert np.allclose(plain.error[both], richardson.error[both], rtol=0, atol=0)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("example", "options"),
    [
        ("two_shapes.toml", []),
        ("three_shapes.toml", ["--diagonals", "40"]),
        ("baromorph.toml", []),
    ],
)
def test_fabkit_check_passes_on_what_fabkit_solve_writes(run_cli, tmp_path, example, options):
    out = tmp_path / "design.npz"
    code, text, _ = run_cli("solve", EXAMPLES / example, "--out", out, *options)
    assert code == 0, text
    code, text, _ = run_cli("check", out, "--no-simulate")  # the residuals' check
    assert code == 0, text
    summary = json.loads(out.with_suffix(".json").read_text())
    assert summary["check"]["passed"]


def test_a_design_file_from_before_the_error_key_still_reads(tmp_path, run_cli):
    """design.npz written before the solver kept its error estimate: 'error' reads as NaN
    (not estimated) and the file checks as before."""
    coarse_design(diagonals=20).save(tmp_path / "new.npz")
    with np.load(tmp_path / "new.npz", allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files if k not in ("error", "format")}
    np.savez_compressed(tmp_path / "old.npz", **arrays)
    design = Design.load(tmp_path / "old.npz")
    assert np.isnan(design.error).all() and design.valid.any()
    code, out, err = run_cli("check", tmp_path / "old.npz")
    assert code == 0, err
