"""Send a G-code file through a printer host: OctoPrint (:mod:`~fabkit.link.host.octoprint`)
or Moonraker (:mod:`~fabkit.link.host.moonraker`).

:func:`send_to_host` is what ``fabkit send FILE --host URL`` calls. The file is checked
first, against the machine of its header as for a serial port
(:func:`~fabkit.link.host.job.prepare_job`), before the host is asked anything (a plain
``http://`` URL excepted: the host is asked which it is first, for its default machine).
Then the host is identified (the API key checked), its printer must be ready, the file is
uploaded (exactly the checked bytes), started, and followed by polling the host: the
progress bar of ``fabkit send`` (commands done from the host's file position, the ETA
the host's or fabkit's estimate), and the end state. Ctrl-C cancels the job on the host
(its cancel call) and raises :class:`~fabkit.link.host.session.SendInterrupted` once the
host says it stopped; Ctrl-Z pauses and resumes it.
"""

from __future__ import annotations

import bisect
import contextlib
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn

from fabkit.errors import FabkitError
from fabkit.gcode.read import line_ends
from fabkit.link.host.job import DryRun, PreparedJob, job_machine, keys, log_file, prepare_job
from fabkit.link.host.moonraker import Moonraker
from fabkit.link.host.octoprint import OctoPrint
from fabkit.link.host.session import LinkControl, SendInterrupted, send_eta
from fabkit.link.host.web import (
    HostOptions,
    JobState,
    PrintHost,
    WebClient,
    parse_host_url,
    resolve_api_key,
)
from fabkit.machines import MachineProfile
from fabkit.progress import ProgressBar

HOSTS: dict[str, Callable[[WebClient], PrintHost]] = {
    "octoprint": OctoPrint,
    "moonraker": Moonraker,
}


@dataclass(frozen=True)
class HostReport:
    """What a send through a printer host did (bytes, %, s): the host as named, the
    server and its version, the file's name there, whether it was started, and the
    host's last word on the job."""

    host: str
    server: str
    file: str
    uploaded_bytes: int
    started: bool
    state: str
    completion_pct: float | None
    elapsed_s: float

    def summary(self) -> str:
        where = f"{self.host} ({self.server})"
        if not self.started:
            return f"uploaded {self.file} ({self.uploaded_bytes} bytes) to {where}; not started"
        done = f", {self.completion_pct:.0f} % done" if self.completion_pct is not None else ""
        return (
            f"printed {self.file} on {where} in {self.elapsed_s:.1f} s: the host says "
            f"{self.state}{done}"
        )

    def figures(self) -> dict[str, Any]:
        """The figures, each named with its unit (report.json, report.html)."""
        return {
            "host": self.host,
            "server": self.server,
            "file": self.file,
            "uploaded_bytes": self.uploaded_bytes,
            "started": self.started,
            "state": self.state,
            "completion_percent": self.completion_pct,
            "seconds": round(self.elapsed_s, 3),
        }


def send_to_host(
    path: str | Path,
    host: str,
    *,
    machine: str | MachineProfile | None = None,
    force: bool = False,
    api_key: str | None = None,
    api_key_file: str | Path | None = None,
    no_start: bool = False,
    log_path: str | Path | None = None,
    dry_run: bool = False,
    options: HostOptions | None = None,
    show_progress: bool = True,
    say: Callable[[str], None] | None = None,
) -> HostReport | DryRun:
    """Check ``path``, then upload it to ``host`` and (unless ``no_start``) print it there,
    following the job to its end (see the module's docstring). Every problem is a one-line
    FabkitError, Ctrl-C a :class:`SendInterrupted` after the host cancelled the job."""
    url = parse_host_url(host)
    key = resolve_api_key(api_key, api_key_file)
    options = options or HostOptions()
    web = WebClient(url, key, options)
    with contextlib.closing(web):
        printer = HOSTS[url.kind or ask_kind(web)](web)
        choice = job_machine(
            path, machine, printer.default_machine, force=force, link_takes=printer.takes
        )
        prepared = prepare_job(path, choice)
        if dry_run:
            return prepared.dry_run()
        if say is not None:
            say(prepared.machine_note)
            say(prepared.plan.summary())
        with log_file(log_path) as log:
            web.log = log
            return _send(printer, prepared, url.text, no_start, options, show_progress)


def ask_kind(web: WebClient) -> str:
    """Which host answers at a plain http(s):// URL. Moonraker is asked first (``GET
    /server/info``), as it may emulate OctoPrint's ``/api/version``; a host that refuses
    the key still says which it is by the shape of its refusal."""
    response = web.call("GET", "/server/info")
    body = _body(response)
    if (response.status_code == 200 and "moonraker_version" in (body.get("result") or {})) or (
        response.status_code == 401 and isinstance(body.get("error"), dict)
    ):
        return "moonraker"
    version = web.call("GET", "/api/version")
    text = _body(version)
    if (version.status_code == 200 and "OctoPrint" in str(text.get("text"))) or (
        version.status_code == 403 and isinstance(text.get("error"), str)
    ):
        return "octoprint"
    raise FabkitError(
        f"{web.url.text} answers as neither OctoPrint nor Moonraker (GET /server/info: "
        f"{response.status_code}, GET /api/version: {version.status_code}): name it "
        "octoprint+http://... or moonraker+http://..."
    )


def _body(response: Any) -> dict[str, Any]:
    try:
        body = response.json()
    except ValueError:
        return {}
    return body if isinstance(body, dict) else {}


def _send(
    printer: PrintHost,
    prepared: PreparedJob,
    host: str,
    no_start: bool,
    options: HostOptions,
    show_progress: bool,
) -> HostReport:
    """Identify, check, upload, start and follow (the prepared job, on the host)."""
    server = printer.identify()
    if not no_start:
        printer.check_ready()
    name = Path(prepared.path).name
    control = LinkControl()
    with keys(control):
        stored = printer.upload(name, prepared.data, select=not no_start)
        if control.interrupted:
            raise SendInterrupted(f"stopped after the upload: {stored} is on {host}, not started")
        if no_start:
            return HostReport(host, server, stored, len(prepared.data), False, "uploaded", None, 0)
        printer.start(stored)
        follow = _Follow(printer, prepared, host, stored, control, options)
        if show_progress:
            follow.progress = ProgressBar(
                "printing", sys.stderr, force=True, eta_s=follow.eta_s, interval_s=0.2
            )
        try:
            state = follow.run()
        finally:
            if follow.progress is not None:
                follow.progress.close()
    return HostReport(
        host, server, stored, len(prepared.data), True, state.state, state.completion_pct,
        time.monotonic() - follow.t0,
    )  # fmt: skip


class _Follow:
    """A started job, polled to its end: progress, pause / resume, Ctrl-C's cancel."""

    def __init__(
        self,
        printer: PrintHost,
        prepared: PreparedJob,
        host: str,
        stored: str,
        control: LinkControl,
        options: HostOptions,
    ) -> None:
        self.printer, self.prepared, self.host, self.stored = printer, prepared, host, stored
        self.control, self.options = control, options
        self.ends = command_ends(prepared)
        self.plan_eta = send_eta(prepared.plan, len(prepared.job))
        self.progress: ProgressBar | None = None
        self.latest: JobState | None = None
        self.position_bytes = 0  # the host's last file position (it forgets it at the end)
        self.t0 = time.monotonic()

    def run(self) -> JobState:
        """Poll until the job ends; its last state (complete), else a FabkitError."""
        seen_active, paused = False, False
        while True:
            if self.control.interrupted:
                self.cancel()
            if self.control.paused != paused:
                paused = self.control.paused
                with contextlib.suppress(FabkitError):  # a job that just ended: see the poll
                    self.printer.pause(paused)
            state = self.poll()
            if state.file is not None and state.file != self.stored and state.active:
                raise FabkitError(
                    f"{self.host} runs {state.file}, not {self.stored}: someone else started "
                    "a job there"
                )
            self.show(state)
            if state.complete:
                return state
            if state.active:
                seen_active = True
            elif seen_active or time.monotonic() - self.t0 > self.options.start_s:
                raise FabkitError(self.ended(state))
            time.sleep(self.options.poll_s)

    def poll(self) -> JobState:
        """The host's job now; failed queries are repeated for ``lost_s``."""
        lost = time.monotonic() + self.options.lost_s
        while True:
            try:
                self.latest = self.printer.status()
                if self.latest.position_bytes is not None:
                    self.position_bytes = self.latest.position_bytes
                return self.latest
            except FabkitError as exc:
                if self.control.interrupted:  # Ctrl-C, and the host cannot be told
                    raise SendInterrupted(
                        f"{exc}; {self.stored} may still run on {self.host}: cancel it there"
                    ) from None
                if time.monotonic() > lost:
                    raise FabkitError(
                        f"lost the link to {self.host} for {self.options.lost_s:g} s ({exc}); "
                        f"the job may still run there: {self.where()}"
                    ) from None
            time.sleep(self.options.poll_s)

    def cancel(self) -> NoReturn:
        """Cancel the job on the host, wait until it stops, raise SendInterrupted."""
        self.poll()  # where the job is now: the host forgets it once cancelled
        with contextlib.suppress(FabkitError):  # a job that ended meanwhile cannot be
            self.printer.cancel()
        deadline = time.monotonic() + self.options.cancel_s
        state = self.poll()
        while state.active and time.monotonic() < deadline:
            time.sleep(self.options.poll_s)
            state = self.poll()
        if state.active:
            raise SendInterrupted(
                f"asked {self.host} to cancel {self.stored}, but after "
                f"{self.options.cancel_s:g} s it says {state.state}: stop it there"
            )
        if state.complete:
            raise SendInterrupted(f"{self.stored} had completed on {self.host} before the cancel")
        raise SendInterrupted(
            f"cancelled {self.stored} on {self.host} ({self.where()}); the host says {state.state}"
        )

    def ended(self, state: JobState) -> str:
        """The one line for a job that stopped without completing (or never showed)."""
        said = f"{state.state}: {state.message}" if state.message else state.state
        return (
            f"the job on {self.host} ended without completing ({said}; {self.where()}): "
            "see the printer and the host's log"
        )

    def done(self) -> int:
        """Commands of the job before the host's last file position."""
        return bisect.bisect_right(self.ends, self.position_bytes)

    def file_line(self) -> int:
        """The file line of the last command the host read (0: none yet)."""
        done = self.done()
        return self.prepared.job[done - 1].file_line if done else 0

    def where(self) -> str:
        line = self.file_line()
        return f"last at file line {line}" if line else "before the first command"

    def show(self, state: JobState) -> None:
        if self.progress is not None:
            detail = f"file line {self.file_line()}  {state.state}"
            self.progress(self.done(), len(self.prepared.job), detail, force=state.complete)

    def eta_s(self, done: int, elapsed_s: float) -> float:
        """The host's estimate of the time left if it gives one, else fabkit's."""
        left = self.latest.left_s if self.latest is not None else None
        return left if left is not None else self.plan_eta(done, elapsed_s)


def command_ends(prepared: PreparedJob) -> list[int]:
    """The byte offset in the file where each command's line ends (its newline included):
    a host's file position past it means the command was read."""
    ends = line_ends(prepared.data)
    return [ends[command.file_line - 1] for command in prepared.job]
