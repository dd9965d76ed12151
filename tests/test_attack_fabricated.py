"""Attack rows of the sheet as fabricated's simulation (``fabkit verify``, and the verdict of
``fabkit check`` and ``fabkit run`` on the sheet as designed)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tests.attack import assert_refused, case
from tests.conftest import coarse_design

pytestmark = pytest.mark.filterwarnings("error")  # a warning would be a second line on stderr

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
    # lambda2 = exp(L eps) = 2e-9 at the bump's L = 2: the squared length of an edge across
    # the director is lost in rounding (it came out below zero: a numpy warning, then
    # 'no face of the design's mesh lies on the sheet as made')
    case(
        "check {collapsing}",
        "the material makes no metric",
        "under the stimulus of 'bump': lambda1 = 1, lambda2 = 2.06e-09 at eps = -10",
        id="fabricated-stretch-collapses",
    ),
    case(
        "check {overflowing}",
        "the material makes no metric",
        "1 of ",  # one point is enough
        "lambda2 = inf at eps = 800",
        id="fabricated-stretch-overflows",
    ),
]


@pytest.fixture(scope="module")
def places(folder) -> dict[str, str]:
    """Designs of Fig. 1 whose features leave the material law's range: eps = -10 at every
    point, eps = 800 at one."""
    design = coarse_design()
    everywhere = np.where(design.valid, -10.0, np.nan)[None]
    one = design.eps.copy()
    one[(0, *np.argwhere(design.valid)[len(np.argwhere(design.valid)) // 2])] = 800.0
    paths = {}
    for name, eps in (("collapsing", everywhere), ("overflowing", one)):
        paths[name] = str(folder / f"{name}.npz")
        dataclasses.replace(design, eps=eps).save(paths[name])
    return paths


@pytest.mark.parametrize("bad", CASES)
def test_bad_simulation_input_is_one_line_and_writes_nothing(bad, places, run_cli, tmp_path):
    assert_refused(bad, places, tmp_path, run_cli)
