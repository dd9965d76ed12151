"""One reading of the distance modes for the pre-flight check, verify and the estimate."""

from __future__ import annotations

import pytest

from fabkit.gcode.duration import estimate
from fabkit.gcode.modes import DistanceModes
from fabkit.gcode.read import commands_from_lines
from fabkit.link.host.preflight import check_job
from fabkit.machines import load_machine
from fabkit.verify.read_gcode import read_gcode


@pytest.mark.parametrize(
    ("flavour", "codes", "relative"),
    [
        ("marlin", ["G91"], True),  # G91 sets E's mode too (gcode.h)
        ("marlin", ["G91", "M82"], False),  # the last one says
        ("marlin", ["M83", "G90"], False),
        ("klipper", ["G91"], True),  # two flags: relative if either is
        ("klipper", ["M83", "G90"], True),  # G90 leaves M83 on
        ("klipper", ["G90", "M82"], False),
        ("reprap", ["G91", "M82"], None),  # the two readings disagree: unknown
        ("reprap", ["G90", "M83"], True),
        ("grbl", ["G91"], None),  # no E
    ],
)
def test_e_mode_as_each_firmware_reads_it(flavour, codes, relative):
    modes = DistanceModes(flavour)
    for code in codes:
        assert modes.apply(code)
    assert modes.e_relative is relative
    assert not modes.apply("G1")


def test_klipper_g91_extrudes_the_same_in_the_check_verify_and_the_estimate(tmp_path):
    # Klipper: G91 makes E relative without M83; verify used to read E as absolute there
    # (only Marlin's G91 set E), the estimate as relative
    lines = [
        "G21", "G28", "G92 E0", "M83", "G90", "G1 Z0.3 F600", "G1 X10 Y10 F3000",
        "G91", "M82",  # Klipper: G91 still on, so E stays relative
        *["G1 X1 E0.05 F1200"] * 20,
        "G90",
    ]  # fmt: skip
    machine = load_machine("klipper_generic")
    job = commands_from_lines(lines)
    checked = check_job(job, machine)  # refuses nothing: every E move is readable
    assert checked.moves > 20
    path = tmp_path / "job.gcode"
    path.write_text("\n".join(lines) + "\n")
    printed = read_gcode(path, machine)
    assert len(printed.start) == 20  # every one of the 20 moves deposits (relative E > 0)
    e = [p[3] for p in estimate(job, machine).positions]
    assert e[-1] == pytest.approx(20 * 0.05)  # 20 relative steps (absolute would be 0.05)
