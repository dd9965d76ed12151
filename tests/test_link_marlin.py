"""The Marlin sender against the emulator: nothing lost, nothing repeated, in order."""

from __future__ import annotations

import contextlib
import io
import re
import threading
from dataclasses import replace

import pytest

from fabkit.errors import FabkitError
from fabkit.gcode.read import Command, commands_from_lines
from fabkit.link.host.ports import open_port
from fabkit.link.host.send import stream_job
from fabkit.link.host.session import (
    OK_LOST,
    LinkControl,
    SendReport,
    UnrunLine,
    oks_lost,
)
from fabkit.machines import load_machine
from fabkit.progress import ProgressBar
from tests.test_link_support import (
    executed,
    lost_and_resumed,
    marlin_job,
    names_the_lost_oks,
    numbers_are_contiguous,
    quick,
    run_sim,
    runs_the_file,
)

FAST = "sim://marlin?time_scale=0&baud=0"
FAULTS = "corrupt=0.01&drop_ok=0.001"


@pytest.mark.slow
def test_100k_lines_with_1_percent_corruption_and_lost_oks_run_exactly_once_in_order():
    # the audit's case: 100,000 lines, 1 % corrupt, 0.1 % lost oks ran 100,001 lines
    job = marlin_job(100_000)
    report, emulator = run_sim(f"{FAST}&{FAULTS}&seed=3", job, "marlin_generic")
    assert executed(emulator) == [c.text for c in job]
    assert numbers_are_contiguous(emulator)
    stats = emulator.stats()
    assert stats.corrupted_lines > 750 and stats.dropped_oks > 50
    assert report.resends >= 750 and report.recoveries == 0
    assert names_the_lost_oks(report, emulator, job)


@pytest.mark.parametrize(
    "variant",
    ["resend_ok=0", "drain=0", "garble=0.01&noise=0.02"],
    ids=["marlin-2.0-no-ok-after-resend", "marlin-1.1-no-drain", "garbled-and-noisy-answers"],
)
def test_every_marlin_variant_and_noisy_answers(variant):
    # with Marlin 2.x at most two lines are unanswered; on 2.0.x (no ok after a resend)
    # both can turn out to be lines whose answer never comes: the link then waits until
    # silence proves nothing is held (quick(): 2 s) before it probes
    job = marlin_job(1500, seed=2)
    report, emulator = run_sim(
        f"{FAST}&{FAULTS}&{variant}&seed=5", job, "marlin_generic", options=quick()
    )
    assert executed(emulator) == [c.text for c in job]
    assert numbers_are_contiguous(emulator)
    assert report.recoveries <= (2 if variant == "resend_ok=0" else 0)
    assert emulator.stats().dropped_ok_lines and names_the_lost_oks(report, emulator, job)


@pytest.mark.parametrize(
    "variant",
    ["ack_on_queue=1", "dialect=repetier&ack_numbered=0"],
    ids=["marlin-ok-when-queued", "repetier-without-line-numbers"],
)
def test_with_the_ok_before_the_output_the_m105_report_finds_lost_oks(variant):
    # ok when a line is queued, M105's T:... on a line of its own when it runs: the
    # handshake learns that form, and each report then names its M105, so lost oks are
    # found at the next report, not by silence (without it: 11 recoveries, 23 s)
    job = marlin_job(1500, seed=2)
    url = f"{FAST}&corrupt=0.01&drop_ok=0.01&seed=7&{variant}"
    report, emulator = run_sim(url, job, "marlin_generic", options=quick())
    assert runs_the_file(emulator, job)
    assert emulator.stats().dropped_oks > 10
    assert report.recoveries == 0 and names_the_lost_oks(report, emulator, job)


def test_the_summary_names_a_line_alone_and_a_run_once_and_the_json_each_line():
    why = oks_lost(1, 20, 22)
    unrun = (
        UnrunLine(7, "G1 X1", OK_LOST),
        *(UnrunLine(n, f"G1 X{n}", why, shared=True) for n in (20, 21, 22)),
    )
    report = SendReport("p", "marlin", 30, 1, 30, 1.0, 0, 31, 0, 0, 0, (), unrun)
    first = report.summary().splitlines()[0]
    assert first == f"WARNING: 4 lines may not have run: file line 7 (G1 X1): {OK_LOST}; {why}"
    assert why.startswith("1 of file lines 20-22 ") and "lost its ok" in why
    items = report.figures()["lines_that_may_not_have_run"]
    assert [item["file_line"] for item in items] == [7, 20, 21, 22]
    assert items[2] == {"file_line": 21, "text": "G1 X21", "why": why}


def test_real_byte_timing_never_overflows_the_receive_buffer():
    # moves take time: the planner fills, the firmware stops reading, the ring fills up
    job = commands_from_lines(["G1 F3000"] + [f"G1 X{10 + i % 90}" for i in range(400)])
    url = f"sim://marlin?time_scale=0.01&baud=1000000&{FAULTS}&seed=9"
    machine = load_machine("marlin_generic")
    report, emulator = run_sim(url, job, "marlin_generic", options=quick())
    assert executed(emulator) == [c.text for c in job]
    assert emulator.stats().overflow_bytes == 0 and emulator.stats().max_rx_bytes <= 127
    assert names_the_lost_oks(report, emulator, job)
    # control: a sender that believes in a 1 KiB buffer (and, the firmware not draining
    # its buffer on errors, keeps up to 200 lines in flight) overruns the 128-byte ring
    serial = replace(machine.serial, rx_buffer_bytes=1024)
    greedy = replace(machine, flavour="klipper", serial=serial)
    port = open_port("sim://marlin?time_scale=0.01&baud=1000000&dialect=smoothieware", 115200)
    with contextlib.suppress(FabkitError):
        stream_job(port, job[:200], greedy, options=quick(dead_s=2.0))
    assert port.emulator.stats().overflow_bytes > 0


class Rewriting:
    """A port whose answers pass through ``change`` (other firmwares' spellings)."""

    def __init__(self, port, change):
        self.port, self.change = port, change
        self.pending = b""  # a partial line, held back until complete

    @property
    def timeout(self):
        return self.port.timeout

    @timeout.setter
    def timeout(self, value):
        self.port.timeout = value

    @property
    def in_waiting(self):
        return self.port.in_waiting

    def read(self, size=1):
        data = self.pending + self.port.read(max(size, self.port.in_waiting))
        cut = data.rfind(b"\n") + 1
        self.pending = data[cut:]
        return self.change(data[:cut])

    def write(self, data):
        return self.port.write(data)


@pytest.mark.slow
@pytest.mark.parametrize("spelling", [b"Resend:", b"rs ", b"rs N"])
def test_other_resend_spellings(spelling):
    port = open_port(f"{FAST}&corrupt=0.02&seed=1", 115200)
    job = marlin_job(2000)
    rewriting = Rewriting(port, lambda data: data.replace(b"Resend: ", spelling))
    report = stream_job(rewriting, job, load_machine("marlin_generic"), options=quick())
    assert executed(port.emulator) == [c.text for c in job] and report.resends > 10
    assert report.may_not_have_run == ()  # no ok lost


@pytest.mark.slow
def test_lost_oks_are_detected_by_probing_and_recovered():
    job = marlin_job(3000)
    report, emulator = run_sim(f"{FAST}&drop_ok=0.01&seed=2", job, "marlin_generic")
    assert emulator.stats().dropped_oks > 10 and report.probes > 0
    assert executed(emulator) == [c.text for c in job]
    assert names_the_lost_oks(report, emulator, job)


@pytest.mark.slow
def test_heating_waits_report_temperatures_and_busy_lines_keep_the_link_alive():
    job = commands_from_lines(["G21", "M109 S210", "G4 S0.4", "G1 X10 F600"])
    url = "sim://marlin?time_scale=1&baud=0&heat_tau_s=0.15&keepalive_s=0.1"
    progress, log = io.StringIO(), io.StringIO()
    report, emulator = run_sim(
        url,
        job,
        "marlin_generic",
        progress=ProgressBar("sending", progress, force=True),
        log=log,
        options=quick(),
    )
    assert executed(emulator) == [c.text for c in job]
    assert "heating T:" in progress.getvalue() and "<< echo:busy: processing" in log.getvalue()
    assert report.probes == 0  # busy and temperature lines count as answers


@pytest.mark.slow
def test_disconnect_names_the_last_acknowledged_line_and_resume_is_continuous():
    job = marlin_job(3000)
    port = open_port(f"{FAST}&disconnect_after=1202", 115200)
    with pytest.raises(FabkitError) as caught:
        stream_job(port, job, load_machine("marlin_generic"), port_name="sim://marlin")
    message = str(caught.value)
    assert "\n" not in message
    assert "lost the connection to sim://marlin" in message
    last = int(re.search(r"last acknowledged file line (\d+)", message).group(1))
    assert f"--resume-from {last + 1}" in message
    first = executed(port.emulator)
    _, emulator = run_sim(FAST, [c for c in job if c.file_line > last], "marlin_generic")
    assert first + executed(emulator) == [c.text for c in job]


def test_a_reset_during_the_job_stops_it():
    with pytest.raises(FabkitError, match=r"reset during the job\); a reset drops the firmware"):
        run_sim(f"{FAST}&reset_after=300", marlin_job(1000), "marlin_generic")


@pytest.mark.parametrize("dialect", ["marlin-2.1", "repetier"])
def test_a_reset_while_moves_are_planned_resumes_from_the_first_that_may_not_have_run(dialect):
    # at a real pace the machine holds acknowledged lines when it resets (its planner, and
    # Repetier acknowledges a line as it queues it): resuming after the last acknowledged
    # one skipped them (found by a helper session on reset-repetier at time_scale=0.01;
    # 0.002 still holds about 20 lines when it resets, and sleeps 3 s where 0.01 slept 14)
    url = f"sim://marlin?time_scale=0.002&baud=0&reset_after=600&dialect={dialect}"
    resumed, message = lost_and_resumed(url, f"{FAST}&dialect={dialect}", marlin_job(1200))
    assert "a reset drops the firmware's planned moves and queued commands" in message
    first, last = map(int, re.search(r"file lines (\d+)-(\d+)", message).groups())
    assert last - first >= 10, message  # moves were planned when it reset
    assert resumed, message


def test_abort_sends_the_safe_stop_and_names_the_line_the_machine_stopped_in():
    # M410 drops the planned moves: the line to resume from is where the tool stopped,
    # not the last acknowledged one (moves acknowledged but still planned never ran)
    machine = load_machine("marlin_diw_pneumatic")
    job = marlin_job(2000)
    port = open_port("sim://marlin?time_scale=0.02&baud=0&accel=500", 115200)
    control = LinkControl()
    threading.Timer(0.3, control.abort).start()
    with pytest.raises(FabkitError) as caught:
        stream_job(port, job, machine, control=control)
    message = str(caught.value)
    assert message.startswith("aborted: safe-stop sent; the machine stopped at X ")
    resume = int(re.search(r"--resume-from (\d+)$", message).group(1))
    emulator = port.emulator
    safe_stop = machine.render("safe_stop_gcode")
    assert executed(emulator)[-len(safe_stop) :] == safe_stop
    finished = set(emulator.firmware.motion.finished)
    moves = [
        (i, e) for i, e in enumerate(emulator.trace) if e.command.startswith("G1 X")
    ]  # the job's moves that ran (were planned)
    assert all(
        (i in finished) == (e.n is not None and _file_line(job, e) < resume) for i, e in moves
    )
    assert len(moves) < 200


def _file_line(job, entry):
    """The file line of a job command the emulator ran (its text is unique in marlin_job)."""
    return next(c.file_line for c in job if c.text == entry.command)


@pytest.mark.slow
def test_pause_stops_sending_and_resume_completes_the_job():
    job = marlin_job(400)
    port = open_port("sim://marlin?time_scale=0.0003&baud=0", 115200)
    control = LinkControl()
    counts = []

    def pause_then_resume():
        control.pause()
        counts.append(len(port.emulator.trace))
        threading.Event().wait(0.4)
        counts.append(len(port.emulator.trace))
        control.resume()

    threading.Timer(0.2, pause_then_resume).start()
    stream_job(port, job, load_machine("marlin_generic"), control=control)
    assert executed(port.emulator) == [c.text for c in job]
    assert counts[1] - counts[0] <= 20  # only the lines already in flight ran


def test_a_silent_port_is_one_line_naming_the_baud_rate():
    class Silent:
        timeout = 0.01
        in_waiting = 0

        def read(self, size=1):
            return b""

        def write(self, data):
            return len(data)

    with pytest.raises(FabkitError, match=r"^no answer from dev at 115200 baud"):
        stream_job(
            Silent(),
            marlin_job(3),
            load_machine("marlin_generic"),
            port_name="dev",
            options=quick(handshake_s=0.3),
        )


def test_a_firmware_error_stops_the_job():
    job = list(marlin_job(10))
    job.insert(5, Command(99, "M112"))
    with pytest.raises(FabkitError, match=r"reported 'Error:Printer halted. kill\(\) called!'"):
        run_sim(FAST, job, "marlin_generic")


def test_the_log_holds_both_directions():
    log = io.StringIO()
    run_sim(FAST, marlin_job(3), "marlin_generic", log=log)
    lines = log.getvalue().splitlines()
    assert re.fullmatch(r" +\d+\.\d{4} >> N0 M110 N0\*125", lines[0])
    assert any(line.endswith("<< ok") for line in lines)


@pytest.mark.parametrize("seed", range(4))
def test_heavy_ok_loss_still_finishes_at_the_last_job_line(seed):
    # with lost "ok T:" answers the last probes may be credited one behind: the job
    # is complete when its last line is, whatever probes follow it
    job = marlin_job(200, seed=seed)
    url = f"{FAST}&drop_ok=0.01&seed={seed}"
    report, emulator = run_sim(url, job, "marlin_generic", options=quick())
    assert executed(emulator) == [c.text for c in job] and report.probes > 0
    assert names_the_lost_oks(report, emulator, job)


@pytest.mark.parametrize("seed", [5, 22, 33])
def test_a_line_cut_by_marlins_drain_never_runs(seed):
    # Marlin 2.x empties its receive buffer on a bad line; a line half-received then
    # would arrive without its N word and run unchecked. The machine is kept busy (moves
    # take time) so that lines queue up behind a blocked command, as when printing.
    job = commands_from_lines(["G1 F3000"] + [f"G1 X{10 + i % 90}" for i in range(400)])
    url = f"sim://marlin?time_scale=0.01&baud=1000000&corrupt=0.02&drop_ok=0.002&seed={seed}"
    report, emulator = run_sim(url, job, "marlin_generic", options=quick())
    assert all(entry.n is not None for entry in emulator.trace)
    assert executed(emulator) == [c.text for c in job] and report.recoveries == 0
    assert names_the_lost_oks(report, emulator, job)
