"""Property tests of the firmware readers and the pre-flight check (hypothesis).

* GRBL: blanks and letter case anywhere inside a line change nothing: the reader's words
  equal a plain reading of the line with its blanks removed (and the emulator's GRBL
  line filter gives that same line).
* Marlin: a line the reader accepts reads as the independent parser ``gcodeparser``
  reads it; a blank inside a number is refused.
* Arcs, both forms: the check accepts an arc exactly when every point of it, sampled
  from an independent construction (the centre from the R-sign rule of the G-code
  standard: the short way for R > 0, the long way for R < 0), lies inside the envelope.
* Whole jobs: any job the check accepts keeps every position the built-in emulator
  reaches inside the check's bounds, which lie inside the envelope.
"""

from __future__ import annotations

import math
import re

import pytest
from gcodeparser import parse_gcode_lines
from hypothesis import HealthCheck, assume, event, given, settings
from hypothesis import strategies as st

from fabkit.errors import FabkitError
from fabkit.gcode.read import GcodeError, commands_from_lines, read_grbl, read_marlin
from fabkit.link.arcs import NEAR_FULL
from fabkit.link.emulator.grbl import grbl_clean
from fabkit.link.host.preflight import check_job
from fabkit.machines import load_machine
from tests.test_link_support import quick, run_sim

SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@st.composite
def numbers(draw, max_int: int = 4, max_frac: int = 3) -> str:
    """A G-code number as text: sign, 1-4 digits, optional fraction of 0-3 digits."""
    sign = draw(st.sampled_from(["", "-", "+"]))
    whole = draw(st.text("0123456789", min_size=1, max_size=max_int))
    frac = draw(st.none() | st.text("0123456789", min_size=0, max_size=max_frac))
    return sign + whole + ("" if frac is None else "." + frac)


@st.composite
def grbl_lines(draw) -> str:
    """A canonical GRBL block (no blanks): command words and distinct value words."""
    codes = draw(st.lists(st.sampled_from(["G0", "G1", "G90", "M8", "G21"]), max_size=1))
    letters = draw(st.lists(st.sampled_from("XYZFIJKRPST"), unique=True, max_size=6))
    values = []
    for letter in letters:  # GRBL refuses negative F, P, S, T and T above 255
        number = draw(numbers(max_int=2 if letter == "T" else 4))
        values.append(letter + (number.lstrip("+-") if letter in "FPST" else number))
    return "".join(codes + values)


@st.composite
def spaced(draw, line: str) -> str:
    """``line`` with blanks at random places and letters in random case."""
    out = []
    for char in line:
        out.append(draw(st.sampled_from(["", " ", "  ", "\t"])))
        out.append(char.lower() if char.isalpha() and draw(st.booleans()) else char)
    return "".join(out) + draw(st.sampled_from(["", " "]))


def plain_reading(line: str) -> tuple[list[str], dict[str, float]]:
    """The words of a blank-free block, read with a regular expression."""
    codes, values = [], {}
    for letter, number in re.findall(r"([A-Z])([-+]?[0-9.]+)", line):
        if letter in "GM":
            codes.append(f"{letter}{int(float(number))}")
        else:
            values[letter] = float(number)
    return codes, values


@pytest.mark.slow
@SETTINGS
@given(st.data())
def test_grbl_reads_a_line_as_if_its_blanks_were_not_there(data):
    line = data.draw(grbl_lines())
    text = data.draw(spaced(line)).strip()
    assume(text)
    block = read_grbl(text)
    codes, values = plain_reading(line)
    assert list(block.codes) == codes
    assert dict(block.values) == values
    assert grbl_clean(text.encode())[0] == line  # the emulator's filter agrees


@st.composite
def marlin_lines(draw) -> tuple[str, dict[str, float]]:
    """A Marlin command with distinct words, blanks between them (and between a letter and
    its number); the values as written."""
    code = draw(st.sampled_from(["G0", "G1", "G92", "M104", "M220"]))
    letters = draw(st.lists(st.sampled_from("XYZEFS"), unique=True, max_size=5))
    text, values = code, {}
    for letter in letters:  # gcodeparser reads neither "X -1" nor "X1." as Marlin does
        number = draw(numbers()).rstrip(".")
        blank = "" if number[0] in "+-" else draw(st.sampled_from(["", " "]))
        gap = draw(st.sampled_from([" ", "  "])) + letter + blank
        text += gap + number
        values[letter] = float(number)
    return text, values


@pytest.mark.slow
@SETTINGS
@given(marlin_lines())
def test_marlin_reads_a_line_as_gcodeparser_does(case):
    text, values = case
    block = read_marlin(text, upper=False)
    (parsed,) = list(parse_gcode_lines(text))
    assert dict(block.values) == values
    assert {k: float(v) for k, v in parsed.params.items()} == values


@pytest.mark.slow
@SETTINGS
@given(marlin_lines(), st.data())
def test_a_blank_inside_a_marlin_number_is_refused(case, data):
    text, _ = case
    after_code = text.index(" ") if " " in text else len(text)
    spots = [m.start() for m in re.finditer(r"(?<=\d)(?=\d)", text) if m.start() > after_code]
    assume(spots)
    spot = data.draw(st.sampled_from(spots))
    with pytest.raises(GcodeError, match="stray number"):
        read_marlin(text[:spot] + " " + text[spot:], upper=False)


# -- arcs ----------------------------------------------------------------------------------

SAMPLES = 4000
MARGIN_MM = 0.01


def _sweep(start: float, end: float, clockwise: bool) -> float:
    """Signed sweep from angle ``start`` to ``end`` in the arc's direction (a full turn if
    they coincide)."""
    if clockwise:
        return -((start - end) % (2 * math.pi) or 2 * math.pi)
    return (end - start) % (2 * math.pi) or 2 * math.pi


def standard_centre(s, e, r: float, clockwise: bool):
    """The centre of an R arc as the G-code standard defines it: of the two circles of
    radius |r| through s and e, the one whose arc in the given direction is at most half a
    turn for r > 0 and more than half a turn for r < 0."""
    mx, my = (s[0] + e[0]) / 2, (s[1] + e[1]) / 2
    dx, dy = e[0] - s[0], e[1] - s[1]
    chord = math.hypot(dx, dy)
    h = math.sqrt(max(r * r - chord * chord / 4, 0.0))
    for sign in (1, -1):
        c = (mx - sign * dy / chord * h, my + sign * dx / chord * h)
        a0, a1 = math.atan2(s[1] - c[1], s[0] - c[0]), math.atan2(e[1] - c[1], e[0] - c[0])
        if (abs(_sweep(a0, a1, clockwise)) <= math.pi) == (r > 0):
            return c
    raise AssertionError("no centre")


def arc_points(s, c, e, clockwise: bool, turns: int = 0):
    """Points along the arc; a sweep within NEAR_FULL of none or a whole turn is the full
    circle, as the check reads it (single-precision firmware may land on either side)."""
    radius = math.hypot(s[0] - c[0], s[1] - c[1])
    a0 = math.atan2(s[1] - c[1], s[0] - c[0])
    sweep = _sweep(a0, math.atan2(e[1] - c[1], e[0] - c[0]), clockwise)
    if not NEAR_FULL < abs(sweep) < 2 * math.pi - NEAR_FULL:
        sweep = math.copysign(2 * math.pi, sweep)
    sweep += math.copysign(2 * math.pi * turns, sweep)
    angles = [a0 + sweep * k / SAMPLES for k in range(SAMPLES + 1)]
    return [(c[0] + radius * math.cos(a), c[1] + radius * math.sin(a)) for a in angles]


@st.composite
def arcs(draw):
    """A start inside the bed, a direction, and either a centre offset with an end on the
    circle or a signed radius with any end point (3 decimals, as G-code carries them)."""
    coordinate = st.floats(5, 215).map(lambda v: round(v, 3))
    s = (draw(coordinate), draw(coordinate))
    clockwise = draw(st.booleans())
    if draw(st.booleans()):
        offset = (draw(st.floats(-150, 150)), draw(st.floats(-150, 150)))
        offset = (round(offset[0], 3), round(offset[1], 3))
        radius = math.hypot(*offset)
        assume(radius > 0.5)
        c = (s[0] + offset[0], s[1] + offset[1])
        angle = draw(st.floats(-math.pi, math.pi))
        e = (round(c[0] + radius * math.cos(angle), 3), round(c[1] + radius * math.sin(angle), 3))
        words = f"X{e[0]:.3f} Y{e[1]:.3f} I{offset[0]:.3f} J{offset[1]:.3f}"
        return s, e, c, clockwise, words
    e = (draw(coordinate), draw(coordinate))
    chord = math.hypot(e[0] - s[0], e[1] - s[1])
    assume(chord > 0.5)
    r = round(draw(st.floats(chord / 2 + 0.01, 400)), 3) * draw(st.sampled_from([1, -1]))
    words = f"X{e[0]:.3f} Y{e[1]:.3f} R{r:.3f}"
    return s, e, standard_centre(s, e, r, clockwise), clockwise, words


@pytest.mark.slow
@pytest.mark.parametrize(
    ("machine", "preamble"),
    [("grbl_diw", ["G21", "G90", "G94", "G17"]), ("marlin_generic", ["G21", "G90", "G28"])],
)
@SETTINGS
@given(case=arcs())
def test_an_arc_is_accepted_exactly_when_all_of_it_is_inside(machine, preamble, case):
    s, e, c, clockwise, words = case
    profile = load_machine(machine)
    (xlo, xhi), (ylo, yhi) = profile.envelope.x_mm, profile.envelope.y_mm
    assume(xlo + 1 < s[0] < xhi - 1 and ylo + 1 < s[1] < yhi - 1)
    points = arc_points(s, c, e, clockwise)
    gaps = [min(x - xlo, xhi - x, y - ylo, yhi - y) for x, y in points]
    assume(abs(min(gaps)) > MARGIN_MM)  # clearly inside, or clearly out somewhere
    lines = [*preamble, f"G1 X{s[0]:.3f} Y{s[1]:.3f} F600", f"G{2 if clockwise else 3} {words}"]
    try:
        check_job(commands_from_lines(lines), profile)
        accepted = True
    except FabkitError as exc:
        assert "is outside the envelope" in str(exc), str(exc)
        accepted = False
    event("accepted" if accepted else "refused")
    assert accepted == all(g > 0 for g in gaps)


# -- whole jobs on the emulator ------------------------------------------------------------


@st.composite
def jobs(draw, grbl: bool):
    """A job of absolute and relative moves; GRBL numbers get blanks inside them."""
    coordinate = st.floats(-20, 320).map(lambda v: round(v, 2))
    step = st.floats(-60, 60).map(lambda v: round(v, 2))
    x, y, z = draw(st.floats(0, 220)), draw(st.floats(0, 220)), draw(st.floats(0, 60))
    preamble = ["G21", "G90", "G94"] if grbl else ["G21", "G90", "G28", "G1 F240"]
    lines = [*preamble, f"G0 X{x:.2f} Y{y:.2f} Z{z:.2f}"]
    absolute = True
    for _ in range(draw(st.integers(1, 8))):
        if draw(st.integers(0, 4)) == 0:
            absolute = not absolute
            lines.append("G90" if absolute else "G91")
            continue
        axes = draw(st.lists(st.sampled_from("XYZ"), unique=True, min_size=1))
        words = []
        for axis in axes:
            value = draw(coordinate if absolute else step)
            if axis == "Z":
                value = round(value / 4, 2)
            number = f"{value:.2f}"
            if grbl and len(number) > 2 and draw(st.booleans()):
                cut = draw(st.integers(1, len(number) - 1))
                number = number[:cut] + " " + number[cut:]
            words.append(axis + number)
        feed = f" F{draw(st.integers(60, 3000))}" if draw(st.booleans()) else ""
        lines.append(f"G{draw(st.sampled_from([0, 1]))} {' '.join(words)}{feed}")
    return lines


@pytest.mark.slow
@pytest.mark.parametrize(
    ("machine", "url"),
    [
        ("grbl_diw", "sim://grbl?baud=0&time_scale=0"),
        ("marlin_generic", "sim://marlin?baud=0&time_scale=0"),
    ],
)
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_an_accepted_job_keeps_the_emulated_machine_inside(machine, url, data):
    lines = data.draw(jobs(machine == "grbl_diw"))
    job = commands_from_lines(lines)
    profile = load_machine(machine)
    try:
        result = check_job(job, profile)
    except FabkitError:
        event("refused")
        return
    event("accepted")
    _, emulator = run_sim(url, job, machine, options=quick())
    moves = [e for e in emulator.trace if re.search(r"[XYZ]", e.command)]
    assert len(moves) == result.moves > 0
    for entry in moves:
        for k, value in enumerate((entry.x_mm, entry.y_mm, entry.z_mm)):
            low, high = result.bounds_mm[k]
            lo, hi = profile.envelope.axis("xyz"[k])
            assert lo - 1e-6 <= low - 1e-6 <= value <= high + 1e-6 <= hi + 1e-6
