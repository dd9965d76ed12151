"""Send a G-code file to a machine: choose the machine, open the port, check the file,
stream it, report.

:func:`stream_job` drives an already-open port (tests inject emulators and pty ports);
:func:`send_file` is what ``fabkit send`` calls: it adds the machine (``--machine``, else
the one the file's header names, else the port's default), the port (opened before the
long pre-flight check, so that a wrong one is refused at once), the pre-flight check, the
duration estimate, ``--resume-from``, ``--dry-run``, the log file, the progress bar and
the keys (Ctrl-C stops with the profile's safe-stop snippet and raises
:class:`~fabkit.link.host.session.SendInterrupted`; Ctrl-Z pauses and resumes). Given a
printer host's URL instead of a port, it hands the file to
:func:`~fabkit.link.host.hosts.send_to_host` (OctoPrint, Moonraker).
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, TextIO

from serial import SerialException

from fabkit.errors import FabkitError
from fabkit.gcode.read import Command
from fabkit.link.host.grbl import GrblProtocol
from fabkit.link.host.job import (
    DryRun,
    PreparedJob,
    job_machine,
    keys,
    log_file,
    prepare_job,
)
from fabkit.link.host.marlin import MarlinProtocol
from fabkit.link.host.ports import (
    SIM_DEFAULT_MACHINES,
    default_machine,
    open_port,
    sim_personality,
    sim_time_scale,
)
from fabkit.link.host.session import (
    LinkControl,
    LinkOptions,
    SendInterrupted,
    SendReport,
    SerialLike,
    send_eta,
)
from fabkit.machines import MachineProfile
from fabkit.progress import ProgressBar
from fabkit.writers.which_machine import MachineChoice

if TYPE_CHECKING:
    from fabkit.link.host.hosts import HostReport
    from fabkit.link.host.web import HostOptions

PROTOCOLS = {"marlin": MarlinProtocol, "grbl": GrblProtocol}


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


def send_file(
    path: str | Path,
    port: str | None = None,
    *,
    host: str | None = None,
    baud: int | None = None,
    machine: str | MachineProfile | None = None,
    force: bool = False,
    api_key: str | None = None,
    api_key_file: str | Path | None = None,
    no_start: bool = False,
    log_path: str | Path | None = None,
    resume_from: int | None = None,
    dry_run: bool = False,
    options: LinkOptions | None = None,
    host_options: HostOptions | None = None,
    show_progress: bool = True,
    say: Callable[[str], None] | None = None,
) -> SendReport | HostReport | DryRun:
    """Choose the machine, open ``port`` (unless ``dry_run``: a port that cannot be opened is
    refused before the file is read), check ``path`` against the machine, then stream it,
    or hand it to the printer host ``host`` (:func:`~fabkit.link.host.hosts.send_to_host`,
    with ``api_key``, ``api_key_file``, ``no_start`` and ``host_options``).

    Returns the check and estimate (dry run) or the send report; every problem is a
    FabkitError, Ctrl-C a :class:`SendInterrupted`. ``say`` gets the lines for the user
    before streaming (which machine, the estimated duration); the progress bar goes to
    stderr unless ``show_progress`` is False. ``port``: a device, a pyserial URL or
    ``sim://marlin?...`` (the emulator); ``baud`` in bit/s (default: the profile's);
    ``resume_from`` a 1-based line of the file; ``machine`` a profile (or its name or .toml path)
    (default: the one the file's header names). A :class:`SendReport` counts the lines
    the machine acknowledged and the seconds it took (``elapsed_s``).
    """
    if host is not None:
        _no_serial_options(port, baud, resume_from, options)
        from fabkit.link.host.hosts import send_to_host

        return send_to_host(
            path,
            host,
            machine=machine,
            force=force,
            api_key=api_key,
            api_key_file=api_key_file,
            no_start=no_start,
            log_path=log_path,
            dry_run=dry_run,
            options=host_options,
            show_progress=show_progress,
            say=say,
        )
    for flag, given in (("--api-key", api_key), ("--api-key-file", api_key_file)):
        if given is not None:
            raise FabkitError(f"{flag} is for a printer host (--host), not a serial port")
    if no_start:
        raise FabkitError("--no-start is for a printer host (--host), not a serial port")
    if port is None and not dry_run:
        raise FabkitError(
            "--port is required (or --host for OctoPrint or Moonraker, or --dry-run to only "
            "check the file)"
        )
    if baud is not None and baud <= 0:
        raise FabkitError(f"--baud {baud}: expected a positive baud rate (bit/s)")
    choice = job_machine(
        path, machine, default_machine(port or ""), force=force, link_takes=_emulates(port)
    )
    if dry_run or port is None:
        return _checked(path, choice, resume_from)[0].dry_run()
    # the port first: a wrong one is refused at once, not after the long check of the file
    with contextlib.closing(open_port(port, baud or choice.profile.serial.baud)) as handle:
        prepared, first = _checked(path, choice, resume_from)
        if say is not None:
            say(prepared.machine_note)
            say(prepared.plan.summary())
        return _stream_file(handle, prepared, first, port, log_path, options, show_progress)


def _checked(
    path: str | Path, choice: MachineChoice, resume_from: int | None
) -> tuple[PreparedJob, int]:
    """The file checked against the chosen machine, and the index of the command that
    ``resume_from`` (a 1-based file line, None: the first) starts at."""
    prepared = prepare_job(path, choice)
    return prepared, 0 if resume_from is None else _resume(prepared.job, resume_from, path)


def _stream_file(
    handle: SerialLike,
    prepared: PreparedJob,
    first: int,
    port: str,
    log_path: str | Path | None,
    options: LinkOptions | None,
    show_progress: bool,
) -> SendReport:
    """Stream the prepared job over the open ``handle`` (the port named ``port``) from its
    command ``first`` on, with the log, the progress bar and the keys."""
    job, profile = prepared.job[first:], prepared.machine
    control = LinkControl()
    progress = None
    if show_progress:
        eta_s = send_eta(prepared.plan, len(job), first, sim_time_scale(port))
        progress = ProgressBar("sending", sys.stderr, force=True, eta_s=eta_s, interval_s=0.2)
    try:
        with log_file(log_path) as log, keys(control):
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


def _no_serial_options(
    port: str | None, baud: int | None, resume_from: int | None, options: LinkOptions | None
) -> None:
    """Refuse the options of a serial port with a printer host."""
    serial_only = (("--port", port), ("--baud", baud), ("--resume-from", resume_from))
    for flag, given in serial_only:
        if given is not None:
            raise FabkitError(f"{flag} is for a serial port, not a printer host (--host)")
    if options is not None:
        raise FabkitError("link options are for a serial port, not a printer host (--host)")


def _emulates(port: str | None) -> Callable[[MachineProfile], None]:
    """Refuse a profile whose protocol a ``sim://`` port does not emulate."""

    def takes(profile: MachineProfile) -> None:
        personality = sim_personality(port or "")
        if personality in SIM_DEFAULT_MACHINES and personality != profile.serial.protocol:
            raise FabkitError(
                f"{port} emulates a {personality} machine but profile {profile.name} speaks "
                f"{profile.serial.protocol}"
            )

    return takes


def _resume(job: list[Command], first_line: int, path: str | Path) -> int:
    """The index of the first command at or after file line ``first_line``."""
    last = job[-1].file_line if job else 0
    if not 1 <= first_line <= last:
        raise FabkitError(f"--resume-from {first_line} is outside {path} (lines 1-{last})")
    return next(i for i, command in enumerate(job) if command.file_line >= first_line)
