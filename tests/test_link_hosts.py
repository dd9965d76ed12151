"""Printer hosts without a server: their URLs, the API key, and the answers that are not
a host's (nothing, silence, another web server); OctoPrint and Moonraker themselves are
in tests/test_link_octoprint.py and tests/test_link_moonraker.py."""

from __future__ import annotations

import functools
import socket
import threading
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer

import pytest

from fabkit.cli import main
from fabkit.errors import FabkitError
from fabkit.link.host.send import send_file
from fabkit.link.host.web import HostOptions, is_host_url, parse_host_url, resolve_api_key
from tests.servers import free_port

JOB = ["G21", "G90", "M82", "G92 E0", "G1 Z0.3 F300", "G1 X60 Y60 E1 F1200"]


@pytest.fixture
def job(tmp_path) -> str:
    path = tmp_path / "job.gcode"
    path.write_text("\n".join(JOB) + "\n")
    return str(path)


def test_host_urls():
    url = parse_host_url("moonraker+https://printer.lab:7130/moonraker/")
    assert (url.kind, url.base) == ("moonraker", "https://printer.lab:7130/moonraker")
    assert parse_host_url("octoprint+http://127.0.0.1:5000").base == "http://127.0.0.1:5000"
    assert parse_host_url("HTTP://printer").kind is None
    for text in ("octoprint+http://x", "http://x:80", "Moonraker+HTTPS://x"):
        assert is_host_url(text)
    for text in ("sim://marlin", "/dev/ttyUSB0", "COM3", "socket://x:1", "rfc2217://x:1"):
        assert not is_host_url(text)
    for text, says in [
        ("ftp://printer", "expected octoprint+http://HOST:PORT"),
        ("octoprint+http://", "expected octoprint+http://HOST:PORT"),
        ("http://printer:99999", "not a URL"),
        ("http://printer/?key=SECRET", "a host URL has no query or fragment"),
    ]:
        with pytest.raises(FabkitError, match=says.replace("+", r"\+").replace("?", r"\?")):
            parse_host_url(text)
    with pytest.raises(FabkitError) as credentials:
        parse_host_url("octoprint+http://admin:SECRET@printer")
    assert "SECRET" not in str(credentials.value)


def test_the_api_key_comes_from_the_option_the_file_or_the_environment(tmp_path):
    key_file = tmp_path / "key"
    key_file.write_text("  FROMFILE  \nsecond line\n")
    environ = {"FABKIT_API_KEY": "FROMENV"}
    assert resolve_api_key("GIVEN", key_file, environ) == "GIVEN"
    assert resolve_api_key(None, key_file, environ) == "FROMFILE"
    assert resolve_api_key(None, None, environ) == "FROMENV"
    assert resolve_api_key(None, None, {}) is None
    for bad in ("has blank", "new\nline", "", "tab\there"):
        with pytest.raises(FabkitError) as refused:
            resolve_api_key(bad, None, {})
        assert str(refused.value) == (
            "the API key from --api-key is empty or holds blanks or control characters"
        )
    with pytest.raises(FabkitError, match="cannot read --api-key-file .*: No such file"):
        resolve_api_key(None, tmp_path / "none", {})


def test_a_dry_run_through_a_host_asks_it_nothing(job, capsys):
    nobody = f"127.0.0.1:{free_port()}"
    assert main(["send", job, "--host", f"octoprint+http://{nobody}", "--dry-run"]) == 0
    assert "6 commands, 2 moves fit machine marlin_generic" in capsys.readouterr().out
    assert main(["send", job, "--host", f"moonraker+http://{nobody}", "--dry-run"]) == 0
    assert "fit machine klipper_generic" in capsys.readouterr().out


def test_a_server_that_never_answers_is_a_timeout(job):
    with socket.socket() as silent:
        silent.bind(("127.0.0.1", 0))
        silent.listen()
        url = f"octoprint+http://127.0.0.1:{silent.getsockname()[1]}"
        options = HostOptions(answer_s=0.3, retries=0)
        with pytest.raises(FabkitError) as timeout:
            send_file(job, host=url, api_key="KEY", host_options=options)
    assert str(timeout.value) == (
        f"{url}: no answer to GET /api/version within 0.3 s: check that the server runs and "
        "the network"
    )


class _QuietFiles(SimpleHTTPRequestHandler):
    def log_message(self, *args: object) -> None:
        pass


def test_a_web_server_that_is_no_printer_host(job, tmp_path, capsys):
    handler = functools.partial(_QuietFiles, directory=str(tmp_path))
    with ThreadingHTTPServer(("127.0.0.1", 0), handler) as server:
        thread = threading.Thread(target=server.serve_forever, args=(0.05,), daemon=True)
        thread.start()
        url = f"http://127.0.0.1:{server.server_address[1]}"
        try:
            assert main(["send", job, "--host", url, "--api-key", "KEY"]) == 2
            neither = capsys.readouterr().err
            assert main(["send", job, "--host", f"octoprint+{url}", "--api-key", "KEY"]) == 2
            refused = capsys.readouterr().err
        finally:
            server.shutdown()
    assert neither == (
        f"fabkit: error: {url} answers as neither OctoPrint nor Moonraker (GET /server/info: "
        "404, GET /api/version: 404): name it octoprint+http://... or moonraker+http://...\n"
    )
    assert refused == (
        f"fabkit: error: octoprint+{url} refused GET /api/version (404: File not found): is "
        "this OctoPrint's address?\n"
    )
