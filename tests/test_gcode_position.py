"""The one position interpreter (:mod:`fabkit.gcode.position`) against the emulator.

Random jobs of absolute and relative moves, G92 shifts, homing and E in both modes are
streamed to the emulated machine (``sim://``, written apart from the interpreter on
purpose: it is the reference) and walked by the interpreter, as the duration estimate
walks them; after every command the two agree on X, Y, Z and E. The Marlin-like jobs are
read with each Marlin-like flavour's rules (Marlin, Klipper, RepRapFirmware, Hyrel),
keeping to the E modes where those firmwares agree (under G91, E is relative: M83); how
they differ elsewhere is tested from their sources in ``tests/test_gcode_modes.py``.
"""

from __future__ import annotations

import dataclasses

import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from fabkit.errors import FabkitError
from fabkit.gcode.duration import estimate
from fabkit.gcode.position import Position
from fabkit.gcode.read import commands_from_lines
from fabkit.link.host.preflight import check_job
from fabkit.machines import load_machine
from tests.test_link_support import quick, run_sim

MARLIN_LIKE = ("marlin", "klipper", "reprap", "hyrel")


@st.composite
def jobs(draw, grbl: bool) -> list[str]:
    """Moves around the middle of the bed, mode switches, G92 and (Marlin-like) E."""
    start = ["G1 Z5 F240", "G1 X100 Y100 F3000", "G1 F240"]
    if grbl:
        lines = ["G21", "G90", "G94", *start]
    else:
        lines = ["G21", "G90", "M82", "G28", "G92 E0", *start]
    absolute = True
    for _ in range(draw(st.integers(1, 12))):
        kind = draw(st.sampled_from(["mode", "g92", "move", "move", "move"]))
        if kind == "mode":
            absolute = not absolute
            lines.append("G90" if absolute else "G91")
            if not grbl:  # under G91 every Marlin-like firmware reads E relative with M83
                lines.append("M83" if not absolute or draw(st.booleans()) else "M82")
        elif kind == "g92":
            axes = draw(st.lists(st.sampled_from("XY" if grbl else "XYE"), min_size=1, unique=True))
            lines.append("G92 " + " ".join(f"{a}{draw(st.integers(-20, 20))}" for a in axes))
        else:
            words = []
            for axis in draw(st.lists(st.sampled_from("XYZ"), min_size=1, unique=True)):
                low, high = {(True, "Z"): (1, 20), (False, "Z"): (-1, 2)}.get(
                    (absolute, axis), (-20, 20) if absolute else (-5, 5)
                )
                words.append(f"{axis}{draw(st.integers(low, high))}")
            if not grbl and draw(st.booleans()):
                words.append(f"E{draw(st.integers(0, 40)) / 10:g}")
            lines.append(f"G1 {' '.join(words)}")
    return lines


def _emulated(url: str, machine: str, lines: list[str]):
    """The emulator's position after every command of ``lines`` (X, Y, Z, E), or None
    when the pre-flight check refuses the job (a move off the bed)."""
    job = commands_from_lines(lines)
    try:
        check_job(job, load_machine(machine))
    except FabkitError:
        return None
    _, emulator = run_sim(url, job, machine, options=quick())
    trace = iter(emulator.trace)  # the job's commands, among the link's own queries
    ran = [next(e for e in trace if e.command == command.text) for command in job]
    return job, [(e.x_mm, e.y_mm, e.z_mm, e.e_mm) for e in ran]


def _agree(walked, emulated, axes: int) -> None:
    for k, (mine, theirs) in enumerate(zip(walked, emulated, strict=True)):
        for axis in range(axes):
            if mine[axis] is not None:  # the interpreter knows it: the machine agrees
                assert mine[axis] == pytest.approx(theirs[axis], abs=1e-6), (k, axis)


@pytest.mark.slow
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(lines=jobs(grbl=False))
def test_every_marlin_like_flavour_walks_where_the_emulated_marlin_goes(lines):
    found = _emulated("sim://marlin?baud=0&time_scale=0", "marlin_generic", lines)
    if found is None:
        event("refused")
        return
    job, emulated = found
    for flavour in MARLIN_LIKE:
        machine = dataclasses.replace(load_machine("marlin_generic"), flavour=flavour)
        walked = estimate(job, machine).positions
        assert all(p is not None for p in walked[-1])  # homed, G92 E0: all known
        _agree(walked, emulated, 4)


@pytest.mark.slow
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(lines=jobs(grbl=True))
def test_grbl_walks_where_the_emulated_grbl_goes(lines):
    found = _emulated("sim://grbl?baud=0&time_scale=0", "grbl_diw", lines)
    if found is None:
        event("refused")
        return
    job, emulated = found
    _agree(estimate(job, load_machine("grbl_diw")).positions, emulated, 3)


def test_g92_shifts_the_machine_frame_and_g28_clears_it():
    position = Position.start("marlin", e_mm=0.0)
    position.apply("G28", {})
    position.apply("G92", {"X": 10.0, "E": 5.0})  # the head stays at machine X 0
    move = position.move({"X": 15.0, "E": 6.0})
    assert move.machine_end[0] == pytest.approx(5.0) and move.deltas()[3] == pytest.approx(1.0)
    position.apply("G28", {}, frozenset("X"))  # G28 X: X homed, its shift cleared
    assert position.machine()[0] == 0.0 and position.logical[0] == 0.0
    unknown = Position.start("marlin")
    unknown.apply("G91", {})
    assert unknown.move({"X": 1.0}).end[0] is None  # relative from an unknown point
