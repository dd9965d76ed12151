"""``fabkit run`` with no ``--layers`` chooses the layers (issue 35): two on a printer,
since one layer cannot program a target's side, one where the route makes one; the choice
is on the run's first line and in report.json's notice. ``--layers K`` decides when given.
The verdicts of the layered runs are tests/test_run_layers.py's."""

from __future__ import annotations

import json

import pytest

from fabkit.design.design import Design
from tests.conftest import EXAMPLES

QUICK = ("--step", "0.1", "--diagonals", "30", "--size", "12", "--no-verify", "--no-simulate",
         "--no-pictures")  # fmt: skip
CHOSEN = "LAYERS CHOSEN: 2 layers of 0.3 mm (no --layers)"


def ran(run_cli, out, *options) -> tuple[str, dict]:
    """A quick run of Fig. 1: its first printed line and its report.json."""
    code, text, err = run_cli("run", EXAMPLES / "two_shapes.toml", "--out", out, *QUICK, *options)
    assert code == 0, err
    return text.splitlines()[0].strip(), json.loads((out / "report.json").read_text())


@pytest.mark.slow
def test_a_printer_gets_two_layers_and_the_first_line_says_so(run_cli, tmp_path):
    first, report = ran(run_cli, tmp_path / "auto")
    assert CHOSEN in first and CHOSEN in report["notice"]
    assert Design.load(tmp_path / "auto" / "design.npz").layers == 2
    assert ";LAYER_COUNT:2" in (tmp_path / "auto" / "sheet.gcode").read_text()


@pytest.mark.slow
def test_layers_given_decide_and_say_nothing_of_a_choice(run_cli, tmp_path):
    first, report = ran(run_cli, tmp_path / "one", "--layers", "1")
    assert "LAYERS CHOSEN" not in first and "LAYERS CHOSEN" not in report["notice"]
    assert Design.load(tmp_path / "one" / "design.npz").layers == 1


@pytest.mark.slow
def test_a_laser_writer_makes_one_layer_and_says_no_side_is_programmed(run_cli, tmp_path):
    first, report = ran(run_cli, tmp_path / "laser", "--machine", "dmd_photoalign")
    assert "ONE LAYER: laser writers such as dmd_photoalign make one layer" in first
    assert "no target's side is programmed" in report["notice"]
    assert Design.load(tmp_path / "laser" / "design.npz").layers == 1
