"""Send a G-code file to a machine: choose the machine, check the file, stream it, report.

:func:`stream_job` drives an already-open port (tests inject emulators and pty ports);
:func:`send_file` is what ``fabkit send`` calls: it adds the machine (``--machine``, else
the one the file's header names, else the port's default), the pre-flight check, the
duration estimate, ``--resume-from``, ``--dry-run``, the log file, the progress bar and
the keys (Ctrl-C stops with the profile's safe-stop snippet and raises
:class:`~fabkit.link.host.session.SendInterrupted`; Ctrl-Z pauses and resumes).
"""

from __future__ import annotations

import contextlib
import re
import signal
import sys
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

from serial import SerialException

from fabkit.errors import FabkitError
from fabkit.link.duration import Estimate, estimate
from fabkit.link.gcode import Command, read_job
from fabkit.link.host.grbl import GrblProtocol
from fabkit.link.host.marlin import MarlinProtocol
from fabkit.link.host.ports import (
    SIM_DEFAULT_MACHINES,
    default_machine,
    open_port,
    sim_personality,
    sim_time_scale,
)
from fabkit.link.host.preflight import JobCheck, check_job
from fabkit.link.host.session import (
    LinkControl,
    LinkOptions,
    SendInterrupted,
    SendReport,
    SerialLike,
    send_eta,
)
from fabkit.machines import MachineProfile, load_machine
from fabkit.progress import ProgressBar

PROTOCOLS = {"marlin": MarlinProtocol, "grbl": GrblProtocol}
_HEADER = re.compile(r";\s*Generated with fabkit \S+ for machine (\S+)")
HEADER_LINES = 40  # the header is at the top of the file


def stream_job(
    port: SerialLike,
    job: Sequence[Command],
    machine: MachineProfile,
    *,
    port_name: str = "port",
    options: LinkOptions | None = None,
    control: LinkControl | None = None,
    progress: ProgressBar | None = None,
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
        reason = str(exc).splitlines()[0]
        raise protocol.lost(protocol_done(protocol), reason, protocol_sent(protocol)) from None
    finally:
        if progress is not None:
            progress.close()


def protocol_done(protocol: MarlinProtocol | GrblProtocol) -> int:
    """Job lines the protocol knows to be executed."""
    return protocol.done_lines if isinstance(protocol, MarlinProtocol) else protocol.acked


def protocol_sent(protocol: MarlinProtocol | GrblProtocol) -> int:
    """Job lines the protocol has written to the port at least once."""
    return protocol.sent_lines if isinstance(protocol, MarlinProtocol) else protocol.sent


@dataclass(frozen=True)
class DryRun:
    """What ``--dry-run`` found: which machine and why, the check, the duration."""

    machine_note: str
    check: JobCheck
    estimate: Estimate

    def summary(self) -> str:
        return f"{self.machine_note}\n{self.check.summary()}\n{self.estimate.summary()}"


def machine_in_header(path: str | Path) -> str | None:
    """The machine a fabkit-written file names in its header (``;Generated with fabkit
    0.1.0 for machine NAME``), or None."""
    try:
        with open(path, encoding="ascii", errors="replace") as handle:
            for _, line in zip(range(HEADER_LINES), handle, strict=False):
                match = _HEADER.match(line.strip())
                if match:
                    return match.group(1)
    except OSError:
        return None
    return None


def choose_machine(
    path: str | Path, requested: str | None, port: str | None, *, force: bool = False
) -> tuple[MachineProfile, str]:
    """The profile to send ``path`` with, and one line saying which and why.

    ``--machine`` wins; without it, the machine the file's header names; without a
    header, the port's default. ``--machine`` and a header that disagree are refused
    unless ``force``."""
    named = machine_in_header(path)
    if requested is None:
        if named is not None:
            return load_machine(named), f"machine {named} (named in the header of {path})"
        fallback = default_machine(port or "")
        note = f"machine {fallback} (the default: {path} names no machine in its header)"
        return load_machine(fallback), note
    profile = load_machine(requested)
    if named is not None and named != profile.name and not force:
        raise FabkitError(
            f"{path} was written for machine {named} (its header), not {profile.name}: "
            f"send it with --machine {named}, or add --force"
        )
    if named is not None and named != profile.name:
        return profile, f"machine {profile.name} (--force: the header names {named})"
    return profile, f"machine {profile.name} (--machine)"


def send_file(
    path: str | Path,
    port: str | None,
    *,
    baud: int | None = None,
    machine: str | None = None,
    force: bool = False,
    log_path: str | Path | None = None,
    resume_from: int | None = None,
    dry_run: bool = False,
    options: LinkOptions | None = None,
    show_progress: bool = True,
    say: Callable[[str], None] | None = None,
) -> SendReport | DryRun:
    """Check ``path`` against the machine, then (unless ``dry_run``) stream it to ``port``.

    Returns the check and estimate (dry run) or the send report; every problem is a
    FabkitError, Ctrl-C a :class:`SendInterrupted`. ``say`` gets the lines for the user
    before streaming (which machine, the estimated duration); the progress bar goes to
    stderr unless ``show_progress`` is False.
    """
    if port is None and not dry_run:
        raise FabkitError("--port is required (or use --dry-run to only check the file)")
    job = read_job(path)
    profile, note = choose_machine(path, machine, port, force=force)
    if profile.serial is None:
        raise FabkitError(f"machine {profile.name} has flavour none and takes no G-code")
    personality = sim_personality(port or "")
    if personality in SIM_DEFAULT_MACHINES and personality != profile.serial.protocol:
        raise FabkitError(
            f"{port} emulates a {personality} machine but profile {profile.name} speaks "
            f"{profile.serial.protocol}"
        )
    checked = check_job(job, profile, source=str(path))
    planned = estimate(job, profile)
    first = 0
    if resume_from is not None:
        first = _resume(job, resume_from, path)
    if dry_run or port is None:
        return DryRun(note, checked, planned)
    if say is not None:
        say(note)
        say(planned.summary())
    job = job[first:]
    handle = open_port(port, baud or profile.serial.baud)
    control = LinkControl()
    progress = None
    if show_progress:
        eta_s = send_eta(planned, len(job), first, sim_time_scale(port))
        progress = ProgressBar("sending", sys.stderr, force=True, eta_s=eta_s, interval_s=0.2)
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
    except FabkitError as exc:
        if control.interrupted:
            raise SendInterrupted(str(exc).removeprefix("aborted: ")) from None
        raise
    finally:
        handle.close()


def _resume(job: list[Command], first_line: int, path: str | Path) -> int:
    """The index of the first command at or after file line ``first_line``."""
    last = job[-1].file_line if job else 0
    if not 1 <= first_line <= last:
        raise FabkitError(f"--resume-from {first_line} is outside {path} (lines 1-{last})")
    return next(i for i, command in enumerate(job) if command.file_line >= first_line)


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
    """Ctrl-C stops safely (a second Ctrl-C interrupts at once); Ctrl-Z pauses / resumes."""
    handlers = {}

    def on_interrupt(signum: int, frame: object) -> None:
        control.interrupt()
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
