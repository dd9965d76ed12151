"""Send a G-code file to a machine: check it, open the port, stream it, report.

:func:`stream_job` drives an already-open port (tests inject emulators and pty ports);
:func:`send_file` is what ``fabkit send`` calls: it adds the profile, the pre-flight
check, ``--resume-from``, ``--dry-run``, the log file, the progress bar and the keys
(Ctrl-C aborts with the profile's safe-stop snippet; Ctrl-Z pauses and resumes).
"""

from __future__ import annotations

import contextlib
import signal
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import TextIO

from serial import SerialException

from fabkit.errors import FabkitError
from fabkit.link.check import JobCheck, check_job
from fabkit.link.gcode import Command, read_job
from fabkit.link.grbl import GrblProtocol
from fabkit.link.marlin import MarlinProtocol
from fabkit.link.ports import SIM_DEFAULT_MACHINES, default_machine, open_port, sim_personality
from fabkit.link.session import LinkControl, LinkOptions, Progress, SendReport, SerialLike
from fabkit.machines import MachineProfile, load_machine

PROTOCOLS = {"marlin": MarlinProtocol, "grbl": GrblProtocol}


def stream_job(
    port: SerialLike,
    job: Sequence[Command],
    machine: MachineProfile,
    *,
    port_name: str = "port",
    options: LinkOptions | None = None,
    control: LinkControl | None = None,
    progress: Progress | None = None,
    log: TextIO | None = None,
) -> SendReport:
    """Stream ``job`` over the open ``port`` with the machine's protocol; FabkitError if the
    job cannot complete (the message names the last acknowledged file line)."""
    if machine.serial is None:
        raise FabkitError(f"machine {machine.name} has flavour none and takes no G-code")
    protocol = PROTOCOLS[machine.serial.protocol](
        port,
        port_name,
        job,
        machine,
        options or LinkOptions(),
        control or LinkControl(),
        progress,
        log,
    )
    try:
        return protocol.run()
    except (SerialException, OSError) as exc:
        raise protocol.lost(protocol_done(protocol), str(exc).splitlines()[0]) from None
    finally:
        if progress is not None:
            progress.finish()


def protocol_done(protocol: MarlinProtocol | GrblProtocol) -> int:
    """Job lines the protocol knows to be executed."""
    return protocol.done_lines if isinstance(protocol, MarlinProtocol) else protocol.acked


def send_file(
    path: str | Path,
    port: str | None,
    *,
    baud: int | None = None,
    machine: str | None = None,
    log_path: str | Path | None = None,
    resume_from: int | None = None,
    dry_run: bool = False,
    options: LinkOptions | None = None,
    show_progress: bool = True,
) -> SendReport | JobCheck:
    """Check ``path`` against the machine, then (unless ``dry_run``) stream it to ``port``.

    Returns the check (dry run) or the send report; every problem is a FabkitError. The
    progress bar goes to stderr unless ``show_progress`` is False.
    """
    if port is None and not dry_run:
        raise FabkitError("--port is required (or use --dry-run to only check the file)")
    profile = load_machine(machine or default_machine(port or ""))
    if profile.serial is None:
        raise FabkitError(f"machine {profile.name} has flavour none and takes no G-code")
    personality = sim_personality(port or "")
    if personality in SIM_DEFAULT_MACHINES and personality != profile.serial.protocol:
        raise FabkitError(
            f"{port} emulates a {personality} machine but profile {profile.name} speaks "
            f"{profile.serial.protocol}"
        )
    job = read_job(path)
    checked = check_job(job, profile, source=str(path))
    if resume_from is not None:
        job = _resume(job, resume_from, path)
    if dry_run or port is None:
        return checked
    handle = open_port(port, baud or profile.serial.baud)
    control = LinkControl()
    progress = Progress(sys.stderr, len(job)) if show_progress else None
    try:
        with _log_file(log_path) as log, _keys(control):
            return stream_job(
                handle,
                job,
                profile,
                port_name=port,
                options=options,
                control=control,
                progress=progress,
                log=log,
            )
    finally:
        handle.close()


def _resume(job: list[Command], first_line: int, path: str | Path) -> list[Command]:
    last = job[-1].file_line if job else 0
    if not 1 <= first_line <= last:
        raise FabkitError(f"--resume-from {first_line} is outside {path} (lines 1-{last})")
    return [command for command in job if command.file_line >= first_line]


@contextlib.contextmanager
def _log_file(path: str | Path | None) -> Iterator[TextIO | None]:
    """The traffic log, appended line by line so that it survives a failed job."""
    if path is None:
        yield None
        return
    try:
        handle = open(path, "w", encoding="latin-1", buffering=1)  # noqa: SIM115
    except OSError as exc:
        raise FabkitError(f"cannot write log file {path}: {exc.strerror}") from None
    with handle:
        yield handle


@contextlib.contextmanager
def _keys(control: LinkControl) -> Iterator[None]:
    """Ctrl-C aborts (a second Ctrl-C interrupts at once); Ctrl-Z pauses / resumes."""
    handlers = {}

    def on_interrupt(signum: int, frame: object) -> None:
        control.abort()
        signal.signal(signal.SIGINT, signal.default_int_handler)

    wanted = {signal.SIGINT: on_interrupt}
    if hasattr(signal, "SIGTSTP"):
        wanted[signal.SIGTSTP] = lambda signum, frame: control.toggle_pause()
    try:
        for signum, handler in wanted.items():
            handlers[signum] = signal.signal(signum, handler)
    except ValueError:  # not the main thread: no keys
        pass
    try:
        yield
    finally:
        for signum, handler in handlers.items():
            signal.signal(signum, handler)
