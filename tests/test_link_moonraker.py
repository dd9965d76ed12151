"""``fabkit send --host moonraker+http://...``: against Moonraker itself, and a responder.

Moonraker (PyPI ``moonraker``) starts without Klipper: uploads, the file list and its
refusals are tested against the real server on loopback (tests/servers.py; it needs a
virtual environment of its own, named by ``FABKIT_MOONRAKER``, as ``.ci/run`` makes).
Printing needs Klipper, which is not on PyPI: progress, pause, cancel and the ends of a
job are tested against tests/moonraker_responder.py, written from Moonraker's API
documentation, not Moonraker.
"""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

import pytest

from fabkit.cli import main
from fabkit.errors import FabkitError
from fabkit.link.host.moonraker import Moonraker
from fabkit.link.host.send import send_file
from fabkit.link.host.web import HostOptions, WebClient, parse_host_url
from tests.moonraker_responder import MoonrakerResponder
from tests.servers import MOONRAKER_ENV, MoonrakerServer

KEY = "0123456789abcdef0123456789abcdef"
START = ["G21", "G90", "M82", "G92 E0", "G1 Z0.3 F300"]


def job_file(folder: Path, name: str, moves: int = 400, x_mm: float = 50.0) -> str:
    """A job of ``moves`` 0.2 mm moves for klipper_generic (about 30 bytes each)."""
    lines = START + [
        f"G1 X{x_mm + 0.2 * (i % 100):.2f} Y{50 + i // 100} F1200" for i in range(moves)
    ]
    path = folder / name
    path.write_text("\n".join(lines) + "\n")
    return str(path)


def when(condition, then, timeout_s: float = 30.0) -> threading.Thread:
    """A thread that calls ``then()`` as soon as ``condition()`` holds."""

    def watch() -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if condition():
                then()
                return
            time.sleep(0.02)

    thread = threading.Thread(target=watch, daemon=True)
    thread.start()
    return thread


# -- Moonraker itself, without Klipper ---------------------------------------------------


@pytest.fixture(scope="module")
def moonraker(tmp_path_factory) -> MoonrakerServer:
    executable = MoonrakerServer.executable_path()
    if executable is None:
        pytest.skip(
            f"no Moonraker: it pins pyserial==3.4, so it needs a virtual environment of its "
            f"own; set {MOONRAKER_ENV} to its moonraker (docs/link.md, .ci/run)"
        )
    with MoonrakerServer(tmp_path_factory.mktemp("moonraker"), executable) as server:
        yield server


@pytest.fixture
def real(moonraker, monkeypatch) -> str:
    monkeypatch.setenv("FABKIT_API_KEY", moonraker.key)
    return f"moonraker+{moonraker.url}"


def test_upload_and_the_file_list_work_without_klipper(moonraker, real, tmp_path, capsys):
    path = job_file(tmp_path, "square.gcode")
    assert main(["send", path, "--host", real, "--no-start"]) == 0
    size = Path(path).stat().st_size
    version = moonraker.call("GET", "/server/info").json()["result"]["moonraker_version"]
    assert capsys.readouterr().out.splitlines()[-1] == (
        f"uploaded square.gcode ({size} bytes) to {real} (Moonraker {version}); not started"
    )
    assert moonraker.files()["square.gcode"] == size
    stored = moonraker.call("GET", "/server/files/gcodes/square.gcode").content
    assert stored == Path(path).read_bytes()


def test_a_print_start_without_klippy_is_one_line(moonraker, real, tmp_path, capsys):
    before = moonraker.files()
    path = job_file(tmp_path, "start.gcode")
    assert main(["send", path, "--host", real]) == 2
    assert capsys.readouterr().err == (
        f"fabkit: error: {real}: Klippy not connected (klippy_state disconnected): start "
        "Klipper (its API server enabled), or upload only with --no-start\n"
    )
    assert moonraker.files() == before  # refused before the upload


def test_moonrakers_own_answers_without_klippy_are_one_line(moonraker):
    url = parse_host_url(f"moonraker+{moonraker.url}")
    printer = Moonraker(WebClient(url, moonraker.key, HostOptions()))
    with pytest.raises(FabkitError) as start:
        printer.start("square.gcode")
    assert str(start.value) == (
        f"{url.text}: Klippy not connected (POST /printer/print/start (503: Klippy Host not "
        "connected)): start Klipper (its API server enabled), or upload only with --no-start"
    )
    with pytest.raises(FabkitError, match=r"Klippy not connected \(POST /printer/objects/query "):
        printer.status()


def test_a_wrong_or_missing_key_is_one_line(moonraker, real, tmp_path, capsys, monkeypatch):
    path = job_file(tmp_path, "square.gcode")
    assert main(["send", path, "--host", real, "--api-key", "WRONG", "--no-start"]) == 2
    out, err = capsys.readouterr()
    assert err.startswith(f"fabkit: error: {real} refused the API key (401): give a valid key")
    assert "WRONG" not in out + err
    monkeypatch.delenv("FABKIT_API_KEY")
    assert main(["send", path, "--host", real, "--no-start"]) == 2
    assert f"{real} needs an API key (401)" in capsys.readouterr().err


def test_a_file_outside_the_envelope_is_refused_before_the_upload(
    moonraker, real, tmp_path, capsys
):
    before = moonraker.files()
    path = job_file(tmp_path, "far.gcode", moves=5, x_mm=400)
    assert main(["send", path, "--host", real, "--no-start"]) == 2
    assert "X=400.000 mm is outside the envelope" in capsys.readouterr().err
    assert moonraker.files() == before


def test_plain_http_asks_which_host_it_is(moonraker, real, tmp_path, capsys):
    path = job_file(tmp_path, "asked.gcode")
    assert main(["send", path, "--host", moonraker.url, "--no-start"]) == 0
    out = capsys.readouterr().out.splitlines()
    version = moonraker.call("GET", "/server/info").json()["result"]["moonraker_version"]
    assert out[0] == f"machine klipper_generic (the default: {path} names no machine in its header)"
    assert out[-1].endswith(f"to {moonraker.url} (Moonraker {version}); not started")


# -- the responder: printing -------------------------------------------------------------


@pytest.fixture
def responder(monkeypatch) -> MoonrakerResponder:
    monkeypatch.setenv("FABKIT_API_KEY", KEY)
    with MoonrakerResponder(KEY) as server:
        yield server


def printing_past(responder: MoonrakerResponder, position: int):
    def condition() -> bool:
        with responder.lock:
            status = responder.status()
        stats = status["print_stats"]
        return stats["state"] == "printing" and status["virtual_sdcard"]["file_position"] > position

    return condition


def test_a_job_prints_to_complete_with_progress(responder, tmp_path, capsys):
    path = job_file(tmp_path, "square.gcode")
    host = f"moonraker+{responder.url}"
    assert main(["send", path, "--host", host]) == 0
    out, err = capsys.readouterr()
    assert out.splitlines()[-1].startswith(
        f"printed square.gcode on {host} (Moonraker responder-0)"
    )
    assert out.splitlines()[-1].endswith("the host says complete, 100 % done")
    assert "printing: 405/405 (100%)" in err
    assert responder.files["square.gcode"] == Path(path).read_bytes()
    assert ("POST", "/printer/print/start") in responder.requests


def test_ctrl_c_cancels_the_job_on_the_host(responder, tmp_path, capsys):
    responder.bytes_per_s = 2000.0
    path = job_file(tmp_path, "long.gcode")
    host = f"moonraker+{responder.url}"
    pid = os.getpid()
    watcher = when(printing_past(responder, 1000), lambda: os.kill(pid, signal.SIGINT))
    assert main(["send", path, "--host", host]) == 130
    watcher.join()
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith(f"fabkit: interrupted: cancelled long.gcode on {host} (last at file line")
    assert err.endswith("the host says cancelled")
    assert responder.job["state"] == "cancelled"
    assert ("POST", "/printer/print/cancel") in responder.requests


def test_ctrl_z_pauses_and_resumes(responder, tmp_path, capsys):
    responder.bytes_per_s = 5000.0
    path = job_file(tmp_path, "paused.gcode")
    pid = os.getpid()

    def paused() -> bool:
        with responder.lock:
            return responder.status()["print_stats"]["state"] == "paused"

    pause = when(printing_past(responder, 1000), lambda: os.kill(pid, signal.SIGTSTP))
    resume = when(paused, lambda: os.kill(pid, signal.SIGTSTP))
    assert main(["send", path, "--host", f"moonraker+{responder.url}"]) == 0
    pause.join()
    resume.join()
    assert ("POST", "/printer/print/pause") in responder.requests
    assert ("POST", "/printer/print/resume") in responder.requests
    assert capsys.readouterr().out.endswith("the host says complete, 100 % done\n")


def test_a_busy_or_shut_down_printer_is_refused_before_the_upload(responder, tmp_path, capsys):
    host = f"moonraker+{responder.url}"
    path = job_file(tmp_path, "square.gcode")
    responder.klippy_state = "shutdown"
    responder.state_message = "MCU 'mcu' shutdown: Timer too close"
    assert main(["send", path, "--host", host]) == 2
    assert capsys.readouterr().err == (
        f"fabkit: error: {host}: Klippy is not ready (klippy_state shutdown: MCU 'mcu' shutdown: "
        "Timer too close): fix the printer (FIRMWARE_RESTART after a shutdown), then send again\n"
    )
    responder.klippy_state = "ready"
    responder.bytes_per_s = 1.0
    responder.files["other.gcode"] = b"G28\n" * 100
    responder.start_print("other.gcode")
    assert main(["send", path, "--host", host]) == 2
    assert capsys.readouterr().err == (
        f"fabkit: error: {host}: the printer is busy (printing other.gcode): wait for the job "
        "to end or cancel it, then send again\n"
    )
    assert "square.gcode" not in responder.files


def test_a_checksum_mismatch_is_one_line(responder, tmp_path, capsys):
    responder.corrupt_uploads = True
    path = job_file(tmp_path, "square.gcode")
    assert main(["send", path, "--host", f"moonraker+{responder.url}"]) == 2
    assert capsys.readouterr().err.endswith(
        "refused POST /server/files/upload (422: File checksum mismatch): the file changed on "
        "its way: send it again\n"
    )


def test_a_job_that_fails_on_the_host_is_one_line(responder, tmp_path, capsys):
    responder.bytes_per_s = 5000.0
    path = job_file(tmp_path, "failing.gcode")

    def fail() -> None:
        with responder.lock:
            responder.set_state("error", "Move out of range: 300.000 10.000 0.300")

    watcher = when(printing_past(responder, 1000), fail)
    assert main(["send", path, "--host", f"moonraker+{responder.url}"]) == 2
    watcher.join()
    err = capsys.readouterr().err
    assert " ended without completing (error: Move out of range: 300.000 10.000 0.300; last " in err
    assert err.endswith("see the printer and the host's log\n")


def test_a_host_that_goes_away_mid_job_is_a_lost_link(responder, tmp_path):
    responder.bytes_per_s = 2000.0
    path = job_file(tmp_path, "lost.gcode")
    watcher = when(printing_past(responder, 1000), responder.close)
    options = HostOptions(poll_s=0.05, lost_s=0.5, retries=0)
    with pytest.raises(FabkitError) as lost:
        send_file(
            path, host=f"moonraker+{responder.url}", host_options=options, show_progress=False
        )
    watcher.join()
    message = str(lost.value)
    assert message.startswith(f"lost the link to moonraker+{responder.url} for 0.5 s (cannot reach")
    assert "the job may still run there: last at file line " in message
