"""The same figure is equal wherever it is printed, and every printed figure is plain data.

One coarse ``fabkit run`` (and the single-stage commands on its files): the areas, the
valid and checked points, the print length, the travel between lines, the G-code's
non-printing moves and the verdict on every target must agree across ``design.json``,
``report.json``, ``report.html``, ``quality.json``, the G-code header and every command's
output; a figure that means something else carries another name. No Python repr, no
``none (none)``. ``report.json`` follows its schema (``docs/report.schema.json``).
"""

from __future__ import annotations

import json
import re

import pytest

from tests.conftest import EXAMPLES, validate_report

pytestmark = pytest.mark.slow  # every test reads one full fabkit run (about 15 s)

SPEC = EXAMPLES / "two_shapes.toml"
COARSE = ("--step", "0.1", "--diagonals", "30")


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """Every file and every command's output, from one coarse run in one layer."""
    import contextlib
    import io

    from fabkit.cli import main

    folder = tmp_path_factory.mktemp("figures")
    out = folder / "out"

    def stdout(*args) -> str:
        buffer = io.StringIO()
        with contextlib.redirect_stdout(buffer):
            assert main([str(a) for a in args]) == 0
        return buffer.getvalue()

    texts = {
        "run": stdout(
            "run",
            SPEC,
            "--out",
            out,
            *COARSE,
            "--size",
            "20",
            "--layers",
            "1",
            "--no-verify",
            "--no-pictures",
            "--send",
            "sim://marlin?baud=0&time_scale=0",
        )  # fmt: skip
    }
    design = out / "design.npz"
    texts["solve"] = stdout("solve", SPEC, "--out", folder / "again.npz", *COARSE)
    texts["energy"] = stdout("energy", design)
    texts["check"] = stdout("check", design)
    texts["check_json"] = stdout("check", design, "--json")
    texts["toolpath"] = stdout("toolpath", design, "--size", "20", "--out", folder / "tp")
    texts["export"] = stdout(
        "export", out / "toolpath" / "toolpath.npz", "--machine", "marlin_diw_pneumatic",
        "--format", "gcode", "-o", folder / "again.gcode",
    )  # fmt: skip
    texts["dry_run"] = stdout("send", out / "sheet.gcode", "--dry-run")
    return {
        "out": out,
        "texts": texts,
        "design": json.loads((out / "design.json").read_text()),
        "report": json.loads((out / "report.json").read_text()),
        "html": (out / "report.html").read_text(),
        "quality": json.loads((out / "toolpath" / "quality.json").read_text()),
        "gcode": (out / "sheet.gcode").read_text(),
    }


def numbers_after(text: str, label: str) -> list[float]:
    """The numbers on the line of ``text`` that holds ``label``, after it."""
    line = next(line for line in text.splitlines() if label in line)
    return [float(x) for x in re.findall(r"-?\d+(?:\.\d+)?(?:e[-+]?\d+)?", line.split(label, 1)[1])]


def test_areas_are_one_figure(made):
    areas = made["design"]["area_design_units2"]
    assert made["report"]["solve"]["area_design_units2"] == areas
    names = list(areas)
    for text in (made["texts"]["run"], made["texts"]["solve"]):
        shown = numbers_after(text, "area over the solved cells (design units^2):")
        assert shown == pytest.approx([areas[n] for n in names], rel=5e-4)
    energy = made["texts"]["energy"].splitlines()
    for name in names:
        row = next(line for line in energy if line.startswith(name))
        flat, target = (float(x) for x in row.split()[2:4])
        assert flat == pytest.approx(areas[names[0]], rel=5e-4)
        assert target == pytest.approx(areas[name], rel=5e-4)
    for value in areas.values():
        assert f"<td>{value:.4g}</td>" in made["html"]


def test_valid_and_checked_points_are_named_apart(made):
    valid = made["design"]["valid_points"]
    assert made["report"]["solve"]["valid_points"] == valid
    assert f"{valid} valid points" in made["texts"]["run"]
    assert f"{valid} valid points" in made["texts"]["solve"]
    checked = [s["checked_points"] for s in made["design"]["check"]["surfaces"]]
    assert checked == [s["checked_points"] for s in made["report"]["check"]["surfaces"]]
    assert checked == [
        s["checked_points"] for s in json.loads(made["texts"]["check_json"])["surfaces"]
    ]
    table = made["texts"]["check"].splitlines()
    assert table[0].split()[1] == "checked"
    rows = table[2 : 2 + len(checked)]  # the residual table; the verdict follows it
    assert [int(line.split()[1]) for line in rows] == checked
    assert len(set(checked)) == 1 and checked[0] < valid
    explained = f"checked points: {checked[0]} per surface (the valid points whose"
    assert explained in made["texts"]["run"] and explained in made["texts"]["solve"]
    assert f"{valid} grid points solved" in made["html"]
    assert "<th>points checked</th>" in made["html"] and f"<td>{checked[0]}</td>" in made["html"]


def test_lengths_are_one_figure_each(made):
    (layer,) = made["quality"]["layers"]
    (reported,) = made["report"]["toolpath quality"]
    assert reported == layer
    between, printing = layer["travel_between_lines_mm"], layer["print_length_mm"]
    assert "travel_length_mm" not in layer
    toolpath = made["texts"]["toolpath"]
    assert numbers_after(toolpath, "travel between lines")[0] == pytest.approx(between, abs=0.05)
    assert numbers_after(toolpath, "printing")[0] == pytest.approx(printing, abs=0.05)
    header = made["gcode"]
    printed = numbers_after(header, ";fabkit printing path")[0]
    moving = numbers_after(header, "non-printing path")[0]
    assert printed == pytest.approx(printing, rel=1e-4)
    assert moving > between  # lifts and the moves to and from the sheet besides
    for line in (made["report"]["exports"]["gcode"], made["texts"]["export"]):
        assert numbers_after(line, "printing")[0] == pytest.approx(printing, abs=0.05)
        assert numbers_after(line, "non-printing moves")[0] == pytest.approx(moving, abs=0.05)
    assert f"<td>{between:.4g}</td>" in made["html"]


def test_the_duration_and_the_moves_are_one_figure_each(made):
    """Issue 37: the header said ;TIME:361 and the report "about 6 min" where send
    --dry-run said 0:06:24 (the writer summed length over feed, send planned the moves);
    the moves were 31,434 in the report and 31,436 in the dry run (the start and end
    G-code's two moves). Every one now quotes the planner's figure on the file."""
    from fabkit.progress import clock

    machine_file = made["report"]["machine file"]
    seconds, moves = machine_file["estimated_seconds"], machine_file["moves"]
    header = made["gcode"]
    assert f";TIME:{round(seconds)}\n" in header
    assert numbers_after(header, ";fabkit printing path")[-1] == pytest.approx(seconds, abs=0.05)
    dry_run = made["texts"]["dry_run"]
    assert f"estimated duration: {clock(seconds)} (moves and dwells" in dry_run
    assert f" {moves} moves fit machine" in dry_run
    html = re.sub(r"<[^>]+>", "", made["html"])
    assert f"({moves} moves), in {clock(seconds)} (h:mm:ss" in html
    for line in (made["report"]["exports"]["gcode"], made["texts"]["export"]):
        assert f"({moves} moves)" in line and f"estimated duration {clock(seconds)};" in line


def test_no_repr_and_no_empty_words(made):
    pages = {
        "report.json": json.dumps(made["report"]),
        "report.html": re.sub(  # the pictures' data and the scripts (plotly.js) are no prose
            r"data:image/png;base64,[A-Za-z0-9+/=]+|<script>.*?</script>",
            "",
            made["html"],
            flags=re.S,
        ),
        **made["texts"],
    }
    for name, text in pages.items():
        assert not re.search(r"\b[A-Z]\w+\(\w+=", text), name  # a dataclass repr
        assert "none (none)" not in text and "E none" not in text, name


def test_the_send_figures_are_named_with_their_units(made):
    sent = made["report"]["sent"]
    assert sent["job_lines"] > 0 and sent["seconds"] >= 0 and sent["lines_per_second"] > 0
    assert {"resent_lines", "status_queries_between_lines", "recoveries_from_lost_answers"} <= set(
        sent
    )
    assert "<th>status queries between lines</th>" in made["html"]


def test_the_verdict_is_one_in_the_terminal_the_json_and_the_page(made):
    """The run's last lines are its verdict, a line per target: the same lines as
    report.json's and the page's, with the same figures."""
    import html

    verdict, final = made["report"]["verdict"], made["report"]["verdicts"][-1]
    lines = made["texts"]["run"].strip().splitlines()
    count = len(final["targets"])
    assert lines[-count - 2] == f"      the sheet {verdict['what']}:"
    assert [line.strip() for line in lines[-count - 1 : -1]] == verdict["lines"]
    assert lines[-1].startswith(f"done: {verdict['headline']}; the design's check passed; ")
    assert verdict["lines"] == [t["line"] for t in final["targets"]]
    for target, line in zip(final["targets"], verdict["lines"], strict=True):
        style = "formed" if target["formed"] else "missed"
        assert f'<p class="{style}">{html.escape(line)}</p>' in made["html"]
        assert f"{target['rms_pct']:.2f} % ({target['rms_mm']:.3g} mm) RMS" in line
        assert target["rms_mm"] == pytest.approx(
            target["rms_pct"] / 100 * target["patch_diameter_mm"]
        )
    headline = verdict["headline"]
    assert f"{headline[:1].upper()}{headline[1:]}." in made["html"]


def test_report_json_follows_its_schema(made):
    validate_report(made["report"])
    assert made["report"]["verify"] is None and made["report"]["sent"]  # --no-verify, --send
