"""The GRBL sender against the emulator: character counting, errors, alarms, real-time."""

from __future__ import annotations

import io
import re
import threading

import pytest

from fabkit.errors import FabkitError
from fabkit.gcode.read import Command, commands_from_lines
from fabkit.link.emulator.firmware import Counters
from fabkit.link.host.ports import open_port
from fabkit.link.host.send import stream_job
from fabkit.link.host.session import LinkControl, SendReport
from fabkit.machines import load_machine
from tests.test_link_support import executed, grbl_job, quick, resumed_once, run_sim

FAST = "sim://grbl?time_scale=0&baud=0"


def runs_every_line(url: str, job: list[Command]) -> tuple[SendReport, Counters]:
    """Stream ``job`` to the GRBL emulator at ``url`` (quick link options), which must run
    every line exactly once, in order; the send report and the emulator's statistics."""
    report, emulator = run_sim(url, job, "grbl_diw", options=quick())
    assert executed(emulator) == [c.text for c in job]
    return report, emulator.stats()


@pytest.mark.slow
def test_20k_lines_with_lost_garbled_and_spurious_answers_arrive_exactly_once_in_order():
    job = grbl_job(20_000)
    url = f"{FAST}&drop_ok=0.001&garble=0.01&noise=0.01&seed=2"
    report, stats = runs_every_line(url, job)
    assert stats.dropped_oks > 10 and stats.garbled_lines > 100 and stats.spurious_lines > 100
    # a barrier ($G) proved the lines whose answer was lost parsed: named, first line
    assert report.recoveries == len(report.may_not_have_run) > 0
    assert report.recoveries <= stats.dropped_oks + stats.garbled_lines
    first = f"WARNING: {report.recoveries} lines may not have run: file line"
    assert report.summary().startswith(first)


@pytest.mark.slow
def test_character_counting_keeps_the_receive_buffer_from_overflowing():
    job = grbl_job(200, seed=3)
    url = "sim://grbl?time_scale=0.001&baud=1000000&drop_ok=0.005&seed=4"
    _, stats = runs_every_line(url, job)
    assert stats.overflow_bytes == 0 and 100 < stats.max_rx_bytes <= 127


@pytest.mark.slow
def test_an_error_lets_the_buffered_lines_run_and_resume_runs_no_line_twice():
    # the machine is busy (moves take time), so lines pile up in GRBL's 127-byte buffer
    # behind the rejected one: they run anyway, and the resume line must come after them
    lines = ["G21", "G90", "F3000"] + [f"G1 X{100 if i % 2 else 10} Y{i % 7}" for i in range(150)]
    lines.insert(100, "G1 X10 Q5")  # Q: not a GRBL word here -> error:20
    job = commands_from_lines(lines)
    # slow enough (a move is 36 ms) that the host fills the buffer even on a loaded machine
    url = "sim://grbl?time_scale=0.02&baud=1000000"
    port = open_port(url, 115200)
    machine = load_machine("grbl_diw")
    with pytest.raises(FabkitError) as caught:
        stream_job(port, job, machine, port_name="sim://grbl")
    message = str(caught.value)
    assert "rejected file line 101 ('G1 X10 Q5'): error:20 unsupported command" in message
    assert "behind it, already in its buffer, ran; safe-stop sent" in message
    assert "\n" not in message
    first = executed(port.emulator)
    assert first[-4:] == machine.render("safe_stop_gcode")
    ran = first[:-4]
    assert len(ran) >= 108  # lines behind the rejected one ran (its 127 bytes were full)
    resume = int(re.search(r"--resume-from (\d+)", message).group(1))
    rest = [c for c in job if c.file_line >= resume]
    stream_job(port, rest, machine, port_name="sim://grbl")  # the same machine, its modes kept
    after = executed(port.emulator)[len(first) :]
    without_rejected = [c.text for c in job if c.file_line != 101]
    assert ran + after == without_rejected  # every line once, in order


def test_a_profile_buffer_larger_than_the_machine_reports_is_refused():
    # the machine has a 64-byte buffer: with grbl_diw's 128 GRBL would get truncated
    # lines (G1 X74F1200); $I says so, and so does an idle Bf: report without $I sizes
    for options, source in (("", "[OPT:V,15,64]"), ("&opt=0", "Bf:15,64")):
        port = open_port(f"{FAST}&rx=64{options}", 115200)
        with pytest.raises(FabkitError) as caught:
            stream_job(port, grbl_job(50), load_machine("grbl_diw"), port_name="sim://grbl")
        assert str(caught.value) == (
            f"sim://grbl reports a 64-byte receive buffer ({source}) but machine grbl_diw has "
            f"[serial] rx_buffer_bytes = 128: set it to 64 in {load_machine('grbl_diw').path}"
        )
        assert port.emulator.trace == []


@pytest.mark.slow
def test_a_larger_buffer_is_used_and_silence_about_it_is_a_warning():
    job = grbl_job(300, seed=3)
    url = "sim://grbl?time_scale=0.001&baud=1000000&rx=256"
    _, stats = runs_every_line(url, job)
    assert stats.overflow_bytes == 0 and stats.max_rx_bytes > 127
    report, emulator = run_sim(f"{FAST}&opt=0&bf=0", job, "grbl_diw")
    assert "did not report its receive buffer" in report.warnings[0]


def test_an_alarm_at_connection_is_refused():
    port = open_port(FAST, 115200)
    port.emulator.firmware.alarm = True
    with pytest.raises(FabkitError, match=r"is in ALARM state: home \(\$H\) or unlock \(\$X\)"):
        stream_job(port, grbl_job(5), load_machine("grbl_diw"), port_name="sim://grbl")


def test_an_alarm_during_the_job_stops_it():
    job = commands_from_lines(["G21", "F600"] + ["G1 X100", "G1 X0"] * 10)
    url = "sim://grbl?time_scale=1&baud=0&reset_after=3"  # a reset while moving: ALARM:3
    with pytest.raises(FabkitError, match=r"raised ALARM:3 reset while in motion; the machine"):
        run_sim(url, job, "grbl_diw", options=quick())


def test_abort_holds_resets_sends_the_safe_stop_and_names_the_line_it_stopped_in():
    job = grbl_job(2000)
    port = open_port("sim://grbl?time_scale=0.02&baud=0&accel=250", 115200)
    control = LinkControl()
    threading.Timer(0.3, control.abort).start()
    log = io.StringIO()
    with pytest.raises(FabkitError, match=r"^aborted: safe-stop sent; the machine stopped at X"):
        stream_job(port, job, load_machine("grbl_diw"), control=control, log=log)
    traffic = log.getvalue()
    assert ">> !" in traffic and ">> '\\x18'" in traffic
    assert executed(port.emulator)[-4:] == ["M9", "G91", "G0 Z5", "G90"]
    assert not port.emulator.firmware.alarm  # reset after the hold completed: no alarm


@pytest.mark.slow
def test_pause_is_a_feed_hold_and_resume_a_cycle_start():
    job = grbl_job(150)
    port = open_port("sim://grbl?time_scale=0.001&baud=0", 115200)
    control = LinkControl()
    states = []

    def pause_then_resume():
        control.pause()
        threading.Event().wait(0.2)
        states.append(port.emulator.firmware.state(port.emulator._now))
        control.resume()

    threading.Timer(0.1, pause_then_resume).start()
    log = io.StringIO()
    stream_job(port, job, load_machine("grbl_diw"), control=control, log=log)
    assert states == ["Hold:0"]
    assert ">> !" in log.getvalue() and ">> ~" in log.getvalue()
    assert executed(port.emulator) == [c.text for c in job]


def test_a_reset_during_the_job_names_the_lines_it_may_have_dropped_and_resume_loses_none():
    # a reset drops GRBL's planner and receive ring: the acknowledged lines still planned
    # and the lines sent last are named; resuming where it says runs each line at least
    # once, and only those named may run twice
    job = grbl_job(300)
    url = f"{FAST}&reset_after=100"
    port = open_port(url, 115200)
    with pytest.raises(FabkitError) as caught:
        stream_job(port, job, load_machine("grbl_diw"), port_name=url, options=quick())
    message = str(caught.value)
    found = re.search(r"file lines (\d+)-(\d+) \(acknowledged or sent last\) may or may", message)
    assert found and message.endswith(f"--resume-from {found.group(1)}")
    first, last = int(found.group(1)), int(found.group(2))
    ran = executed(port.emulator)
    texts = [c.text for c in job]
    assert ran == texts[: len(ran)]
    assert job[len(ran) - 1].file_line in range(first, last + 1)  # the reset fell in the range
    assert sum(first <= c.file_line <= last for c in job) <= 16 + 8  # planner + in flight
    modes = list(job[:6])  # a reset sets the modes back to GRBL's defaults: G21 G90 G94 ... F1200
    rest = [c for c in job if c.file_line >= first]
    stream_job(port, modes + rest, load_machine("grbl_diw"), port_name=url, options=quick())
    again = executed(port.emulator)[len(ran) :]
    assert again == [c.text for c in modes + rest]


@pytest.mark.slow
def test_a_lost_connection_names_the_lines_in_flight_and_resume_runs_each_once():
    # the line dies after 150 executed lines, with more in GRBL's ring: the message names
    # the lines sent and not answered (a GRBL whose cable was pulled runs them), and the
    # resume it prints runs every line, at most those twice
    job = grbl_job(400)
    url = "sim://grbl?time_scale=0.01&baud=1000000&disconnect_after=150"
    port = open_port(url, 115200)
    with pytest.raises(FabkitError) as caught:
        stream_job(port, job, load_machine("grbl_diw"), port_name=url, options=quick())
    message = str(caught.value)
    assert re.search(r"file lines \d+-\d+ were sent but not acknowledged and may have run", message)
    first = executed(port.emulator)
    resume = int(re.search(r"--resume-from (\d+)$", message).group(1))
    fresh = open_port("sim://grbl?time_scale=0&baud=0", 115200)
    rest = list(job[:6]) + [c for c in job if c.file_line >= resume]  # the modes, then the rest
    stream_job(fresh, rest, load_machine("grbl_diw"), options=quick())
    then = executed(fresh.emulator)[6:]
    assert resumed_once(first, then, job, message)
