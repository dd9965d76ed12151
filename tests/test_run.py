"""fabkit run: spec to machine files in one go."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.conftest import COARSE_RUN, EXAMPLES, validate_report


def run_ok(run_cli, spec: str, out: Path, *options) -> tuple[dict, str]:
    """``fabkit run examples/SPEC --out OUT OPTIONS``, which must succeed: the figures of
    its report.json, and what it printed."""
    code, text, err = run_cli("run", EXAMPLES / spec, "--out", out, *options)
    assert code == 0, err
    return json.loads((out / "report.json").read_text()), text


@pytest.mark.slow
def test_run_writes_every_file(run_cli, tmp_path):
    out = tmp_path / "out"
    figures, text = run_ok(
        run_cli, "two_shapes.toml", out, "--format", "gcode", "--format", "dxf", "--no-verify",
        "--step", "0.1", "--diagonals", "30", "--layers", "2",  # the choice: test_auto_layers
    )  # fmt: skip
    expected = [
        "design.npz",
        "design.json",
        "report.html",
        "report.json",
        "sheet.gcode",
        "sheet.dxf",
        "pictures/flat_sheet.png",
        "pictures/eps.png",
        "pictures/surfaces.png",
        "pictures/residuals.png",
        "patches/1_sphere.ply",
        "patches/2_bump.ply",
        "toolpath/toolpath.npz",
        "toolpath/quality.json",
        "toolpath/preview.png",
    ]
    for name in expected:
        assert (out / name).is_file(), name
    leftovers = [p for p in out.rglob("*") if ".part" in p.name]
    assert leftovers == []
    assert figures["check"]["passed"]
    quality = figures["toolpath quality"][0]
    # issue 5's bounds for Fig. 1 at 60 mm and the default 0.41 mm road (a coarse grid here)
    assert quality["empty_fraction"] <= 0.03 and quality["mean_overlap"] <= 0.03
    assert quality["mean_angle_error_deg"] <= 3.0
    gcode = (out / "sheet.gcode").read_text()
    assert ";LAYER:0" in gcode and "G1" in gcode
    assert "report.html" in text
    page = (out / "report.html").read_text()
    # the key figures are flat tables in words: one row per surface, its residual columns
    assert "<th>length along u</th>" in page and "<td>sphere</td>" in page
    assert figures["verify"] is None  # --no-verify: tests/test_verify.py reads runs back
    # the shapes it takes are the sheet's as designed: a mesh and a picture per target
    assert figures["shapes"]["folder"] == "as_designed"
    for name in ("as_designed/sphere.ply", "as_designed/bump.ply", "as_designed/bump.png"):
        assert (out / name).is_file(), name
    assert page.count("<img alt=") == 7  # 2 shapes, 4 design pictures, preview


@pytest.mark.slow
def test_a_stage_that_fails_after_the_pictures_were_handed_on_still_writes_them(
    run_cli, tmp_path, monkeypatch
):
    """The pictures are drawn in a second process while the later stages run; when one of
    those fails, the run still writes the pictures it drew (as it writes every file of the
    stages before the failure), and no report."""
    from fabkit.errors import FabkitError

    def failing(*_args, **_kwargs):
        raise FabkitError("verify: made to fail by this test")

    monkeypatch.setattr("fabkit.run.fabricate._verify", failing)
    out = tmp_path / "out"
    args = ("--step", "0.1", "--diagonals", "30", "--size", "20")
    code, _, err = run_cli("run", EXAMPLES / "two_shapes.toml", "--out", out, *args)
    assert code == 2 and err == "fabkit: error: verify: made to fail by this test\n"
    pictures = sorted(p.name for p in (out / "pictures").iterdir())
    assert pictures == ["eps.png", "flat_sheet.png", "residuals.png", "surfaces.png"]
    assert (out / "sheet.gcode").is_file() and not (out / "report.json").exists()


def test_run_bad_inputs_are_one_line(run_cli, tmp_path):
    code, _, err = run_cli("run", tmp_path / "missing.toml", "--out", tmp_path / "o")
    assert code == 2 and err.count("\n") == 1 and "does not exist" in err
    code, _, err = run_cli(
        "run", EXAMPLES / "two_shapes.toml", "--out", tmp_path / "o", "--machine", "nope"
    )
    assert code == 2 and err.count("\n") == 1 and "nope" in err


@pytest.mark.slow
@pytest.mark.parametrize("size", ["58", "63"])
def test_the_channels_read_back_does_not_hang_on_the_size(run_cli, tmp_path, size):
    # read 11.0 % and 15.5 % RMS before the drawing marked its manifold and the reader
    # skipped cuts that end on a turned wall (a channel's round end, a junction): only
    # the default 60 mm read 1.5 %
    baromorph = ("--baromorph", EXAMPLES / "baromorph_channels.toml", "--no-simulate")
    baromorph += ("--no-pictures",)
    figures, _ = run_ok(run_cli, "baromorph.toml", tmp_path / "out", "--size", size, *baromorph)
    (width,) = figures["verify"]["features"]
    assert width["rms_pct"] < 2.5 and width["p95_pct"] < 5.0
    assert figures["verify"]["director_mean_deg"] < 3.0


@pytest.mark.slow
def test_run_baromorph_writes_channels_dxf_and_mould(run_cli, tmp_path):
    import ezdxf
    import trimesh

    out = tmp_path / "baro"
    baromorph = ("--baromorph", EXAMPLES / "baromorph_channels.toml")
    figures, _ = run_ok(run_cli, "baromorph.toml", out, *baromorph)
    verified = figures["verify"]
    assert verified["kind"] == "channels"  # read back by the channels' widths and directions
    (width,) = verified["features"]
    assert width["channel"] == "channel_width_mm" and width["rms_pct"] < 3.0
    assert verified["director_mean_deg"] < 4.0
    channels = figures["channels"]
    assert channels["valid"] and channels["connected"]
    assert channels["max_width_error"] <= 0.01 and channels["min_wall_mm"] >= 0.6
    drawing = figures["exports"]["dxf"]
    assert "entities per layer CHANNELS" in drawing and "Summary(" not in drawing  # no repr
    document = ezdxf.readfile(out / "channels.dxf")
    assert len(document.audit().errors) == 0
    layers = {entity.dxf.layer for entity in document.modelspace()}
    assert {"CHANNELS", "OUTLINE", "INLET"} <= layers
    assert trimesh.load(out / "channels" / "mould.stl").is_watertight
    code, _, err = run_cli(
        "run", EXAMPLES / "baromorph.toml", "--out", out, "--format", "gcode", *baromorph
    )
    assert code == 2 and "DXF only" in err


@pytest.mark.slow
def test_a_run_not_simulated_says_so_first_and_last(run_cli, tmp_path):
    out = tmp_path / "quick"
    figures, text = run_ok(
        run_cli, "two_shapes.toml", out, "--no-simulate", "--step", "0.1", "--diagonals", "30",
        "--size", "20", "--no-pictures",
    )  # fmt: skip
    lines = text.strip().splitlines()
    assert lines[0].strip().startswith("NOT SIMULATED (--no-simulate): no verdict on the shapes")
    assert lines[-1].startswith("done: NOT SIMULATED (--no-simulate)")
    assert "forms every target" not in text and "formed" not in text
    assert figures["verdict"]["formed"] is None and figures["verdicts"] == []
    assert figures["as designed"] is None and figures["shapes"] is None
    assert figures["notice"].startswith("NOT SIMULATED") and figures["verify"]["targets"] == []
    assert not (out / "as_designed").exists() and not (out / "as_fabricated").exists()
    body = (out / "report.html").read_text().split("<body>", 1)[1]
    assert body.lstrip().startswith('<p class="notice">NOT SIMULATED (--no-simulate)')
    validate_report(figures)


@pytest.mark.slow
def test_a_run_without_pictures_writes_every_other_file_and_says_so(coarse_run, run_cli, tmp_path):
    """``--no-pictures`` on the shared coarse run of Fig. 1 (verified and simulated: its
    simulations kept): no PNG anywhere, the same figures but the pictures' names, the
    shapes' meshes, and the report says why it has no picture."""
    drawn, _ = coarse_run("two_shapes.toml")
    out = tmp_path / "out"
    figures, text = run_ok(run_cli, "two_shapes.toml", out, *COARSE_RUN, "--no-pictures")
    assert "[2/7] no pictures (--no-pictures); patch meshes" in text
    assert list(out.rglob("*.png")) == [] and list(out.rglob("*.svg")) == []
    assert list(drawn.rglob("*.png"))  # the same run with pictures draws them
    expected = json.loads((drawn / "report.json").read_text())
    for shape in expected["shapes"]["targets"]:
        del shape["picture"]
    same = ("verdict", "verdicts", "as designed", "check", "part", "layers", "shapes")
    for key in (*same, "channels", "toolpath quality"):
        assert figures[key] == expected[key], key
    for shape in figures["shapes"]["targets"]:
        assert (out / shape["mesh"]).is_file()
    assert figures["verify"]["verdict"] == expected["verify"]["verdict"]
    page = (out / "report.html").read_text()
    assert "<img" not in page and "No pictures drawn (fabkit run --no-pictures)." in page
    validate_report(figures)
