"""OctoPrint's REST API (docs.octoprint.org/en/master/api; shapes as in OctoPrint 1.11's
``octoprint/server/api``): a Marlin-protocol printer behind OctoPrint, which streams the
file itself.

``GET /api/version`` (and the key), ``GET /api/connection`` (the printer must be
``Operational``), ``GET /api/job`` (no job running), ``POST /api/files/local`` (multipart
``file``, ``select=true`` to print it), ``POST /api/job`` (``start``, ``pause``,
``cancel``), ``GET /api/job`` for progress (``progress.filepos`` bytes, ``completion`` %,
``printTimeLeft`` s). A job that ends leaves the printer ``Operational`` with
``completion`` 100; a cancelled one with ``completion`` null.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from fabkit.errors import FabkitError
from fabkit.link.host.web import JobState, WebClient
from fabkit.machines import MachineProfile

if TYPE_CHECKING:
    import requests

_KEY_WHERE = "OctoPrint: Settings > Application Keys"
_ACTIVE = ("Starting", "Printing", "Sending", "Pausing", "Paused", "Resuming", "Cancelling",
           "Finishing")  # fmt: skip


class OctoPrint:
    """A printer behind OctoPrint (see the module's docstring)."""

    default_machine = "marlin_generic"

    def __init__(self, web: WebClient) -> None:
        self.web = web
        self.name = web.url.text

    def takes(self, machine: MachineProfile) -> None:
        if machine.serial is None or machine.serial.protocol != "marlin":
            protocol = machine.serial.protocol if machine.serial else "none"
            raise FabkitError(
                f"{self.name} streams to Marlin-protocol firmware but machine {machine.name} "
                f"speaks {protocol}"
            )

    def identify(self) -> str:
        response = self.web.call("GET", "/api/version")
        if response.status_code in (401, 403):
            raise self.web.key_refused(response, _KEY_WHERE)
        if response.status_code != 200:
            raise self.web.refused(response, "is this OctoPrint's address?")
        return str(self.web.json(response).get("text", "OctoPrint"))

    def check_ready(self) -> None:
        response = self._get("/api/connection")
        state = str(self.web.json(response).get("current", {}).get("state"))
        if state.startswith(_ACTIVE):
            job = self.status()
            raise FabkitError(
                f"{self.name}: the printer is busy ({job.state} {job.file}): wait for the "
                "job to end or cancel it, then send again"
            )
        if state != "Operational":
            raise FabkitError(
                f"{self.name}: the printer is not operational (state {state}): connect it "
                "in OctoPrint, then send again"
            )

    def upload(self, name: str, data: bytes, select: bool) -> str:
        form = {"select": "true"} if select else {}
        response = self.web.call(
            "POST",
            "/api/files/local",
            files={"file": (name, data, "application/octet-stream")},
            data=form,
            answer_s=self.web.options.upload_s,
        )
        if response.status_code in (401, 403):
            raise self.web.key_refused(response, _KEY_WHERE)
        if response.status_code == 409:
            raise self.web.refused(response, "wait for the job that prints it to end")
        if response.status_code == 415:
            raise self.web.refused(response, "OctoPrint takes G-code named *.gcode or *.gco")
        if response.status_code != 201:
            raise self.web.refused(response, "see OctoPrint's log")
        answer = self.web.json(response)
        if select and not answer.get("effectiveSelect"):
            raise FabkitError(
                f"{self.name} stored {name} but could not select it: the printer is busy or "
                "no longer operational; start it in OctoPrint when the printer is free"
            )
        return str(answer.get("files", {}).get("local", {}).get("path", name))

    def start(self, stored: str) -> None:
        self._command(
            {"command": "start"}, "free or connect the printer in OctoPrint, then send again"
        )

    def status(self) -> JobState:
        answer = self.web.json(self._get("/api/job"))
        state = str(answer.get("state", "Unknown"))
        progress = answer.get("progress") or {}
        left = progress.get("printTimeLeft")
        position = progress.get("filepos")
        completion = progress.get("completion")
        return JobState(
            state=state,
            active=state.startswith(_ACTIVE),
            complete=state == "Operational" and progress.get("completion") == 100,
            file=((answer.get("job") or {}).get("file") or {}).get("path"),
            position_bytes=int(position) if position is not None else None,
            completion_pct=float(completion) if completion is not None else None,
            left_s=float(left) if left is not None else None,
            message=str(answer.get("error") or ""),
        )

    def pause(self, paused: bool) -> None:
        action = "pause" if paused else "resume"
        self._command({"command": "pause", "action": action}, "the job is not running")

    def cancel(self) -> None:
        self._command({"command": "cancel"}, "the job is not running")

    def _get(self, path: str) -> requests.Response:
        response = self.web.call("GET", path)
        if response.status_code in (401, 403):
            raise self.web.key_refused(response, _KEY_WHERE)
        if response.status_code != 200:
            raise self.web.refused(response, "see OctoPrint's log")
        return response

    def _command(self, body: dict[str, str], busy: str) -> None:
        response = self.web.call("POST", "/api/job", json=body)
        if response.status_code in (401, 403):
            raise self.web.key_refused(response, _KEY_WHERE)
        if response.status_code == 409:
            raise self.web.refused(response, busy)
        if response.status_code != 204:
            raise self.web.refused(response, "see OctoPrint's log")
