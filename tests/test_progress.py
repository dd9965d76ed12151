"""Progress of the long commands: on stderr only; a bar on a terminal; with ``--progress``
plain lines where stderr is not one; nothing otherwise, so piped output stays clean."""

from __future__ import annotations

import io
import re

import pytest

from fabkit.progress import STEPS, ProgressBar
from tests.conftest import EXAMPLES


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def _walk(bar: ProgressBar, total: int = 37) -> None:
    for done in range(1, total + 1):
        bar(done, total)
    bar.close()


def test_nothing_is_shown_off_a_terminal_unless_asked():
    stream = io.StringIO()
    _walk(ProgressBar("job", stream))
    assert stream.getvalue() == ""


def test_asked_for_off_a_terminal_it_writes_a_line_per_tenth():
    stream = io.StringIO()
    _walk(ProgressBar("job", stream, force=True))
    lines = stream.getvalue().splitlines()
    assert "\r" not in stream.getvalue()
    assert 2 <= len(lines) <= STEPS + 1
    assert lines[-1].startswith("job: 37/37 (100%)")
    percents = [int(re.search(r"\((\d+)%\)", line).group(1)) for line in lines]
    assert percents == sorted(percents)


def test_on_a_terminal_one_bar_is_redrawn_and_ends_its_line():
    stream = Terminal()
    first, second = ProgressBar("a", stream), ProgressBar("b", stream)
    _walk(first)
    _walk(second)
    text = stream.getvalue()
    assert text.count("\r") == 2 * 37 and text.count("\n") == 2
    assert text.split("\n")[0].endswith("100% ETA 0 s\x1b[K")  # erased to the line end


@pytest.fixture(scope="module")
def tiny_swimmer(tmp_path_factory):
    spec = tmp_path_factory.mktemp("swimmer") / "swimmer.toml"
    text = (EXAMPLES / "swimmer.toml").read_text()
    text = text.replace("rings = 12", "rings = 4").replace("rings = 20", "rings = 5")
    spec.write_text(text.replace("stations = 6", "stations = 2"))
    return spec


@pytest.mark.slow
def test_swimmer_progress_goes_to_stderr_only_when_asked(tiny_swimmer, tmp_path, run_cli):
    args = ("swimmer", tiny_swimmer, "--no-fabricate", "--out")
    code, quiet_out, quiet_err = run_cli(*args, tmp_path / "a")
    assert code == 0 and quiet_err == ""
    code, out, err = run_cli(*args, tmp_path / "b", "--progress")
    assert code == 0
    for label in ("shapes", "flow", "flow, fewer points", "flow, half the stations"):
        assert re.search(rf"^{label}: (\d+)/\1 \(100%\)", err, re.M), label
    assert "ETA" not in out
    timing = re.compile(r"^time: .*$", re.M)  # the one line that differs between two runs
    same = timing.sub("", out).replace(str(tmp_path / "b"), str(tmp_path / "a"))
    assert same == timing.sub("", quiet_out)


def test_simulate_progress_when_asked(tmp_path, run_cli):
    design = tmp_path / "design.npz"
    spec = EXAMPLES / "two_shapes.toml"
    code, _, err = run_cli("solve", spec, "--out", design, "--step", "0.1", "--diagonals", "20")
    assert code == 0 and err == ""
    args = ("simulate", design, "--stimulus", "1", "--steps", "4", "--max-iterations", "20")
    code, out, err = run_cli(*args, "--progress")
    assert code == 0, err
    assert re.findall(r"^simulating: (\d)/4", err, re.M) == ["1", "2", "3", "4"]
    assert "simulating" not in out


@pytest.mark.slow
def test_verify_progress_counts_every_simulation_when_asked(tmp_path, run_cli):
    out = tmp_path / "out"
    spec = EXAMPLES / "two_shapes.toml"
    coarse = ("--step", "0.1", "--diagonals", "20", "--size", "20", "--no-verify", "--no-pictures")
    assert run_cli("run", spec, "--out", out, *coarse)[0] == 0
    args = ("verify", out / "design.npz", out / "sheet.gcode", "--stride", "3")
    code, quiet_out, quiet_err = run_cli(*args, "--max-iterations", "10")
    assert code == 0 and quiet_err == ""
    code, out_text, err = run_cli(*args, "--max-iterations", "10", "--progress", "--reference")
    assert code == 0, err
    counts = re.findall(r"^simulating the sheet as made: (\d+)/(\d+)", err, re.M)
    done, total = zip(*((int(a), int(b)) for a, b in counts), strict=True)
    assert done[-1] == total[0] and len(set(total)) == 1 and list(done) == sorted(done)
    assert "simulating" not in out_text


@pytest.mark.parametrize("stream_type", [io.StringIO, Terminal])
@pytest.mark.parametrize("interval_s", [0.0, 3600.0])
def test_a_caller_that_asks_due_first_writes_what_calling_every_time_writes(
    stream_type, interval_s
):
    # a send calls the bar for every line: it makes the line's detail only when due
    streams = []
    for gated in (False, True):
        stream = stream_type()
        bar = ProgressBar(
            "job", stream, force=True, eta_s=lambda d, e: 99.0 - d, interval_s=interval_s
        )
        for done in [*range(0, 41), 40, 40]:
            if not gated or bar.due(done, 40, force=done == 20):
                bar(done, 40, f"line {done}", force=done == 20)
        bar.close()
        streams.append(stream.getvalue())
    assert streams[0] == streams[1] and "line 40" in streams[0]
