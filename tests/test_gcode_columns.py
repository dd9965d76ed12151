"""The fast path of the pre-flight check and the duration plan (runs of plain moves read
into columns, :mod:`fabkit.gcode.columns`) gives exactly the per-command path's results:
the same JobCheck, the same Estimate (every float equal, sign of zero included) and, for a
refused job, the same message naming the same line. The writers' plan of a file
(:func:`~fabkit.gcode.duration.estimate`, which refuses nothing) is the per-command
plan's too, and so is ``fabkit verify``'s reading of it
(:func:`~fabkit.verify.read_gcode.read_gcode`: every deposited segment, the same
floats)."""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fabkit.errors import FabkitError
from fabkit.gcode.columns import LETTERS, read_columns
from fabkit.gcode.duration import Planner, _passes, _passes_in_order, estimate
from fabkit.gcode.read import Block, GcodeError, commands_from_lines, firmware_reader, read_marlin
from fabkit.link.host.preflight import check_job
from fabkit.machines import load_machine
from fabkit.verify.read_gcode import read_gcode
from fabkit.writers.gcode import GcodeOptions, gcode_bytes
from tests.test_writers_common import baromorph_toolpath, fig1_toolpath, reprap_machine

MARLIN = ["G21", "G90", "G28", "M82", "G92 E0", "G1 F1200"]


def _outcome(lines: list[str], machine, fast: bool):
    """(JobCheck or the refusal's message, Estimate or None, runs taken at once)."""
    planner = Planner(machine)
    runs = []

    def add_run(run) -> None:
        runs.append(len(run))
        planner.add_run(run)

    job = commands_from_lines(lines)
    try:
        result = check_job(job, machine, "job.gcode", planner.add, add_run, fast=fast)
    except FabkitError as exc:
        return str(exc), None, runs
    return result, planner.estimate(), runs


def _same_floats(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal arrays, NaN where NaN and the sign of every zero alike."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return (
        a.shape == b.shape
        and np.array_equal(a, b, equal_nan=True)
        and np.array_equal(np.signbit(a), np.signbit(b))
    )


def _each(text: str, read) -> Block:
    try:
        return read(text)
    except GcodeError:
        return Block(())


def assert_same_estimate(lines: list[str], machine) -> None:
    """:func:`estimate` plans ``lines`` as the per-command planner does."""
    planner, read = Planner(machine), firmware_reader(machine)
    for command in commands_from_lines(lines):
        planner.add(_each(command.text, read))
    slow, fast = planner.estimate(), estimate(commands_from_lines(lines), machine)
    assert fast == slow
    assert _same_floats(fast.end_s, slow.end_s)
    assert _same_floats(fast.positions.xyze, slow.positions.xyze)


PRINTED = ("start", "end", "feed", "volume", "pressure", "temperature", "mix", "ink", "road")


def assert_same_reading(lines: list[str], machine) -> None:
    """:func:`read_gcode` reads ``lines`` alike both ways (or refuses them alike)."""
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "job.gcode"
        path.write_text("\n".join(lines) + "\n")
        outcomes = []
        for fast in (False, True):
            try:
                outcomes.append(read_gcode(path, machine, fast=fast))
            except FabkitError as exc:
                outcomes.append(str(exc))
    slow, fast = outcomes
    if isinstance(slow, str) or isinstance(fast, str):
        assert fast == slow
        return
    for name in PRINTED:
        assert _same_floats(getattr(fast, name), getattr(slow, name)), name
    assert (fast.layers, fast.commands) == (slow.layers, slow.commands)


def assert_same(lines: list[str], machine) -> int:
    """Both paths agree on ``lines``; the number of commands the fast path took at once."""
    assert_same_estimate(lines, machine)
    assert_same_reading(lines, machine)
    slow, slow_plan, _ = _outcome(lines, machine, fast=False)
    fast, fast_plan, runs = _outcome(lines, machine, fast=True)
    assert fast == slow
    if slow_plan is None:
        return sum(runs)
    assert fast_plan == slow_plan
    assert _same_floats(fast_plan.end_s, slow_plan.end_s)
    assert _same_floats(fast_plan.positions.xyze, slow_plan.positions.xyze)
    bounds = [b for span in slow.bounds_mm if span for b in span]
    assert _same_floats([b for s in fast.bounds_mm if s for b in s], bounds)
    return sum(runs)


def _file_lines(toolpath, machine, options: GcodeOptions | None = None) -> list[str]:
    data, _ = gcode_bytes(toolpath(machine), machine, options)
    return data.decode("ascii").splitlines()


# -- fabkit's own files --------------------------------------------------------------------


@pytest.mark.parametrize(
    "name",
    ["marlin_generic", "klipper_generic", "hyrel_pulse", "marlin_diw_pneumatic", "grbl_diw"],
)
@pytest.mark.parametrize("example", [fig1_toolpath, baromorph_toolpath])
def test_fabkits_own_files_plan_and_check_alike(name, example):
    machine = load_machine(name)
    taken = assert_same(_file_lines(example, machine), machine)
    assert (taken == 0) == (name == "grbl_diw")  # GRBL: every command one at a time


@pytest.mark.parametrize("e_mode", ["absolute", "relative"])
def test_both_e_modes_plan_and_check_alike(e_mode):
    machine = load_machine("marlin_generic")
    lines = _file_lines(fig1_toolpath, machine, GcodeOptions(e_mode=e_mode))
    assert assert_same(lines, machine) > 100


def test_a_reprap_profile_plans_and_checks_alike(tmp_path):
    machine = reprap_machine(tmp_path, 1.75)
    assert assert_same(_file_lines(baromorph_toolpath, machine), machine) > 100


# -- written by hand -----------------------------------------------------------------------

RUN = [f"G1 X{10 + k} Y{20 + k % 3}.5 E{k * 0.1:.1f}" for k in range(12)]
CASES = {
    "plain": [*MARLIN, *RUN],
    "G92 and G91 between runs": [
        *MARLIN, *RUN, "G92 X0 Y0 E0", *RUN, "G91", "M83", *RUN[:6], "G90", "M82", *RUN,
    ],
    "arcs, comments, odd spacing": [
        *MARLIN, *RUN[:5], "G2 X20 Y20 I5 J0", "G1  X30 Y30", *RUN, "G1 X40 ; a comment",
        "G1 X41 (and another)", "G1 x42", *RUN, "G1 X10 Y10 E2 Z1", "G1 Z1 X11",
    ],
    "F first, fractions, signs": [
        *MARLIN, "G1 F3000 X+.5 Y1.", "G1 X-0 Y0.000001 F600", "G0 F9000 X1 Y2 Z3", *RUN,
    ],
    "a move outside the envelope": [*MARLIN, *RUN, "G1 X5000 Y10", *RUN],
    "an over-speed feed": [*MARLIN, *RUN[:6], "G1 X100 F60000", *RUN],
    "an over-speed axis": [*MARLIN, *RUN[:6], "G1 Z200 F6000", *RUN],
    "a refused word in a run": [*MARLIN, *RUN[:6], "G1 X10 Q5", *RUN],
    "a letter twice": [*MARLIN, *RUN[:6], "G1 X10 X11", *RUN],
    "F0": [*MARLIN, *RUN[:6], "G1 X10 F0", *RUN],
    "no feed yet": ["G21", "G90", "G28", "M82", "G92 E0", *RUN],
    "absolute E from an unknown E": ["G21", "G90", "G28", "M82", "G1 F600", *RUN],
    "no distance mode": ["G21", "G28", "M83", "G1 F600", *RUN],
    "relative from an unknown position": ["G21", "G91", "M83", "G1 F600", *RUN],
    "M220 and M221": [*MARLIN, "M220 S150", "M221 S90", *RUN, "M220 S400", *RUN],
    "a long line": [*MARLIN, *RUN, "G1 X1." + "0" * 80, *RUN],
    "many digits": [*MARLIN, "G1 X10.1234567890123456 Y1", *RUN, "G1 X0.00000000000001"],
    "G0 and G1 with feeds": [*MARLIN, *(f"G{k % 2} X{k} Y{k} F{600 + k}" for k in range(20))],
}  # fmt: skip


@pytest.mark.parametrize("name", ["marlin_generic", "klipper_generic", "hyrel_pulse"])
@pytest.mark.parametrize("case", list(CASES))
def test_written_jobs_plan_and_check_alike(case, name):
    assert_same(CASES[case], load_machine(name))


DIW = ["G21", "G90", "M42 P4 S0", "M42 P5 S0", "G28", "G1 Z1 F600", "G1 X10 Y10 F1200"]
LINE = [f"G1 X{20 + 2 * k} Y{30 + k % 2}" for k in range(8)]
FASTER = ["G1 X60 Y60 F1800", "G1 X70 Y60", "G1 X70 Y70", "G1 X60 Y70"]  # 30 mm/s
VALVES = {
    "valves": [
        *DIW, "M42 P4 S255", *LINE, "M42 P4 S0", "G0 Z2 F600", "G0 X10 Y10 F2400", "G0 Z1 F600",
        "M42 P5 S255", *LINE, "M42 P5 S0", *FASTER,
    ],
    "faster than printing while the first ink flows": [*DIW, "M42 P4 S255", *LINE, *FASTER],
    "faster than printing while the second ink flows": [*DIW, "M42 P5 S255", *LINE, *FASTER],
    "one ink off, the other still on": [
        *DIW, "M42 P4 S255", *LINE, "M42 P5 S255", "M42 P4 S0", *LINE, *FASTER,
    ],
    "both off: travel": [*DIW, "M42 P4 S255", "M42 P5 S255", *LINE, "M42 P5 S0", "M42 P4 S0",
                         *FASTER],
    "a pin the profile does not write": [*DIW, *LINE, "M42 P6 S255", *LINE],
    "a pin write spaced otherwise": [*DIW, *LINE, "M42  P4 S255", *LINE, *FASTER],
}  # fmt: skip


@pytest.mark.parametrize("case", list(VALVES))
def test_the_profiles_pin_writes_switch_the_flow_alike(case):
    assert_same(VALVES[case], load_machine("marlin_diw_pneumatic"))


def test_pin_writes_join_a_run():
    machine = load_machine("marlin_diw_pneumatic")
    assert assert_same(VALVES["valves"], machine) == len(VALVES["valves"]) - 5  # G21 ... G28
    message, _, _ = _outcome(
        VALVES["faster than printing while the first ink flows"], machine, True
    )
    assert message.startswith(f"job.gcode:{len(DIW) + 1 + len(LINE) + 1}: feed 30.000 mm/s")


def test_runs_are_taken_at_once():
    assert (
        assert_same(CASES["G92 and G91 between runs"], load_machine("marlin_generic")) == 43
    )  # G1 F1200 too


def test_a_refusal_in_a_run_names_its_line():
    lines = [*MARLIN, *RUN, "G1 X5000 Y10", *RUN]
    slow, _, _ = _outcome(lines, load_machine("marlin_generic"), fast=False)
    assert slow.startswith(f"job.gcode:{len(MARLIN) + len(RUN) + 1}: X=5000.000 mm is outside")


# -- the reader against read_marlin --------------------------------------------------------


@st.composite
def command_texts(draw) -> str:
    """Texts near a plain move: codes, letters, blanks, numbers of every form."""
    code = draw(st.sampled_from(["G0", "G1", "G1", "G01", "G10", "g1", "M104", "G2"]))
    words = []
    for _ in range(draw(st.integers(0, 6))):
        letter = draw(st.sampled_from("XYZEFXYZEQx"))
        sign = draw(st.sampled_from(["", "", "-", "+", "--"]))
        digits = draw(st.text("0123456789.", max_size=19))
        blank = draw(st.sampled_from([" ", " ", " ", "", "  "]))
        words.append(blank + letter + sign + digits)
    return code + "".join(words)


@pytest.mark.slow
@settings(max_examples=400, deadline=None)
@given(texts=st.lists(command_texts(), min_size=1, max_size=12))
def test_a_plain_move_reads_as_the_marlin_reader_reads_it(texts):
    columns = read_columns(texts, 0, 80, "01", {})
    for k, text in enumerate(texts):
        if not columns.plain[k]:
            continue
        block = read_marlin(text, upper=False)
        assert block.codes == (("G0",) if columns.g0[k] else ("G1",)) and not block.flags
        given = {LETTERS[i]: columns.values[k, i] for i in range(5) if columns.given[k, i]}
        assert given == block.values
        for letter, value in block.values.items():
            assert math.copysign(1, value) == math.copysign(1, given[letter])


@pytest.mark.parametrize(
    ("texts", "plain"),
    [
        (["G1 X."], [False]),
        (["G1 X.", "G1 Y-."], [False, False]),
        (["G1 X+", "G1 X1"], [False, True]),
    ],
)
def test_numbers_without_a_digit_are_not_plain(texts, plain):
    assert read_columns(texts, 0, 80, "01", {}).plain.tolist() == plain


def test_named_commands_count_as_plain():
    columns = read_columns(["G1 X1", "M42 P4 S255", "M42 P4  S255", "G1 Y2"], 0, 80, "01",
                           {"M42 P4 S255": 3, "G1 Y2": 5})  # fmt: skip
    assert columns.plain.tolist() == [True, True, False, True]
    assert columns.other.tolist() == [-1, 3, -1, -1]  # a plain move stays one
    assert not columns.given[1].any() and not columns.g0.any()


# -- random jobs through both paths --------------------------------------------------------


BETWEEN = [
    "G90", "G91", "M82", "M83", "G92 E0", "G92 X10 Y10", "M220 S80", "M221 S120", "G4 P10",
    "G28", "M400", "G1 X1 Q1", "M104 S200", "M106 S255", "M107", "M82", "M83", "M400",
]  # fmt: skip
"""Non-plain commands between the runs of random jobs."""


@st.composite
def number(draw, low: float, high: float) -> str:
    """A number in [low, high] as a G-code writer or a person might write it."""
    value = draw(st.floats(low, high))
    text = f"{value:.{draw(st.integers(0, 5))}f}"
    form = draw(st.integers(0, 9))
    if form == 0 and text.startswith("0."):
        return text[1:]  # .5
    if form == 1 and not text.startswith("-"):
        return "+" + text
    return text


@st.composite
def random_jobs(draw, pin_writes: tuple[str, ...] = ()) -> list[str]:
    """Plain moves, mostly inside the envelope and the limits, in both distance modes,
    with non-plain commands (and ``pin_writes``) and now and then a refused value between
    them."""
    absolute = draw(st.booleans())
    lines = [*MARLIN, "G1 X100 Y100 Z1", *([] if absolute else ["G91", "M83"])]
    e = 0.0  # the absolute E so far
    for _ in range(draw(st.integers(1, 60))):
        if pin_writes and draw(st.integers(0, 5)) == 0:
            lines.append(draw(st.sampled_from(pin_writes)))
            continue
        if draw(st.integers(0, 11)) == 0:
            lines.append(draw(st.sampled_from(BETWEEN)))
            absolute = {"G90": True, "G91": False}.get(lines[-1], absolute)
            e = 0.0 if lines[-1] == "G92 E0" else e
            continue
        e += draw(st.floats(-0.1, 0.5))
        ranges = {"X": (5, 200), "Y": (5, 200), "Z": (0.2, 3), "E": (e, e), "F": (300, 4800)}
        if not absolute:
            ranges |= {"X": (-5, 5), "Y": (-5, 5), "Z": (-0.05, 0.05), "E": (-0.1, 0.5)}
        if draw(st.integers(0, 40)) == 0:  # a value the check may refuse
            ranges[draw(st.sampled_from("XYZEF"))] = (-1000, 100000)
        letters = draw(st.lists(st.sampled_from("XYXYXYEF"), unique=True, max_size=4))
        if draw(st.integers(0, 15)) == 0:
            letters += ["Z"] if "X" in letters else ["X", "Z"]  # Z alone: too fast for Z
        words = [f"{k}{draw(number(*ranges[k]))}" for k in letters]
        lines.append(" ".join([draw(st.sampled_from(["G0", "G1", "G1"])), *words]))
    return lines


@pytest.mark.slow
@pytest.mark.parametrize(
    "name", ["marlin_generic", "klipper_generic", "hyrel_pulse", "marlin_diw_pneumatic"]
)
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_random_jobs_plan_and_check_alike(name, data):
    """Random jobs (60 a machine here, the suite's time; 6,000 in all were run when the
    fast path was written) check and plan alike on both paths."""
    valves = ("M42 P4 S255", "M42 P4 S0", "M42 P5 S255", "M42 P5 S0", "M42 P4  S255")
    lines = data.draw(random_jobs(valves if name == "marlin_diw_pneumatic" else ()))
    assert_same(lines, load_machine(name))


# -- the planner's passes ------------------------------------------------------------------


@settings(max_examples=300, deadline=None)
@given(
    moves=st.lists(
        st.tuples(
            st.floats(1e-4, 50),  # length, mm
            st.sampled_from([math.inf, 10.0, 500.0, 3000.0]),  # acceleration, mm/s^2
            st.floats(0, 300),  # the junction's highest entry speed, mm/s
            st.integers(0, 9),  # 0: the planner emptied before this move
        ),
        min_size=1,
        max_size=300,
    )
)
def test_the_passes_in_array_sweeps_are_the_passes_in_order(moves):
    length, accel, max_entry, stop = (np.array(column) for column in zip(*moves, strict=True))
    first = np.r_[True, stop[1:] == 0]
    max_entry[first] = 0.0
    swept = _passes(length, accel, max_entry, first)
    assert _same_floats(swept, _passes_in_order(length, accel, max_entry, first))


def test_a_long_ramp_is_passed_in_order_alike():
    length, accel = np.full(2000, 0.01), np.full(2000, 100.0)  # 2000 moves, each limited
    max_entry = np.r_[0.0, np.full(1999, 200.0)]
    first = np.r_[True, np.zeros(1999, bool)]
    swept = _passes(length, accel, max_entry, first)
    assert _same_floats(swept, _passes_in_order(length, accel, max_entry, first))
