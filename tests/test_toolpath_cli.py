"""``fabkit toolpath`` and ``fabkit channels`` end to end, and their one-line errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fabkit.cli import main
from fabkit.toolpath import load_toolpath
from tests.test_fields import write_design

EXAMPLES = Path(__file__).resolve().parent.parent / "examples" / "directors"
PROCESS = EXAMPLES / "process_lce.toml"


@pytest.mark.slow
def test_director_expression_to_toolpath(tmp_path, capsys):
    out = tmp_path / "out"
    code = main(
        ["toolpath", "--director", "arctan2(y, x)", "--shape", "disc:4", "--road-width", "0.25"]
        + ["--out", str(out), "--json"]
    )
    assert code == 0
    printed = capsys.readouterr().out
    assert printed.startswith("layer 1: empty")
    names = {"toolpath.npz", "toolpath.json", "quality.json", "preview.png", "preview.svg"}
    assert names <= {p.name for p in out.iterdir()}
    report = json.loads((out / "quality.json").read_text())
    assert report["layers"][0]["empty_fraction"] < 0.1  # a small disc: R = 16 w
    toolpath = load_toolpath(out / "toolpath.npz")
    assert len(toolpath.layers) == 1 and toolpath.channels == {}
    assert toolpath.layers[0].moves[0].width[0] == 0.25


@pytest.mark.slow
def test_design_with_encoding_and_a_bilayer(tmp_path, capsys):
    design = write_design(tmp_path / "design.npz", eps=lambda u, v: 0.5 + 0.2 * u)
    out = tmp_path / "out"
    arguments = [str(design), str(EXAMPLES / "azimuthal.toml"), "--size", "20", "--layers", "4"]
    code = main(["toolpath", *arguments, "--process", str(PROCESS), "--out", str(out)])
    assert code == 0
    toolpath = load_toolpath(out / "toolpath.npz")
    assert [layer.z_mm for layer in toolpath.layers] == pytest.approx([0.2, 0.4, 0.6, 0.8])
    assert toolpath.channels == {"print_speed_mm_s": "eps"}
    speeds = [m.speed for m in toolpath.layers[0].moves if m.kind == "print"]
    assert min(s.min() for s in speeds) >= 2.0 and max(s.max() for s in speeds) <= 16.0
    assert len(json.loads((out / "quality.json").read_text())["layers"]) == 4
    assert "layer 4" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["--director", "phi", "--shape", "disc:3", "--eps", "5"], "outside the calibrated"),
        (["--director", "phi", "--shape", "disc:3", "--machine", "nope"], "nope"),
        (["--director", "phi", "--shape", "blob:3"], "unknown shape"),
        (["--director", "phi", "--shape", "disc:1e308"], "between 0.001 and 1e+06 mm"),
        (["--director", "phi", "--shape", "ellipse:3,1e-320"], "between 0.001 and 1e+06 mm"),
        (["--director", "phi"], "--director needs --shape"),
        (["--director", "import os", "--shape", "disc:3"], "cannot parse"),
        (["--director", "phi", "--shape", "disc:3", "--layers", "0"], "--layers"),
        (["--director", "phi", "--shape", "disc:3", "--end-inset", "2"], "--end-inset"),
        (["--director", "phi", "--shape", "disc:3", "--road-width", "-1"], "road_width_mm"),
        (["--director", "phi", "--shape", "disc:3", "--process", "missing.toml"], "missing"),
        (["--director", "phi", "--shape", "disc:3", "--ignore-feature", "eps"], "not a feature"),
        (
            [
                "--director",
                "phi",
                "--shape",
                "disc:3",
                "--eps",
                "0.1",
                "--machine",
                "klipper_generic",
            ]
            + ["--process", str(EXAMPLES.parent / "three_shapes.toml")],
            "process: missing (expected a table)",
        ),
    ],
)
def test_bad_input_is_one_line_and_writes_nothing(tmp_path, capsys, arguments, message):
    out = tmp_path / "out"
    process = [] if "--process" in arguments else ["--process", str(PROCESS)]
    code = main(["toolpath", *arguments, *process, "--out", str(out)])
    error = capsys.readouterr().err.strip()
    assert code == 2
    assert error.startswith("fabkit: error:") and message in error and "\n" not in error
    assert not out.exists() or not any(out.iterdir())


def test_a_feature_without_a_channel_is_refused_unless_ignored(tmp_path, capsys):
    arguments = ["--director", "0", "--shape", "disc:3", "--eps", "0.2"]
    code = main(["toolpath", *arguments, "--machine", "klipper_generic", "--out", str(tmp_path)])
    error = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in error
    assert "machine klipper_generic encodes no channel for feature eps" in error
    assert "--ignore-feature eps" in error
    out = tmp_path / "ignored"
    arguments += ["--machine", "klipper_generic", "--ignore-feature", "eps", "--out", str(out)]
    assert main(["toolpath", *arguments]) == 0
    warning = capsys.readouterr().err.strip()
    assert warning.startswith("fabkit: warning: feature eps left out (--ignore-feature)")
    assert load_toolpath(out / "toolpath.npz").channels == {}
    report = json.loads((out / "quality.json").read_text())
    assert report["ignored_features"] == ["eps"]


@pytest.mark.slow
def test_clipped_eps_is_a_warning_with_the_fraction(tmp_path, capsys):
    arguments = ["--director", "0", "--shape", "disc:3", "--eps", "x/2", "--clip-eps"]
    assert main(["toolpath", *arguments, "--process", str(PROCESS), "--out", str(tmp_path)]) == 0
    warning = capsys.readouterr().err.strip()
    assert warning.startswith("fabkit: warning:") and "eps clipped" in warning and "%" in warning


def test_a_broken_machine_profile_is_one_line(tmp_path, capsys):
    profile = tmp_path / "machine.toml"
    profile.write_text('name = "x"\nkind = "pneumatic_diw"\n')
    arguments = ["--director", "0", "--shape", "disc:2", "--machine", str(profile)]
    code = main(["toolpath", *arguments, "--out", str(tmp_path / "out")])
    error = capsys.readouterr().err.strip()
    assert code == 2 and error.startswith("fabkit: error:") and "\n" not in error


@pytest.mark.slow
def test_alternate_layers_are_staggered(tmp_path):
    out = tmp_path / "out"
    arguments = ["--director", "0", "--shape", "square:4", "--road-width", "0.4", "--layers", "2"]
    assert main(["toolpath", *arguments, "--pattern", "alternate", "--out", str(out)]) == 0
    first, second = load_toolpath(out / "toolpath.npz").layers
    heights = [np.array([m.xyz[0, 1] for m in layer.prints]) for layer in (first, second)]
    gaps = np.abs(heights[1][:, None] - heights[0][None, :]).min(axis=1)
    assert np.median(gaps) == pytest.approx(0.2, abs=0.01)  # halfway between the lines below


@pytest.mark.slow
def test_channels_command(tmp_path, capsys):
    out = tmp_path / "channels"
    code = main(
        ["channels", "--director", "0.3", "--shape", "disc:30", "--eps", "0.5 + 0.5*x/30"]
        + ["--baromorph", str(EXAMPLES / "baromorph.toml"), "--out", str(out)]
    )
    assert code == 0
    assert "connected True" in capsys.readouterr().out
    report = json.loads((out / "channels.json").read_text())
    assert report["report"]["valid"] and report["polarity"].startswith("mould = negative")
    assert {"mould.stl", "channels.png", "channels.svg"} <= {p.name for p in out.iterdir()}
