"""Real printer hosts on loopback for the tests: OctoPrint with its virtual printer, and
Moonraker without Klipper. Each runs in a process group of its own, in a temporary
folder, on a free port of 127.0.0.1, and is ended (SIGTERM, then SIGKILL) with its whole
group when the ``with`` block ends.

:class:`OctoPrintServer` runs ``octoprint serve`` (PyPI ``octoprint``, a test extra) from a
prepared base folder: ``config.yaml`` with the first-run wizard off, the online check and
the plugin blacklist off, and the bundled plugins the tests do not need disabled, first
those that reach past loopback (announcements, tracking, error tracking, software
update, plugin manager, discovery's zeroconf, backup's plugin repository); its
``virtual_printer`` enabled with no simulated errors; a user ``fabkit`` in ``users.yaml``
and an application key for it in the appkeys plugin's ``keys.yaml``, both written before
the start. It then connects the ``VIRTUAL`` port and waits until the printer is
Operational. OctoPrint runs as root only with ``--iknowwhatimdoing``.

:class:`MoonrakerServer` runs PyPI ``moonraker`` (Klipper's API server) with no Klippy
behind it. Moonraker pins ``pyserial==3.4``, which fabkit and OctoPrint (``>=3.5``)
cannot share, so it lives in a virtual environment of its own: ``FABKIT_MOONRAKER`` names
its ``moonraker`` executable (``.ci/run`` makes one; see docs/link.md). Its configuration
keeps it on loopback: no service provider, no announcements feed, an empty ``usb.ids``
so that it fetches none. Its API key is read through its Unix socket, which it trusts.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import requests

OCTOPRINT_KEY = "FABKITTESTKEY0123456789ABCDEF012"
MOONRAKER_ENV = "FABKIT_MOONRAKER"
_OFF_LOOPBACK_PLUGINS = [
    "announcements", "tracking", "errortracking", "softwareupdate", "pluginmanager",
    "discovery", "backup", "achievements", "health_check", "firmware_check", "file_check",
    "pi_support",
]  # fmt: skip


def free_port() -> int:
    """A TCP port of 127.0.0.1 nobody listens on (now)."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


class _Server:
    """A server process in a group of its own; ``url`` its base URL, ``key`` its API key."""

    url = ""
    key = ""
    process: subprocess.Popen | None = None

    def __enter__(self):
        try:
            self.start()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def start(self) -> None:
        raise NotImplementedError

    def spawn(self, args: list[str], log: Path) -> None:
        with open(log, "wb") as output:
            self.process = subprocess.Popen(
                args, stdout=output, stderr=subprocess.STDOUT, start_new_session=True
            )
        self.log = log

    def wait_for(self, ready, what: str, timeout_s: float = 60.0) -> None:
        """Poll ``ready()`` until it is true; fail with the server's log otherwise."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.process is not None and self.process.poll() is not None:
                break
            try:
                if ready():
                    return
            except (requests.RequestException, OSError):
                pass
            time.sleep(0.1)
        tail = self.log.read_text(errors="replace")[-3000:]
        raise RuntimeError(f"{what} did not happen within {timeout_s:g} s:\n{tail}")

    def close(self) -> None:
        """End the server's whole process group: SIGTERM, then SIGKILL for what is left."""
        if self.process is None:
            return
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.process.pid, signal.SIGTERM)
        with contextlib.suppress(subprocess.TimeoutExpired):
            self.process.wait(timeout=15)
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.process.pid, signal.SIGKILL)
        self.process.wait(timeout=5)

    def call(self, method: str, path: str, **kwargs: Any) -> requests.Response:
        headers = {"X-Api-Key": self.key}
        return requests.request(method, self.url + path, headers=headers, timeout=10, **kwargs)


class OctoPrintServer(_Server):
    """OctoPrint with its virtual printer connected (see the module's docstring)."""

    def __init__(self, folder: Path) -> None:
        self.base = folder / "octoprint"
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.key = OCTOPRINT_KEY

    def start(self) -> None:
        self._prepare()
        args = [sys.executable, "-m", "octoprint", "serve", "--host", "127.0.0.1",
                "--port", str(self.port), "--basedir", str(self.base)]  # fmt: skip
        if os.geteuid() == 0:
            args.append("--iknowwhatimdoing")
        self.spawn(args, self.base.parent / "octoprint.out")
        self.wait_for(lambda: self.call("GET", "/api/version").ok, "OctoPrint's API")
        self.connect()

    def connect(self) -> None:
        """Connect the virtual printer; wait until it is Operational."""
        answer = self.call(
            "POST", "/api/connection", json={"command": "connect", "port": "VIRTUAL"}
        )
        answer.raise_for_status()
        self.wait_for(lambda: self.connection() == "Operational", "the virtual printer", 20)

    def disconnect(self) -> None:
        self.call("POST", "/api/connection", json={"command": "disconnect"}).raise_for_status()
        self.wait_for(lambda: self.connection() == "Closed", "the disconnection", 20)

    def connection(self) -> str:
        return self.call("GET", "/api/connection").json()["current"]["state"]

    def job(self) -> dict[str, Any]:
        return self.call("GET", "/api/job").json()

    def files(self) -> dict[str, int]:
        """The files OctoPrint stores, with their sizes (bytes)."""
        answer = self.call("GET", "/api/files/local", params={"recursive": "true"}).json()
        return {item["path"]: item.get("size") for item in answer["files"]}

    def file(self, name: str) -> dict[str, Any]:
        return self.call("GET", f"/api/files/local/{name}").json()

    def wait_idle(self, timeout_s: float = 60.0) -> None:
        self.wait_for(lambda: self.job()["state"] == "Operational", "the end of the job", timeout_s)

    def _prepare(self) -> None:
        from argon2 import PasswordHasher  # OctoPrint's own password hasher (argon2-cffi)

        (self.base / "data" / "appkeys").mkdir(parents=True)
        config = {
            "server": {
                "firstRun": False,
                "onlineCheck": {"enabled": False},
                "pluginBlacklist": {"enabled": False},
            },
            "plugins": {
                "_disabled": _OFF_LOOPBACK_PLUGINS,
                "virtual_printer": {"enabled": True, "simulated_errors": []},
            },
            "serial": {"autoconnect": False},
        }
        user = {
            "password": PasswordHasher().hash(os.urandom(16).hex()),  # never used: the key is
            "active": True,
            "groups": ["admins", "users"],
            "permissions": [],
            "apikey": None,
            "settings": {},
        }
        keys = {"fabkit": [{"app_id": "fabkit tests", "api_key": self.key}]}
        _write_yaml(self.base / "config.yaml", config)
        _write_yaml(self.base / "users.yaml", {"_version": 2, "fabkit": user})
        _write_yaml(self.base / "data" / "appkeys" / "keys.yaml", keys)


class MoonrakerServer(_Server):
    """Moonraker without Klipper (see the module's docstring)."""

    def __init__(self, folder: Path, executable: str) -> None:
        self.data = folder / "moonraker"
        self.executable = executable
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"

    @staticmethod
    def executable_path() -> str | None:
        """The ``moonraker`` to run: ``FABKIT_MOONRAKER``, else one on the PATH."""
        return os.environ.get(MOONRAKER_ENV) or shutil.which("moonraker")

    def start(self) -> None:
        for folder in ("config", "misc", "comms", "gcodes"):
            (self.data / folder).mkdir(parents=True, exist_ok=True)
        (self.data / "misc" / "usb.ids").write_text("")
        (self.data / "config" / "moonraker.conf").write_text(
            f"[server]\nhost: 127.0.0.1\nport: {self.port}\n"
            f"klippy_uds_address: {self.data / 'comms' / 'klippy.sock'}\n\n"
            "[machine]\nprovider: none\nvalidate_service: False\n\n"
            "[announcements]\nenable_moonlight: False\n\n"
            "[authorization]\ncors_domains:\ntrusted_clients:\n\n"
            "[file_manager]\nenable_object_processing: False\n"
        )
        self.spawn(
            [self.executable, "-d", str(self.data), "-n"], self.data.parent / "moonraker.out"
        )
        sock = self.data / "comms" / "moonraker.sock"
        self.wait_for(lambda: sock.exists() and self._answers(), "Moonraker's API")
        self.key = self._unix_call(sock, "access.get_api_key")

    def files(self) -> dict[str, int]:
        """The files in the gcodes root, with their sizes (bytes)."""
        answer = self.call("GET", "/server/files/list", params={"root": "gcodes"}).json()
        return {item["path"]: item["size"] for item in answer["result"]}

    def _answers(self) -> bool:
        return requests.get(self.url + "/server/info", timeout=2).status_code == 401

    @staticmethod
    def _unix_call(path: Path, method: str) -> Any:
        """A JSON-RPC call on Moonraker's Unix socket (messages end with 0x03)."""
        with socket.socket(socket.AF_UNIX) as unix:
            unix.settimeout(10)
            unix.connect(str(path))
            unix.sendall(
                json.dumps({"jsonrpc": "2.0", "method": method, "id": 1}).encode() + b"\x03"
            )
            answer = b""
            while not answer.endswith(b"\x03"):
                answer += unix.recv(65536)
        return json.loads(answer[:-1])["result"]


def _write_yaml(path: Path, data: Any) -> None:
    """``data`` in YAML's JSON form (OctoPrint reads YAML)."""
    path.write_text(json.dumps(data, indent=1))
