"""Attack rows of the sheet as fabricated's simulation options (``fabkit verify``)."""

from __future__ import annotations

import pytest

from tests.attack import assert_refused, case

CASES = [
    case(
        "verify {missing} {missing} --smoothing -1",
        "--smoothing: expected a finite number >= 0",
        "got -1",
        id="fabricated-negative-smoothing",
    ),
    case(
        "verify {missing} {missing} --smoothing nan",
        "--smoothing",
        "finite",
        id="fabricated-nan-smoothing",
    ),
]


@pytest.mark.parametrize("bad", CASES)
def test_bad_simulation_option_is_one_line_and_writes_nothing(bad, run_cli, tmp_path):
    assert_refused(bad, {}, tmp_path, run_cli)
