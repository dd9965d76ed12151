"""solve_batch: candidates marched together get the designs solve() gives each alone."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fabkit.design.solver import solve, solve_batch
from fabkit.errors import FabkitError
from fabkit.problem.spec import Spec, build_spec, spec_from_json
from tests.conftest import EXAMPLES, example_table


def with_eps(spec: Spec, eps: float) -> Spec:
    table = json.loads(spec.to_json())
    table["initial"]["eps"] = [str(eps)] * len(table["initial"]["eps"])
    return spec_from_json(json.dumps(table))


@pytest.mark.slow
@pytest.mark.parametrize(("example", "step", "diagonals"), [("three_shapes.toml", 0.1, 40)])
def test_a_batch_gives_every_candidate_its_own_design(example, step, diagonals):
    """Candidates whose solved windows differ in width (eps 0.45 and 0.55 on Fig. 3): each
    row's window must stay on its own diagonal (a narrower row once ran past the end)."""
    table = example_table(example)
    table["solver"].update(step=step, diagonals=diagonals)
    spec = build_spec(table, EXAMPLES)
    specs = [with_eps(spec, eps) for eps in (0.45, 0.55)]
    batch = solve_batch(specs)
    for candidate, together in zip(specs, batch, strict=True):
        alone = solve(candidate).design
        assert np.array_equal(together.design.valid, alone.valid)
        for key in ("alpha", "beta", "eps", "r", "n"):
            a, b = getattr(together.design, key), getattr(alone, key)
            at = (alone.valid,) if key in ("alpha", "beta") else (slice(None), alone.valid)
            assert np.array_equal(a[at], b[at]), key
    cropped = solve_batch(specs, crop=True)
    assert [int(c.design.valid.sum()) for c in cropped] == [
        int(b.design.valid.sum()) for b in batch
    ]


def test_a_refused_candidate_gives_its_error_and_the_others_their_designs():
    table = example_table("two_shapes.toml")
    table["solver"].update(step=0.1, diagonals=10)
    spec = build_spec(table, EXAMPLES)
    bad = with_eps(spec, 5.0)  # beyond max_strain at the start point
    results = solve_batch([spec, bad])
    assert isinstance(results[1], FabkitError)
    assert np.array_equal(results[0].design.valid, solve(spec).design.valid)
