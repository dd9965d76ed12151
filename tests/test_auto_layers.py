"""``fabkit run`` with no ``--layers`` chooses the layers (issue 35): two or more on a
printer, since one layer cannot program a target's side (the counts its size allows,
judged as designed: the thickest sheet clear of every limit by the print's margin), one
where the route makes one; the choice is on the run's first line and in report.json's
notice. ``--layers K`` decides when given. The verdicts of the layered runs are
tests/test_run_layers.py's."""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from types import SimpleNamespace

import pytest

from fabkit.design.design import Design
from fabkit.mechanics.verdict import Shape, Verdict
from fabkit.run.inputs import layer_choices
from fabkit.run.solve import PRINT_MARGIN, chosen_layers, fallback_layers
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


def test_the_counts_printed_next_are_those_formed_as_designed_farthest_inside_first():
    # bowl_saddle_trough at 60 mm as measured: 2 chosen (clear), 3 formed, 4 and 5 missed
    bowl = {2: _sheet(2, 0.0122), 3: _sheet(3, 0.0258), 4: _sheet(4, 0.0335), 5: _sheet(5, 0.0351)}
    assert chosen_layers(bowl)[0] == 2 and fallback_layers(bowl, 2) == (3,)
    fig1 = {2: _sheet(2, 0.0293), 3: _sheet(3, 0.0257), 4: _sheet(4, 0.0227), 5: _sheet(5, 0.0865)}
    assert fallback_layers(fig1, 4) == (3, 2)
    assert fallback_layers({2: _sheet(2, 0.05), 3: _sheet(3, 0.02)}, 3) == ()


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


@dataclass(frozen=True)
class _Sheet:
    """What the run's print loop asks of a solved design: its layers (``refined``: a
    refinement as printed of them), saved."""

    layers: int
    refined: bool = False
    layering: bool = True
    saved: list = field(default_factory=list, compare=False)

    def save(self, path) -> None:
        self.saved.append(path)


@dataclass(frozen=True)
class _Solved:
    design: _Sheet
    layering: dict | None
    fallbacks: tuple = ()


def _print_loop(
    monkeypatch, tmp_path, chosen: int, fallbacks: tuple[int, ...], printed: dict, given=False
):
    """``fabkit.run.pipeline._printed`` with every count's print judged as ``printed``
    (count, or (count, "refined") for its layers refined as printed -> verdict as
    fabricated) instead of made, and a refinement as printed that refines when
    ``printed`` has one: the prints made, in order, and what the loop returned."""
    from fabkit.run import pipeline
    from fabkit.run.fabricate import Run
    from fabkit.run.solve import LayerChoice

    made = []

    def make(run):
        design = run.solved.design
        made.append((design.layers, "refined") if design.refined else design.layers)
        return SimpleNamespace(verification=object(), final=printed[made[-1]]), []

    def layer(solved, choice, options, inputs, say, tried):
        assert tried == {"2": "judged"}  # the choice's lines go on with every count
        return replace(solved, design=_Sheet(choice.layers), layering={"layers_tried": tried})

    def refine(run):
        key = (run.solved.design.layers, "refined")
        if key not in printed:
            return run.solved
        return replace(run.solved, design=_Sheet(key[0], refined=True))

    monkeypatch.setattr(pipeline, "_made", make)
    monkeypatch.setattr(pipeline, "layers_solved", layer)
    monkeypatch.setattr(pipeline, "refine_as_printed", refine)
    tried = {} if given else {"2": "judged"}
    solved = _Solved(_Sheet(chosen), {"layers_tried": tried}, tuple(map(LayerChoice, fallbacks)))
    said = []
    options = SimpleNamespace(out=str(tmp_path), refine=False)
    kept, _, _ = pipeline._printed(Run(options, None, solved, None, said.append))
    return made, kept, said


def test_a_print_that_misses_a_target_hands_over_to_the_next_count(monkeypatch, tmp_path):
    # bowl_saddle_trough at 60 mm as measured: 2 layers chosen, its print misses the saddle
    # and the trough; 3 layers, which formed every target as designed too, forms them
    printed = {2: _sheet(2, 0.0123, 0.0414, 0.0395), 3: _sheet(3, 0.0261, 0.0107, 0.008)}
    made, kept, said = _print_loop(monkeypatch, tmp_path, 2, (3, 4), printed)
    assert made == [2, 3] and kept.design.layers == 3  # 4 is not printed: 3 formed
    assert kept.layering["counts_printed"] == {str(k): v.outcome() for k, v in printed.items()}
    assert "the print of 2 layers does NOT form t1 (4.14 % RMS); t2 (3.95 % RMS)" in said[0]
    assert "printing 3 layers" in said[0]
    # a print that forms every target first is the run's only one
    made, kept, _ = _print_loop(monkeypatch, tmp_path, 3, (2,), printed)
    assert made == [3] and "counts_printed" not in kept.layering


def test_when_no_count_s_print_forms_every_target_the_best_is_refined_as_printed(
    monkeypatch, tmp_path
):
    printed = {2: _sheet(2, 0.035), 3: _sheet(3, 0.05), 4: _sheet(4, 0.04)}
    made, kept, said = _print_loop(monkeypatch, tmp_path, 2, (3, 4), printed)
    assert made == [2, 3, 4, 2] and kept.design.layers == 2  # nearest: 2 layers, made last
    assert kept.design.saved == [tmp_path / "design.npz"]  # its design.npz written again
    assert "making 2 layers again, the print that formed the most, nearest" in said[-2]
    assert "refining its layers as printed" in said[-1]  # no refinement kept: it stands
    assert list(kept.layering["counts_printed"]) == ["2", "3", "4"]
    # Fig. 3 at 50 mm as measured: 3, 2 and 4 layers miss the face, 4 refined forms it
    printed = {3: _sheet(3, 0.0533), 2: _sheet(2, 0.0727), 4: _sheet(4, 0.0332)}
    printed[4, "refined"] = _sheet(4, 0.0239)
    made, kept, said = _print_loop(monkeypatch, tmp_path, 3, (2, 4), printed)
    assert made == [3, 2, 4, (4, "refined")] and kept.design.refined
    assert "the print of 4 layers does NOT form t0 (3.32 % RMS): refining" in said[-1]
    # layers given, or a part too small to judge more than two: one print, not refined
    made, kept, said = _print_loop(monkeypatch, tmp_path, 4, (), printed, given=True)
    assert made == [4] and not kept.design.refined and not said
