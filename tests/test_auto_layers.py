"""``fabkit run`` with no ``--layers`` chooses the layers (issue 35): two or more on a
printer, since one layer cannot program a target's side (the counts its size allows,
judged as designed: the thickest sheet clear of every limit by the print's margin), one
where the route makes one; the choice is on the run's first line and in report.json's
notice. ``--layers K`` decides when given. The verdicts of the layered runs are
tests/test_run_layers.py's."""

from __future__ import annotations

import json

import pytest

from fabkit.design.design import Design
from fabkit.mechanics.verdict import Shape, Verdict
from fabkit.run.inputs import layer_choices
from fabkit.run.solve import PRINT_MARGIN, chosen_layers
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


def test_a_run_judges_the_layer_counts_that_keep_the_sheet_thin_for_its_size():
    assert layer_choices(20, 0.3) == (2,)  # 0.9 mm would be 1/22 of 20 mm
    assert layer_choices(40, 0.3) == (2, 3, 4)
    assert layer_choices(60, 0.3) == (2, 3, 4, 5)
    assert layer_choices(5, 0.3) == (2,)  # at least the fewest that program a side


def _sheet(layers: int, *rms: float) -> Verdict:
    shapes = tuple(Shape(f"t{i}", r, 2 * r, False, True, 0.03) for i, r in enumerate(rms))
    return Verdict("as designed", shapes, layers)


def test_the_thickest_sheet_clear_of_every_limit_by_the_print_s_margin_is_chosen():
    clear = 0.03 - PRINT_MARGIN
    # Fig. 3 at 80 mm as measured: every count forms, 5 layers still clear of the limit
    chosen, why = chosen_layers(
        {2: _sheet(2, 0.0042, 0.0177), 3: _sheet(3, 0.0073, 0.0176), 5: _sheet(5, 0.0173, 0.0196)}
    )
    assert chosen == 5 and "thickest" in why
    # a thicker sheet nearer a limit than the margin is passed over for a thinner clear one
    assert chosen_layers({2: _sheet(2, clear - 0.001), 4: _sheet(4, clear + 0.001)})[0] == 2
    # none clear (Fig. 1 at 60 mm): the one farthest inside; one that misses is never it
    fig1 = {2: _sheet(2, 0.0293), 3: _sheet(3, 0.0257), 4: _sheet(4, 0.0227), 5: _sheet(5, 0.0865)}
    chosen, why = chosen_layers(fig1)
    assert chosen == 4 and "nearest" in why
    # none forms every target: the one that forms the most
    chosen, why = chosen_layers({2: _sheet(2, 0.02, 0.041), 3: _sheet(3, 0.05, 0.04)})
    assert chosen == 2 and "none forms every target" in why


@pytest.mark.slow
def test_a_run_at_a_size_that_allows_thicker_sheets_judges_each_and_prints_one(run_cli, tmp_path):
    out = tmp_path / "thirty"
    coarse = ("--step", "0.1", "--diagonals", "30", "--no-verify", "--no-pictures")
    code, text, err = run_cli("run", EXAMPLES / "two_shapes.toml", "--out", out, *coarse,
                              "--size", "30")  # fmt: skip
    assert code == 0, err
    lines = [line.strip() for line in text.splitlines()]
    assert lines[0].startswith("LAYERS CHOSEN: 2 to 3 layers of 0.3 mm (no --layers), judged")
    report = json.loads((out / "report.json").read_text())
    assert report["notice"] == lines[0]
    tried = report["layers"]["layers_tried"]
    assert set(tried) == {"2", "3"}
    for count, said in tried.items():
        assert f"{count} layers ({0.3 * int(count):.2g} mm): {said}" in lines
    (chosen,) = [line for line in lines if line.startswith("chosen: ") and "layers," in line]
    layers = int(chosen.split()[1])
    assert Design.load(out / "design.npz").layers == layers
    assert report["as designed"]["layers"] == layers
    assert f";LAYER_COUNT:{layers}" in (out / "sheet.gcode").read_text()
