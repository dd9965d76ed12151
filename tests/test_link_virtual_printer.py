"""fabkit's sender against OctoPrint's VirtualPrinter, a Marlin written by others.

VirtualPrinter (PyPI ``octoprint``, ``octoprint.plugins.virtual_printer``) runs here as a
library behind a pyserial-like port (tests/virtual_printer.py) and, once, on a
pseudo-terminal in a process of its own. Every trace is compared with the file line by
line.

One of its default simulated errors cannot be survived by any host: ``105:resend_with_
timeout`` answers the first ``N105`` with ``Resend:105``, drops the next line unseen and
counts 105 as received, so whatever is sent as ``N105`` afterwards is refused as a
repeat and never runs. OctoPrint's own sender loses the same line (it takes the ``wait``
that follows as its ``ok``; tests/test_virtual_printer_port.py pins the behaviour). With
the default settings the test therefore asks for the file minus exactly the line sent as
``N105``, which VirtualPrinter lists as received, and for the report to name that line,
and no other, first; with the other default errors, and with each setting the brief
names, the trace is the whole file and the report names no line.
"""

from __future__ import annotations

import io
import re
import time

import pytest

from fabkit.gcode.read import commands_from_lines
from fabkit.link.host.ports import open_port
from fabkit.link.host.send import stream_job
from fabkit.link.host.session import OK_LOST, REFUSED_COPY, UnrunLine
from fabkit.machines import load_machine
from tests.test_link_support import HOUSEKEEPING, quick
from tests.virtual_printer import VirtualPrinterPort, VirtualPrinterPty

RECOVERABLE = ["100:resend", "110:missing_lineno", "115:checksum_mismatch"]  # the defaults
MARLIN = load_machine("marlin_generic")


def short_moves(n: int) -> list:
    """A file of ``n`` 0.2 mm extruding moves in a serpentine (VirtualPrinter runs a move at
    a tenth of its duration: short moves keep it quick)."""
    lines = ["G21", "G90", "M82", "G92 E0", "G1 Z0.3 F600"]
    x, y = 50.0, 50.0
    for i in range(n):
        x += 0.2 if (i // 200) % 2 == 0 else -0.2
        y += 0.4 if i % 200 == 199 else 0.0
        lines.append(f"G1 X{x:.2f} Y{y:.2f} E{0.001 * (i + 1):.4f} F6000")
    return commands_from_lines(lines)


def ran(executed: list[str]) -> list[str]:
    return [text for text in executed if text not in HOUSEKEEPING]


def sent_as(log: str, number: int) -> set[str]:
    """The texts the log shows sent under line ``number``."""
    return set(re.findall(rf">> N{number} (.*)\*\d+$", log, flags=re.MULTILINE))


@pytest.mark.parametrize("late", [b"N105 ", None], ids=["105-read-late", "as-it-comes"])
def test_default_settings_3000_lines_lose_only_the_line_virtualprinter_swallows(late):
    # Which line VirtualPrinter swallows after Resend:105 is a race. Read late (as a busy
    # firmware reads), N105 reaches it with the next line, which it swallows: the copy
    # of 105 is then refused as a repeat. As it comes, the swallowed line is mostly that
    # copy itself: no answer, exactly as a lost ok, then the probe behind it is accepted,
    # so 105's ok never came though VirtualPrinter went on past it. Either way the
    # report names line 105's text, and no other line.
    job = short_moves(2995)
    log = io.StringIO()
    with VirtualPrinterPort(late=late) as port:
        start = time.monotonic()
        report = stream_job(port, job, MARLIN, port_name="virtual", log=log)
        elapsed = time.monotonic() - start
        executed, accepted = ran(port.executed), port.accepted
    assert len(job) == 3000 and elapsed < 10.0
    (swallowed,) = sent_as(log.getvalue(), 105)  # one text under that number, sent twice
    assert swallowed in {c.text for c in job} and 105 in accepted
    assert executed == [c.text for c in job if c.text != swallowed]
    # VirtualPrinter's own account, the numbers it took as received, is the whole file
    received = [next(iter(sent_as(log.getvalue(), n))) for n in accepted]
    assert [text for text in received if text not in HOUSEKEEPING] == [c.text for c in job]
    assert report.resends >= 4  # 100, 105, 110, 115 each asked for a line again
    refused = "expected line 106 got 105" in log.getvalue()
    assert refused or late is None
    (lost,) = [c for c in job if c.text == swallowed]
    named = UnrunLine(lost.file_line, lost.text, REFUSED_COPY if refused else OK_LOST)
    assert report.may_not_have_run == (named,)
    first = report.summary().splitlines()[0]
    assert first == f"WARNING: 1 line may not have run: {named.sentence()}"


def test_ok_before_the_output_3000_lines_with_the_recoverable_errors_run_once():
    # okBeforeCommandOutput: "ok", then the output on lines of its own (M105: "T:..."),
    # as Repetier answers a line it queues before running it (gcode.cpp
    # checkAndPushCommand): the handshake and the M105 anchors read that form too
    job = short_moves(2995)
    with VirtualPrinterPort(simulated_errors=RECOVERABLE, okBeforeCommandOutput=True) as port:
        report = stream_job(port, job, MARLIN, port_name="virtual")
        executed = ran(port.executed)
    assert len(job) == 3000 and executed == [c.text for c in job]
    assert report.resends >= 3 and report.may_not_have_run == ()


@pytest.mark.parametrize(
    "settings",
    [
        {},
        {"okAfterResend": True},
        {"forceChecksum": True},
        {"simulateReset": False},
        {"rxBuffer": 16},
        {"brokenResend": True},
        {"commandBuffer": 1, "sendBusy": True},
        {"okBeforeCommandOutput": True},
    ],
    ids=[
        "defaults",
        "okAfterResend",
        "forceChecksum",
        "no-reset-banner",
        "rxBuffer-16",
        "brokenResend",
        "busy-1-slot",
        "okBeforeCommandOutput",
    ],  # fmt: skip
)
def test_each_setting_runs_the_whole_file_once_in_order(settings):
    job = short_moves(600)
    with VirtualPrinterPort(simulated_errors=RECOVERABLE, **settings) as port:
        report = stream_job(port, job, MARLIN, options=quick())
        executed = ran(port.executed)
    assert executed == [c.text for c in job]
    assert report.resends >= 3 and report.may_not_have_run == ()


def test_on_its_pseudo_terminal_with_its_errors_off_the_file_runs_once():
    job = short_moves(1000)
    with VirtualPrinterPty(simulated_errors=[]) as printer:
        port = open_port(printer.path, 115200)
        report = stream_job(port, job, MARLIN, port_name=printer.path)
        port.close()
    assert ran(printer.executed) == [c.text for c in job]
    assert report.resends == 0 and report.recoveries == 0
