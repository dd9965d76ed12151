"""The solver's designs agree with the previous algorithm's.

``tests/data/solver_reference.npz`` holds coarse solves of Fig. 1 (step 0.1), Fig. 3 (step
0.2) and the baromorph (step 0.1), 24 diagonals each, written by the solver as it was at
commit 230450e: the two marches one after the other, quadrant by quadrant, assembled on
the full grid (before error control and the speed work of issue 21). Keys
``<case>_<variable>`` for valid, alpha, beta, eps, r, n.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fabkit.design.solver import solve
from fabkit.problem.spec import build_spec
from tests.conftest import EXAMPLES, example_table

REFERENCE = Path(__file__).parent / "data" / "solver_reference.npz"
REFERENCE_TOLERANCE = 1e-9
"""numpy's vectorised exp and sin differ in their last bit between CPU instruction sets
(the reference was written on one, an AMD EPYC without AVX-512 gives 1 ulp elsewhere), and
the march carries that to 2e-11 on Fig. 3; a change of algorithm moves far more."""
CASES = {
    "fig1": ("two_shapes.toml", 0.1),
    "fig3": ("three_shapes.toml", 0.2),
    "baro": ("baromorph.toml", 0.1),
}


def coarse(name: str, **solver):
    example, step = CASES[name]
    table = example_table(example)
    table["solver"].update(step=step, diagonals=24, **solver)
    return solve(build_spec(table, EXAMPLES)).design


@pytest.mark.parametrize("name", CASES)
def test_same_design_as_the_previous_algorithm(name):
    design = coarse(name, tolerance=1e9)  # no point over tolerance: nothing dropped
    with np.load(REFERENCE, allow_pickle=False) as reference:
        assert np.array_equal(design.valid, reference[f"{name}_valid"])
        for key in ("alpha", "beta", "eps", "r", "n"):
            np.testing.assert_allclose(
                getattr(design, key),
                reference[f"{name}_{key}"],
                rtol=REFERENCE_TOLERANCE,
                atol=REFERENCE_TOLERANCE,
            )


@pytest.mark.slow
@pytest.mark.parametrize("name", CASES)
def test_error_control_only_removes_points(name):
    design = coarse(name)
    with np.load(REFERENCE, allow_pickle=False) as reference:
        valid = reference[f"{name}_valid"]
        assert not (design.valid & ~valid).any()
        assert design.valid.sum() >= 0.25 * valid.sum()  # Fig. 3 at twice its step: 28 %
        kept = design.valid
        np.testing.assert_allclose(
            design.alpha[kept],
            reference[f"{name}_alpha"][kept],
            rtol=REFERENCE_TOLERANCE,
            atol=REFERENCE_TOLERANCE,
        )
        np.testing.assert_allclose(
            design.r[:, kept],
            reference[f"{name}_r"][:, kept],
            rtol=REFERENCE_TOLERANCE,
            atol=REFERENCE_TOLERANCE,
        )
