"""One figure, one source, with the sheet verified (issue 37): a coarse ``fabkit run`` of
Fig. 1 and of Fig. 3, read back and simulated, then ``fabkit verify``, ``fabkit send
--dry-run`` and ``fabkit simulate`` on its files. The part, the coverage read back, the
material, the patch diameters, the duration and moves, and the verdict as fabricated must
be the same figure in the run's lines, ``fabkit verify``'s (and ``simulate``'s part),
report.json, report.html and the G-code header. ``fabkit verify`` ends with the verdict,
as ``fabkit run`` does."""

from __future__ import annotations

import contextlib
import html
import io
import json
import re

import pytest

pytestmark = pytest.mark.slow  # a coarse run with its verification per spec


@pytest.fixture(scope="module", params=["two_shapes.toml", "three_shapes.toml"])
def verified(coarse_run, request):
    """The run's output, its files and the single commands' outputs on them."""
    from fabkit.cli import main

    out, run = coarse_run(request.param)

    def stdout(*args) -> str:
        buffer = io.StringIO()
        with contextlib.redirect_stdout(buffer):
            assert main([str(a) for a in args]) == 0
        return buffer.getvalue()

    design, gcode = out / "design.npz", out / "sheet.gcode"
    return {
        "run": run,
        "verify": stdout("verify", design, gcode),
        "dry_run": stdout("send", gcode, "--dry-run"),
        "simulate": stdout("simulate", design, "--stimulus", "1", "--size", "20"),
        "report": json.loads((out / "report.json").read_text()),
        "page": html.unescape(re.sub(r"<[^>]+>", "", (out / "report.html").read_text())),
        "gcode": gcode.read_text(),
    }


def lines_with(text: str, label: str) -> list[str]:
    return [line.strip() for line in text.splitlines() if line.strip().startswith(label)]


def test_the_part_is_one_figure(verified):
    report = verified["report"]
    summary = report["verify"]["extra"]["part"]["summary"]
    assert set(lines_with(verified["run"], "part: ")) == {summary}  # solve and verify stages
    assert lines_with(verified["verify"], "part: ") == [summary]
    assert lines_with(verified["simulate"], "part: ") == [summary]  # the sheet run prints
    width, length = report["part"]["extent"]
    assert summary.startswith(f"part: {width:.3g} x {length:.3g} mm")
    assert f"{width:.3g} x {length:.3g} mm" in verified["page"]


def test_the_coverage_read_back_is_one_figure(verified):
    read = verified["report"]["verify"]
    empty, overlap = 100 * read["empty_fraction"], 100 * read["mean_overlap"]
    figure = f"empty {empty:.2f} %, overlap {overlap:.2f} %"
    for printed in (verified["run"], verified["verify"]):  # "coverage (layer 1 of 2, ...): "
        lines = lines_with(printed, "coverage")
        assert [line.split(": ", 1)[1] for line in lines] == [figure]


def test_the_material_duration_and_moves_are_one_figure(verified):
    from fabkit.progress import clock

    made = verified["report"]["machine file"]
    volume, seconds, moves = made["volume_mm3"], made["estimated_seconds"], made["moves"]
    assert f"volume {volume:.4f} mm^3, time {seconds:.1f} s" in verified["gcode"]
    assert f"volume {volume:.2f} mm^3" in verified["report"]["exports"]["gcode"]
    assert f"volume {volume:.2f} mm³" in verified["page"]
    assert f"estimated duration: {clock(seconds)} (" in verified["dry_run"]
    assert f" {moves} moves fit machine" in verified["dry_run"]


def test_the_patch_diameter_is_one_figure_as_designed_and_as_fabricated(verified):
    designed, fabricated = verified["report"]["verdicts"]
    assert (designed["what"], fabricated["what"]) == ("as designed", "as fabricated")
    for before, after in zip(designed["targets"], fabricated["targets"], strict=True):
        assert before["target"] == after["target"]
        assert before["patch_diameter_mm"] == after["patch_diameter_mm"]
        assert f"of the patch diameter ({after['patch_diameter_mm']:.3g} mm)" in after["line"]


def test_the_verdict_as_fabricated_is_one_and_ends_verify_as_it_ends_run(verified):
    verdict = verified["report"]["verdict"]
    assert verdict["what"] == "as fabricated"
    ran, checked = verified["run"].strip().splitlines(), verified["verify"].strip().splitlines()
    count = len(verdict["lines"])
    assert checked[-1] == verdict["headline"]  # the last line tells the verdict
    assert [line.strip() for line in checked[-count - 1 : -1]] == verdict["lines"]
    assert [line.strip() for line in ran[-count - 1 : -1]] == verdict["lines"]
    for line in verdict["lines"]:
        assert line in verified["page"]
