"""Process settings and the eps encoding: monotone interpolation, range errors, clipping,
the process file format (channels per feature, the one-feature table), and the planner
encoding every feature."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

from fabkit.calibration import Calibration
from fabkit.errors import FabkitError
from fabkit.field.flat import field_from_expression
from fabkit.field.outlines import parse_shape
from fabkit.process import Encode
from fabkit.toolpath.model import PRINT
from fabkit.toolpath.plan import PlanSettings, plan_toolpath
from fabkit.toolpath.process_file import load_process, machine_process
from tests.conftest import ROOT

SPEED = Calibration("print_speed_mm_s", (0.0, 0.2, 0.5, 1.0), (20.0, 12.0, 6.0, 2.0))


def test_encoding_hits_the_table_and_stays_monotone():
    assert SPEED.encode(np.array(SPEED.eps))[0] == pytest.approx(SPEED.value)
    dense = SPEED.encode(np.linspace(0, 1, 501))[0]
    assert np.all(np.diff(dense) < 0)  # decreasing table, decreasing everywhere
    assert dense.min() >= 2.0 and dense.max() <= 20.0  # no overshoot


def test_decoding_inverts_the_encoding():
    eps = np.linspace(0, 1, 333)
    assert SPEED.decode(SPEED.encode(eps)[0]) == pytest.approx(eps, abs=1e-6)


def test_eps_outside_the_table_is_an_error_naming_both_ranges():
    with pytest.raises(FabkitError, match=r"spans \[-0.1, 0.5\].*range \[0, 1\]"):
        SPEED.encode(np.array([-0.1, 0.5]))


def test_clipping_reports_the_clipped_fraction():
    clipping = dataclasses.replace(SPEED, clip=True)
    value, clipped = clipping.encode(np.array([-0.5, 0.0, 0.5, 1.5]))
    assert clipped == pytest.approx(0.5)
    assert value[[0, 3]] == pytest.approx([20.0, 2.0])


@pytest.mark.parametrize(
    ("eps", "value", "message"),
    [
        ((0.0, 0.0), (1.0, 2.0), "strictly increasing"),
        ((0.0, 1.0, 2.0), (1.0, 3.0, 2.0), "increasing or decreasing"),
        ((0.0, 1.0), (1.0, -2.0), "positive"),
        ((0.0, 1.0), (0.5, 1.5), "in \\[0, 1\\]"),
        ((0.0,), (1.0,), "at least 2"),
    ],
)
def test_bad_calibration_tables(eps, value, message):
    parameter = "ink_fraction" if "0, 1" in message else "print_speed_mm_s"
    with pytest.raises(FabkitError, match=message):
        Calibration(parameter, eps, value)


def test_process_files_and_their_errors(tmp_path):
    good = tmp_path / "p.toml"
    good.write_text(
        "[process]\nroad_width_mm = 0.3\nlayer_height_mm = 0.2\nprint_speed_mm_s = 5\n"
        "travel_speed_mm_s = 20\n[process.calibration]\nparameter = 'extrusion_multiplier'\n"
        "eps = [0, 1]\nvalue = [0.8, 1.2]\nclip = true\n"
    )
    process = load_process(good)
    (channel,) = process.encodes
    assert process.road_width_mm == 0.3 and channel.table.clip
    assert channel.features == (0,)  # the one-feature table: the design's first feature
    cases = {
        "[process]\nroad_width_mm = 0.3\n": r"process\.layer_height_mm: missing \(expected",
        "[other]\n": "bad\\.toml: process: missing \\(expected a table\\)",
        good.read_text().replace(
            "0.3", "'wide'"
        ): "process\\.road_width_mm: expected a positive number .*, got 'wide' \\(a string\\)",
        good.read_text().replace(
            "clip = true", "colour = 1"
        ): "process\\.calibration\\.colour: unknown key \\(allowed: ",
        good.read_text().replace("extrusion_multiplier", "pressure"): "parameter: expected one of",
        good.read_text()
        + "[[process.encode]]\nfeature = 1\nparameter = 'temperature_c'\n"
        + "eps = [0, 1]\nvalue = [200, 220]\n": "cannot be mixed",
    }
    for text, message in cases.items():
        bad = tmp_path / "bad.toml"
        bad.write_text(text)
        with pytest.raises(FabkitError, match=message) as error:
            load_process(bad)
        assert "\n" not in str(error.value)


def test_machine_profiles():
    default = machine_process(None)
    assert default.road_width_mm > 0 and "marlin_diw_pneumatic" in default.source
    with pytest.raises(FabkitError):
        machine_process("no_such_machine")


@pytest.mark.parametrize("parameter", ["print_speed_mm_s", "extrusion_multiplier"])
def test_plan_encodes_eps_on_every_vertex(parameter):
    field = field_from_expression("0", parse_shape("square:6"), eps="0.1 + 0.05*x")
    channel = Encode(("eps",), Calibration(parameter, (-0.5, 0.5), (1.0, 3.0)))
    process = dataclasses.replace(machine_process(None), road_width_mm=0.4, encodes=(channel,))
    plan = plan_toolpath([field], process, PlanSettings())
    assert plan.toolpath.channels == {parameter: "eps"}
    for _, move in plan.toolpath.moves():
        if move.kind != PRINT:
            continue
        expected = channel.table.encode(field.eps(move.xyz[:, :2]))[0]
        assert move.channels[parameter] == pytest.approx(expected)
        encoded = move.speed if parameter == "print_speed_mm_s" else move.flow
        assert encoded == pytest.approx(expected)


@pytest.mark.slow
def test_an_eps_outside_the_table_names_options_the_command_has(run_cli, tmp_path):
    from fabkit.cli import build_parser

    machine = (ROOT / "machines" / "marlin_diw_pneumatic.toml").read_text()
    narrow = tmp_path / "narrow.toml"  # the first feature's table covers half its range
    narrow.write_text(
        machine.replace("eps = [0.0, 0.25, 0.5, 0.75, 1.0]", "eps = [0.0, 0.1, 0.2, 0.3, 0.4]")
    )
    spec = ROOT / "examples" / "two_shapes.toml"
    out = tmp_path / "out"
    code, _, err = run_cli(
        "run",
        spec,
        "--out",
        out,
        "--process",
        narrow,
        "--step",
        "0.1",
        "--diagonals",
        "30",
        "--layers",
        "2",
    )
    assert code != 0 and "outside the calibrated range" in err and len(err.splitlines()) == 1, err
    named_commands = ("run", "toolpath")
    commands = build_parser(named_commands)._subparsers._group_actions[0].choices  # as clidoc
    options = {name: set(commands[name]._option_string_actions) for name in named_commands}
    named = re.findall(r"fabkit (run|toolpath) (--[a-z-]+)", err)
    assert named and all(option in options[command] for command, option in named), err
