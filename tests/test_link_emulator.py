"""The emulator answers like real Marlin and GRBL, with real byte timing and buffers."""

from __future__ import annotations

import math

import pytest
import serial

import fabkit.link  # noqa: F401  (registers sim://)
from fabkit.gcode.read import frame_marlin
from fabkit.link.emulator import protocol_sim
from fabkit.link.emulator.port import Emulator, config_from_url


def marlin(options: str = "", now: float = 0.0) -> Emulator:
    url = "sim://marlin?time_scale=0&baud=0" + (f"&{options}" if options else "")
    emulator = Emulator(config_from_url(url, 115200), now=now)
    emulator.poll(now)  # the power-up banner
    return emulator


def grbl(options: str = "") -> Emulator:
    url = "sim://grbl?time_scale=0&baud=0" + (f"&{options}" if options else "")
    emulator = Emulator(config_from_url(url, 115200))
    assert b"Grbl 1.1h" in emulator.poll(0.0)
    return emulator


def talk(emulator: Emulator, data: bytes, now: float = 0.0) -> list[str]:
    emulator.host_write(data, now)
    return emulator.poll(now).decode("latin-1").splitlines()


def test_sim_urls_open_the_emulator_through_pyserial():
    assert "fabkit.link.emulator" in serial.protocol_handler_packages
    port = serial.serial_for_url("sim://marlin?time_scale=0", timeout=0.1)
    assert isinstance(port, protocol_sim.Serial)
    assert port.read(100).startswith(b"start\n")
    port.write(frame_marlin(0, "M110 N0"))
    assert port.read(3) == b"ok\n"
    port.close()


@pytest.mark.parametrize(
    ("url", "message"),
    [
        ("sim://reprap", "not sim://marlin or sim://grbl"),
        ("sim://marlin?colour=red", "unknown sim option 'colour'"),
        ("sim://marlin?corrupt=2", "corrupt='2': must be between 0 and 1"),
        ("sim://grbl?time_scale=-1", "time_scale='-1': must be a finite number >= 0"),
        ("sim://marlin?latency_ms=nan", "latency_ms='nan': must be a finite number >= 0"),
        ("sim://marlin?baud=inf", "baud='inf': must be a finite number >= 0"),  # not int(inf)
    ],
)
def test_bad_urls_say_what_is_wrong(url, message):
    with pytest.raises(serial.SerialException, match=message):
        serial.serial_for_url(url)


def test_marlin_checks_line_numbers_and_checksums_like_marlin():
    m = marlin()
    assert talk(m, frame_marlin(0, "M110 N0") + frame_marlin(1, "G1 X5 F600")) == ["ok", "ok"]
    bad = frame_marlin(2, "G1 X6").replace(b"*", b"*1")
    assert talk(m, bad) == ["Error:checksum mismatch, Last Line: 1", "Resend: 2", "ok"]
    assert talk(m, frame_marlin(3, "G1 X7")) == [
        "Error:Line Number is not Last Line Number+1, Last Line: 1",
        "Resend: 2",
        "ok",
    ]
    assert talk(m, b"N2 G1 X6\n") == [
        "Error:No Checksum with line number, Last Line: 1",
        "Resend: 2",
        "ok",
    ]
    assert talk(m, frame_marlin(2, "G1 X6")) == ["ok"]
    assert [(e.n, e.command, e.x_mm) for e in m.trace[1:]] == [
        (1, "G1 X5 F600", 5),
        (2, "G1 X6", 6),
    ]


def test_marlin_variants_differ_in_ok_after_resend_and_draining():
    bad = frame_marlin(1, "G1 X1").replace(b"G1", b"G2")
    follow = frame_marlin(2, "G1 X2")
    v20 = marlin("resend_ok=0")
    assert talk(v20, bad + follow) == ["Error:checksum mismatch, Last Line: 0", "Resend: 1"]
    assert v20.counters.drained_bytes == len(follow)  # arrived with the bad line: drained
    v11 = marlin("drain=0")
    assert talk(v11, bad + follow)[-3:] == [
        "Error:Line Number is not Last Line Number+1, Last Line: 0",
        "Resend: 1",
        "ok",
    ]


def test_unnumbered_lines_run_unchecked_and_unknown_commands_are_echoed():
    m = marlin()
    assert talk(m, b"G1 X3*99\n") == ["ok"]  # no N: Marlin ignores the checksum
    assert talk(m, b"G12 X1\n") == ['echo:Unknown command: "G12 X1"', "ok"]
    assert [e.command for e in m.trace] == ["G1 X3"]


def test_m105_answers_ok_with_temperatures_and_m109_reports_while_heating():
    m = marlin("time_scale=1&heat_tau_s=2")
    assert talk(m, b"M105\n") == ["ok T:25.00 /0.00 B:25.00 /0.00 @:0 B@:0"]
    m.host_write(b"M109 S200\n", 0.0)
    reports = m.poll(1.5).decode().splitlines()
    assert len(reports) == 2 and all(r.startswith(" T:") for r in reports)
    later = m.poll(20.0).decode().splitlines()
    assert later[-1] == "ok" and "T:199" in later[-2]


def test_byte_timing_at_the_port_baud_rate():
    m = Emulator(config_from_url("sim://marlin?time_scale=0", 115200))
    m.poll(10.0)
    frame = frame_marlin(0, "M110 N0")
    m.host_write(frame, 10.0)
    byte_s = 10 / 115200  # 10 bits per byte
    assert m.poll(10.0 + (len(frame) + 2.9) * byte_s) == b""
    assert m.poll(10.0 + (len(frame) + 3.1) * byte_s) == b"ok\n"


def test_full_planner_stops_reading_and_the_receive_buffer_overflows():
    m = marlin("time_scale=1&planner=2")
    talk(m, b"G1 X100 F600\nG1 X0\nG1 X100\n")  # 10 s each: the third waits for room
    assert not m.firmware.reading
    m.host_write(b"G1 Y1\n" * 40, 0.0)  # 240 bytes into a 127-byte ring
    m.poll(0.1)
    assert m.counters.overflow_bytes == 240 - 127 and m.counters.max_rx_bytes == 127


def test_dropped_oks_and_spurious_lines_come_from_the_seed():
    def answers(seed: int) -> list[str]:
        m = marlin(f"drop_ok=0.3&noise=0.3&seed={seed}")
        return talk(m, b"G1 X1\n" * 50)

    assert answers(7) == answers(7) != answers(8)
    assert 0 < answers(7).count("ok") < 50


def test_disconnect_after_delivering_the_ok_and_reset_banner():
    m = marlin("disconnect_after=2")
    assert talk(m, b"G1 X1\nG1 X2\nG1 X3\n") == ["ok", "ok"]
    assert m.disconnected and len(m.trace) == 2
    r = marlin("reset_after=1")
    assert talk(r, b"G1 X1\nG1 X2\n")[:2] == ["ok", "start"]


def test_grbl_answers_ok_error_and_status():
    g = grbl()
    assert talk(g, b"G1 X1\n") == ["error:22"]  # no feed rate yet
    assert talk(g, b"G1 X1 F600\nM99\n") == ["ok", "error:20"]
    assert talk(g, b"G0 X5\r\n") == ["ok", "ok"]  # \r and \n each end a line
    # grbl/report.c: Bf is free planner blocks (BLOCK_BUFFER_SIZE - 1 of 16) and rx bytes (128)
    assert talk(g, b"?")[0].startswith("<Idle|MPos:5.000,0.000,0.000|Bf:15,128")
    assert [e.command for e in g.trace] == ["G1 X1 F600", "G0 X5"]


def test_grbl_real_time_hold_resume_and_reset_alarm():
    g = grbl("time_scale=1")
    talk(g, b"G1 X100 F600\n")  # a 10 s move
    assert talk(g, b"!?", 1.0)[0].startswith("<Hold:0")
    assert talk(g, b"~?", 5.0)[0].startswith("<Run")
    lines = talk(g, b"\x18", 6.0)
    assert lines[0] == "ALARM:3" and "Grbl 1.1h" in lines[2]  # reset while moving
    assert talk(g, b"G1 X1\n", 7.0) == ["error:9"]
    assert talk(g, b"$X\n", 7.0) == ["[MSG:Caution: Unlocked]", "ok"]


def test_grbl_real_time_bytes_bypass_a_full_receive_buffer():
    g = grbl("time_scale=1&planner=1")
    talk(g, b"G1 X100 F600\nG1 X0\n")
    g.host_write(b"G1 Y1\n" * 30, 0.0)
    assert talk(g, b"?", 0.5)[0].startswith("<Run")
    assert g.counters.overflow_bytes > 0


def test_the_planner_accelerates_looks_ahead_and_knows_where_the_tool_is():
    m = marlin("time_scale=1&accel=500")
    # 100 mm at 50 mm/s, 500 mm/s^2 from rest to rest: 0.1 s up, 1.9 s cruise, 0.1 s down
    # (a move into an empty planner waits 0.1 s for company, as Marlin's does)
    talk(m, b"G1 X100 F3000\n")
    motion = m.firmware.motion
    assert motion.idle_time(0.0) == pytest.approx(0.1 + 2.1)
    assert motion.position_at(0.2)[0] == pytest.approx(2.5)  # the end of the ramp
    assert motion.position_at(1.1)[0] == pytest.approx(2.5 + 0.9 * 50)
    # a straight continuation planned before the first move runs: no stop between them
    talk(m, b"G1 X200\n", 0.05)
    assert motion.idle_time(0.05) == pytest.approx(0.1 + 0.1 + (200 - 5) / 50 + 0.1)
    # planned while the last one runs: its stop at X200 is fixed, as in Marlin
    talk(m, b"G1 X300\n", 3.0)
    assert motion.idle_time(3.0) == pytest.approx(0.1 + 4.1 + 2.1)
    stop = motion.position_at(3.5)[0]
    talk(m, b"M410\n", 3.5)  # quick stop: the planned moves are dropped, the tool stays
    assert 100 < stop < 200 and motion.pos[0] == pytest.approx(stop)
    assert motion.idle_time(3.5) == 3.5
    assert motion.finished == [0]  # only the first move ran to its end


def test_grbl_reports_its_buffers_as_grbl_does():
    g = grbl("rx=64&planner=8")
    assert talk(g, b"$I\n") == ["[VER:1.1h.20190830:fabkit emulator]", "[OPT:V,7,64]", "ok"]
    assert talk(g, b"?")[0].startswith("<Idle|MPos:0.000,0.000,0.000|Bf:7,64|")
    quiet = grbl("opt=0&bf=0")
    assert talk(quiet, b"$I\n")[1] == "[OPT:V]"
    assert "Bf:" not in talk(quiet, b"?")[0]


def test_repetier_says_wait_when_idle_and_skips_lines_it_has_seen():
    m = marlin("dialect=repetier")
    assert talk(m, frame_marlin(0, "M110 N0") + frame_marlin(1, "G1 X1")) == ["ok", "ok 1"]
    assert talk(m, frame_marlin(1, "G1 X1")) == ["skip 1", "ok"]  # a repeat: not run twice
    assert m.poll(1.5).decode().splitlines() == ["wait"]
    assert [e.command for e in m.trace] == ["G1 X1"]


@pytest.mark.parametrize(
    "url", ["sim://marlin?baud=0&time_scale=0", "sim://grbl?baud=0&time_scale=0"]
)
def test_polling_at_infinity_runs_everything_written_and_the_clock_stays_finite(url):
    emulator = Emulator(config_from_url(url, 115200), now=0.0)
    emulator.host_write(b"G1 X1 F600\n", 0.0)
    assert emulator.poll(math.inf).rstrip().endswith(b"ok")  # the boot text, then the ok
    emulator.host_write(b"G1 X2\n", 1.0)  # and it goes on from there
    assert emulator.poll(2.0).strip() == b"ok"
