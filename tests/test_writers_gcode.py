"""G-code writer: parsed back by an independent parser, inside the envelope, within the
limits, and extruding exactly the toolpath's volume, for every flavour and both examples."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from fabkit.errors import FabkitError
from fabkit.machines import load_machine
from fabkit.toolpath import PRINT, TRAVEL, Layer, Move, Toolpath
from fabkit.writers.gcode import GcodeOptions, gcode_bytes, write_gcode
from tests.test_writers_common import (
    baromorph_toolpath,
    fig1_toolpath,
    model_volume,
    replay,
    reprap_machine,
)

MACHINES = ["marlin_generic", "klipper_generic", "hyrel_pulse", "grbl_diw", "marlin_diw_pneumatic"]
EXAMPLES = {"fig1": fig1_toolpath, "baromorph": baromorph_toolpath}


def _e_per_mm3(summary) -> float:
    return {"filament": 4 / (math.pi * 1.75**2), "volume": 1.0}[summary.e_units]


@pytest.mark.parametrize("example", EXAMPLES)
@pytest.mark.parametrize("name", MACHINES)
def test_every_flavour_parses_inside_limits_with_exact_volume(tmp_path, name, example):
    machine = load_machine(name)
    toolpath = EXAMPLES[example](machine)
    out = tmp_path / "job.gcode"
    summary = write_gcode(toolpath, machine, out)
    text = out.read_text(encoding="ascii")
    flow_on = machine.gcode.flow_on_gcode.strip()
    run = replay(text, flow_on, machine.gcode.flow_off_gcode.strip())

    known = np.isfinite(run.position).all(axis=1)
    for k, axis in enumerate("xyz"):
        lo, hi = machine.envelope.axis(axis)
        assert lo <= run.position[known, k].min() and run.position[known, k].max() <= hi

    length = np.linalg.norm(run.step, axis=1)
    moving = np.isfinite(length) & (length > 0)
    limits = machine.limits
    extruding = (run.e_step > 0) | run.flowing
    printing = moving & (run.code == "G1") & extruding
    assert run.feed[printing].max() <= limits.print_mm_s * (1 + 1e-9)
    assert run.feed[moving & (run.code == "G0")].max() <= limits.travel_mm_s * (1 + 1e-9)
    for k, axis in enumerate("xyz"):
        component = np.abs(run.step[moving, k]) / length[moving] * run.feed[moving]
        assert component.max() <= limits.axis_mm_s(axis) * (1 + 1e-6)

    expected = model_volume(toolpath)
    if flow_on:  # no E axis: volume = length printed with the flow on x width x height
        assert not run.e_step.any()
        process = machine.process
        laid = length[printing].sum() * process.road_width_mm * process.layer_height_mm
        assert laid == pytest.approx(expected, rel=5e-3)
        assert run.commands.count(flow_on.split()[0]) >= len(toolpath.layers[0].prints)
    else:
        volume = run.e_step[moving].sum() / _e_per_mm3(summary)
        assert volume == pytest.approx(expected, rel=5e-3)
        assert run.e_step.sum() / _e_per_mm3(summary) == pytest.approx(expected, rel=5e-3)
    assert summary.volume_mm3 == pytest.approx(expected, rel=1e-9)
    assert summary.print_length_mm == pytest.approx(toolpath.print_length_mm, rel=1e-9)

    layers = [c for c in run.comments if c.startswith("LAYER:")]
    assert layers == [f"LAYER:{k}" for k in range(len(toolpath.layers))]
    assert "TYPE:FILL" in run.comments
    assert f"TIME:{round(summary.duration_s)}" in run.comments


def test_print_feeds_follow_the_calibrated_speeds():
    machine = load_machine("marlin_generic")
    toolpath = fig1_toolpath(machine)
    assert toolpath.channels == {"print_speed_mm_s": "eps"}
    text, _ = gcode_bytes(toolpath, machine)
    run = replay(text.decode())
    moving = np.nan_to_num(np.linalg.norm(run.step, axis=1)) > 0
    printing = (run.code == "G1") & (run.e_step > 0) & moving
    wanted = np.concatenate([m.speed[1:] for _, m in toolpath.moves() if m.kind == PRINT])
    np.testing.assert_allclose(np.sort(run.feed[printing]), np.sort(wanted), atol=0.05 / 60)
    assert len(np.unique(np.round(wanted, 1))) > 10  # eps really varies the feed


def test_hyrel_writes_volume_and_flow_from_the_calibration():
    machine = load_machine("hyrel_pulse")
    toolpath = fig1_toolpath(machine)
    assert toolpath.channels == {"extrusion_multiplier": "eps"}
    text, summary = gcode_bytes(toolpath, machine)
    assert summary.e_units == "volume" and summary.e_mode == "relative"
    run = replay(text.decode())
    length = np.nan_to_num(np.linalg.norm(run.step, axis=1))
    printing = (run.code == "G1") & (run.e_step > 0) & (length > 0)
    per_mm = run.e_step[printing] / length[printing]
    nominal = machine.process.road_width_mm * machine.process.layer_height_mm
    flows = per_mm / nominal
    cal = machine.process.encodes[0].table.value
    assert flows.min() >= cal[0] * 0.99 and flows.max() <= cal[-1] * 1.01


@pytest.mark.parametrize("mode", ["absolute", "relative"])
def test_absolute_and_relative_e_extrude_the_same(mode):
    machine = load_machine("klipper_generic")
    toolpath = baromorph_toolpath(machine)
    text, summary = gcode_bytes(toolpath, machine, GcodeOptions(e_mode=mode))
    lines = text.decode().splitlines()
    assert ("M82" if mode == "absolute" else "M83") in lines
    run = replay(text.decode())
    volume = run.e_step.sum() / _e_per_mm3(summary)
    assert volume == pytest.approx(model_volume(toolpath), rel=1e-4)
    # retraction: every hop retracts and un-retracts by the profile's length
    retract = machine.tool.retract_mm
    e_only = (np.nan_to_num(np.linalg.norm(run.step, axis=1)) == 0) & (run.e_step != 0)
    np.testing.assert_allclose(np.abs(run.e_step[e_only]), retract, atol=1e-5)
    assert run.e_step[e_only].sum() == pytest.approx(0.0, abs=1e-6)


def test_travels_lift_and_long_travels_only():
    machine = load_machine("marlin_generic")
    z = 0.2
    first = Move.make(PRINT, [[0, 0], [10, 0]], z, 0.45, 20.0)
    short = Move.make(TRAVEL, [[10, 0], [10, 0.5]], z, 0.0, 100.0, 0.0)
    second = Move.make(PRINT, [[10, 0.5], [0, 0.5]], z, 0.45, 20.0)
    third = Move.make(PRINT, [[0, 20], [10, 20]], z, 0.45, 20.0)  # implicit long travel
    toolpath = Toolpath((Layer(z, 0.2, (first, short, second, third)),))
    run = replay(gcode_bytes(toolpath, machine)[0].decode())
    travel_z = run.position[run.code == "G0", 2]
    assert np.nanmax(travel_z) == pytest.approx(z + machine.tool.travel_lift_mm)
    lifted = run.position[:, 2] > z + 1e-9
    short_travel = (run.code == "G0") & np.isclose(run.step[:, 1], 0.5)
    assert short_travel.sum() == 1 and not lifted[short_travel].any()
    long_travel = (run.code == "G0") & np.isclose(run.step[:, 1], 19.5)
    assert long_travel.sum() == 1 and lifted[long_travel].all()


def test_outside_the_envelope_is_an_error_before_writing(tmp_path):
    machine = load_machine("marlin_generic")
    toolpath = baromorph_toolpath(machine)
    out = tmp_path / "job.gcode"
    with pytest.raises(FabkitError, match=r"layer 0, move 0 \(print\).*X = .*outside the envelope"):
        write_gcode(toolpath, machine, out, GcodeOptions(offset_mm=(5.0, 110.0)))
    assert not out.exists() and not list(tmp_path.iterdir())


def test_feed_above_a_limit_is_an_error_before_writing(tmp_path):
    machine = load_machine("grbl_diw")  # print limit 30 mm/s
    move = Move.make(PRINT, [[0, 0], [10, 0], [20, 0]], 0.2, 0.25, np.array([10, 10, 45.0]))
    toolpath = Toolpath((Layer(0.2, 0.2, (move,)),))
    out = tmp_path / "job.gcode"
    with pytest.raises(FabkitError, match=r"vertex 2: print speed 45 mm/s is above the limit 30"):
        write_gcode(toolpath, machine, out)
    assert not out.exists()


def test_e_rate_above_the_limit_is_an_error():
    machine = load_machine("hyrel_pulse")  # e_mm_s = 2 (mm^3/s in volume units)
    move = Move.make(PRINT, [[0, 0], [10, 0]], 0.2, 2.0, 20.0)
    with pytest.raises(FabkitError, match="E rate"):
        gcode_bytes(Toolpath((Layer(0.2, 0.2, (move,)),)), machine)


def test_temperature_encoding_writes_m104_and_checks_the_maximum():
    machine = load_machine("marlin_generic")
    moves = [
        Move.make(PRINT, [[0, y], [10, y]], 0.2, 0.45, 20.0, 1.0, {"temperature_c": t})
        for y, t in ((0, 200.0), (1, 200.0), (2, 215.0))
    ]
    named = {"temperature_c": "eps"}
    toolpath = Toolpath((Layer(0.2, 0.2, tuple(moves)),), named)
    text = gcode_bytes(toolpath, machine)[0].decode()
    body = text.split("G92 E0")[-1]
    assert re.findall(r"^M104 S(\d+)$", body, flags=re.M) == ["200", "215", "0"]
    hot = {"temperature_c": 300.0}
    too_hot = Move.make(PRINT, [[0, 0], [10, 0]], 0.2, 0.45, 20.0, 1.0, hot)
    hot = Toolpath((Layer(0.2, 0.2, (too_hot,)),), named)
    with pytest.raises(FabkitError, match="300 C is above the maximum 260 C"):
        gcode_bytes(hot, machine)


def test_pneumatic_flow_multiplier_becomes_a_slower_feed():
    machine = load_machine("marlin_diw_pneumatic")
    move = Move.make(PRINT, [[0, 0], [10, 0], [20, 0]], 0.3, 0.41, 8.0, np.array([1, 1, 2.0]))
    run = replay(
        gcode_bytes(Toolpath((Layer(0.3, 0.3, (move,)),)), machine)[0].decode(),
        "M42 P4 S255",
        "M42 P4 S0",
    )
    printing = run.flowing & (run.code == "G1")
    assert run.feed[printing].tolist() == [8.0, 4.0]


def test_reprap_flavour_and_the_profiles_e_settings(tmp_path):
    machine = reprap_machine(tmp_path, 2.85)
    assert "M82" in machine.render("start_gcode")  # the profile's e_mode wins over it
    toolpath = baromorph_toolpath(machine)
    data, summary = gcode_bytes(toolpath, machine)
    assert data.startswith(b";FLAVOR:RepRap\n") and summary.e_mode == "relative"
    assert data.decode().splitlines().count("M83") == 1
    run = replay(data.decode())
    volume = run.e_step.sum() * math.pi * 2.85**2 / 4
    assert volume == pytest.approx(model_volume(toolpath), rel=1e-4)
    data, _ = gcode_bytes(toolpath, machine, GcodeOptions(filament_diameter_mm=1.75))
    volume = replay(data.decode()).e_step.sum() * math.pi * 1.75**2 / 4
    assert volume == pytest.approx(model_volume(toolpath), rel=1e-4)  # the option wins


def test_refusals_are_one_line_errors():
    toolpath = baromorph_toolpath(load_machine("marlin_generic"))
    with pytest.raises(FabkitError, match="takes no G-code"):
        gcode_bytes(toolpath, load_machine("dmd_photoalign"))
    with pytest.raises(FabkitError, match="pulses per mm"):
        gcode_bytes(toolpath, load_machine("hyrel_pulse"), GcodeOptions(e_units="pulses"))
    empty = Toolpath((Layer(0.2, 0.2, (Move.make(TRAVEL, [[0, 0], [1, 1]], 0.2, 0, 10, 0),)),))
    with pytest.raises(FabkitError, match="no print moves"):
        gcode_bytes(empty, load_machine("marlin_generic"))


def test_pulse_units_scale_the_volume():
    machine = load_machine("hyrel_pulse")
    toolpath = baromorph_toolpath(machine)
    text, summary = gcode_bytes(
        toolpath, machine, GcodeOptions(e_units="pulses", pulses_per_mm3=0.5)
    )
    run = replay(text.decode())
    assert run.e_step.sum() / 0.5 == pytest.approx(model_volume(toolpath), rel=1e-4)
    assert summary.e_units == "pulses"


@pytest.mark.parametrize(
    "options",
    [GcodeOptions(), GcodeOptions(filament_diameter_mm=2.85), GcodeOptions(e_units="volume")],
    ids=["profile", "filament-2.85", "volume"],
)
def test_verify_reads_the_volume_with_the_e_units_the_file_was_written_with(tmp_path, options):
    """The writer's E options may differ from the profile's tool; the reader takes them
    from the file's ;fabkit header, so the volume read back is the volume written."""
    from fabkit.verify.read_gcode import read_gcode

    machine = load_machine("marlin_generic")
    toolpath = baromorph_toolpath(machine)
    summary = write_gcode(toolpath, machine, tmp_path / "sheet.gcode", options)
    printed = read_gcode(tmp_path / "sheet.gcode", machine)
    assert printed.volume.sum() == pytest.approx(summary.volume_mm3, rel=1e-4)
