"""Moonraker's HTTP API (moonraker.readthedocs.io, docs/external_api of Arksine/moonraker):
a Klipper printer behind Moonraker, which hands the file to Klipper's virtual SD card.

``GET /server/info`` (``klippy_state`` must be ``ready`` to print), ``POST
/server/files/upload`` (multipart ``file``, ``root=gcodes``, ``checksum`` the SHA-256
the server compares), ``POST /printer/print/start?filename=...``, ``POST
/printer/print/pause|resume|cancel``, ``POST /printer/objects/query`` of ``print_stats``
(``state``: standby, printing, paused, complete, cancelled, error; ``message``) and
``virtual_sdcard`` (``file_position`` bytes) for progress. Answers come as ``{"result":
...}``, errors as ``{"error": {"code": ..., "message": ...}}``; ``X-Api-Key`` carries the
key (a trusted client needs none).
"""

from __future__ import annotations

import hashlib
from typing import TYPE_CHECKING, Any

from fabkit.errors import FabkitError
from fabkit.link.host.web import JobState, WebClient
from fabkit.machines import MachineProfile

if TYPE_CHECKING:
    import requests

_KEY_WHERE = "Moonraker: GET /access/api_key from a trusted client"
_START_KLIPPER = "start Klipper (its API server enabled), or upload only with --no-start"


class Moonraker:
    """A Klipper printer behind Moonraker (see the module's docstring)."""

    default_machine = "klipper_generic"

    def __init__(self, web: WebClient) -> None:
        self.web = web
        self.name = web.url.text

    def takes(self, machine: MachineProfile) -> None:
        if machine.flavour != "klipper":
            raise FabkitError(
                f"{self.name} runs Klipper but machine {machine.name} is flavour "
                f"{machine.flavour}: send a file checked for a Klipper profile (--machine)"
            )

    def identify(self) -> str:
        info = self._result(self._checked(self.web.call("GET", "/server/info")))
        return f"Moonraker {info.get('moonraker_version', '')}".strip()

    def check_ready(self) -> None:
        info = self._result(self._checked(self.web.call("GET", "/server/info")))
        state = str(info.get("klippy_state"))
        if state == "disconnected":
            raise FabkitError(
                f"{self.name}: Klippy not connected (klippy_state {state}): {_START_KLIPPER}"
            )
        if state == "startup":
            raise FabkitError(f"{self.name}: Klippy is starting up: send again in a few seconds")
        if state != "ready":
            raise FabkitError(
                f"{self.name}: Klippy is not ready (klippy_state {state}{self._why()}): "
                "fix the printer (FIRMWARE_RESTART after a shutdown), then send again"
            )
        job = self.status()
        if job.active:
            raise FabkitError(
                f"{self.name}: the printer is busy ({job.state} {job.file}): wait for the job "
                "to end or cancel it, then send again"
            )

    def upload(self, name: str, data: bytes, select: bool) -> str:
        form = {"root": "gcodes", "checksum": hashlib.sha256(data).hexdigest()}
        response = self.web.call(
            "POST",
            "/server/files/upload",
            files={"file": (name, data, "application/octet-stream")},
            data=form,
            answer_s=self.web.options.upload_s,
        )
        if response.status_code == 422:
            raise self.web.refused(response, "the file changed on its way: send it again")
        answer = self.web.json(self._checked(response))
        return str((answer.get("item") or {}).get("path", name))

    def start(self, stored: str) -> None:
        self._post("/printer/print/start", params={"filename": stored})

    def status(self) -> JobState:
        query = {"objects": {"print_stats": None, "virtual_sdcard": None}}
        status = self._result(self._post("/printer/objects/query", json=query)).get("status", {})
        stats, card = status.get("print_stats") or {}, status.get("virtual_sdcard") or {}
        state = str(stats.get("state", "unknown"))
        position, progress = card.get("file_position"), card.get("progress")
        return JobState(
            state=state,
            active=state in ("printing", "paused"),
            complete=state == "complete",
            file=stats.get("filename") or None,
            position_bytes=int(position) if position is not None else None,
            completion_pct=100 * float(progress) if progress is not None else None,
            message=str(stats.get("message") or ""),
        )

    def pause(self, paused: bool) -> None:
        self._post("/printer/print/pause" if paused else "/printer/print/resume")

    def cancel(self) -> None:
        self._post("/printer/print/cancel")

    def _post(self, path: str, **kwargs: Any) -> requests.Response:
        return self._checked(self.web.call("POST", path, **kwargs))

    def _checked(self, response: requests.Response) -> requests.Response:
        """``response`` if it succeeded, else the one-line refusal."""
        if response.status_code in (401, 403):
            raise self.web.key_refused(response, _KEY_WHERE)
        if response.status_code == 503 or (
            response.status_code == 404 and self.web.path_of(response).startswith("/printer/")
        ):  # Klippy's endpoints are missing while it is not connected
            raise FabkitError(
                f"{self.name}: Klippy not connected ({self.web.said(response)}): {_START_KLIPPER}"
            )
        if response.status_code >= 400:
            raise self.web.refused(response, "see moonraker.log")
        return response

    def _result(self, response: requests.Response) -> dict[str, Any]:
        result = self.web.json(response).get("result")
        return result if isinstance(result, dict) else {}

    def _why(self) -> str:
        """``: Klippy's state message``, or nothing if it cannot be had."""
        try:
            info = self._result(self._checked(self.web.call("GET", "/printer/info")))
        except FabkitError:
            return ""
        message = " ".join(str(info.get("state_message", "")).split())
        return f": {message}" if message else ""
