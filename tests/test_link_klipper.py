"""fabkit's sender against Klipper's words: every answer form, and whole jobs on a pty.

The answers come from Klipper's source (klippy/gcode.py, extras/heaters.py, toolhead.py
at 84104bbbd) as recorded from a real klippy on its pseudo-terminal; the machine is the
Klipper-wording responder of tests/klipper_responder.py, written from the same source.
"""

from __future__ import annotations

import re

import pytest

from fabkit.errors import FabkitError
from fabkit.gcode.read import commands_from_lines
from fabkit.link import answers
from fabkit.link.answers import classify, identify
from fabkit.link.host.ports import open_port
from fabkit.link.host.send import stream_job
from fabkit.machines import load_machine
from tests.klipper_responder import KlipperResponder
from tests.test_link_support import HOUSEKEEPING, quick


@pytest.mark.parametrize(
    ("line", "kind", "temperatures"),
    [
        ("ok", answers.OK, False),
        ("ok B:0.0 /0.0 T0:0.0 /0.0", answers.OK, True),  # M105 with heaters
        ("ok B:21.4 /60.0 T0:180.2 /215.0", answers.OK, True),
        ("ok T:0", answers.OK, True),  # M105 without heaters
        ("ok FIRMWARE_NAME:Klipper FIRMWARE_VERSION:v0.13.0-730-g84104bbbd", answers.OK, False),
        ("B:20.1 /60.0 T0:25.0 /215.0", answers.TEMPERATURES, False),  # M109/M190 waiting
        ("X:0.000 Y:0.000 Z:0.000 E:0.000", answers.POSITION, False),  # M114
        ("!! Must home axis first: 10.000 10.000 0.000 [0.000]", answers.FATAL, False),
        ("!! Move out of range: 300.000 10.000 0.000 [0.000]", answers.FATAL, False),
        ("!! Shutdown due to M112 command", answers.FATAL, False),
        ("!! Printer is not ready", answers.FATAL, False),
        ("// Klipper state: Shutdown", answers.FATAL, False),
        ("// Klipper state: Disconnect", answers.FATAL, False),
        ("// Klipper state: Ready", answers.INFO, False),
        ("// Printer is shutdown", answers.INFO, False),
    ],
)
def test_every_klipper_answer_form(line, kind, temperatures):
    answer = classify(line)
    assert (answer.kind, answer.temperatures) == (kind, temperatures)
    assert answer.number is None  # Klipper's ok never names a line


def test_klipper_unknown_command_names_the_command():
    answer = classify('// Unknown command:"FOO"')
    assert (answer.kind, answer.text) == (answers.UNKNOWN_COMMAND, "FOO")


def test_klipper_is_known_by_its_m115_and_never_asked_for_a_resend():
    report = "ok FIRMWARE_NAME:Klipper FIRMWARE_VERSION:v0.13.0-730-g84104bbbd"
    firmware = identify(report, "marlin")
    assert firmware.name == "Klipper" and not firmware.drains and firmware.sequenced
    assert firmware.resend_ok is False  # never a resend request: nothing pairs with one
    assert identify("", "klipper").name == "Klipper"  # the profile's flavour alone


def klipper_job(moves: int) -> list:
    lines = ["G21", "G90", "M83", "G28", "M104 S200", "M109 S200", "G1 Z0.3 F600"]
    for i in range(moves):
        lines.append(f"G1 X{10 + i % 200} Y{10 + (7 * i) % 200} E0.05 F3000")
    return commands_from_lines(lines + ["M104 S0", "M400"])


@pytest.mark.parametrize("heaters", [True, False], ids=["heaters", "no-heaters"])
def test_a_job_completes_on_klipper_with_and_without_heaters(heaters):
    job = klipper_job(400)
    if not heaters:  # no extruder: no E, no hot end
        job = commands_from_lines(
            [c.text.replace(" E0.05", "") for c in job if not c.text.startswith("M10")]
        )
    machine = load_machine("klipper_generic")
    with KlipperResponder(heaters=heaters) as klipper:
        port = open_port(klipper.path, 250000)
        report = stream_job(port, job, machine, port_name=klipper.path, options=quick())
        port.close()
    assert [text for text in klipper.executed if text not in HOUSEKEEPING] == [c.text for c in job]
    assert klipper.errors == [] and report.resends == 0


def test_a_move_klipper_refuses_stops_the_job_naming_its_file_line():
    job = list(klipper_job(20))
    job.insert(12, job[12].__class__(99, "G1 X300 Y10 F3000"))  # outside the envelope
    machine = load_machine("klipper_generic")
    with KlipperResponder() as klipper:
        port = open_port(klipper.path, 250000)
        with pytest.raises(FabkitError) as caught:
            stream_job(port, job, machine, port_name="/tmp/printer", options=quick())
        port.close()
    assert re.fullmatch(
        r"/tmp/printer reported '!! Move out of range: 300\.000 10\.000 0\.300 \[[\d.]+\]' "
        r"at file line 99 \(G1 X300 Y10 F3000\)",
        str(caught.value),
    )


def test_a_move_before_homing_and_a_shutdown_are_one_line_each():
    machine = load_machine("klipper_generic")
    unhomed = commands_from_lines(["G90", "G1 X10 Y10 F3000"])
    with KlipperResponder() as klipper:
        port = open_port(klipper.path, 250000)
        with pytest.raises(FabkitError, match=r"reported '!! Must home axis first: 10.000 10"):
            stream_job(port, unhomed, machine, port_name="/tmp/printer", options=quick())
        port.close()
    shutdown = commands_from_lines(["G28", "G1 X10 F3000", "M112", "G1 X20 F3000"])
    with KlipperResponder() as klipper:
        port = open_port(klipper.path, 250000)
        with pytest.raises(FabkitError) as caught:
            stream_job(port, shutdown, machine, port_name="/tmp/printer", options=quick())
        port.close()
    assert "reported '// Klipper state: Shutdown' at file line 3 (M112)" in str(caught.value)
    assert "\n" not in str(caught.value)


def test_an_unknown_command_is_a_warning_and_the_job_goes_on():
    job = commands_from_lines(["G28", "M117 printing", "G1 X10 F3000"])
    with KlipperResponder() as klipper:
        port = open_port(klipper.path, 250000)
        report = stream_job(port, job, load_machine("klipper_generic"), options=quick())
        port.close()
    assert report.warnings == ("the machine did not know 'M117 printing'",)
    assert [text for text in klipper.executed if text not in HOUSEKEEPING] == [
        c.text for c in job
    ]  # acknowledged, once each (Klipper did not know M117: it did nothing)
