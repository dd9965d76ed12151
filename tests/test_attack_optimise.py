"""Attack rows for ``fabkit optimise``: keys that vary nothing, bad ranges and tables, bad
budgets and options, and checkpoints that are not this search's. Each is refused in one
line before any work, writing nothing."""

from __future__ import annotations

import json

import pytest

from fabkit.optimise.search import CHECKPOINT_FORMAT
from fabkit.optimise.tomlout import dumps
from tests.attack import assert_refused, case, write_texts
from tests.conftest import example_table

pytestmark = pytest.mark.filterwarnings("error")  # a warning would be a second line on stderr

OPT = "optimise {fig1} --out {out}/best.toml"
VARY = "--vary initial.eps[0]=0.2:0.7"

BAD_VARY = [
    # --vary KEY=LO:HI, what the refusal names, the row's id
    (
        "initial.colour[0]=0:1",
        ("not a key the search can vary", "initial.colour[0]"),
        "unknown_key",
    ),
    ("initial.eps[2]=0:1", ("the spec has no", "initial.eps[2]"), "no_such_index"),
    (
        "surfaces.torus.start[0]=0:1",
        ("no target surface", "torus", "targets: sphere, bump"),
        "unknown_surface",
    ),
    ("surfaces.flat.director[0]=0:1", ("no target surface", "flat"), "flat_sheet_start"),
    ("initial.eps[0]=0.7:0.2", ("LO must be below HI",), "range_reversed"),
    ("initial.eps[0]=0.2:inf", ("expected KEY=LO:HI",), "range_infinite"),
    ("initial.eps[0]", ("expected KEY=LO:HI",), "range_missing"),
]
CHECKPOINTS = {
    # file (a placeholder), its text, what the refusal says, the row's id
    "other_checkpoint": (
        json.dumps(
            {"fabkit_optimise": CHECKPOINT_FORMAT, "fingerprint": "0" * 64, "evaluations": []}
        ),
        "belongs to another search",
        "of_another_search",
    ),
    "not_checkpoint": (
        json.dumps({"evaluations": []}),
        "not a fabkit optimise checkpoint",
        "not_one",
    ),
    "garbage": ("{ not json", "not valid JSON", "garbage"),
}

CASES = [
    case(
        f"{OPT} --curvature-median 0",
        "expected a positive finite number",
        "--curvature-median 0",
        id="optimise_tolerance_zero",
    ),
    *[case(f"{OPT} --vary {vary}", *says, id=f"optimise_{name}") for vary, says, name in BAD_VARY],
    case(OPT, "nothing to vary", id="optimise_nothing_to_vary"),
    case(
        "optimise {curve_in_t} --out {out}/best.toml --vary initial.eps[0]=0:1",
        "depends on t",
        id="optimise_key_depends_on_t",
    ),
    case(
        "optimise {value_outside} --out {out}/best.toml",
        "expected a number in [",
        "optimise.parameters.R.value",
        id="optimise_value_outside_range",
    ),
    case(
        "optimise {min_above_max} --out {out}/best.toml",
        "expected a number below max",
        "optimise.parameters.R.min",
        id="optimise_table_range_reversed",
    ),
    case(
        "optimise {bad_name} --out {out}/best.toml",
        "expected a parameter name like",
        "optimise.parameters.sin",
        id="optimise_parameter_name",
    ),
    case(
        "optimise {bad_objective} --out {out}/best.toml",
        "optimise.objective: expected one of",
        id="optimise_unknown_objective",
    ),
    case(
        "optimise {unknown_table_key} --out {out}/best.toml",
        "unknown key",
        "budget",
        id="optimise_unknown_table_key",
    ),
    case(f"{OPT} {VARY} --generations 0", "expected a positive integer", id="optimise_generations"),
    case(f"{OPT} {VARY} --batch -1", "expected a positive integer", id="optimise_batch"),
    case(
        f"optimise {{fig1}} --out {{out}}/best.json {VARY}",
        "the best spec is written as TOML",
        id="optimise_out_not_toml",
    ),
    case(
        f"{OPT} {VARY} --scale 0.5",
        "applies with --machine or --process only",
        id="optimise_scale_without_process",
    ),
    case(
        f"{OPT} {VARY} --machine marlin_diw_pneumatic",
        "give --scale",
        id="optimise_process_without_scale",
    ),
    *[
        case(f"{OPT} {VARY} --checkpoint {{{name}}}", says, id=f"optimise_checkpoint_{suffix}")
        for name, (_, says, suffix) in CHECKPOINTS.items()
    ],
]


@pytest.fixture(scope="module")
def places(folder) -> dict[str, str]:
    base = example_table("two_shapes.toml")
    base["solver"] = {"step": 0.1, "diagonals": 10, "quadrants": "all"}
    radius = {"R": {"value": 2.0, "min": 1.0, "max": 4.0}}
    tables = {
        "fig1": {},
        "curve_in_t": {"initial": {**base["initial"], "eps": ["1/2 + t/10"]}},
        "value_outside": {"optimise": {"parameters": {"R": {"value": 5.0, "min": 1, "max": 4}}}},
        "min_above_max": {"optimise": {"parameters": {"R": {"value": 2.0, "min": 4, "max": 1}}}},
        "bad_name": {"optimise": {"parameters": {"sin": radius["R"]}}},
        "bad_objective": {"optimise": {"objective": "volume", "parameters": radius}},
        "unknown_table_key": {"optimise": {"budget": 3, "parameters": radius}},
    }
    specs = {name: dumps({**base, **change}) for name, change in tables.items()}
    checkpoints = {name: text for name, (text, _, _) in CHECKPOINTS.items()}
    return {**write_texts(folder, specs, ".toml"), **write_texts(folder, checkpoints, ".json")}


@pytest.mark.parametrize("bad", CASES)
def test_bad_optimise_input_is_one_line_and_writes_nothing(bad, places, run_cli, tmp_path):
    assert_refused(bad, places, tmp_path, run_cli)
