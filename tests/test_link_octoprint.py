"""``fabkit send --host octoprint+http://...`` against OctoPrint itself, on loopback.

One real OctoPrint server (PyPI ``octoprint``, tests/servers.py) runs for the whole
module, its bundled virtual printer connected. Every assertion about the job is the
server's own account (``GET /api/job``, the file's ``prints`` record), not fabkit's.
"""

from __future__ import annotations

import json
import os
import signal
import threading
import time
from pathlib import Path

import pytest

from fabkit.cli import main
from tests.servers import OctoPrintServer, free_port

SHORT = ["G21", "G90", "M82", "G92 E0", "G1 Z0.3 F300"]


def short_moves(n: int) -> list[str]:
    """``n`` 0.2 mm moves: the virtual printer takes them as fast as OctoPrint sends."""
    return SHORT + [f"G1 X{50 + 0.2 * (i % 100):.2f} Y{50 + i // 100} F1200" for i in range(n)]


def long_moves(n: int) -> list[str]:
    """``n`` 20 mm moves at 20 mm/s: the virtual printer, at a tenth of the time, spends
    0.1 s on each."""
    return SHORT + [f"G1 X{50 + 20 * (i % 2)} Y{50 + 0.5 * i:.1f} F1200" for i in range(n)]


def write(folder: Path, name: str, lines: list[str]) -> str:
    path = folder / name
    path.write_text("\n".join(lines) + "\n")
    return str(path)


@pytest.fixture(scope="module")
def octoprint(tmp_path_factory) -> OctoPrintServer:
    with OctoPrintServer(tmp_path_factory.mktemp("octoprint")) as server:
        yield server


@pytest.fixture
def host(octoprint, monkeypatch) -> str:
    """The server's URL; the key in the environment, as a user would keep it."""
    monkeypatch.setenv("FABKIT_API_KEY", octoprint.key)
    octoprint.wait_idle()
    return f"octoprint+{octoprint.url}"


def when(condition, then, timeout_s: float = 30.0) -> threading.Thread:
    """A thread that calls ``then()`` as soon as ``condition()`` holds."""

    def watch() -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if condition():
                then()
                return
            time.sleep(0.05)

    thread = threading.Thread(target=watch, daemon=True)
    thread.start()
    return thread


def printing(octoprint: OctoPrintServer, name: str):
    def condition() -> bool:
        job = octoprint.job()
        return job["state"] == "Printing" and (job["progress"]["filepos"] or 0) > 200

    return condition


def test_a_job_prints_to_completion_with_progress_and_no_key_anywhere(
    octoprint, host, tmp_path, capsys
):
    path = write(tmp_path, "square.gcode", short_moves(600))
    log = tmp_path / "send.log"
    assert main(["send", path, "--host", host, "--log", str(log)]) == 0
    out, err = capsys.readouterr()
    job = octoprint.job()
    assert job["state"] == "Operational" and job["progress"]["completion"] == 100
    assert job["job"]["file"]["path"] == "square.gcode"
    assert octoprint.file("square.gcode")["prints"]["last"]["success"] is True
    lines = out.splitlines()
    assert (
        lines[0] == f"machine marlin_generic (the default: {path} names no machine in its header)"
    )
    assert lines[2].startswith(f"printed square.gcode on {host} (OctoPrint 1.11.")
    assert lines[2].endswith("the host says Operational, 100 % done")
    assert "printing: 605/605 (100%)" in err  # the progress bar of fabkit send, on stderr
    traffic = log.read_text()
    assert ">> POST /api/files/local" in traffic and "<< 201 CREATED" in traffic
    for text in (out, err, traffic):
        assert octoprint.key not in text


def test_ctrl_c_cancels_the_job_on_the_server(octoprint, host, tmp_path, capsys):
    path = write(tmp_path, "long.gcode", long_moves(200))
    pid = os.getpid()
    watcher = when(printing(octoprint, "long.gcode"), lambda: os.kill(pid, signal.SIGINT))
    assert main(["send", path, "--host", host]) == 130
    watcher.join()
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith(f"fabkit: interrupted: cancelled long.gcode on {host} (last at file line")
    assert err.endswith("the host says Operational")
    job = octoprint.job()
    assert job["state"] == "Operational" and job["progress"]["completion"] is None
    assert octoprint.file("long.gcode")["prints"]["last"]["success"] is False  # cancelled


def test_ctrl_z_pauses_and_resumes_the_job_on_the_server(octoprint, host, tmp_path, capsys):
    path = write(tmp_path, "paused.gcode", long_moves(50))
    pid = os.getpid()
    states = []

    def paused() -> bool:
        states.append(octoprint.job()["state"])
        return states[-1] == "Paused"

    pause = when(printing(octoprint, "paused.gcode"), lambda: os.kill(pid, signal.SIGTSTP))
    resume = when(paused, lambda: os.kill(pid, signal.SIGTSTP))
    assert main(["send", path, "--host", host]) == 0
    pause.join()
    resume.join()
    assert "Paused" in states
    assert octoprint.job()["progress"]["completion"] == 100
    assert "the host says Operational, 100 % done" in capsys.readouterr().out


def test_a_wrong_key_is_one_line_with_exit_2(octoprint, host, tmp_path, capsys, monkeypatch):
    wrong = "WRONGKEY0123456789"
    path = write(tmp_path, "square.gcode", short_moves(10))
    assert main(["send", path, "--host", host, "--api-key", wrong]) == 2
    out, err = capsys.readouterr()
    assert err == (
        f"fabkit: error: {host} refused the API key (403): give a valid key (OctoPrint: "
        "Settings > Application Keys) with --api-key, --api-key-file or FABKIT_API_KEY\n"
    )
    assert wrong not in out + err
    monkeypatch.delenv("FABKIT_API_KEY")
    assert main(["send", path, "--host", host]) == 2
    assert "needs an API key (403)" in capsys.readouterr().err


def test_a_file_outside_the_envelope_is_refused_before_the_upload(
    octoprint, host, tmp_path, capsys
):
    before = octoprint.files()
    path = write(tmp_path, "far.gcode", [*SHORT, "G1 X300 Y10 F1200"])
    assert main(["send", path, "--host", host]) == 2
    assert capsys.readouterr().err == (
        f"fabkit: error: {path}:6: X=300.000 mm is outside the envelope x_mm = [0, 220] of "
        "machine marlin_generic\n"
    )
    assert octoprint.files() == before


def test_no_start_uploads_only_and_plain_http_asks_the_server(octoprint, tmp_path, capsys):
    key = tmp_path / "octoprint.key"
    key.write_text(octoprint.key + "\n")
    octoprint.wait_idle()
    path = write(tmp_path, "later.gcode", short_moves(50))
    args = ["send", path, "--host", octoprint.url, "--api-key-file", str(key), "--no-start"]
    assert main(args) == 0
    size = Path(path).stat().st_size
    assert capsys.readouterr().out.splitlines()[-1] == (
        f"uploaded later.gcode ({size} bytes) to {octoprint.url} (OctoPrint 1.11.8); not started"
    )
    assert octoprint.files()["later.gcode"] == size
    assert octoprint.job()["job"]["file"]["path"] != "later.gcode"  # not even selected


def test_a_printer_that_is_not_operational_is_refused(octoprint, host, tmp_path, capsys):
    before = octoprint.files()
    octoprint.disconnect()
    try:
        path = write(tmp_path, "square.gcode", short_moves(10))
        assert main(["send", path, "--host", host]) == 2
    finally:
        octoprint.connect()
    assert capsys.readouterr().err == (
        f"fabkit: error: {host}: the printer is not operational (state Closed): connect it "
        "in OctoPrint, then send again\n"
    )
    assert octoprint.files() == before


def test_a_busy_printer_and_its_409_are_one_line(octoprint, host, tmp_path, capsys):
    path = write(tmp_path, "busy.gcode", long_moves(100))
    with open(path, "rb") as data:
        octoprint.call("POST", "/api/files/local", files={"file": ("busy.gcode", data)},
                       data={"print": "true"}).raise_for_status()  # fmt: skip
    try:
        octoprint.wait_for(printing(octoprint, "busy.gcode"), "the other job", 20)
        other = write(tmp_path, "square.gcode", short_moves(10))
        assert main(["send", other, "--host", host]) == 2
        assert capsys.readouterr().err == (
            f"fabkit: error: {host}: the printer is busy (Printing busy.gcode): wait for the "
            "job to end or cancel it, then send again\n"
        )
        assert main(["send", path, "--host", host, "--no-start"]) == 2  # the printed file
        assert capsys.readouterr().err == (
            f"fabkit: error: {host} refused POST /api/files/local (409: Trying to overwrite "
            "file that is currently being printed): wait for the job that prints it to end\n"
        )
    finally:
        octoprint.call("POST", "/api/job", json={"command": "cancel"})
        octoprint.wait_idle()


def test_a_file_octoprint_does_not_take_is_its_415_in_one_line(octoprint, host, tmp_path, capsys):
    path = write(tmp_path, "square.txt", short_moves(10))
    assert main(["send", path, "--host", host]) == 2
    assert capsys.readouterr().err == (
        f"fabkit: error: {host} refused POST /api/files/local (415: Could not upload file, "
        "invalid type): OctoPrint takes G-code named *.gcode or *.gco\n"
    )


def test_nothing_listening_is_one_line(tmp_path, capsys):
    url = f"octoprint+http://127.0.0.1:{free_port()}"
    path = write(tmp_path, "square.gcode", short_moves(10))
    assert main(["send", path, "--host", url, "--api-key", "KEY"]) == 2
    assert capsys.readouterr().err == (
        f"fabkit: error: cannot reach {url} (Connection refused): check that the server runs "
        "and the URL is right\n"
    )


@pytest.mark.slow
def test_run_send_prints_the_sheet_and_reports_without_the_key(octoprint, host, tmp_path, capsys):
    """The whole way: fabkit run writes sheet.gcode for marlin_diw_pneumatic (its header
    names it, its valve is M42) and prints it through OctoPrint."""
    key = tmp_path / "octoprint.key"
    key.write_text(octoprint.key)
    out = tmp_path / "out"
    spec = Path(__file__).parent.parent / "examples" / "two_shapes.toml"
    args = ["run", str(spec), "--out", str(out), "--step", "0.1", "--diagonals", "30",
            "--size", "20", "--send", host, "--api-key-file", str(key),
            "--no-pictures"]  # fmt: skip
    assert main(args) == 0
    printed = capsys.readouterr()
    job = octoprint.job()
    assert job["job"]["file"]["path"] == "sheet.gcode" and job["progress"]["completion"] == 100
    report = json.loads((out / "report.json").read_text())
    sent = report["sent"]
    assert sent["host"] == host and sent["file"] == "sheet.gcode" and sent["started"]
    assert sent["state"] == "Operational" and sent["completion_percent"] == 100
    assert sent["uploaded_bytes"] == (out / "sheet.gcode").stat().st_size
    for text in (printed.out, printed.err, *(p.read_text() for p in out.glob("report.*"))):
        assert octoprint.key not in text
