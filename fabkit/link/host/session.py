"""What both protocols share: options, user controls, progress, the report, port I/O.

A protocol (:class:`~fabkit.link.host.marlin.MarlinProtocol`,
:class:`~fabkit.link.host.grbl.GrblProtocol`) subclasses :class:`Session` and drives an
already-open serial-like port: anything with ``read(n)``, ``write(b)``, ``in_waiting``
and a ``timeout`` attribute (pyserial ports, the ``sim://`` emulator, test doubles).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, TextIO

from fabkit.errors import FabkitError
from fabkit.gcode.duration import Estimate, estimate
from fabkit.gcode.read import Command
from fabkit.machines import MachineProfile
from fabkit.progress import ProgressBar


class SerialLike(Protocol):
    """The part of a pyserial port the link uses."""

    timeout: float | None

    @property
    def in_waiting(self) -> int: ...

    def read(self, size: int = 1) -> bytes: ...

    def write(self, data: bytes) -> int | None: ...


@dataclass(frozen=True)
class LinkOptions:
    """Tuning of the link (s). The defaults suit real machines and the emulator alike.

    ``window_lines`` caps the lines in flight (None: the profile's planner depth;
    1: one line per ``ok``, the classic ping-pong). A silent machine with lines in
    flight is probed after between ``probe_min_s`` and ``probe_max_s`` (adapting to the
    recent pace of answers); it counts as lost after ``dead_s`` of silence, or
    ``wait_dead_s`` while a waiting command (heat-up, homing, dwell) is in flight.
    """

    window_lines: int | None = None
    poll_s: float = 0.01
    probe_min_s: float = 0.05
    probe_max_s: float = 2.0
    assume_idle_s: float = 5.0
    dead_s: float = 30.0
    wait_dead_s: float = 1800.0
    handshake_s: float = 10.0
    finish_s: float = 60.0


class SendInterrupted(KeyboardInterrupt):
    """Ctrl-C ended a send after the machine's safe stop; the message (one line) says
    where the job stopped and which ``--resume-from`` continues it."""


class LinkControl:
    """Pause, resume and abort requests, safe to call from signal handlers or threads.

    ``interrupt()`` is an abort asked for with Ctrl-C (``interrupted`` then says so)."""

    def __init__(self) -> None:
        self._paused = threading.Event()
        self._aborted = threading.Event()
        self._interrupted = threading.Event()

    def pause(self) -> None:
        self._paused.set()

    def resume(self) -> None:
        self._paused.clear()

    def toggle_pause(self) -> None:
        if self._paused.is_set():
            self.resume()
        else:
            self.pause()

    def abort(self) -> None:
        self._aborted.set()

    def interrupt(self) -> None:
        self._interrupted.set()
        self._aborted.set()

    @property
    def interrupted(self) -> bool:
        return self._interrupted.is_set()

    @property
    def paused(self) -> bool:
        return self._paused.is_set()

    @property
    def aborted(self) -> bool:
        return self._aborted.is_set()


def send_eta(
    plan: Estimate | None, total: int, offset: int = 0, time_scale: float = 1.0
) -> Callable[[int, float], float]:
    """Seconds left after ``done`` of ``total`` job lines, ``elapsed_s`` into the send: the
    longer of the machine's time (``plan``, the planned duration of the moves left
    after the first ``offset + done`` commands of the file, times ``time_scale``) and the
    host's (the lines left at the line rate so far). For :class:`~fabkit.progress.ProgressBar`."""

    def eta_s(done: int, elapsed_s: float) -> float:
        left = [0.0]
        if plan is not None:
            left.append(plan.remaining_s(offset + done) * time_scale)
        if done > 0 and elapsed_s > 0:
            left.append((total - done) * elapsed_s / done)
        return max(left)

    return eta_s


def _visible(line: str) -> str:
    """``line`` as is, or as a Python literal in ASCII (every other byte escaped) if it
    holds anything but printable ASCII: the log stays ASCII whatever the machine sends
    (VirtualPrinter's banner holds a 0x80 byte)."""
    return ascii(line) if any(ord(c) < 32 or ord(c) > 126 for c in line) else line


REFUSED_COPY = "the machine asked for it again, then refused the copy as a line it had"
ANSWER_LOST = "its answer (ok or error:) was lost; the machine read it"
OK_LOST = (
    "its ok never came, though the machine went on past it (the ok lost on the wire, "
    "or the line dropped)"
)


def oks_lost(lost: int, first: int, last: int) -> str:
    """Why each of file lines ``first``-``last`` may not have run: ``lost`` oks of theirs
    (or of a status query sent among them) never came, and the answers do not say whose."""
    whose = "its ok" if lost == 1 else "their oks"
    return (
        f"{lost} of file lines {first}-{last} (or a status query among them) lost {whose}, "
        "though the machine went on past them (oks lost on the wire, or lines dropped)"
    )


@dataclass(frozen=True)
class UnrunLine:
    """A job line that may not have run: its file line (1-based), its text and why
    (:data:`REFUSED_COPY`, :data:`ANSWER_LOST`, :data:`OK_LOST`, :func:`oks_lost`).
    ``shared``: the reason is one that each of a run of lines has (:func:`oks_lost`),
    said once for all of them in the summary."""

    file_line: int
    text: str
    why: str
    shared: bool = False

    def sentence(self) -> str:
        return f"file line {self.file_line} ({self.text}): {self.why}"

    def figures(self) -> dict[str, Any]:
        return {"file_line": self.file_line, "text": self.text, "why": self.why}


@dataclass(frozen=True)
class SendReport:
    """What a finished job did (s, bytes, lines). ``may_not_have_run``: the job lines the
    machine may not have run, and why (:mod:`fabkit.link.host.marlin`: a line refused as
    one it had without ever taking a copy, or one whose ``ok`` never came though the
    machine went on past it; :mod:`fabkit.link.host.grbl`: a line whose answer was
    lost)."""

    port: str
    protocol: str
    job_lines: int
    first_file_line: int
    last_file_line: int
    elapsed_s: float
    bytes_sent: int
    transmissions: int
    resends: int
    probes: int
    recoveries: int
    warnings: tuple[str, ...]
    may_not_have_run: tuple[UnrunLine, ...] = ()

    @property
    def lines_per_s(self) -> float:
        return self.job_lines / self.elapsed_s if self.elapsed_s > 0 else float("inf")

    def figures(self) -> dict[str, Any]:
        """The figures, each named with its unit (report.json, report.html)."""
        return {
            "port": self.port,
            "protocol": self.protocol,
            "job_lines": self.job_lines,
            "file_lines": f"{self.first_file_line}-{self.last_file_line}",
            "seconds": round(self.elapsed_s, 3),
            "lines_per_second": round(self.lines_per_s, 1),
            "resent_lines": self.resends,
            "status_queries_between_lines": self.probes,
            "recoveries_from_lost_answers": self.recoveries,
            "warnings": list(self.warnings),
            "lines_that_may_not_have_run": [line.figures() for line in self.may_not_have_run],
        }

    def summary(self) -> str:
        """The lines for the user: first the job lines that may not have run, if any."""
        text = (
            f"sent {self.job_lines} lines (file lines {self.first_file_line}-"
            f"{self.last_file_line}) to {self.port} in {self.elapsed_s:.1f} s "
            f"({self.lines_per_s:.0f} lines/s, {self.protocol}); "
            f"{self.resends} resends, {self.probes} probes, {self.recoveries} recoveries"
        )
        return "\n".join([*self._unrun_line(), text, *(f"warning: {w}" for w in self.warnings)])

    def _unrun_line(self) -> list[str]:
        """The warning line: one sentence per line named, one for a run of lines that
        share a reason."""
        if not self.may_not_have_run:
            return []
        count = len(self.may_not_have_run)
        said: list[str] = []
        for i, line in enumerate(self.may_not_have_run):
            previous = self.may_not_have_run[i - 1] if i else None
            if not (line.shared and previous is not None and previous.why == line.why):
                said.append(line.why if line.shared else line.sentence())
        lines = "; ".join(said)
        return [f"WARNING: {count} line{'s' if count > 1 else ''} may not have run: {lines}"]


class Session:
    """Port I/O, line splitting, logging and bookkeeping shared by the protocols."""

    protocol = ""

    def __init__(
        self,
        port: SerialLike,
        port_name: str,
        job: Sequence[Command],
        machine: MachineProfile,
        options: LinkOptions,
        control: LinkControl,
        progress: ProgressBar | None,
        log: TextIO | None,
    ) -> None:
        if machine.serial is None:
            raise FabkitError(f"machine {machine.name} has flavour none and takes no G-code")
        self.port = port
        self.port_name = port_name
        self.job = job
        self.machine = machine
        self.serial = machine.serial
        self.options = options
        self.control = control
        self.progress = progress
        self.log = log
        self.rx = bytearray()
        self.t0 = time.monotonic()
        self.last_rx_s = self.last_tx_s = self.t0
        self.bytes_sent = 0
        self.transmissions = 0
        self.resends = 0
        self.probes = 0
        self.recoveries = 0
        self.warnings: list[str] = []
        self.unrun: dict[int, UnrunLine] = {}  # by job index: lines that may not have run
        self.aborting = False
        port.timeout = options.poll_s

    # -- I/O -------------------------------------------------------------------------------

    def write(self, data: bytes) -> None:
        """Send bytes, all of them (a port may take part of them, as a pyserial port with
        a write timeout or OctoPrint's VirtualPrinter does, and say how many)."""
        rest = data
        while rest:
            written = self.port.write(rest)
            if written is None or written >= len(rest):
                break
            rest = rest[written:]
        self.bytes_sent += len(data)
        self.last_tx_s = time.monotonic()
        if self.log is not None:
            for line in data.decode("latin-1").split("\n")[: data.count(b"\n") or 1]:
                self.log.write(f"{self.last_tx_s - self.t0:10.4f} >> {_visible(line)}\n")

    def discard_input(self) -> None:
        """Forget what arrived before now (a power-up banner, a previous session)."""
        reset = getattr(self.port, "reset_input_buffer", None)
        if reset is not None:
            reset()
        self.rx.clear()

    def read_line(self) -> str | None:
        """The next line from the machine (stripped), or None after ``poll_s`` without one."""
        i = self.rx.find(b"\n")
        if i < 0:
            waiting = self.port.in_waiting
            self.rx += self.port.read(waiting or 1)
            i = self.rx.find(b"\n")
            if i < 0:
                return None
        line = self.rx[:i].decode("latin-1").strip()
        del self.rx[: i + 1]
        self.last_rx_s = time.monotonic()
        if self.log is not None:
            self.log.write(f"{self.last_rx_s - self.t0:10.4f} << {_visible(line)}\n")
        return line

    # -- results ---------------------------------------------------------------------------

    def file_line_after(self, done: int) -> int:
        """The file line of the ``done``-th job line (the first line's predecessor if 0)."""
        if not self.job:
            return 0
        return self.job[done - 1].file_line if done > 0 else self.job[0].file_line - 1

    def lost(self, done: int, reason: str, sent: int | None = None) -> FabkitError:
        """The one-line error for a connection lost after ``done`` job lines were
        acknowledged and ``sent`` (default ``done``) were written at least once. The lines
        in between are ambiguous: the machine may have run them (a cable pulled while it
        works through its buffer) or not. The resume line runs them again, so that
        nothing is lost, and the message says so first."""
        last = self.file_line_after(done)
        sent = done if sent is None else max(sent, done)
        if sent == done:
            return FabkitError(
                f"lost the connection to {self.port_name} ({reason}); last acknowledged "
                f"file line {last}; after reconnecting continue with --resume-from {last + 1}"
            )
        first, final = self.job[done].file_line, self.job[sent - 1].file_line
        one = first == final
        span = f"file line {first} was" if one else f"file lines {first}-{final} were"
        them = "it" if one else "them"
        skip = self.job[sent].file_line if sent < len(self.job) else None
        instead = f" (--resume-from {skip} skips {them})" if skip is not None else ""
        return FabkitError(
            f"lost the connection to {self.port_name} ({reason}); last acknowledged file "
            f"line {last}; {span} sent but not acknowledged and may have run, so continuing "
            f"from {first} may run {them} twice{instead}; after reconnecting continue with "
            f"--resume-from {first}"
        )

    def reset_error(self, acked: int, sent: int, held: int, drops: str) -> FabkitError:
        """The one-line error for a machine that reset after ``acked`` job lines were
        acknowledged and ``sent`` written: a reset drops what it held (``drops``, in
        words), up to ``held`` acknowledged lines, so those and the ones sent after them
        may or may not have run; the resume line is the first of them."""
        reason = "the machine reset during the job"
        first = max(0, acked - held)
        if first >= sent:
            return self.lost(acked, reason)
        start, end = self.job[first].file_line, self.job[sent - 1].file_line
        return FabkitError(
            f"lost the connection to {self.port_name} ({reason}); a reset drops {drops}, "
            f"so file lines {start}-{end} (acknowledged or sent last) may or may not have "
            f"run, and continuing from {start} may run some of them twice; look at the "
            f"part, then continue with --resume-from {start}"
        )

    def aborted_error(self, done: int, detail: str) -> FabkitError:
        last = self.file_line_after(done)
        return FabkitError(
            f"aborted: {detail}; last acknowledged file line {last}; "
            f"continue later with --resume-from {last + 1}"
        )

    def stopped_error(
        self, detail: str, point: tuple[float, float, float] | None, last: int
    ) -> FabkitError:
        """The one line after a stop that dropped the planned moves: where the machine
        stopped (``point``, X, Y, Z mm) places it in the file, among the moves up to job
        index ``last`` that the planner may have held; else the last acknowledged line."""
        window = self.serial.planner_depth + 8  # planner blocks, command queue, lines in flight
        index = None
        if point is not None and self.job:
            index = estimate(self.job, self.machine).stopped_in(point, last, window)
        if index is None:
            return self.aborted_error(max(0, min(last + 1, len(self.job))), detail)
        where = " ".join(f"{axis} {value:.3f}" for axis, value in zip("XYZ", point, strict=True))
        if index >= len(self.job):
            return FabkitError(
                f"aborted: {detail}; the machine stopped at {where}, after the last line"
            )
        line = self.job[index].file_line
        return FabkitError(
            f"aborted: {detail}; the machine stopped at {where}, in file line {line}; "
            f"continue later with --resume-from {line}"
        )

    def report(self) -> SendReport:
        return SendReport(
            port=self.port_name,
            protocol=self.protocol,
            job_lines=len(self.job),
            first_file_line=self.job[0].file_line if self.job else 0,
            last_file_line=self.job[-1].file_line if self.job else 0,
            elapsed_s=time.monotonic() - self.t0,
            bytes_sent=self.bytes_sent,
            transmissions=self.transmissions,
            resends=self.resends,
            probes=self.probes,
            recoveries=self.recoveries,
            warnings=tuple(self.warnings),
            may_not_have_run=tuple(self.unrun[i] for i in sorted(self.unrun)),
        )

    def name_unrun(self, index: int, why: str, *, shared: bool = False) -> None:
        """Job line ``index`` may not have run, because ``why`` (the first reason found
        for a line is the one kept)."""
        command = self.job[index]
        self.unrun.setdefault(index, UnrunLine(command.file_line, command.text, why, shared))

    def show(self, done: int, note: str = "", *, force: bool = False) -> None:
        """``done`` job lines on the progress bar (with where the job is and ``note``),
        when the bar writes now."""
        if self.progress is not None and self.progress.due(done, len(self.job), force):
            where = f"file line {self.file_line_after(done)}" + (f"  {note}" if note else "")
            self.progress(done, len(self.job), where, force=force)
