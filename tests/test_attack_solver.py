"""Attack rows for the solver's error control: bad solver.tolerance / solver.extrapolate in
a spec, and design files whose error estimate is missing or damaged."""

from __future__ import annotations

import numpy as np
import pytest

from fabkit.design.solver import solve
from fabkit.problem.spec import build_spec
from tests.attack import assert_refused, case
from tests.conftest import EXAMPLES, example_table

FIG1 = (EXAMPLES / "two_shapes.toml").read_text()
COARSE = "[solver]\nstep = 0.1\ndiagonals = 10\n"

CASES = [
    case(
        "solve {tolerance_negative} --out {out}/design.npz",
        "solver.tolerance: expected a positive finite number",
        id="solver-tolerance-negative",
    ),
    case(
        "solve {tolerance_zero} --out {out}/design.npz",
        "solver.tolerance: expected a positive finite number",
        id="solver-tolerance-zero",
    ),
    case(
        "solve {tolerance_infinite} --out {out}/design.npz",
        "solver.tolerance: expected a positive finite number",
        id="solver-tolerance-infinite",
    ),
    case(
        "solve {tolerance_text} --out {out}/design.npz",
        "solver.tolerance: expected a number",
        id="solver-tolerance-text",
    ),
    case(
        "solve {extrapolate_text} --out {out}/design.npz",
        "solver.extrapolate: expected true or false",
        id="solver-extrapolate-text",
    ),
    case(
        "check {inf_error}",
        "'error' must be a non-negative estimate or NaN",
        outputs=(),
        id="solver-design-infinite-error",
    ),
]


@pytest.fixture(scope="module")
def places(tmp_path_factory) -> dict[str, str]:
    folder = tmp_path_factory.mktemp("solver_inputs")
    specs = {
        "tolerance_negative": "tolerance = -0.01\n",
        "tolerance_zero": "tolerance = 0\n",
        "tolerance_infinite": "tolerance = inf\n",
        "tolerance_text": 'tolerance = "small"\n',
        "extrapolate_text": 'extrapolate = "yes"\n',
    }
    paths = {}
    for name, line in specs.items():
        old = "[solver]\nstep = 0.05\ndiagonals = 200\n"
        assert old in FIG1
        text = FIG1.replace(old, COARSE + line)
        path = folder / f"{name}.toml"
        path.write_text(text)
        paths[name] = str(path)
    table = example_table("two_shapes.toml")
    table["solver"].update(step=0.1, diagonals=10)
    design = solve(build_spec(table, EXAMPLES)).design
    design.save(folder / "design.npz")
    arrays = dict(np.load(folder / "design.npz"))
    arrays["error"] = np.where(arrays["valid"], np.inf, arrays["error"])
    np.savez(folder / "inf_error.npz", **arrays)
    paths["inf_error"] = str(folder / "inf_error.npz")
    return paths


@pytest.mark.parametrize("bad", CASES)
def test_bad_solver_input_is_one_line_and_writes_nothing(bad, places, run_cli, tmp_path):
    assert_refused(bad, places, tmp_path, run_cli)
