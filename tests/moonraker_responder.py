"""A Moonraker responder written from Moonraker's API documentation, not Moonraker.

Moonraker starts without Klipper (tests/test_link_moonraker.py runs the real one from
PyPI for uploads, the file list and its refusals), but a print needs Klipper, which is
not on PyPI: for printing, progress, pause and cancel the tests talk to this responder,
written from the documentation of Moonraker's HTTP API (moonraker.readthedocs.io,
``docs/external_api/`` of Arksine/moonraker: introduction.md, server.md,
file_manager.md, printer.md), with a pretend Klipper behind it that reads the file at
``bytes_per_s``.

It answers ``GET /server/info``, ``GET /printer/info``, ``GET /server/files/list``,
``POST /server/files/upload`` (multipart ``file``, ``root``, ``checksum``: 422 on a
mismatch; 201 and ``{item, print_started, print_queued, action}``, not wrapped),
``POST /printer/print/start|pause|resume|cancel`` (``"ok"``) and ``POST
/printer/objects/query`` (``print_stats``: state standby / printing / paused / complete /
cancelled, filename, message; ``virtual_sdcard``: file_position, progress). Answers are
``{"result": ...}``, errors ``{"error": {"code": N, "message": "..."}}``. A request
without the ``X-Api-Key`` ``key`` is 401. While ``klippy_state`` is not ``ready`` the
printer's endpoints answer as documented for a Klippy that is not there (503 ``Klippy
Host not connected``) or shut down (400 on a start).
"""

from __future__ import annotations

import hashlib
import json
import threading
import time
import urllib.parse
from email.parser import BytesParser
from email.policy import HTTP
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any


class MoonrakerResponder:
    """The responder on a free port of 127.0.0.1 (a context manager); ``url`` its base."""

    def __init__(self, key: str, bytes_per_s: float = 20_000.0) -> None:
        self.key = key
        self.bytes_per_s = bytes_per_s
        self.klippy_state = "ready"
        self.state_message = "Printer is ready"
        self.files: dict[str, bytes] = {}
        self.requests: list[tuple[str, str]] = []  # (method, path) of every request
        self.corrupt_uploads = False
        self.lock = threading.Lock()
        self.job: dict[str, Any] = {"state": "standby", "filename": "", "size": 0}
        self.server = ThreadingHTTPServer(("127.0.0.1", 0), _handler(self))
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}"
        self.thread = threading.Thread(target=self.server.serve_forever, args=(0.05,), daemon=True)

    def __enter__(self) -> MoonrakerResponder:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self.thread.is_alive():
            self.server.shutdown()
        self.server.server_close()

    # -- the pretend Klipper ------------------------------------------------------------

    def start_print(self, filename: str) -> None:
        self.job = {
            "state": "printing",
            "filename": filename,
            "size": len(self.files[filename]),
            "read": 0.0,
            "since": time.monotonic(),
        }

    def advance(self) -> None:
        """Move the job on to now."""
        job = self.job
        if job["state"] != "printing":
            return
        now = time.monotonic()
        job["read"] = min(job["size"], job["read"] + (now - job["since"]) * self.bytes_per_s)
        job["since"] = now
        if job["read"] >= job["size"]:
            job["state"] = "complete"

    def set_state(self, state: str, message: str = "") -> None:
        """Move the job to ``state`` (Klipper's ``print_stats.message`` ``message``)."""
        self.advance()
        self.job.update(state=state, message=message, since=time.monotonic())

    def status(self) -> dict[str, Any]:
        self.advance()
        job = self.job
        size = job["size"] or 1
        read = int(job.get("read", 0))
        return {
            "print_stats": {
                "state": job["state"],
                "filename": job["filename"],
                "message": job.get("message", ""),
                "print_duration": 0.0,
            },
            "virtual_sdcard": {
                "file_position": read,
                "progress": read / size,
                "is_active": job["state"] == "printing",
            },
        }


def _handler(responder: MoonrakerResponder) -> type[BaseHTTPRequestHandler]:
    """The request handler class, bound to ``responder``."""
    return type("Handler", (_Handler,), {"responder": responder})


def _control(state: str, allowed: tuple[str, ...]) -> Any:
    """A route that moves a job in one of the ``allowed`` states to ``state``."""

    def control(handler: _Handler, query: dict, body: bytes) -> None:
        if not handler.klippy_here():
            return
        if handler.responder.status()["print_stats"]["state"] in allowed:
            handler.responder.set_state(state)
        handler.send(200, {"result": "ok"})

    return control


class _Handler(BaseHTTPRequestHandler):
    responder: MoonrakerResponder

    def log_message(self, *args: Any) -> None:  # quiet
        pass

    def do_GET(self) -> None:
        self.answer("GET")

    def do_POST(self) -> None:
        self.answer("POST")

    def answer(self, method: str) -> None:
        url = urllib.parse.urlsplit(self.path)
        query = {k: v[-1] for k, v in urllib.parse.parse_qs(url.query).items()}
        body = self.rfile.read(int(self.headers.get("Content-Length") or 0))
        with self.responder.lock:
            self.responder.requests.append((method, url.path))
            if self.headers.get("X-Api-Key") != self.responder.key:
                return self.error(401, "Unauthorized")
            route = ROUTES.get((method, url.path))
            if route is None:
                return self.error(404, "Not Found")
            route(self, query, body)

    def send(self, code: int, payload: Any) -> None:
        data = json.dumps(payload).encode()
        self.send_response(code)
        self.send_header("Content-Type", "application/json; charset=UTF-8")
        self.send_header("Content-Length", str(len(data)))
        self.end_headers()
        self.wfile.write(data)

    def error(self, code: int, message: str) -> None:
        self.send(code, {"error": {"code": code, "message": message}})

    def klippy_here(self) -> bool:
        """Whether the printer's endpoints can answer (else the error is sent)."""
        if self.responder.klippy_state in ("disconnected", "startup"):
            self.error(503, "Klippy Host not connected")
            return False
        return True

    def server_info(self, query: dict, body: bytes) -> None:
        state = self.responder.klippy_state
        info = {
            "klippy_connected": state != "disconnected",
            "klippy_state": state,
            "moonraker_version": "responder-0",
            "api_version_string": "1.5.0",
        }
        self.send(200, {"result": info})

    def printer_info(self, query: dict, body: bytes) -> None:
        if self.klippy_here():
            state = self.responder.klippy_state
            info = {"state": state, "state_message": self.responder.state_message}
            self.send(200, {"result": info})

    def files_list(self, query: dict, body: bytes) -> None:
        files = self.responder.files.items()
        self.send(200, {"result": [{"path": name, "size": len(data)} for name, data in files]})

    def upload(self, query: dict, body: bytes) -> None:
        header = f"Content-Type: {self.headers['Content-Type']}\r\n\r\n".encode()
        form = BytesParser(policy=HTTP).parsebytes(header + body)
        fields, name, data = {}, None, b""
        for part in form.iter_parts():
            field = part.get_param("name", header="content-disposition")
            if field == "file":
                name, data = part.get_filename(), part.get_payload(decode=True)
            else:
                fields[field] = part.get_content().strip()
        if name is None or fields.get("root", "gcodes") != "gcodes":
            return self.error(400, "No file or unknown root")
        if self.responder.corrupt_uploads:
            data = data[:-1] + bytes([data[-1] ^ 1])
        checksum = fields.get("checksum")
        if checksum is not None and hashlib.sha256(data).hexdigest() != checksum:
            return self.error(422, "File checksum mismatch")
        self.responder.files[name] = data
        item = {"path": name, "root": "gcodes", "size": len(data), "permissions": "rw"}
        self.send(201, {"item": item, "print_started": False, "print_queued": False,
                        "action": "create_file"})  # fmt: skip

    def print_start(self, query: dict, body: bytes) -> None:
        if not self.klippy_here():
            return
        if self.responder.klippy_state != "ready":
            return self.error(400, f"Printer is {self.responder.klippy_state}")
        name = query.get("filename", "")
        if self.responder.status()["print_stats"]["state"] in ("printing", "paused"):
            return self.error(400, "SD busy")
        if name not in self.responder.files:
            return self.error(400, f"Unable to open file {name}")
        self.responder.start_print(name)
        self.send(200, {"result": "ok"})

    def objects_query(self, query: dict, body: bytes) -> None:
        if not self.klippy_here():
            return
        wanted = json.loads(body or b"{}").get("objects") or dict.fromkeys(query)
        status = {k: v for k, v in self.responder.status().items() if k in wanted}
        self.send(200, {"result": {"eventtime": time.monotonic(), "status": status}})


ROUTES = {
    ("GET", "/server/info"): _Handler.server_info,
    ("GET", "/printer/info"): _Handler.printer_info,
    ("GET", "/server/files/list"): _Handler.files_list,
    ("POST", "/server/files/upload"): _Handler.upload,
    ("POST", "/printer/print/start"): _Handler.print_start,
    ("POST", "/printer/print/pause"): _control("paused", ("printing",)),
    ("POST", "/printer/print/resume"): _control("printing", ("paused",)),
    ("POST", "/printer/print/cancel"): _control("cancelled", ("printing", "paused")),
    ("POST", "/printer/objects/query"): _Handler.objects_query,
}
