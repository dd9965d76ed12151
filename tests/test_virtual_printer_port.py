"""The VirtualPrinterPort adapter alone: OctoPrint's VirtualPrinter behind a pyserial face.

Hand-written clients here, not fabkit's sender: these tests say what the outside model
does with the Marlin line protocol, so that a sender's test can rely on it (and know
its quirks: the last tests pin down two of them)."""

from __future__ import annotations

import os
import threading
import time

import pytest
import serial
from octoprint.plugins.virtual_printer import virtual

from fabkit.gcode.read import frame_marlin
from tests.virtual_printer import DEFAULT_SETTINGS, VirtualPrinterPort, ping_pong_send

QUIET = {"simulateReset": False, "sendWait": False}  # no boot banner, no idle "wait"


def answers(port: VirtualPrinterPort, until: str = "ok", timeout: float = 2.0) -> list[str]:
    """Lines read up to and including the first starting with ``until``."""
    port.timeout = timeout
    lines = []
    while True:
        line = port.readline()
        assert line.endswith(b"\n"), f"no {until!r} within {timeout} s after {lines}"
        lines.append(line.decode("latin-1").strip())
        if lines[-1].startswith(until):
            return lines


def quiet(port: VirtualPrinterPort, for_s: float = 0.2) -> list[str]:
    """Everything that arrives until ``for_s`` of silence."""
    port.timeout = for_s
    lines = []
    while line := port.readline():
        lines.append(line.decode("latin-1").strip())
    return lines


def moves(count: int, first: int = 1) -> list[str]:
    return [f"G1 X{0.2 * n:.1f} Y{0.1 * n:.1f} F6000" for n in range(first, first + count)]


def test_a_one_line_per_ok_client_is_answered_like_by_marlin():
    assert frame_marlin(0, "M110 N0") == b"N0 M110 N0*125\n"
    assert frame_marlin(1, "M115") == b"N1 M115*39\n"
    with VirtualPrinterPort() as port:
        assert port.readline() == b"start\n"  # the boot banner is there on open
        port.reset_input_buffer()
        assert port.in_waiting == 0
        port.write(b"N0 M110 N0*125\n")
        assert answers(port) == ["ok"]
        port.write(b"N1 M115*39\n")
        reply = answers(port)
        assert reply[0] == "FIRMWARE_NAME:Virtual Marlin 1.0 PROTOCOL_VERSION:1.0"
        assert reply[-1] == "ok"
        texts = ["G90", *moves(4)]
        for n, text in enumerate(texts, start=2):
            assert port.write(frame_marlin(n, text)) == len(frame_marlin(n, text))
            assert answers(port) == ["ok"]
        assert port.executed == ["M115", *texts]  # the numbered M110 only sets the number
        assert port.accepted == [1, 2, 3, 4, 5, 6]


def test_a_bad_checksum_gets_error_resend_ok_and_the_resent_line_runs_once():
    with VirtualPrinterPort(**QUIET) as port:
        port.write(frame_marlin(0, "M110 N0"))
        port.write(frame_marlin(1, "G90"))
        assert answers(port) == ["ok"] and answers(port) == ["ok"]
        good = frame_marlin(2, "G1 X1 F6000")
        port.write(good.replace(b"*", b"*1"))
        assert answers(port) == ["Error: Missing checksum", "Resend:2", "ok"]
        port.write(good)
        port.write(frame_marlin(3, "G1 X2 F6000"))
        assert answers(port) == ["ok"] and answers(port) == ["ok"]
        assert port.executed == ["G90", "G1 X1 F6000", "G1 X2 F6000"]
        assert port.accepted == [1, 2, 3]


def test_lines_written_together_are_each_answered_at_once():
    # VirtualPrinter takes one line per item of its receive queue: the port hands it
    # one line per item, so a send-ahead host is answered line for line, not one late
    texts = moves(6)
    with VirtualPrinterPort(**QUIET, simulated_errors=[]) as port:
        port.write(
            frame_marlin(0, "M110 N0")
            + b"".join(frame_marlin(n, t) for n, t in enumerate(texts, 1))
        )
        assert [answers(port, timeout=0.5) for _ in range(7)] == [["ok"]] * 7
        assert port.executed == texts


def test_a_small_rx_buffer_still_gets_long_lines_through():
    texts = [
        f"G1 X{n}.123 Y{n}.456 Z0.300 E{n}.01234 F1800 ; a comment to be long" for n in range(8)
    ]
    frames = [frame_marlin(n, t) for n, t in enumerate(["M110 N0", *texts])]
    assert min(len(f) for f in frames[1:]) > 3 * 16
    with VirtualPrinterPort(**QUIET, rxBuffer=16, simulated_errors=[]) as port:
        port.write(frames[0] + frames[1])
        port.write(b"".join(frames[2:]))
        assert [answers(port) for _ in frames] == [["ok"]] * len(frames)
        assert port.executed == texts
        assert port.accepted == list(range(1, len(texts) + 1))


def test_read_waits_for_its_size_or_the_timeout():
    with VirtualPrinterPort(**QUIET) as port:
        port.timeout = 0.1
        start = time.monotonic()
        assert port.read(10) == b""
        assert 0.09 < time.monotonic() - start < 0.5
        port.write(b"M115\n")
        head = port.read(15)
        assert head == b"FIRMWARE_NAME:V"
        time.sleep(0.05)
        assert port.in_waiting > 0
        port.timeout = 0
        assert port.read(port.in_waiting).endswith(b"ok\n")
        assert port.read(1) == b""


def test_a_full_receive_queue_does_not_block_a_resend_request():
    # VirtualPrinter.write holds its _incoming_lock while it waits for room, and its
    # reader takes that lock to ask for a resend: called directly, both would wait for
    # write_timeout. The port waits for room without the lock.
    with VirtualPrinterPort(
        **QUIET, simulated_errors=[], rxBuffer=48, commandBuffer=1, write_timeout=3.0
    ) as port:
        port.write(frame_marlin(0, "M110 N0") + frame_marlin(1, "G91"))
        for n in (2, 3, 4):  # 0.3 s of simulated move each; the reader waits for the planner
            port.write(frame_marlin(n, "G1 X30 F600"))
        time.sleep(0.1)
        queue = port.printer.incoming
        port.printer.write(frame_marlin(5, "G1 X1 F600").replace(b"*", b"*1"))
        port.printer.write(frame_marlin(6, "G1 X1 F600"))
        port.printer.write(b"N7 G1 X1 F600 ;;;;;;;;;;;;;"[: queue.maxsize - queue.qsize()])
        assert queue.qsize() == queue.maxsize
        start = time.monotonic()
        port.write(b"\n" + frame_marlin(8, "G1 X1 Y1 Z0.1 E0.1 F600 ; longer than one line"))
        assert time.monotonic() - start < 2.5  # not write_timeout (3 s)
        assert "Resend:5" in quiet(port, 0.5)


def test_close_stops_every_thread_even_with_moves_and_reports_pending():
    before = set(threading.enumerate())
    port = VirtualPrinterPort(commandBuffer=2)
    folder = port.folder
    assert os.path.exists(os.path.join(folder, "eeprom.json"))
    port.write(frame_marlin(0, "M110 N0") + frame_marlin(1, "M155 S1"))  # a report timer
    port.write(b"".join(frame_marlin(n, "G1 X500 F60") for n in range(2, 8)))  # 50 s each
    time.sleep(0.1)
    assert len(set(threading.enumerate()) - before) >= 4  # reader, planner, timer, pump
    start = time.monotonic()
    port.close()
    assert time.monotonic() - start < 2.0  # the moves are cut short
    assert set(threading.enumerate()) - before == set()
    assert not os.path.exists(folder)
    port.close()  # again: nothing to do
    with pytest.raises(serial.PortNotOpenError):
        port.write(b"M105\n")
    with pytest.raises(serial.PortNotOpenError):
        port.read(1)


def test_nothing_of_octoprint_stays_patched():
    plugin_manager = virtual.plugin_manager
    command_regex = virtual.VirtualPrinter.command_regex
    with VirtualPrinterPort():
        assert virtual.plugin_manager is plugin_manager
    assert virtual.plugin_manager is plugin_manager
    assert virtual.VirtualPrinter.command_regex is command_regex


def test_settings_are_checked_and_nested_ones_merged():
    with pytest.raises(TypeError, match="rxbuffer"):
        VirtualPrinterPort(rxbuffer=16)
    with VirtualPrinterPort(**QUIET, errors={"checksum_mismatch": "Wrong sum"}) as port:
        assert port.settings["errors"]["checksum_missing"] == "Missing checksum"
        port.write(frame_marlin(0, "M110 N0"))
        port.write(frame_marlin(1, "M117 hi").replace(b"*", b"*9"))
        assert answers(port) == ["ok"]
        assert answers(port) == ["Error: Missing checksum", "Resend:1", "ok"]
    assert DEFAULT_SETTINGS["rxBuffer"] == 64  # the defaults stay as OctoPrint has them


def test_the_ping_pong_sender_gets_the_simulated_resend_right():
    texts = ["G90", *moves(101)]  # up to line 102: through the simulated resend at 100
    with VirtualPrinterPort(**QUIET) as port:
        assert ping_pong_send(port, texts) > 0
        assert port.executed == texts
        assert port.accepted == list(range(1, 103))


# -- VirtualPrinter's quirks, pinned down -----------------------------------------------------


def test_resend_with_timeout_claims_a_line_it_never_runs():
    # the default simulated error at 105: Error/Resend:105/ok, then the next line is
    # dropped unseen, yet VirtualPrinter counts 105 as received and refuses it after
    line_105 = "G1 X1 F6000"
    with VirtualPrinterPort(**QUIET) as port:
        port.write(frame_marlin(104, "M110 N104"))
        assert answers(port) == ["ok"]
        port.write(frame_marlin(105, line_105))
        assert answers(port) == ["Error: Missing checksum", "Resend:105", "ok"]
        port.write(frame_marlin(105, line_105))
        assert quiet(port, 0.3) == []  # swallowed
        port.write(frame_marlin(105, line_105))
        assert answers(port) == ["Error: expected line 106 got 105", "Resend:106", "ok"]
        assert port.accepted == [105] and port.executed == []


def test_after_a_resend_a_checksum_error_asks_for_the_wrong_line():
    # VirtualPrinter answers a checksum error with Resend: <checksummed lines counted
    # since M110> + 1, which runs ahead of the line number after each resend: the
    # corrupted line 6 is taken as received and never run
    texts = moves(8)
    with VirtualPrinterPort(**QUIET, simulated_errors=["3:resend"]) as port:
        port.write(frame_marlin(0, "M110 N0"))
        assert answers(port) == ["ok"]
        for n in (1, 2, 3):
            port.write(frame_marlin(n, texts[n - 1]))
            answers(port)
        for n in (3, 4, 5):
            port.write(frame_marlin(n, texts[n - 1]))
            assert answers(port) == ["ok"]
        port.write(frame_marlin(6, texts[5]).replace(b"*", b"*1"))
        assert answers(port) == ["Error: Missing checksum", "Resend:7", "ok"]
        assert port.accepted == [1, 2, 3, 4, 5, 6]
        assert texts[5] not in port.executed


def test_a_line_read_late_reaches_it_with_the_next_one_and_that_one_is_swallowed():
    # late=b"N105 ": N105 waits in the port until N106 comes, then goes first; after
    # its Resend:105 VirtualPrinter swallows N106, and the copy of 105 is a repeat to it
    with VirtualPrinterPort(**QUIET, late=b"N105 ") as port:
        port.write(frame_marlin(104, "M110 N104"))
        assert answers(port) == ["ok"]
        port.write(frame_marlin(105, "G1 X1 F6000"))
        assert quiet(port, 0.3) == []  # held back
        port.write(frame_marlin(106, "G1 X2 F6000"))
        assert answers(port) == ["Error: Missing checksum", "Resend:105", "ok"]
        assert quiet(port, 0.3) == []  # 106 swallowed
        port.write(frame_marlin(105, "G1 X1 F6000"))
        assert answers(port) == ["Error: expected line 106 got 105", "Resend:106", "ok"]
        assert port.accepted == [105] and port.executed == []
