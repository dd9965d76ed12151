"""Process settings and the eps encoding: monotone interpolation, range errors, clipping."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fabkit.errors import FabkitError
from fabkit.fields import field_from_expression, parse_shape
from fabkit.toolpath.model import PRINT
from fabkit.toolpath.plan import PlanSettings, plan_toolpath
from fabkit.toolpath.process import (
    Calibration,
    encode_eps,
    load_process,
    machine_process,
)

SPEED = Calibration("print_speed_mm_s", (0.0, 0.2, 0.5, 1.0), (20.0, 12.0, 6.0, 2.0))


def test_encoding_hits_the_table_and_stays_monotone():
    assert encode_eps(np.array(SPEED.eps), SPEED).value == pytest.approx(SPEED.value)
    dense = encode_eps(np.linspace(0, 1, 501), SPEED).value
    assert np.all(np.diff(dense) < 0)  # decreasing table, decreasing everywhere
    assert dense.min() >= 2.0 and dense.max() <= 20.0  # no overshoot


def test_eps_outside_the_table_is_an_error_naming_both_ranges():
    with pytest.raises(FabkitError, match=r"spans \[-0.1, 0.5\].*range \[0, 1\]"):
        encode_eps(np.array([-0.1, 0.5]), SPEED)


def test_clipping_reports_the_clipped_fraction():
    clipping = dataclasses.replace(SPEED, clip=True)
    result = encode_eps(np.array([-0.5, 0.0, 0.5, 1.5]), clipping)
    assert result.clipped_fraction == pytest.approx(0.5)
    assert result.value[[0, 3]] == pytest.approx([20.0, 2.0])


@pytest.mark.parametrize(
    ("eps", "value", "message"),
    [
        ((0.0, 0.0), (1.0, 2.0), "strictly increasing"),
        ((0.0, 1.0, 2.0), (1.0, 3.0, 2.0), "increasing or decreasing"),
        ((0.0, 1.0), (1.0, -2.0), "positive"),
        ((0.0,), (1.0,), "at least 2"),
    ],
)
def test_bad_calibration_tables(eps, value, message):
    with pytest.raises(FabkitError, match=message):
        Calibration("print_speed_mm_s", eps, value)


def test_process_files_and_their_errors(tmp_path):
    good = tmp_path / "p.toml"
    good.write_text(
        "[process]\nroad_width_mm = 0.3\nlayer_height_mm = 0.2\nprint_speed_mm_s = 5\n"
        "travel_speed_mm_s = 20\n[process.calibration]\nparameter = 'extrusion_multiplier'\n"
        "eps = [0, 1]\nvalue = [0.8, 1.2]\nclip = true\n"
    )
    process = load_process(good)
    assert process.road_width_mm == 0.3 and process.calibration.clip
    cases = {
        "[process]\nroad_width_mm = 0.3\n": "layer_height_mm is missing",
        "[other]\n": "missing table \\[process\\]",
        good.read_text().replace("0.3", "'wide'"): "road_width_mm must be a number",
        good.read_text().replace("clip = true", "colour = 1"): "unknown key 'colour'",
        good.read_text().replace("extrusion_multiplier", "pressure"): "not one of",
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
    calibration = Calibration(parameter, (-0.5, 0.5), (1.0, 3.0))
    process = dataclasses.replace(machine_process(None), road_width_mm=0.4, calibration=calibration)
    plan = plan_toolpath([field], process, PlanSettings())
    assert plan.toolpath.parameter == parameter
    for _, move in plan.toolpath.moves():
        if move.kind != PRINT:
            continue
        expected = encode_eps(field.eps(move.xyz[:, :2]), calibration).value
        assert move.value == pytest.approx(expected)
        encoded = move.speed if parameter == "print_speed_mm_s" else move.flow
        assert encoded == pytest.approx(expected)
