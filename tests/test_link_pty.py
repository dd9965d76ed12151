"""The real-tty path: the sender opens the slave of a pseudo-terminal like any serial
device, and the emulator serves the master side from a thread."""

from __future__ import annotations

import re

import pytest

from fabkit.errors import FabkitError
from fabkit.link.emulator.port import PtyEmulator, config_from_url
from fabkit.link.host.ports import open_port
from fabkit.link.host.send import stream_job
from fabkit.machines import load_machine
from tests.test_link_support import (
    executed,
    grbl_job,
    marlin_job,
    names_the_lost_oks,
    numbers_are_contiguous,
    quick,
)


@pytest.mark.slow
def test_marlin_over_a_pty_with_faults_arrives_exactly_once_in_order():
    job = marlin_job(3000)
    config = config_from_url("sim://marlin?time_scale=0&baud=0&corrupt=0.01&drop_ok=0.002", 0)
    with PtyEmulator(config) as pty:
        assert pty.path.startswith("/dev/")
        port = open_port(pty.path, 115200)
        assert type(port).__module__ == "serial.serialposix"  # the real device code path
        report = stream_job(port, job, load_machine("marlin_generic"), port_name=pty.path)
        port.close()
    assert executed(pty.emulator) == [c.text for c in job]
    assert numbers_are_contiguous(pty.emulator) and report.resends > 10
    assert pty.emulator.stats().dropped_ok_lines and names_the_lost_oks(report, pty.emulator, job)


def test_grbl_over_a_pty():
    job = grbl_job(1000)
    config = config_from_url("sim://grbl?time_scale=0&baud=0&drop_ok=0.005", 0)
    with PtyEmulator(config) as pty:
        port = open_port(pty.path, 115200)
        stream_job(port, job, load_machine("grbl_diw"), options=quick())
        port.close()
    assert executed(pty.emulator) == [c.text for c in job]


def test_a_pty_that_goes_away_is_one_line_with_the_resume_point():
    job = marlin_job(2000)
    config = config_from_url("sim://marlin?time_scale=0&baud=0&disconnect_after=802", 0)
    with PtyEmulator(config) as pty:
        port = open_port(pty.path, 115200)
        with pytest.raises(FabkitError) as caught:
            stream_job(port, job, load_machine("marlin_generic"), port_name=pty.path)
        port.close()
    message = str(caught.value)
    assert message.startswith(f"lost the connection to {pty.path}") and "\n" not in message
    last = int(re.search(r"last acknowledged file line (\d+)", message).group(1))
    assert executed(pty.emulator) == [c.text for c in job if c.file_line <= last]
