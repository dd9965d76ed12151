"""Attack rows for the solver's error control: bad solver.tolerance / solver.extrapolate in
a spec, and design files whose error estimate is missing or damaged."""

from __future__ import annotations

import numpy as np
import pytest

from tests.attack import assert_refused, case, edited, write_texts
from tests.conftest import EXAMPLES, coarse_design

pytestmark = pytest.mark.filterwarnings("error")  # a warning would be a second line on stderr

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
        "solver.tolerance: expected a positive finite number",
        "got 'small' (a string)",
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
def places(folder) -> dict[str, str]:
    lines = {
        "tolerance_negative": "tolerance = -0.01\n",
        "tolerance_zero": "tolerance = 0\n",
        "tolerance_infinite": "tolerance = inf\n",
        "tolerance_text": 'tolerance = "small"\n',
        "extrapolate_text": 'extrapolate = "yes"\n',
    }
    solver = "[solver]\nstep = 0.05\ndiagonals = 200\n"
    specs = {name: edited(FIG1, solver, COARSE + line) for name, line in lines.items()}
    paths = write_texts(folder, specs, ".toml")
    coarse_design(diagonals=10).save(folder / "design.npz")
    arrays = dict(np.load(folder / "design.npz"))
    arrays["error"] = np.where(arrays["valid"], np.inf, arrays["error"])
    np.savez(folder / "inf_error.npz", **arrays)
    paths["inf_error"] = str(folder / "inf_error.npz")
    return paths


@pytest.mark.parametrize("bad", CASES)
def test_bad_solver_input_is_one_line_and_writes_nothing(bad, places, run_cli, tmp_path):
    assert_refused(bad, places, tmp_path, run_cli)
