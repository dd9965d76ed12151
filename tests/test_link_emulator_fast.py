"""The emulator's shortcuts change nothing: on the same writes at the same times, an
emulator with its fast paths (instant wire, faultless output, framed lines, direct moves)
answers, traces and counts exactly as one forced down the general path."""

from __future__ import annotations

import dataclasses
import random
import re

import pytest

from fabkit.gcode.read import (
    code_of,
    frame_marlin,
    frame_summed,
    marlin_checksum,
    text_checksums,
)
from fabkit.link.emulator.marlin import command_code
from fabkit.link.emulator.port import Emulator, config_from_url

_JOB = [
    "G21",
    "G90",
    "M82",
    "G92 E0",
    "G28",
    "M104 S200",
    "M105",
    "G1 X10 Y10 F3000",
    "G0 X20 Y5",
    "G1 X22 Y6.5 E2",
    "G1 X+23 Y.5 F900",
    "G0 Z1.",
    "g1 x21 y6",
    "G2 X30 Y5 I5 J0",
    "G1  X31   Y8 E1.5",
    "G1\tX32 Y9",
    "M114",
    "G4 P20",
    "G1 X40 Y40 E3 F1200",
    "G91",
    "G1 X1 Y1",
    "G90",
    "M400",
    "M109 S210",
    "M12 X1",
    "M115",
    "G1 X50 Y50",
    "M84",
]
_UNNUMBERED = [b"G1 X22 Y7 ; a comment\n", b"G1 X" + b"1" * 120 + b"\n", b"M83\n", b"\n"]
_RESEND = re.compile(rb"(?:Resend: ?|rs N)(\d+)")


def _general(emulator: Emulator) -> Emulator:
    """``emulator`` with every shortcut turned off."""
    emulator.direct = False
    emulator.input.instant = False
    emulator.output.faultless = False
    emulator.firmware._accept_framed = lambda raw, t: False
    return emulator


def _write(emulator: Emulator, rng: random.Random, n: int, text: str, t: float) -> None:
    """Line ``n`` as a host sends it, now and then with the mistakes hosts and wires make:
    a wrong checksum or number, an unnumbered line, the line in two writes."""
    frame = frame_marlin(n, text)
    roll = rng.random()
    if roll < 0.05:
        emulator.host_write(frame.replace(b"*", b"*1", 1), t)
    elif roll < 0.08:
        emulator.host_write(frame_marlin(n + 1, text), t)
    elif roll < 0.11:
        emulator.host_write(rng.choice(_UNNUMBERED), t)
    elif roll < 0.14:
        emulator.host_write(frame[:5], t)
        emulator.host_write(frame[5:], t)
        return
    emulator.host_write(frame, t)


def _run(emulator: Emulator, seed: str, step_s: float, joined: float = 0.0) -> list[object]:
    """Send the job three times over at a fake clock, following resend requests, polling as
    a host does, two lines in one write with probability ``joined``; everything the
    emulator said and did."""
    rng, joins = random.Random(seed), random.Random(seed + " joins")
    texts = {0: "M110 N0"}
    job = iter(_JOB * 3)
    seen: list[object] = []
    n, t = 0, 0.0
    for _ in range(400):
        lines = 2 if joins.random() < joined else 1
        for k in range(n, n + lines):
            if k not in texts:
                texts[k] = next(job, "")
        if not texts[n]:
            break
        if lines == 2 and texts[n + 1]:
            emulator.host_write(frame_marlin(n, texts[n]) + frame_marlin(n + 1, texts[n + 1]), t)
        else:
            lines = 1
            _write(emulator, rng, n, texts[n], t)
        out = emulator.poll(t)
        seen.append((t, out, emulator.next_time()))
        asked = _RESEND.findall(out)
        n = int(asked[-1]) if asked else n + lines
        t += step_s
        if rng.random() < 0.2 and emulator.next_time() < float("inf"):
            t = max(t, emulator.next_time())  # let a waiting command finish
    trace = [dataclasses.astuple(entry) for entry in emulator.trace]
    return [seen, trace, dataclasses.asdict(emulator.counters), emulator.firmware.motion.pos]


_OPTIONS = [
    "baud=0&time_scale=0",
    "baud=0&time_scale=0&dialect=marlin-2.0",
    "baud=0&time_scale=0&dialect=prusa&slots=1",
    "baud=0&time_scale=0&drain=0",
    "baud=0&time_scale=1&accel=1000&heat_tau_s=0.05",
    "baud=0&time_scale=1&planner=2",
    "baud=0&time_scale=0&corrupt=0.05&drop_ok=0.05&garble=0.02&noise=0.02",
    "baud=0&time_scale=0&reset_after=40",
    "baud=0&time_scale=0&disconnect_after=50",
    "baud=0&time_scale=0&dialect=repetier",
    "baud=0&time_scale=0&dialect=smoothieware",
    "baud=0&time_scale=0&ack_on_queue=1",
    "time_scale=0&latency_ms=1",
]


@pytest.mark.parametrize("options", _OPTIONS)
@pytest.mark.parametrize("step_s", [0.0, 0.001])
def test_the_fast_paths_answer_trace_and_count_as_the_general_path(options, step_s):
    url = f"sim://marlin?{options}"
    fast = _run(Emulator(config_from_url(url, 115200)), options, step_s)
    general = _run(_general(Emulator(config_from_url(url, 115200))), options, step_s)
    assert fast == general
    assert len(fast[1]) > 10  # the job ran


@pytest.mark.parametrize("options", [options for options in _OPTIONS if "baud=0" in options])
@pytest.mark.parametrize("step_s", [0.0, 0.001])
def test_lines_written_together_answer_trace_and_count_as_on_the_general_path(options, step_s):
    # the firmware reads lines that arrive together before it runs the first
    url = f"sim://marlin?{options}"
    fast = _run(Emulator(config_from_url(url, 115200)), options, step_s, joined=0.3)
    general = _run(_general(Emulator(config_from_url(url, 115200))), options, step_s, 0.3)
    assert fast == general
    assert len(fast[1]) > 10  # the job ran


def _pairs(emulator: Emulator, seed: int, step_s: float) -> list[object]:
    """Two move lines in each write, the second now and then one the firmware refuses (a
    bad checksum, a wrong number) or no move; everything the emulator said and did."""
    rng = random.Random(seed)
    seen: list[object] = []
    emulator.host_write(frame_marlin(0, "M110 N0"), 0.0)
    n, t = 1, 0.0
    for k in range(150):
        second = f"G1 X{k % 3}.5 Y{k % 4}"
        roll = rng.random()
        if roll < 0.15:
            second = frame_marlin(n + 1, second).replace(b"*", b"*1", 1)
        elif roll < 0.3:
            second = frame_marlin(n + 2, second)
        else:
            second = frame_marlin(n + 1, "M400" if roll < 0.4 else second)
        emulator.host_write(frame_marlin(n, f"G1 X{k % 7} Y{k % 5} F{600 + k}") + second, t)
        out = emulator.poll(t)
        seen.append((t, out, emulator.next_time()))
        asked = _RESEND.findall(out)
        n = int(asked[-1]) if asked else n + 2
        t = max(t + step_s, min(emulator.next_time(), t + 0.01))
    trace = [dataclasses.astuple(entry) for entry in emulator.trace]
    return [seen, trace, dataclasses.asdict(emulator.counters), emulator.firmware.motion.pos]


@pytest.mark.parametrize(
    "options",
    ["baud=0&time_scale=0", "baud=0&time_scale=0.02&planner=3", "baud=0&time_scale=0&slots=1"],
)
@pytest.mark.parametrize("step_s", [0.0, 0.001])
def test_two_moves_in_one_write_answer_as_on_the_general_path(options, step_s):
    # the firmware reads both lines before it runs the first: a refused second line is
    # answered before the first one's ok, and a full planner holds both
    url = f"sim://marlin?{options}"
    fast = _pairs(Emulator(config_from_url(url, 115200)), 3, step_s)
    general = _pairs(_general(Emulator(config_from_url(url, 115200))), 3, step_s)
    assert fast == general
    assert len(fast[1]) > 150  # the job ran


def test_a_send_through_the_fast_paths_runs_the_job_exactly():
    emulator = Emulator(config_from_url("sim://marlin?baud=0&time_scale=0", 115200))
    assert emulator.direct
    emulator.poll(0.0)  # the banner
    frames = [frame_marlin(0, "M110 N0")]
    frames += [frame_marlin(n, f"G1 X{n} Y{2 * n} F600") for n in range(1, 201)]
    for i, frame in enumerate(frames):
        emulator.host_write(frame, 0.001 * i)
    assert emulator.poll(1.0) == b"ok\n" * len(frames)
    assert [(e.n, e.x_mm, e.y_mm, e.t_s) for e in emulator.trace[1:]] == [
        (n, n, 2 * n, 0.001 * n) for n in range(1, 201)
    ]
    motion = emulator.firmware.motion
    assert not motion.blocks and motion.finished == list(range(1, 201))
    assert motion.stopped_at == motion.pos == motion.position_at(1.0) == [200, 400, 0, 0]


_TEXTS = [
    "G1 X1",
    "G1X1",
    "G 1 X1",
    "G1\tX1",
    "g1 x1",
    "G01 X1",
    "G1.5",
    "G38.2 Z-1",
    "M105",
    "T0",
    "T",
    "$H",
    "$ H",
    "X10 Y5",
    "SET_PIN PIN=x",
    "G",
    "M",
    "1 X",
    " G1",
    "\u00a0G1",
    "G\u00a01",
    "G1\u00a0X1",
    "G-1",
    "G+1.0",
    "G1.",
    "G.5",
]


@pytest.mark.parametrize("text", _TEXTS)
def test_command_codes_remembered_by_their_first_word_are_code_of(text):
    assert command_code(text) == code_of(text)
    assert command_code(text + " F100") == code_of(text + " F100")
    assert command_code(text) == code_of(text)  # now perhaps from the memory


def test_command_codes_of_random_texts_are_code_of():
    rng = random.Random(7)
    alphabet = "GMTXYgm$ \t\u00a0_.-+0123456789"
    for _ in range(3000):
        text = "".join(rng.choice(alphabet) for _ in range(rng.randrange(1, 8)))
        assert command_code(text) == code_of(text), text


def test_a_job_line_framed_from_its_text_checksum_is_frame_marlin():
    rng = random.Random(36)
    texts = ["", "G1 X1", "M105", *(f"G1 X{rng.uniform(-99, 99):.3f} F{k}" for k in range(300))]
    texts += ["".join(rng.choice("GMXYZEF0123456789 .-;*\t") for _ in range(rng.randrange(60)))]
    sums = text_checksums(texts)
    assert sums == [marlin_checksum(text.encode("ascii")) for text in texts]
    for n, (text, text_sum) in enumerate(zip(texts, sums, strict=True)):
        number = rng.choice([n, 10 * n + 7, 10**6 + n])
        assert frame_summed(number, text, text_sum) == frame_marlin(number, text)
    assert text_checksums(["G1 X1", "G1 Y\u00b52"]) is None  # not ASCII: framed line by line
