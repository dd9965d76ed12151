"""What every way of sending a job shares, over a serial line or through a printer host.

:func:`job_machine` chooses the machine (``--machine``, else the one the file's header
names, else the link's default) from the header alone, at once, so that a port can be
opened before the long part; :func:`prepare_job` then reads the file once, checks the job
against the machine and estimates its duration, before a single byte leaves; :func:`keys`
turns Ctrl-C into an abort and Ctrl-Z into pause / resume; :func:`log_file` opens the
traffic log.
"""

from __future__ import annotations

import contextlib
import signal
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

from fabkit.errors import FabkitError
from fabkit.gcode.duration import Estimate, Planner
from fabkit.gcode.read import Command, read_job_bytes
from fabkit.link.host.preflight import JobCheck, check_job
from fabkit.link.host.session import LinkControl
from fabkit.machines import MachineProfile
from fabkit.writers.which_machine import MachineChoice, choose_machine


@dataclass(frozen=True)
class PreparedJob:
    """A G-code file checked against its machine: the file's bytes (exactly what was
    checked), its commands, the machine and one line saying which and why, the check and
    the planned duration."""

    path: str
    data: bytes
    job: list[Command]
    machine: MachineProfile
    machine_note: str
    check: JobCheck
    plan: Estimate

    def dry_run(self) -> DryRun:
        """What ``--dry-run`` reports of this job."""
        return DryRun(self.machine_note, self.check, self.plan)


@dataclass(frozen=True)
class DryRun:
    """What ``--dry-run`` found: which machine and why, the check, the duration."""

    machine_note: str
    check: JobCheck
    estimate: Estimate

    def summary(self) -> str:
        return f"{self.machine_note}\n{self.check.summary()}\n{self.estimate.summary()}"


def job_machine(
    path: str | Path,
    requested: str | MachineProfile | None,
    default: str,
    *,
    force: bool = False,
    link_takes: Callable[[MachineProfile], None] | None = None,
) -> MachineChoice:
    """The machine for the file at ``path`` (see :func:`choose_machine`, which reads only
    its header; ``default`` is the link's); FabkitError for a machine that takes no G-code
    or that ``link_takes`` refuses (a machine the link cannot drive)."""
    choice = choose_machine(path, requested, default, force=force)
    if choice.profile.serial is None:
        raise FabkitError(f"machine {choice.profile.name} has flavour none and takes no G-code")
    if link_takes is not None:
        link_takes(choice.profile)
    return choice


def prepare_job(path: str | Path, choice: MachineChoice) -> PreparedJob:
    """Read ``path``, check the job against the machine ``choice`` (:func:`job_machine`)
    and plan its duration; FabkitError at the first problem."""
    data, job = read_job_bytes(path)
    planner = Planner(choice.profile)  # fed each command as the check reads it: one reading
    checked = check_job(job, choice.profile, str(path), also=planner.add, also_run=planner.add_run)
    return PreparedJob(
        str(path), data, job, choice.profile, choice.note, checked, planner.estimate()
    )


@contextlib.contextmanager
def log_file(path: str | Path | None) -> Iterator[TextIO | None]:
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
def keys(control: LinkControl) -> Iterator[None]:
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
