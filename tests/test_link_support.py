"""Helpers shared by the link tests: jobs, running them on the emulator, comparing traces."""

from __future__ import annotations

import random
import re
import time

from fabkit.errors import FabkitError
from fabkit.gcode.read import Command, commands_from_lines
from fabkit.link.emulator.port import Emulator
from fabkit.link.host.ports import open_port
from fabkit.link.host.send import stream_job
from fabkit.link.host.session import LinkOptions, SendReport
from fabkit.machines import load_machine

HOUSEKEEPING = ("M110 N0", "M115", "M105", "M114")  # lines the Marlin sender adds


def marlin_job(n: int, seed: int = 1) -> list[Command]:
    """A printing job of ``n`` moves inside marlin_generic's envelope and limits."""
    rng = random.Random(seed)
    lines = ["; a test job", "G21", "G90", "M82", "G92 E0", "G1 Z0.3 F300"]
    for i in range(n):
        x, y = rng.uniform(10, 200), rng.uniform(10, 200)
        lines.append(f"G1 X{x:.3f} Y{y:.3f} E{0.01 * (i + 1):.4f} F2400")
    return commands_from_lines(lines)


def grbl_job(n: int, seed: int = 1) -> list[Command]:
    """A dispensing job of ``n`` moves for grbl_diw (flow on M8, off M9 every 50 moves)."""
    rng = random.Random(seed)
    lines = ["G21", "G90", "G94", "M9", "G0 Z1", "F1200"]
    for i in range(n):
        if i % 50 == 0:
            lines.append("M8")
        lines.append(f"G1 X{rng.uniform(10, 200):.3f} Y{rng.uniform(10, 200):.3f}")
        if i % 50 == 49:
            lines.append("M9")
    return commands_from_lines(lines)


def executed(emulator: Emulator) -> list[str]:
    """The executed job commands, in order (the sender's own M110/M105 left out)."""
    return [e.command for e in emulator.trace if e.command not in HOUSEKEEPING]


def runs_the_file(emulator: Emulator, job: list[Command]) -> bool:
    """The trace is the file, command for command, nothing lost or repeated.

    The one allowed difference is not the link's: Repetier, Smoothieware and
    RepRapFirmware without ``M575 P0 S1`` run a numbered line that arrives without a
    checksum, so a corrupted ``*`` or a ``;`` made of another byte lets a damaged line
    run; the emulator marks those lines unchecked."""
    trace = [e for e in emulator.trace if e.command not in HOUSEKEEPING]
    return len(trace) == len(job) and all(
        e.command == c.text or not e.checked for e, c in zip(trace, job, strict=True)
    )


def resumed_once(first: list[str], then: list[str], job: list[Command], message: str) -> bool:
    """A job lost and resumed as the message said ran the file once: ``first`` (what ran
    before the loss) then ``then`` (what ran from the printed ``--resume-from`` on) is
    the file, but for lines the message names as sent and not acknowledged, or as dropped
    by a reset, which may have run in both."""
    resume = int(re.search(r"--resume-from (\d+)$", message).group(1))
    start = next(i for i, c in enumerate(job) if c.file_line >= resume)
    texts = [c.text for c in job]
    ambiguous = re.search(
        r"file lines? (\d+)(?:-(\d+))? (?:(?:was|were) sent but not|\(acknowledged or sent "
        r"last\) may or may not)",
        message,
    )
    end = start
    if ambiguous:
        last = int(ambiguous.group(2) or ambiguous.group(1))
        end = max(i + 1 for i, c in enumerate(job) if c.file_line <= last)
    return then == texts[start:] and any(first == texts[:i] for i in range(start, end + 1))


def lost_and_resumed(url: str, again: str, job: list[Command]) -> tuple[bool, str]:
    """Stream ``job`` to ``url`` (marlin_generic) until the link is lost, let that machine
    finish what it holds, then send the lines from the message's ``--resume-from`` to a
    fresh ``again``: whether the two ran the file once (:func:`resumed_once`), and the
    one-line message."""
    port = open_port(url, 115200)
    try:
        stream_job(port, job, load_machine("marlin_generic"), options=quick())
    except FabkitError as error:
        message = str(error)
    else:
        raise AssertionError(f"{url}: the job was not lost")
    assert "\n" not in message
    port.emulator.poll(time.monotonic() + 600)
    first = executed(port.emulator)
    resume = int(re.search(r"--resume-from (\d+)$", message).group(1))
    _, emulator = run_sim(again, [c for c in job if c.file_line >= resume], "marlin_generic")
    return resumed_once(first, executed(emulator), job, message), message


def numbers_are_contiguous(emulator: Emulator) -> bool:
    """Marlin line numbers executed 0, 1, 2, ... without gap or repeat."""
    numbers = [e.n for e in emulator.trace]
    return numbers == list(range(len(numbers)))


def names_the_lost_oks(report: SendReport, emulator: Emulator, job: list[Command]) -> bool:
    """The report names every job line whose ``ok`` the emulator dropped (alone, or among
    the lines of which some lost theirs), and no line when no answer was lost (none
    dropped, none garbled). The emulator ran the job in order (checked apart)."""
    stats = emulator.stats()
    named = {line.file_line for line in report.may_not_have_run}
    if stats.dropped_oks + stats.garbled_lines == 0:
        return not named
    ran = [e.n for e in emulator.trace if e.command not in HOUSEKEEPING]
    file_line = dict(zip(ran, (c.file_line for c in job), strict=True))
    dropped = {file_line[n] for n in stats.dropped_ok_lines if n in file_line}
    return dropped <= named


def run_sim(url: str, job: list[Command], machine: str, **options) -> tuple[SendReport, Emulator]:
    """Stream ``job`` to a ``sim://`` URL; the report and the emulator, which has then run
    what it acknowledged (Repetier acknowledges a line when it queues it)."""
    port = open_port(url, 115200)
    report = stream_job(port, job, load_machine(machine), port_name=url, **options)
    port.emulator.poll(time.monotonic() + 600)
    return report, port.emulator


def quick(**options) -> LinkOptions:
    """Link options for tests: short probes and timeouts."""
    return LinkOptions(**{"probe_min_s": 0.02, "assume_idle_s": 2.0, **options})


def test_jobs_are_what_the_helpers_say():
    assert len(marlin_job(10)) == 15 and marlin_job(3)[0].file_line == 2
    assert sum(c.text == "M8" for c in grbl_job(100)) == 2
