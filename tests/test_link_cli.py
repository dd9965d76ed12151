"""``fabkit send``: the whole path from a file to the emulator, and every refusal is one
line with exit code 2."""

from __future__ import annotations

import errno
import os
import re
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest
import serial.serialposix

import fabkit.link.host.send as send_module
from fabkit.cli import main
from fabkit.errors import FabkitError
from fabkit.link.host.ports import open_port
from tests.conftest import ROOT
from tests.test_link_support import grbl_job, marlin_job
from tests.test_link_virtual_printer import sent_as
from tests.virtual_printer import VirtualPrinterPty

SIM = "sim://marlin?time_scale=0&baud=0"


def write(tmp_path: Path, lines: list[str], name: str = "job.gcode") -> str:
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    return str(path)


def marlin_file(tmp_path: Path, n: int = 300) -> str:
    return write(tmp_path, ["; sliced by a test"] + [c.text for c in marlin_job(n)])


def error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("fabkit: error: ")
    return err[-1]


def test_send_streams_and_reports(tmp_path, capsys):
    path = marlin_file(tmp_path)
    assert main(["send", path, "--port", f"{SIM}&corrupt=0.01&seed=1"]) == 0
    captured = capsys.readouterr()
    lines = captured.out.splitlines()
    assert lines[0].startswith("machine marlin_generic (the default:")
    assert lines[1].startswith("estimated duration: ")
    assert re.match(r"sent 305 lines \(file lines 2-306\) to sim://marlin", lines[2])
    assert "sending: 305/305 (100%)" in captured.err  # the progress bar is on stderr


def test_dry_run_checks_and_sends_nothing(tmp_path, capsys):
    path = marlin_file(tmp_path, 10)
    assert main(["send", path, "--dry-run"]) == 0
    assert "15 commands, 11 moves fit machine marlin_generic" in capsys.readouterr().out
    assert main(["send", path, "--dry-run", "--machine", "grbl_diw"]) == 2
    assert error_line(capsys).endswith("job.gcode:4: unknown command M82 for flavour grbl")


def test_a_port_that_does_not_exist_is_refused_before_the_long_check_of_the_file(tmp_path):
    # The file's last move leaves the machine: had the file been checked first (seconds on
    # a long file), that would be the error. The order is what is tested, not a time.
    moves = [f"G1 X{10 + k % 50} Y{10 + k % 7} F1200" for k in range(20_000)]
    path = write(tmp_path, ["G21", "G90", *moves, "G1 X100000 F1200"])
    process = subprocess.run(
        [sys.executable, "-m", "fabkit", "send", path, "--port", "/dev/fabkit-no-such-port"],
        capture_output=True, text=True, timeout=120, env={**os.environ, "PYTHONPATH": str(ROOT)},
    )  # fmt: skip
    assert process.returncode == 2
    assert (
        process.stderr
        == "fabkit: error: cannot open port /dev/fabkit-no-such-port: no such device\n"
    )
    assert process.stdout == ""  # no machine note, no estimate: they come after the check
    dry = subprocess.run(
        [sys.executable, "-m", "fabkit", "send", path, "--dry-run"],
        capture_output=True, text=True, timeout=120, env={**os.environ, "PYTHONPATH": str(ROOT)},
    )  # fmt: skip
    assert dry.returncode == 2 and "outside the envelope" in dry.stderr, dry.stderr


def test_a_refused_file_closes_the_port_opened_before_it_and_sends_nothing(
    tmp_path, capsys, monkeypatch
):
    opened = []

    def recording(port: str, baud: int):
        opened.append(open_port(port, baud))
        return opened[-1]

    monkeypatch.setattr(send_module, "open_port", recording)
    path = write(tmp_path, ["G21", "G90", "G1 X10 F600", "G1 X300 Y5"])
    assert main(["send", path, "--port", SIM]) == 2
    captured = capsys.readouterr()
    assert captured.err == (
        f"fabkit: error: {path}:4: X=300.000 mm is outside the envelope x_mm = [0, 220] "
        "of machine marlin_generic\n"
    )
    assert captured.out == ""
    [port] = opened
    assert not port.is_open
    assert port.emulator.counters.max_rx_bytes == 0  # not a byte reached the machine
    assert main(["send", marlin_file(tmp_path, 5), "--port", SIM, "--resume-from", "99"]) == 2
    assert "--resume-from 99 is outside" in error_line(capsys)
    assert len(opened) == 2 and not opened[1].is_open


def test_a_dry_run_opens_no_port(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(send_module, "open_port", None)  # calling it would fail
    path = marlin_file(tmp_path, 5)
    assert main(["send", path, "--port", "/dev/fabkit-no-such-port", "--dry-run"]) == 0
    assert "fit machine marlin_generic" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("port", "reason"),
    [
        ("/dev/does-not-exist", "no such device"),
        ("/dev/null", "not a serial device"),
        ("sim://marlin?speed=9", "unknown sim option 'speed'"),
        ("sim://printer", "'sim://printer' is not sim://marlin or sim://grbl"),
        ("nosuchscheme://x", "bad URL (a device path, or a URL pyserial or fabkit knows: "),
        ("loop://?speed=9", "bad URL"),  # pyserial's loop:// raises a KeyError
    ],
)
def test_bad_ports_are_one_line_of_fabkit_s_own(tmp_path, capsys, port, reason):
    assert main(["send", marlin_file(tmp_path, 5), "--port", port]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"fabkit: error: cannot open port {port}: {reason}")
    assert err.count("\n") == 1 and "Errno" not in err and "could not" not in err


def test_a_folder_is_not_a_serial_device(tmp_path):
    with pytest.raises(FabkitError, match=r": not a serial device$"):
        open_port(str(tmp_path), 115200)


@pytest.mark.parametrize(
    ("number", "reason"),
    [
        (errno.EACCES, "permission denied (add your user to the dialout group: sudo usermod"),
        (errno.EBUSY, "busy (another program has it open)"),
        (errno.EIO, "input/output error (unplug the device and plug it in again)"),
        (errno.EPROTO, "protocol error"),  # any other: the system's words, once
    ],
)
def test_why_a_device_does_not_open_says_it_once(monkeypatch, number, reason):
    def refuse(path: str, flags: int, *args: object) -> int:
        raise OSError(number, os.strerror(number), path)

    monkeypatch.setattr(serial.serialposix.os, "open", refuse)  # the open pyserial calls
    with pytest.raises(FabkitError) as refused:
        open_port("/dev/ttyUSB0", 115200)
    assert str(refused.value).startswith(f"cannot open port /dev/ttyUSB0: {reason}")
    assert "Errno" not in str(refused.value)


def test_missing_port_and_a_mismatched_emulator(tmp_path, capsys):
    path = marlin_file(tmp_path, 5)
    assert main(["send", path]) == 2
    assert "--port is required" in error_line(capsys)
    assert main(["send", path, "--port", SIM, "--machine", "grbl_diw"]) == 2
    assert "sim://marlin?time_scale=0&baud=0 emulates a marlin machine" in error_line(capsys)


def test_sim_grbl_pairs_with_grbl_diw_by_default(tmp_path, capsys):
    path = write(tmp_path, [c.text for c in grbl_job(200)])
    assert main(["send", path, "--port", "sim://grbl?time_scale=0&baud=0"]) == 0
    assert "lines/s, grbl);" in capsys.readouterr().out


def test_disconnect_then_resume_from_the_named_line(tmp_path, capsys):
    path = marlin_file(tmp_path, 400)
    log = tmp_path / "send.log"
    assert main(["send", path, "--port", f"{SIM}&disconnect_after=150", "--log", str(log)]) == 2
    message = error_line(capsys)
    last = int(re.search(r"last acknowledged file line (\d+);", message).group(1))
    assert 140 < last < 150  # 150 commands ran, some of them the sender's M110 and M105
    assert message.endswith(f"continue with --resume-from {last + 1}")
    assert ">> N0 M110 N0*125" in log.read_text()  # the log survives the failure
    assert main(["send", path, "--port", SIM, "--resume-from", str(last + 1)]) == 0
    assert f"(file lines {last + 1}-406)" in capsys.readouterr().out


def test_resume_from_outside_the_file(tmp_path, capsys):
    path = marlin_file(tmp_path, 5)
    assert main(["send", path, "--port", SIM, "--resume-from", "99"]) == 2
    assert "--resume-from 99 is outside" in error_line(capsys)


def test_a_machine_without_gcode_and_an_unwritable_log(tmp_path, capsys):
    path = marlin_file(tmp_path, 5)
    assert main(["send", path, "--dry-run", "--machine", "dmd_photoalign"]) == 2
    assert "dmd_photoalign has flavour none" in error_line(capsys)
    log = str(tmp_path / "no" / "dir" / "x.log")
    assert main(["send", path, "--port", SIM, "--log", log]) == 2
    assert "cannot write log file" in error_line(capsys)


def test_a_missing_or_binary_file(tmp_path, capsys):
    assert main(["send", str(tmp_path / "none.gcode"), "--dry-run"]) == 2
    assert "cannot read G-code file" in error_line(capsys)
    binary = tmp_path / "bin.gcode"
    binary.write_bytes(b"G1 X1\nG1 X\xff2\n")
    assert main(["send", str(binary), "--dry-run"]) == 2
    assert error_line(capsys).endswith("bin.gcode:2: non-ASCII byte in G-code")


DIW_LINES = [
    ";FLAVOR:Marlin",
    ";Generated with fabkit 0.1.0 for machine marlin_diw_pneumatic",
    "G21",
    "G90",
    "M42 P4 S0",
    "G28",
    "G1 Z1 F600",
    "M42 P4 S255",
    *[f"G1 X{20 + k % 150} Y{20 + (7 * k) % 150} F1200" for k in range(400)],
    "M42 P4 S0",
]


def test_send_takes_the_machine_from_the_header_and_says_so(tmp_path, capsys):
    # a file fabkit wrote for marlin_diw_pneumatic uses M42 (not in marlin_generic's
    # list of commands): send used to check it against marlin_generic and refuse it
    path = write(tmp_path, DIW_LINES)
    assert main(["send", path, "--port", SIM]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0] == f"machine marlin_diw_pneumatic (named in the header of {path})"
    assert out[1].startswith("estimated duration: 0:")
    assert main(["send", path, "--dry-run"]) == 0
    dry = capsys.readouterr().out
    assert "fit machine marlin_diw_pneumatic" in dry and "estimated duration: " in dry


def test_a_machine_other_than_the_header_needs_force(tmp_path, capsys):
    path = write(tmp_path, DIW_LINES)
    assert main(["send", path, "--port", SIM, "--machine", "marlin_generic"]) == 2
    assert error_line(capsys) == (
        f"fabkit: error: {path} was written for machine marlin_diw_pneumatic (its header), "
        "not marlin_generic: send it with --machine marlin_diw_pneumatic, or add --force"
    )
    klipper = [line for line in DIW_LINES if "M42" not in line]  # klipper_generic has no valve
    path = write(tmp_path, klipper, "any.gcode")
    args = ["send", path, "--dry-run", "--machine", "klipper_generic", "--force"]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert out.startswith(
        "machine klipper_generic (--force: the header names marlin_diw_pneumatic)"
    )


@pytest.mark.slow
def test_ctrl_c_stops_safely_exits_130_and_names_the_resume_line(tmp_path, capsys, monkeypatch):
    # docs/troubleshooting.md: Ctrl-C exits with 130; fabkit send stops the machine first
    ports = []
    opened = send_module.open_port

    def keep(port, baud):
        ports.append(opened(port, baud))
        return ports[-1]

    monkeypatch.setattr(send_module, "open_port", keep)
    path = write(tmp_path, DIW_LINES)
    url = "sim://marlin?baud=0&time_scale=0.05&accel=500"
    timer = threading.Timer(0.5, os.kill, (os.getpid(), signal.SIGINT))
    timer.start()
    code = main(["send", path, "--port", url])
    timer.join()
    assert code == 130
    err = capsys.readouterr().err.strip().splitlines()[-1]
    match = re.fullmatch(
        r"fabkit: interrupted: safe-stop sent; the machine stopped at X [-\d.]+ Y [-\d.]+ "
        r"Z [-\d.]+, in file line (\d+); continue later with --resume-from (\d+)",
        err,
    )
    assert match and match.group(1) == match.group(2), err
    emulator = ports[0].emulator
    safe_stop = ["M410", "M114", "M42 P4 S0", "M42 P5 S0", "G91", "G1 Z5 F600", "G90"]
    ran = [e.command for e in emulator.trace if e.command != "M105"]  # the sender's probes
    assert ran[-len(safe_stop) :] == safe_stop


@pytest.mark.slow
def test_ctrl_c_during_run_send_names_the_resume_line_too(tmp_path, capsys, monkeypatch):
    """One behaviour everywhere: fabkit run --send stops like fabkit send (exit 130, the
    line where the machine stopped and the --resume-from that continues)."""
    from fabkit.link.host.session import SendInterrupted

    def interrupted(*_, **__):
        raise SendInterrupted("safe-stop sent; continue later with --resume-from 42")

    monkeypatch.setattr(send_module, "send_file", interrupted)
    spec = Path(__file__).parent.parent / "examples" / "two_shapes.toml"
    args = ["run", str(spec), "--out", str(tmp_path / "out"), "--send", "sim://marlin"]
    code = main([*args, "--step", "0.1", "--diagonals", "30", "--size", "20"])
    assert code == 130
    err = capsys.readouterr().err
    assert err == ("fabkit: interrupted: safe-stop sent; continue later with --resume-from 42\n")


@pytest.mark.parametrize("strict", [False, True], ids=["plain", "strict"])
def test_a_line_the_machine_may_not_have_run_comes_first_and_fails_strict(tmp_path, capsys, strict):
    # VirtualPrinter (default settings) on its pseudo-terminal: after Resend:105 it
    # swallows the next line and takes 105 as received, so 105 never runs (its copy is
    # refused, or is the line swallowed and never answered)
    moves = [f"G1 X{50 + 0.2 * i:.2f} Y50 E{0.001 * (i + 1):.4f} F3000" for i in range(195)]
    texts = ["G21", "G90", "M82", "G92 E0", "G1 Z0.3 F300", *moves]  # short: quick there
    path = write(tmp_path, texts)
    log = tmp_path / "send.log"
    with VirtualPrinterPty() as printer:
        args = ["send", path, "--port", printer.path, "--log", str(log)]
        code = main(args + (["--strict"] if strict else []))
    assert code == (1 if strict else 0)
    (text,) = sent_as(log.read_text(), 105)
    line = 1 + texts.index(text)
    summary = capsys.readouterr().out.splitlines()[2:]
    assert summary[0].startswith(f"WARNING: 1 line may not have run: file line {line} ({text}): ")
    assert summary[1].startswith("sent 200 lines (file lines 1-200)")
