"""Spec validation: every refusal is a one-line FabkitError naming the problem."""

from __future__ import annotations

import numpy as np
import pytest

from fabkit.errors import FabkitError
from fabkit.problem.material import ACROSS, ALONG
from fabkit.problem.solver_settings import MAX_SOLVER_BYTES, solver_memory
from fabkit.problem.spec import build_spec, load_spec
from tests.attack import run_bounded
from tests.conftest import EXAMPLES


def refuse(table: dict, match: str) -> str:
    with pytest.raises(FabkitError, match=match) as info:
        build_spec(table, EXAMPLES)
    assert "\n" not in str(info.value)
    return str(info.value)


def test_examples_load_and_classify():
    assert load_spec(EXAMPLES / "two_shapes.toml").classes == (ACROSS,)
    assert load_spec(EXAMPLES / "three_shapes.toml").classes == (ALONG, ACROSS)


def test_unknown_keys(fig1):
    fig1["material"]["lambda3"] = "1"
    refuse(fig1, r"^spec: material\.lambda3: unknown key \(allowed: features, lambda1")


def test_unknown_section(fig1):
    fig1["extra"] = {}
    refuse(fig1, r"^spec: extra: unknown key \(allowed: initial, material")


def test_unknown_geometry_key(fig1):
    fig1["surfaces"][1]["geometry"]["radious"] = 1
    refuse(fig1, r"surfaces\[1\]\.geometry\.radious: unknown key \(allowed: kind, radius\)")


def test_unknown_surface_kind(fig1):
    fig1["surfaces"][2]["geometry"] = {"kind": "torus"}
    refuse(fig1, r"surfaces\[2\]\.geometry\.kind: expected one of plane, .*, got 'torus'")


def test_wrong_number_of_surfaces(fig1):
    fig1["surfaces"].pop()
    refuse(fig1, r"surfaces: expected 3 \[\[surfaces\]\] tables .*, got an array of 2 tables")


def test_stimulus_of_wrong_length(fig1):
    fig1["surfaces"][1]["stimulus"] = [1, 2]
    refuse(fig1, r"surfaces\[1\].stimulus: expected one value per stimulus")


@pytest.mark.parametrize("key", ["start", "director"])
@pytest.mark.parametrize("value", [[1.0], [1.0, 2.0, 3.0], "x", [1.0, "a"]])
def test_start_and_director_must_be_two_vectors(fig1, key, value):
    fig1["surfaces"][1][key] = value
    refuse(fig1, rf"surfaces\[1\].{key}")


def test_curves_must_meet(fig1):
    fig1["initial"]["v_curve"] = ["1 + 2*(1 - cos(t))", "2*sin(t)"]
    refuse(fig1, "must meet at t = 0")


def test_curves_must_be_perpendicular(fig1):
    fig1["initial"]["v_curve"] = ["t", "t"]
    refuse(fig1, "must be perpendicular")


def test_v_curve_must_turn_counter_clockwise(fig1):
    fig1["initial"]["v_curve"] = ["0", "-t"]
    refuse(fig1, "counter-clockwise")


def test_stretch_must_be_one_on_the_flat_sheet(fig1):
    fig1["surfaces"][0]["stimulus"] = [0.5]
    refuse(fig1, r"lambda2 must equal 1 at the flat sheet's stimulus")


def test_start_outside_chart(fig1):
    fig1["surfaces"][1]["start"] = [4.0, 0.0]
    refuse(fig1, r"surfaces\[1\]\.start: expected a point inside the sphere chart, got \[4")


def test_feature_acting_both_ways_is_not_hyperbolic(fig1):
    fig1["material"]["lambda1"] = "exp(L*eps/2)"
    refuse(fig1, "not hyperbolic")


def test_feature_acting_neither_way(fig1):
    fig1["material"]["lambda2"] = "exp(L)"
    refuse(fig1, "changes neither")


def test_bad_expression_in_spec_names_the_field(fig1):
    fig1["surfaces"][2]["geometry"]["z"] = "__import__('os')"
    refuse(fig1, r"surfaces\[2\].geometry.z: calling")


def test_initial_series_per_feature(fig1):
    fig1["initial"]["eps"] = ["1", "2"]
    refuse(fig1, "initial.eps: expected 1 expression")


def test_solver_settings(fig1):
    fig1["solver"]["quadrants"] = [[1, 2]]
    refuse(fig1, "solver.quadrants")
    fig1["solver"]["quadrants"] = "all"
    fig1["solver"]["step"] = -1
    refuse(fig1, "solver.step")


def test_flat_sheet_must_be_a_plane(fig1):
    fig1["surfaces"][0]["geometry"] = {"kind": "sphere"}
    refuse(fig1, 'surfaces\\[0\\].geometry: expected kind = "plane"')


def test_round_trip_through_json(fig3):
    from fabkit.problem.spec import spec_from_json

    spec = build_spec(fig3, EXAMPLES)
    again = spec_from_json(spec.to_json())
    assert again.to_json() == spec.to_json()
    assert again.classes == spec.classes


def test_cli_summary(run_cli):
    code, out, _ = run_cli("spec", EXAMPLES / "two_shapes.toml")
    assert code == 0
    assert "eps: acts across the director" in out
    lines = {line.split(":")[0].strip(): line for line in out.splitlines()}
    assert "K = 1 at start" in lines["[1] sphere"]
    assert "K = 1 at start" in lines["[2] bump"]
    assert "p = 1/2 along the v-curve" in out


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (None, "does not exist"),
        ("[material\nfeatures = 1", "not valid TOML"),
        ('[material]\nfeatures = ["eps"]\n', "surfaces: missing (expected [[surfaces]] tables)"),
        (b"\xff\xfe\x00garbage", "cannot read spec file"),
    ],
)
def test_cli_bad_input_is_one_line_exit_2(run_cli, tmp_path, content, message):
    path = tmp_path / "spec.toml"
    if isinstance(content, bytes):
        path.write_bytes(content)
    elif content is not None:
        path.write_text(content)
    code, out, err = run_cli("spec", path)
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and message in err and err.startswith("fabkit: error:")


def test_version(run_cli):
    with pytest.raises(SystemExit) as info:
        run_cli("--version")
    assert info.value.code == 0


def test_surface_names_must_be_safe_file_names(fig1):
    fig1["surfaces"][1]["name"] = "x/../../name"
    refuse(fig1, r"surfaces\[1\].name: name 'x/../../name' must be")


@pytest.mark.parametrize(
    ("geometry", "key"),
    [
        ({"kind": "graph", "z": "log(x)"}, r"surfaces\[2\].geometry.z"),
        ({"kind": "graph", "z": "sqrt(x - 100)"}, r"surfaces\[2\].geometry.z"),
        ({"kind": "metric", "g11": "1", "g22": "1/a"}, r"surfaces\[2\].geometry.g22"),
        ({"kind": "parametric", "x": "a", "y": "b", "z": "a*log(b)"}, r"geometry.z"),
    ],
)
def test_geometry_must_be_finite_at_the_start(fig1, geometry, key):
    fig1["surfaces"][2]["geometry"] = geometry
    message = refuse(fig1, key + r": not finite at the start point \(\w+ = 0, \w+ = 0\)")
    assert geometry.get("z", geometry.get("g22")) in message


def test_a_height_defined_on_part_of_the_plane_ends_the_design_there(fig1):
    """NaN away from the start is the edge of the surface: the solver stops there."""
    fig1["surfaces"][2]["geometry"] = {"kind": "graph", "z": "sqrt(0.09 - x**2 - y**2)"}
    fig1["solver"].update(step=0.02, diagonals=30)
    from fabkit.design.solver import solve

    solution = solve(build_spec(fig1, EXAMPLES))
    assert solution.design.valid.sum() > 100
    assert any(stop.reason == "non-finite values" for stop in solution.stops)
    r = solution.design.r[2][solution.design.valid]
    assert np.all(np.hypot(r[:, 0], r[:, 1]) < 0.3)


def test_material_must_be_finite_at_the_start_point(fig1):
    fig1["material"]["lambda2"] = "exp(L*eps) + log(1 - L/2)"
    refuse(fig1, r"material.lambda2: not finite at the start point.*eps = 0.5, L = 2")


def test_initial_data_must_be_finite_at_t_0(fig1):
    fig1["initial"]["u_curve"] = ["t", "sqrt(-t**2)"]
    refuse(fig1, r"initial.u_curve: not finite at t = 0")
    fig1["initial"]["u_curve"] = ["t", "0"]
    fig1["initial"]["eps"] = ["0.5 + sqrt(t)"]
    refuse(fig1, r"initial.eps\[0\]: not finite at t = 0 on the v_curve")


def test_classification_needs_no_computer_algebra(fig1):
    """Identically zero derivatives are recognised by value, in milliseconds (simplify
    took seconds to minutes on such laws)."""
    fig1["material"]["lambda1"] = "1 + L*(sin(eps)**2 + cos(eps)**2 - 1)"
    fig1["material"]["lambda2"] = "(1 + L*eps)**1000"
    (spec, seconds) = run_bounded(lambda: build_spec(fig1, EXAMPLES), seconds=5)
    assert spec.classes == (ACROSS,)
    fig1["material"]["lambda2"] = "1 + L*((1 + eps)**2 - 1 - 2*eps - eps**2)"
    refuse(fig1, "changes neither lambda1 nor lambda2")


@pytest.mark.slow
def test_solver_memory_is_estimated_before_solving(fig1):
    import tracemalloc

    from fabkit.design.solver import solve

    fig1["solver"].update(step=0.002, diagonals=40)
    spec = build_spec(fig1, EXAMPLES)
    tracemalloc.start()
    try:
        solve(spec)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    estimate = solver_memory(spec.solver, 1)
    assert peak <= estimate <= 1.5 * peak


def test_grid_bounds_name_the_option(fig1):
    fig1["solver"]["diagonals"] = 20000
    message = refuse(fig1, r"solver.diagonals 20000: the solver would need about [\d,]+ GiB")
    assert f"more than the {MAX_SOLVER_BYTES / 2**30:g} GiB limit" in message
    most = int(message.split("use at most about ")[1].split()[0])
    fig1["solver"]["diagonals"] = most
    spec = build_spec(fig1, EXAMPLES)
    assert solver_memory(spec.solver, 1) <= MAX_SOLVER_BYTES
    with pytest.raises(FabkitError, match="--diagonals 20000: the solver would need"):
        spec.with_solver(diagonals=20000)
    with pytest.raises(FabkitError, match="--step 1e-09: below 1e-06"):
        spec.with_solver(step=1e-9)
    with pytest.raises(FabkitError, match="the grid would reach 2e"):
        spec.with_solver(step=1e5, diagonals=20)
    assert spec.with_solver(step=0.1, diagonals=30).solver.diagonals == 30
