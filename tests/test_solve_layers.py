"""The Fig. 3 sheet in one layer and as a layered design (``fabkit solve --layers``).

Programmed by its metric alone, the sheet misses the wavy target (its mirror image from
some starts, farther than the limit from all), and ``run --strict`` exits 1 saying so;
``solve --layers 2`` programs the wavy sheet's curvature and ``check`` judges the layered
design: the wavy sheet formed from all six starts. (tests/test_run_layers.py runs the
layered sheet through the printer, apart so that the two run on both workers.)
"""

from __future__ import annotations

import re

import pytest

from fabkit.design.design import Design
from tests.conftest import EXAMPLES

THREE = EXAMPLES / "three_shapes.toml"


@pytest.mark.slow
def test_one_layer_names_the_wavy_sheet_and_strict_fails(tmp_path, capsys):
    from fabkit.cli import main

    out = tmp_path / "one"
    code = main(["run", str(THREE), "--out", str(out), "--no-verify", "--strict"])
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert code == 1
    assert last.startswith("done: the sheet as designed does NOT form ")
    assert re.search(r"wavy \(5\.\d\d % RMS, mirror image from \d of 6 starts\)", last), last
    assert last.endswith(f"; the design's check passed; see {out}/report.html")


@pytest.mark.slow
def test_solve_layers_writes_a_layered_design_that_check_judges(tmp_path, run_cli):
    out = tmp_path / "d.npz"
    code, text, _ = run_cli("solve", THREE, "--out", out, "--layers", "2", "--diagonals", "60")
    assert code == 0 and "programmed with the curvature of the targets the metric misses" in text
    assert Design.load(out).layers == 2
    code, text, _ = run_cli("check", out, "--strict")
    assert "(2 layers, " in text and "wavy: formed from all 6 starts" in text, text
    formed = "NOT formed" not in text  # the sphere's and the face's sides: not programmed
    assert code == (0 if formed else 1), text
