"""The pre-flight check: a job is read as the machine's firmware reads it and refused before
any byte is sent, with one line naming the file line, if any command would leave the
envelope, exceed a limit, or cannot be checked."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from fabkit.errors import FabkitError
from fabkit.gcode.read import (
    MAX_JOB_BYTES,
    MAX_LINE_CHARS,
    code_of,
    commands_from_lines,
    frame_marlin,
    marlin_checksum,
    read_job,
    words,
)
from fabkit.link.host.preflight import check_job
from fabkit.machines import load_machine
from fabkit.writers.gcode import gcode_bytes
from tests.test_writers_common import baromorph_toolpath, fig1_toolpath, reprap_machine

GRBL = ["G21", "G90", "G94", "G17"]  # the modes a GRBL job must set itself
MARLIN = ["G21", "G90", "G28", "M82", "G92 E0"]
GCODE_MACHINES = [
    "marlin_generic",
    "klipper_generic",
    "hyrel_pulse",
    "grbl_diw",
    "marlin_diw_pneumatic",
    "laser_cutter",
]


def check(lines: list[str], machine: str = "marlin_generic"):
    return check_job(commands_from_lines(lines), load_machine(machine), source="job.gcode")


def refused(lines: list[str], machine: str = "marlin_generic") -> str:
    with pytest.raises(FabkitError) as caught:
        check(lines, machine)
    message = str(caught.value)
    assert "\n" not in message and message.startswith("job.gcode:")
    return message


# -- fabkit's own G-code -------------------------------------------------------------------


@pytest.mark.parametrize("example", [fig1_toolpath, baromorph_toolpath])
@pytest.mark.parametrize("name", GCODE_MACHINES)
def test_fabkits_own_gcode_passes_for_every_machine(name, example):
    machine = load_machine(name)
    data, summary = gcode_bytes(example(machine), machine)
    job = commands_from_lines(data.decode("ascii").splitlines())
    result = check_job(job, machine, "sheet.gcode")
    assert result.moves >= summary.motion_lines - 2  # every move is followed
    for k, axis in enumerate("xyz"):
        lo, hi = machine.envelope.axis(axis)
        assert lo <= result.bounds_mm[k][0] <= result.bounds_mm[k][1] <= hi


def test_the_reprap_flavour_of_a_profile_passes_too(tmp_path):
    machine = reprap_machine(tmp_path, 1.75)
    data, _ = gcode_bytes(baromorph_toolpath(machine), machine)
    assert check_job(commands_from_lines(data.decode().splitlines()), machine).moves > 100


# -- a good job ----------------------------------------------------------------------------


def test_a_good_job_is_summarised():
    result = check([*MARLIN, "G1 X10 Y20 Z0.3 F1200", "G1 X110 E5", "G0 X0 Y0"])
    assert result.commands == 8 and result.moves == 3
    assert result.bounds_mm == ((0.0, 110.0), (0.0, 20.0), (0.3, 0.3))  # of the moves
    assert "8 commands, 3 moves fit machine marlin_generic" in result.summary()


@pytest.mark.parametrize(
    ("lines", "expected"),
    [
        (["G1 X230 F600"], "job.gcode:6: X=230.000 mm is outside the envelope x_mm = [0, 220]"),
        (["G91", "G1 Z200 F300", "G1 Z60"], "job.gcode:8: Z=260.000 mm is outside"),
        (["G1 X100 Y100 F600", "G2 X100 Y100 I70 J0"], "job.gcode:7: X=240.000 mm"),
        (["G1 X10 Y110 F600", "G3 X10 Y110 I0 J-105"], "job.gcode:7: X=-95.000 mm is outside"),
        (["G1 X10 F12000"], "feed 200.000 mm/s exceeds [limits] travel_mm_s = 150 mm/s"),
        (["G1 X10 E1 F6000"], "feed 100.000 mm/s exceeds [limits] print_mm_s = 80 mm/s"),
        (["G1 Z10 F600"], "job.gcode:6: Z speed 10.000 mm/s exceeds [limits] z_mm_s = 5"),
        (["G1 E-10 F4200"], "E speed 70.000 mm/s exceeds [limits] e_mm_s = 60"),
        (["M109 S300"], "M109 S300: 300 C exceeds [temperature] nozzle_max_c = 260 C"),
        (["M190 S150"], "exceeds [temperature] bed_max_c = 110 C"),
        (["M104 S200 B400"], "M104 B400: 400 C exceeds [temperature] nozzle_max_c"),
        (["M104 S-65236"], "S-65236 is a negative temperature"),
        (["M999"], "job.gcode:6: unknown command M999 for flavour marlin"),
        (["G20"], "inch units (G20) are not supported"),
        (["G1 X1*50"], "'*' is not allowed in a command (marlin)"),
        (["N10 G1 X1"], "already carries a line number"),
        (["N-5 G1 X1"], "already carries a line number"),
        (["M117 " + "x" * 80], "command is 85 characters long, the limit is 80"),
    ],
)
def test_refusals_name_the_line_the_value_and_the_limit(lines, expected):
    assert expected in refused(MARLIN + lines)


# -- reading as Marlin, Klipper, RepRapFirmware and Hyrel do -------------------------------


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        ("G1 X4 00 F600", "stray number '00' in 'G1 X4 00 F600'"),
        ("G1 X10 X500 F600", "X given twice"),
        ("g1 x500", "lower-case 'g'"),
        ("G1 X10 f600", "lower-case 'f'"),
        ("G1 X{500} F600", "unexpected character '{'"),
        ("G1 X1.2.3 F600", "malformed number after X"),
        ("G01 X10 F600", "write G1 (Klipper does not know G01)"),
        ("G28 XY", "'XY' in 'G28 XY'"),
        ("G1 X F600", "X without a number"),
        ("G92.1", "unknown command G92.1 for flavour marlin"),
    ],
)
def test_text_the_firmwares_read_differently_is_refused(line, expected):
    assert expected in refused([*MARLIN, "G1 X5 F600", line])


def test_marlin_words_read_as_marlin_reads_them():
    result = check([*MARLIN, "G1 X 20Y30 F600", "G1X40E1", "M117 hello X500 world"])
    assert result.bounds_mm[:2] == ((20.0, 40.0), (30.0, 30.0))  # M117's text is not a move
    assert "Z speed" in refused([*MARLIN, "G1 X1E3 Z50 F600"])  # X1 E3: no exponent
    check(["g21", "g90", "g28", "g1 x10 f600"], "klipper_generic")  # Klipper upper-cases


def test_moves_need_the_modes_from_the_job():
    assert "no G90/G91 in the job before it" in refused(["G21", "G28", "G1 X10 F600"])
    assert "G1 before any feed rate (F) was set" in refused([*MARLIN, "G1 X10"])
    assert "the X position is unknown (not homed" in refused(["G91", "G1 X10 F600"])
    assert "absolute E from an unknown E position" in refused(["G90", "G28", "G1 X1 E1 F60"])
    check(["G90", "G28", "M83", "G1 X1 E1 F60"])  # relative E needs no position


def test_an_unknown_start_limits_the_feed_to_each_named_axis():
    assert "Z speed 100.000 mm/s exceeds" in refused(["G90", "G1 Z10 F6000"])
    check(["G90", "G1 Z10 F300"])  # the Z limit is 5 mm/s


def test_e_modes_follow_each_firmware():
    marlin = ["G91", "M83", "G90", "G28", "G92 E0", "G1 X10 E5 F600", "G1 X20 E10"]
    assert check(marlin).moves == 2  # Marlin: G90 makes E absolute again
    klipper = ["G91", "M83", "G90", "G28", "G1 X10 E5 F600", "G1 X20 E10"]
    assert check(klipper, "klipper_generic").moves == 2  # Klipper: M83 still holds
    check(marlin[:-1] + ["G1 X20 E64"])  # Marlin: absolute, 59 mm of E in 10 mm at 10 mm/s
    with pytest.raises(FabkitError, match="E speed 64.000 mm/s exceeds"):
        check(klipper[:-1] + ["G1 X20 E64"], "klipper_generic")  # Klipper: relative, 64 mm


def test_homing_clears_the_g92_shift_and_may_raise_z():
    result = check([*MARLIN, "G1 X50 F600", "G92 X0", "G1 X100"])
    assert result.bounds_mm[0] == (50.0, 150.0)  # machine X = 100 + the 50 mm shift
    assert "X=230.000 mm" in refused([*MARLIN, "G1 X50 F600", "G92 X0", "G1 X180"])
    assert check([*MARLIN, "G1 X50 F600", "G92 X0", "G28 X", "G1 X180"]).bounds_mm[0][1] == 180
    assert "'G28 X' may raise Z" in refused([*MARLIN, "G28 X", "G91", "G1 Z1 F60"])
    assert "G92 X0 cannot be checked: the X position is unknown" in refused(["G90", "G92 X0"])


@pytest.mark.parametrize(
    ("lost", "why"),
    [
        ("M84", "'M84' turned its motor off"),
        ("M18 X", "'M18 X' turned its motor off"),
        ("M410", "'M410' stopped the planned moves"),
        ("G29", "'G29' probes the bed"),
    ],
)
def test_commands_that_lose_the_position(lost, why):
    assert why in refused([*MARLIN, "G1 X10 F600", lost, "G91", "G1 X10"])
    check([*MARLIN, "G1 X10 F600", "M84 S30", "G91", "G1 X10"])  # S only sets the timeout


def test_feed_and_flow_overrides_scale_what_is_checked():
    assert "feed 250.000 mm/s exceeds" in refused([*MARLIN, "M220 S500", "G1 X100 F3000"])
    check([*MARLIN, "M220 S50", "G1 X100 F12000"])  # 200 mm/s at 50 % = 100 mm/s
    assert "E speed 100.000 mm/s exceeds" in refused(
        [*MARLIN, "G1 X10 F600", "M221 S500", "G1 X20 E20"]  # 5 x 20 mm of E in 10 mm
    )
    check([*MARLIN, "G1 X10 F600", "G1 X20 E20"])  # 20 mm/s without the override
    assert "an override must be between 1 and 999 %" in refused([*MARLIN, "M220 S0.5"])
    assert "an override must be between" in refused([*MARLIN, "M221 S70000"])
    assert "the check does not model R in M220" in refused([*MARLIN, "M220 R"])


def test_arcs_in_both_forms():
    start = [*MARLIN, "G1 X100 Y100 F600"]
    assert "X=386.449 mm is outside" in refused([*start, "G2 X120 Y110 R-500"])
    assert check([*start, "G2 X120 Y110 R500"]).bounds_mm[0] == (100.0, 120.0)
    assert "R10 is shorter than half the distance" in refused([*start, "G2 X200 Y100 R10"])
    assert "needs an end point different from its start" in refused([*start, "G2 R5"])
    assert "off its circle" in refused([*start, "G2 X110 Y100 I10 J3"])
    assert "X=300.000 mm" in refused([*start, "G2 I100 J0 P1"])  # P: whole turns
    assert "is outside the envelope" in refused([*start, "G2 X120 Y110 R500 P1"])
    assert check([*start, "G2 I60 J0"]).bounds_mm[0] == (100.0, 220.0)  # a full circle
    assert "R together with I/J" in refused([*start, "G2 X120 Y100 I10 R10"])
    assert "Klipper refuses R arcs" in refused(
        ["G90", "G28", "G1 X100 Y100 F600", "G2 X120 Y100 R10"], "klipper_generic"
    )


def test_m42_may_only_repeat_the_profiles_pin_writes():
    diw = ["G21", "G90", "G28"]
    check([*diw, "M42 P4 S255", "M42 P4 S0"], "marlin_diw_pneumatic")
    for line in ("M42 P4 S255 I", "M42 P6 S255", "M42 P4 S128", "M42 P4 T1 S255"):
        message = refused([*diw, line], "marlin_diw_pneumatic")
        assert "M42 may only repeat a pin write of the machine's own G-code (M42 P4 S0, " in (
            message
        )


def test_a_second_inks_valve_is_flow_too():
    """marlin_diw_pneumatic's second ink (M42 P5): moves while either valve is open print."""
    lines = ["G21", "G90", "G28", "G1 X10 F1800", "M42 P5 S255", "G1 X20"]
    assert "job.gcode:6: feed 30.000 mm/s exceeds [limits] print_mm_s = 25" in refused(
        lines, "marlin_diw_pneumatic"
    )
    switched = [*lines[:4], "M42 P5 S255", "M42 P5 S0", "M42 P4 S255", "M42 P4 S0", "G1 X20"]
    check(switched, "marlin_diw_pneumatic")  # both closed again: a travel at 30 is fine
    still_open = [*lines[:4], "M42 P4 S255", "M42 P5 S255", "M42 P4 S0", "G1 X20"]
    assert "print_mm_s = 25" in refused(still_open, "marlin_diw_pneumatic")


def test_flow_commands_make_moves_printing_moves():
    lines = ["G21", "G90", "G28", "G1 X10 F1800", "M42 P4 S255", "G1 X20", "M42 P4 S0", "G1 X30"]
    assert "job.gcode:6: feed 30.000 mm/s exceeds [limits] print_mm_s = 25" in refused(
        lines, "marlin_diw_pneumatic"
    )
    check([*lines[:4], "G1 X20", lines[7]], "marlin_diw_pneumatic")  # travel at 30 is fine


@pytest.mark.parametrize(
    ("machine", "line", "expected"),
    [
        ("marlin_generic", "T1", "T1 cannot be checked: a tool change may move the head"),
        ("marlin_generic", "M110 N100", "M110 N100 cannot be checked: fabkit numbers the lines"),
        ("marlin_generic", "G29 L-500", "cannot be checked: the check does not model L in G29"),
        ("marlin_generic", "G28 R50", "cannot be checked: the check does not model R in G28"),
        ("marlin_generic", "M104 I1", "cannot be checked: the check does not model I in M104"),
        ("hyrel_pulse", "M721 S100", "M721 S100 cannot be checked: Hyrel's unprime"),
        ("klipper_generic", "FORCE_MOVE STEPPER=stepper_x DISTANCE=500", "cannot be checked"),
        ("klipper_generic", "SET_KINEMATIC_POSITION X=0", "a Klipper extended command or macro"),
        ("klipper_generic", "SDCARD_PRINT_FILE FILENAME=x.gcode", "cannot be checked"),
        ("klipper_generic", "PRINT_START", "PRINT_START cannot be checked"),
        ("klipper_generic", "SET_GCODE_OFFSET Z=10 MOVE=1", "cannot be checked"),
        ("klipper_generic", "RESPOND MSG='hi'", "is not KEY=VALUE"),
        ("marlin_generic", "SET_PRESSURE_ADVANCE ADVANCE=1", "unknown command SET_PRESSURE"),
    ],
)
def test_commands_that_cannot_be_checked_are_named(machine, line, expected):
    assert expected in refused(["G21", "G90", "G28", line], machine)


def test_klipper_extended_commands_that_move_nothing_and_checked_heaters():
    klipper = ["G21", "G90", "G28", "SET_PRESSURE_ADVANCE ADVANCE=0.05", "STATUS"]
    heat = "SET_HEATER_TEMPERATURE HEATER=extruder TARGET=210"
    check([*klipper, heat, "G1 X1 F600"], "klipper_generic")
    expected = "SET_HEATER_TEMPERATURE TARGET=400: 400 C exceeds [temperature] nozzle_max_c"
    assert expected in refused([heat.replace("210", "400")], "klipper_generic")
    bed = "SET_HEATER_TEMPERATURE HEATER=heater_bed TARGET=150"
    assert "bed_max_c = 110 C" in refused([bed], "klipper_generic")
    chamber = "SET_HEATER_TEMPERATURE HEATER=chamber TARGET=50"
    assert "cannot be checked" in refused([chamber], "klipper_generic")


def test_hyrel_g0_feed_is_for_that_move_only():
    lines = ["G21", "G90", "G28", "G1 F99999", "G0 X10 F600", "G1 X20"]
    assert "job.gcode:6: feed 1666.650 mm/s exceeds" in refused(lines, "hyrel_pulse")
    assert check(lines[:5] + ["G0 X100"], "hyrel_pulse").moves == 2  # G0 alone: rapid


def test_reprap_only_models_temperature_g10_and_agreeing_e_modes(tmp_path):
    text = Path(load_machine("marlin_generic").path).read_text()
    (tmp_path / "rrf.toml").write_text(text.replace('flavour = "marlin"', 'flavour = "reprap"'))
    machine = str(tmp_path / "rrf.toml")
    check(["G21", "G90", "G28", "G10 P0 S200 R150", "M568 P0 S210"], machine)
    assert "only G10 P<tool> S<C> R<C>" in refused(["G21", "G90", "G28", "G10 L2 P1 X10"], machine)
    assert "M568 S300: 300 C exceeds" in refused(["M568 P0 S300"], machine)
    assert "the job has not set the E mode" in refused(
        ["G21", "G28", "M83", "G90", "G1 X1 E1 F60"],
        machine,  # Marlin absolute, Klipper not
    )
    assert "runs the tool change macros" in refused(["T0"], machine)


# -- reading as GRBL does ------------------------------------------------------------------


def test_grbl_strips_blanks_inside_words():
    assert "job.gcode:5: X=400.000 mm is outside the envelope x_mm = [0, 300]" in refused(
        [*GRBL, "G0 X4 00"], "grbl_diw"
    )
    assert "feed 100.000 mm/s exceeds [limits] travel_mm_s = 60" in refused(
        [*GRBL, "G1 X10 F6 000"], "grbl_diw"
    )
    result = check([*GRBL, "g 0 x1 0 0 (comment X900) y 2.5", "G1X10F6 00"], "grbl_diw")
    assert result.bounds_mm[:2] == ((10.0, 100.0), (2.5, 2.5))


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        ("G0 X10 X400", "GRBL rejects 'G0 X10 X400': X given twice (error:25)"),
        ("G1 X10 E5 F60", "GRBL has no E word (error:20)"),
        ("%", "GRBL rejects '%': '%' where a word letter is expected (error:1)"),
        ("G0 X", "no number after 'X' (error:2)"),
        ("G0 G1 X10", "two commands of one modal group (G1) (error:21)"),
        ("G1 X10 F-5", "F must not be negative (error:4)"),
        ("G0 X10 R5", "unused word R (error:36)"),
        ("G92 G0 X10", "two commands that use axis words (error:24)"),
        ("G1.5 X10", "G1.5 is not an integer command (error:23)"),
        ("G43 Z1", "unknown command G43 for flavour grbl"),
        ("M82", "unknown command M82 for flavour grbl"),
        ("G38.9 X1", "unknown command G38.9 for flavour grbl"),
        ("G0 X000000000100", "has more than 8 digits: GRBL and grblHAL read it differently"),
        ("G0 X1/00", "'/' in 'G0 X1/00': GRBL and grblHAL read it differently"),
        ("$J=G91X500F100", "unknown command $J for flavour grbl"),
        ("$N0=G0X400", "unknown command $N0 for flavour grbl"),
        ("G1 X1 F60 (stop!)x!", "'!' is not allowed"),
        ("G4", "G4 needs P (seconds) (error:28)"),
        ("G80 X10", "axis words with G80 (no motion mode) (error:31)"),
        ("G2 X10 F60", "no arc centre offsets in the plane (error:35)"),
        ("G2 Z10 I5 F60", "no axis words in the arc's plane (error:32)"),
        ("G53 G2 X10 I5 F60", "G53 needs G0 or G1 (error:30)"),
        ("G43.1 X1", "G43.1 takes exactly one Z word (error:37)"),
        ("G10 L3 P1 X0", "only G10 L2 and L20 are supported (error:20)"),
        ("G10 L2 P7 X0", "G10 P must be a whole number 0-6 (error:29)"),
        ("G10 L2 X0", "G10 needs P and L (error:28)"),
        ("G92", "no axis words (error:26)"),
        ("T300", "tool number above 255 (error:38)"),
    ],
)
def test_lines_grbl_rejects_are_refused_with_its_error(line, expected):
    assert expected in refused([*GRBL, "G0 X5 Y5 Z5", line], "grbl_diw")


def test_grbl_reads_command_numbers_as_it_does():
    assert "X=400.000 mm" in refused([*GRBL, "G0.001 X400"], "grbl_diw")  # hundredths: G0
    assert check([*GRBL, "G00 X10", "G01 X20 F60", "M08", "M09"], "grbl_diw").moves == 2


def test_grbl_moves_need_the_modes_from_the_job():
    assert "no G21 in the job before it" in refused(["G90", "G0 X10"], "grbl_diw")
    assert "no G90/G91 in the job before it" in refused(["G21", "G0 X10"], "grbl_diw")
    assert "no G94/G93 in the job before it" in refused(["G21", "G90", "G1 X10 F60"], "grbl_diw")
    assert "axis words without G0/G1 before any motion word" in refused([*GRBL, "X10"], "grbl_diw")
    assert "no G17/G18/G19 in the job before this arc" in refused(
        ["G21", "G90", "G94", "G0 X10 Y10", "G2 X20 Y10 I5 F60"], "grbl_diw"
    )
    assert "G1 before any feed rate (F) was set" in refused([*GRBL, "G1 X1"], "grbl_diw")
    result = check([*GRBL, "G0 X10 Y10", "F600", "X20", "G91 X5", "$H"], "grbl_diw")
    assert result.bounds_mm[0] == (10.0, 25.0)  # bare axis words move in the modal mode
    assert "X=310.000 mm" in refused([*GRBL, "G0 X300", "G91", "G1 X10 F60"], "grbl_diw")


def test_grbl_work_offsets_are_followed_in_machine_coordinates():
    start = [*GRBL, "G0 X100 Y100"]
    assert "X=350.000 mm" in refused([*start, "G10 L2 P1 X200", "G0 X150"], "grbl_diw")
    assert "X=350.000 mm" in refused([*GRBL, "G0 X250", "G10 L20 P1 X0", "G0 X100"], "grbl_diw")
    assert "X=350.000 mm" in refused([*GRBL, "G0 X250", "G92 X0", "G0 X100"], "grbl_diw")
    assert "the G55 offset of X is stored in the controller" in refused(
        [*start, "G55 G0 X10"], "grbl_diw"
    )
    result = check([*start, "G10 L2 P2 X50 Y0 Z0", "G55 G0 X10", "G54 G0 X20"], "grbl_diw")
    assert result.bounds_mm[0] == (20.0, 100.0)  # G55 X10 is machine X60
    assert "X=400.000 mm" in refused([*start, "G92 X0", "G92.1 X400"], "grbl_diw")
    assert "Z=100.000 mm" in refused([*start, "G43.1 Z100", "G0 Z0"], "grbl_diw")
    assert check([*start, "G43.1 Z10", "G49", "G0 Z0"], "grbl_diw").bounds_mm[2] == (0.0, 0.0)
    result = check([*start, "G91 G53 G0 X290", "G90 G0 X10"], "grbl_diw")
    assert result.bounds_mm[0] == (10.0, 290.0)  # G53: machine coordinates, not incremental
    assert "X=400.000 mm" in refused([*start, "G53 G0 X400"], "grbl_diw")


def test_grbl_g28_and_g30_go_through_their_intermediate_point():
    start = [*GRBL, "G0 X10 Y10 Z10"]
    assert "X=400.000 mm" in refused([*start, "G28.1", "G28 X400"], "grbl_diw")
    assert "Z=500.000 mm" in refused([*start, "G30.1", "G30 Z500"], "grbl_diw")
    assert "position stored in the controller by G28.1" in refused([*start, "G28"], "grbl_diw")
    result = check([*start, "G28.1", "G0 X200 Y200", "G28 X250", "G0 Y50"], "grbl_diw")
    assert result.bounds_mm[0] == (10.0, 250.0) and result.bounds_mm[1] == (10.0, 200.0)


def test_grbl_inverse_time_feed_is_converted_to_a_speed():
    start = [*GRBL, "G0 X10"]
    assert "feed 90.000 mm/s exceeds [limits] travel_mm_s = 60" in refused(
        [*start, "G93 G1 X100 F60"], "grbl_diw"
    )  # 90 mm in 1/60 min
    assert check([*start, "G93 G1 X100 F30", "G94 G1 X10 F600"], "grbl_diw").moves == 3
    assert "needs F on every feed move (error:22)" in refused(
        [*start, "G93 G1 X100 F30", "G1 X10"], "grbl_diw"
    )
    assert "G1 before any feed rate" in refused(
        [*start, "G93 G1 X100 F30", "G94 G1 X10"], "grbl_diw"
    )


def test_grbl_arcs_in_every_plane_and_both_forms():
    start = [*GRBL, "G0 X100 Y100 Z40"]
    assert "X=386.449 mm" in refused([*start, "G2 X120 Y110 R-500 F600"], "grbl_diw")
    assert "shorter than half the distance" in refused([*start, "G2 X200 Y100 R10 F60"], "grbl_diw")
    assert "Z=90.000 mm" in refused([*start, "G18 G3 X100 Z40 K25 F600"], "grbl_diw")
    assert "Z=90.000 mm" in refused([*start, "G19 G2 Y100 Z40 K25 F600"], "grbl_diw")
    result = check([*start, "G18 G2 X140 Z40 I20 F600"], "grbl_diw")
    assert result.bounds_mm[2] == (20.0, 40.0)  # clockwise from Z toward X: down to Z20
    assert "Y=-90.000 mm" in refused([*GRBL, "G0 X10 Y10", "G2 X10 Y10 I100 F600"], "grbl_diw")


def test_grbl_probe_stops_anywhere_on_its_way():
    start = [*GRBL, "G0 X100 Y100 Z5"]
    assert "Z=-10.000 mm" in refused([*start, "G38.2 Z-10 F100"], "grbl_diw")
    zeroed = [*start, "G38.2 Z0 F100", "G92 Z0"]  # Z0 is now somewhere in machine 0..5
    assert check([*zeroed, "G0 Z75"], "grbl_diw").bounds_mm[2] == (0.0, 80.0)
    assert "Z=80.500 mm" in refused([*zeroed, "G0 Z75.5"], "grbl_diw")
    assert "an arc from or to an uncertain point" in refused(
        [*start, "G38.2 Y50 F100", "G2 X110 Y50 I5 F60"], "grbl_diw"
    )


def test_grbl_flow_program_end_and_laser_power():
    assert "print_mm_s = 30" in refused([*GRBL, "G0 X10", "G1 X50 F2400 M8"], "grbl_diw")
    check([*GRBL, "G0 X10", "M8", "M2", "G90 G1 X50 F2400"], "grbl_diw")  # M2: flow off
    assert "X=400.000 mm" in refused([*GRBL, "G1 X10 F600", "M2", "X400"], "grbl_diw")
    laser = [*GRBL, "G0 X10 Y10 A20", "M3 S5", "G1 X20 F300"]
    assert check(laser, "scan_photoalign").moves == 2
    assert "laser power S50 mW exceeds [laser] max_power_mw = 20" in refused(
        [*laser, "G1 X30 S50"], "scan_photoalign"
    )
    assert "GRBL has no A word" in refused([*GRBL, "G0 X10 A20"], "grbl_diw")


MODELLED = {
    "marlin_generic": "G0 G1 G4 G21 G28 G29 G90 G91 M0 M1 M3 M4 M5 M7 M8 M9 M17 M18 M82 M83 M84 "
    "M104 M105 M106 M107 M109 M114 M115 M117 M118 M140 M190 M201 M203 M204 M205 M220 M221 "
    "M300 M400 M410 T0",
    "grbl_diw": "G0 G1 G17 G18 G19 G21 G28.1 G30.1 G40 G49 G53 G54 G55 G56 G57 G58 G59 G61 G80 "
    "G90 G91 G91.1 G92.1 G93 G94 M0 M1 M2 M3 M4 M5 M7 M8 M9 M30 M56 T0 T1 T2 T3 T4 T5 T6 T7 "
    "T8 T9",
}


@pytest.mark.slow
@pytest.mark.parametrize(("machine", "preamble"), [("marlin_generic", MARLIN), ("grbl_diw", GRBL)])
def test_every_other_command_is_refused(machine, preamble):
    """The check is an allow-list: of every G0-G199 (and .1, .2), M0-M999 and T0-T9 given
    alone, only these pass; each is a move, mode or offset the check follows, or moves and
    heats nothing (GRBL only records T). Everything else is refused."""
    profile = load_machine(machine)
    passed = []
    for code in [f"G{n}{s}" for n in range(200) for s in ("", ".1", ".2")] + [
        f"{letter}{n}" for letter, top in (("M", 1000), ("T", 10)) for n in range(top)
    ]:
        try:
            check_job(commands_from_lines([*preamble, "G0 X10 Y10 Z10 F300", code]), profile)
            passed.append(code)
        except FabkitError:
            pass
    assert passed == MODELLED[machine].split()


# -- reading a file ------------------------------------------------------------------------


def test_read_job_refuses_files_over_the_limits_quickly(tmp_path):
    big = tmp_path / "big.gcode"
    with big.open("wb") as handle:  # sparse: the size is refused before reading
        handle.truncate(MAX_JOB_BYTES + 1)
    with pytest.raises(FabkitError, match=r"big.gcode: G-code file of 64.0 MiB is larger than"):
        read_job(big)
    wide = tmp_path / "wide.gcode"
    wide.write_text("G21\nG1 X1 ;" + "x" * MAX_LINE_CHARS + "\n")
    with pytest.raises(FabkitError, match=r"wide.gcode:2: line longer than 4096 characters"):
        read_job(wide)
    many = tmp_path / "many.gcode"
    many.write_bytes(b"\n" * 2_000_001)
    with pytest.raises(FabkitError, match="more than 2000000 lines"):
        read_job(many)
    with pytest.raises(FabkitError, match="not a regular file"):
        read_job(tmp_path)
    if hasattr(os, "mkfifo"):  # a FIFO would block a plain open()
        os.mkfifo(tmp_path / "pipe.gcode")
        with pytest.raises(FabkitError, match="not a regular file"):
            read_job(tmp_path / "pipe.gcode")


def test_read_job_numbers_lines_as_an_editor_does(tmp_path):
    path = tmp_path / "job.gcode"
    path.write_bytes(b"G21\r\nG90\rG1 X1\x0cY2 F60\n\n(comment)\nM84")
    assert [(c.file_line, c.text) for c in read_job(path)] == [
        (1, "G21"), (2, "G90"), (3, "G1 X1\x0cY2 F60"), (6, "M84"),
    ]  # fmt: skip
    assert "control character in command" in str(
        pytest.raises(FabkitError, check_job, read_job(path), load_machine("marlin_generic")).value
    )
    path.write_bytes(b"G21\n\xe9\n")
    with pytest.raises(FabkitError, match=r"job.gcode:2: non-ASCII byte in G-code"):
        read_job(path)


def test_a_machine_without_gcode_refuses_every_job():
    assert "takes no G-code" in str(
        pytest.raises(FabkitError, check, ["G1 X1"], "dmd_photoalign").value
    )


def test_gcode_helpers():
    assert marlin_checksum(b"N0 M110 N0") == 125
    assert frame_marlin(0, "M110 N0") == b"N0 M110 N0*125\n"
    assert words("g1 x1.5 Y-2 e.5") == {"G": 1.0, "X": 1.5, "Y": -2.0, "E": 0.5}
    codes = ["G1 X1", "G01", "G38.2 Z-1", "$H", "X5", "SET_LED", "PRINT_START", "m104 S1", "G+ X1"]
    assert [code_of(text) for text in codes] == [
        "G1", "G1", "G38.2", "$H", "X", "SET_LED", "PRINT_START", "M104", "G",
    ]  # fmt: skip
