"""The pre-flight check: a job that does not fit the machine is refused before any byte
is sent, with one line naming the file line, the value and the limit."""

from __future__ import annotations

import pytest

from fabkit.errors import FabkitError
from fabkit.link.check import check_job
from fabkit.link.gcode import code_of, commands_from_lines, frame_marlin, marlin_checksum, words
from fabkit.machines import load_machine


def check(lines: list[str], machine: str = "marlin_generic"):
    return check_job(commands_from_lines(lines), load_machine(machine), source="job.gcode")


def refused(lines: list[str], machine: str = "marlin_generic") -> str:
    with pytest.raises(FabkitError) as caught:
        check(lines, machine)
    message = str(caught.value)
    assert "\n" not in message
    return message


def test_a_good_job_is_summarised():
    result = check(["G21", "G90", "G28", "G1 X10 Y20 Z0.3 F1200", "G1 X110 E5", "G0 X0 Y0"])
    assert result.commands == 6 and result.moves == 3
    assert result.bounds_mm == ((0.0, 110.0), (0.0, 20.0), (0.3, 0.3))  # of the moves
    assert result.motion_time_s == pytest.approx((22.36 + 100 + 110.0 + 0.3) / 20, rel=1e-2)
    assert "6 commands, 3 moves fit machine marlin_generic" in result.summary()


@pytest.mark.parametrize(
    ("lines", "expected"),
    [
        (["G1 X230 F600"], "job.gcode:1: X=230.000 mm is outside the envelope x_mm = [0, 220]"),
        (["G28", "G91", "G1 Z200 F300", "G1 Z60"], "job.gcode:4: Z=260.000 mm is outside"),
        (["G1 X100 Y100 F600", "G2 X100 Y100 I70 J0"], "job.gcode:2: X=240.000 mm"),
        (["G1 X10 Y110 F600", "G3 X10 Y110 I0 J-105"], "job.gcode:2: X=-95.000 mm is outside"),
        (["G1 X10 F12000"], "feed 200.000 mm/s exceeds [limits] travel_mm_s = 150 mm/s"),
        (["G1 X10 E1 F6000"], "feed 100.000 mm/s exceeds [limits] print_mm_s = 80 mm/s"),
        (["G28", "G1 Z10 F600"], "job.gcode:2: Z speed 10.000 mm/s exceeds [limits] z_mm_s = 5"),
        (["G1 E-10 F4200"], "E speed 70.000 mm/s exceeds [limits] e_mm_s = 60"),
        (["M109 S300"], "M109 S300: 300 C exceeds [temperature] nozzle_max_c = 260 C"),
        (["M190 S150"], "exceeds [temperature] bed_max_c = 110 C"),
        (["M999"], "job.gcode:1: unknown command M999 for flavour marlin"),
        (["G20"], "inch units (G20) are not supported"),
        (["G1 X1*50"], "'*' is not allowed in a command (marlin)"),
        (["N10 G1 X1"], "already carries a line number"),
        (["M117 " + "x" * 80], "command is 85 characters long, the limit is 80"),
    ],
)
def test_refusals_name_the_line_the_value_and_the_limit(lines, expected):
    assert expected in refused(lines)


def test_flow_commands_make_moves_printing_moves():
    lines = ["G1 X10 F1800", "M42 P4 S255", "G1 X20", "M42 P4 S0", "G1 X30"]
    assert "job.gcode:3: feed 30.000 mm/s exceeds [limits] print_mm_s = 25" in refused(
        lines, "marlin_diw_pneumatic"
    )
    check([lines[0], "G1 X20", lines[4]], "marlin_diw_pneumatic")  # travel at 30 is fine


def test_grbl_rules():
    assert "G1 before any feed rate (F) was set" in refused(["G1 X1"], "grbl_diw")
    assert "'!' is not allowed" in refused(["G1 X1 F60 (stop!)x!"], "grbl_diw")
    assert "unknown command M82 for flavour grbl" in refused(["M82"], "grbl_diw")
    assert "unknown command G38.9" in refused(["G90 G38.9 X1"], "grbl_diw")
    result = check(["G90 G0 X10 Y10", "F600", "X20", "G91 X5", "$H"], "grbl_diw")
    assert result.bounds_mm[0] == (10.0, 25.0)  # bare axis words move in the modal mode
    assert "X=310.000 mm" in refused(["G0 X300", "G91", "G1 X10 F60"], "grbl_diw")


def test_klipper_extended_commands_and_profile_snippets_are_known():
    check(["SET_PRESSURE_ADVANCE ADVANCE=0.05", "G1 X1 F600"], "klipper_generic")
    assert "unknown command SET_PRESSURE_ADVANCE" in refused(["SET_PRESSURE_ADVANCE ADVANCE=1"])
    check(["M42 P4 S255", "M42 P4 S0"], "marlin_diw_pneumatic")


def test_a_manual_zero_makes_the_axis_uncheckable_and_says_so():
    result = check(["G92 X0 Y0 Z0", "G1 X500 Y-3 F600", "G1 Z1"])
    assert result.unchecked_axes == ("X", "Y", "Z")
    assert "X, Y, Z zeroed with G92 at an unknown position" in result.summary()
    homed = check(["G28", "G1 X50 F600", "G92 X0", "G1 X100"])  # a known zero stays checked
    assert homed.bounds_mm[0] == (50.0, 150.0)
    assert "X=230.000 mm" in refused(["G28", "G1 X50 F600", "G92 X0", "G1 X180"])


def test_a_machine_without_gcode_refuses_every_job():
    assert "takes no G-code" in refused(["G1 X1"], "dmd_photoalign")


def test_gcode_helpers():
    assert marlin_checksum(b"N0 M110 N0") == 125
    assert frame_marlin(0, "M110 N0") == b"N0 M110 N0*125\n"
    assert words("g1 x1.5 Y-2 e.5") == {"G": 1.0, "X": 1.5, "Y": -2.0, "E": 0.5}
    codes = ["G1 X1", "G01", "G38.2 Z-1", "$H", "X5", "SET_LED", "PRINT_START", "m104 S1"]
    assert [code_of(text) for text in codes] == [
        "G1", "G1", "G38.2", "$H", "X", "SET_LED", "PRINT_START", "M104",
    ]  # fmt: skip
