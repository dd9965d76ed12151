"""A run whose sheet misses a target, and a layered design (``fabkit solve --layers``).

``run --strict`` exits 1 when the sheet misses a target, and its last line says which and
why. ``solve --layers 2`` programs every Fig. 3 target's curvature (a share of the
first-order layering chosen by simulation: tests/test_run_layers.py) and ``check`` judges
the layered design: the wavy sheet formed from all six starts (both on a coarse grid: the
layered run through the printer, at the default grid, is tests/test_run_layers.py).
"""

from __future__ import annotations

import re

import pytest

from fabkit.design.design import Design
from tests.conftest import EXAMPLES

THREE = EXAMPLES / "three_shapes.toml"
TWO = EXAMPLES / "two_shapes.toml"


@pytest.mark.slow
def test_strict_fails_a_run_whose_sheet_misses_a_target(tmp_path, capsys):
    # Fig. 1 (coarse) in one layer: its metric gives both shapes but not their side, so
    # from some starts the sheet ends as a target's mirror image
    from fabkit.cli import main

    out = tmp_path / "one"
    coarse = ["--step", "0.1", "--diagonals", "30"]
    one = ["--layers", "1", "--no-verify", "--strict", "--no-pictures"]
    code = main(["run", str(TWO), "--out", str(out), *coarse, *one])
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert code == 1
    assert last.startswith("done: the sheet as designed does NOT form ")
    assert re.search(r"(sphere|bump) \(\d\.\d\d % RMS, mirror image from \d of 6 starts\)", last)
    assert last.endswith(f"; the design's check passed; see {out}/report.html")


@pytest.mark.slow
def test_solve_layers_writes_a_layered_design_that_check_judges(tmp_path, run_cli):
    out = tmp_path / "d.npz"
    coarse = ["--step", "0.1", "--diagonals", "30"]
    code, text, _ = run_cli("solve", THREE, "--out", out, "--layers", "2", *coarse)
    assert code == 0 and "programmed with every target's curvature" in text
    assert re.search(r"chosen: (100|10)% of the layering", text), text
    assert Design.load(out).layers == 2
    code, text, _ = run_cli("check", out, "--strict")
    assert "(2 layers, " in text and "wavy: formed from all 6 starts" in text, text
    formed = "NOT formed" not in text
    assert code == (0 if formed else 1), text
