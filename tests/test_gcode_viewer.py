"""G-code as slicer viewers read it: layer, type, height and width comments, and nominal E.

The file is read back with the independent parser ``gcodeparser`` the way Cura's
``FlavorParser`` and PrusaSlicer's ``GCodeProcessor`` read it: ``;LAYER:n`` starts layer
n, ``;TYPE:`` names the role of what follows, ``;HEIGHT:`` and ``;WIDTH:`` (mm) size the
roads, and a move is an extrusion when its E grows. A viewer's picture of the sheet (the
roads' length x width x height) must be the toolpath's roads; on a valve
machine with nominal E, E must mark exactly the moves the valve prints, at the width of
the road, and the machine must do the same thing as without it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
import pytest

from fabkit.errors import FabkitError
from fabkit.gcode.read import commands_from_lines
from fabkit.link.host.preflight import check_job
from fabkit.machines import load_machine
from fabkit.toolpath import PRINT, Layer, Move, Toolpath
from fabkit.writers.gcode import GcodeOptions, gcode_bytes
from tests.test_writers_common import fig1_toolpath, model_volume, read_lines

MACHINES = ["marlin_generic", "klipper_generic", "hyrel_pulse", "grbl_diw", "marlin_diw_pneumatic"]
FILAMENT_MM2 = math.pi / 4 * 1.75**2
"""Cross-section of the 1.75 mm filament viewers assume, mm^2."""


@dataclass
class Viewer:
    """What a viewer takes from the file: per extrusion, its layer, length (mm), the
    ``;WIDTH:`` and ``;HEIGHT:`` in force (mm), its E increment and whether the valve
    (flow-on G-code) was open; the ``;TYPE:`` names and layer numbers met."""

    layer: list[int] = field(default_factory=list)
    length: list[float] = field(default_factory=list)
    width: list[float] = field(default_factory=list)
    height: list[float] = field(default_factory=list)
    e: list[float] = field(default_factory=list)
    valve: list[bool] = field(default_factory=list)
    types: list[str] = field(default_factory=list)
    layers: list[int] = field(default_factory=list)
    travel_e: float = 0.0


def view(text: str, flow_on: str = "", flow_off: str = "") -> Viewer:
    """Read ``text`` as a slicer viewer does (module docstring)."""
    seen = Viewer()
    width = height = math.nan
    for line in read_lines(text, flow_on, flow_off):
        if line.comment is not None:
            key, _, value = line.comment.partition(":")
            if key == "LAYER" and value.isdigit():
                seen.layers.append(int(value))
            elif key == "TYPE":
                seen.types.append(value)
            elif key == "WIDTH":
                width = float(value)
            elif key == "HEIGHT":
                height = float(value)
            continue
        length = float(np.linalg.norm(line.step[:2]))
        if line.e_step > 0 and length > 0 or line.flowing and length > 0:
            seen.layer.append(seen.layers[-1] if seen.layers else -1)
            seen.length.append(length)
            seen.width.append(width)
            seen.height.append(height)
            seen.e.append(line.e_step)
            seen.valve.append(line.flowing)
        elif line.e_step > 0:
            seen.travel_e += line.e_step
    return seen


def _write(machine, toolpath, **options) -> str:
    text, _ = gcode_bytes(toolpath, machine, GcodeOptions(**options))
    return text.decode("ascii")


@pytest.mark.parametrize("name", MACHINES)
def test_viewers_see_every_layer_as_fill_at_its_height_and_road_width(name):
    machine = load_machine(name)
    toolpath = fig1_toolpath(machine)
    gcode = machine.gcode
    seen = view(_write(machine, toolpath), gcode.flow_on_gcode.strip(), gcode.flow_off_gcode)
    assert seen.layers == list(range(len(toolpath.layers)))
    assert set(seen.types) == {"FILL"} and len(seen.types) == len(toolpath.layers)
    heights = np.array([layer.height_mm for layer in toolpath.layers])
    assert np.array_equal(seen.height, heights[seen.layer])
    assert np.isfinite(seen.width).all()
    laid = np.sum(np.array(seen.length) * seen.width * np.array(seen.height))
    assert laid == pytest.approx(_roads_volume(toolpath), rel=5e-3)


def _roads_volume(toolpath: Toolpath) -> float:
    """Length x road width x layer height over the print segments (the flow multiplier
    left out: a viewer draws the road, the volume a flow channel changes is in E), mm^3."""
    total = 0.0
    for layer in toolpath.layers:
        for move in layer.prints:
            lengths = np.linalg.norm(np.diff(move.xyz[:, :2], axis=0), axis=1)
            total += float((lengths * move.width[1:]).sum()) * layer.height_mm
    return total


def test_width_is_written_where_the_road_width_changes():
    machine = load_machine("marlin_generic")
    moves = tuple(
        Move.make(PRINT, [[0, 2 * k], [10, 2 * k]], 0.3, width, 10.0)
        for k, width in enumerate((0.4, 0.4, 0.55, 0.4004))
    )
    text = _write(machine, Toolpath((Layer(0.3, 0.3, moves),)))
    widths = [line for line in text.splitlines() if line.startswith(";WIDTH:")]
    assert widths == [";WIDTH:0.4", ";WIDTH:0.55", ";WIDTH:0.4"]
    assert view(text).width == [0.4, 0.4, 0.55, 0.4]


def test_nominal_e_marks_exactly_the_roads_the_valve_prints():
    machine = load_machine("marlin_diw_pneumatic")
    toolpath = fig1_toolpath(machine)
    on, off = machine.gcode.flow_on_gcode.strip(), machine.gcode.flow_off_gcode.strip()
    plain = _write(machine, toolpath)
    nominal = _write(machine, toolpath, nominal_e=True)
    assert not _has_e(plain) and "M83" not in plain
    seen = view(nominal, on, off)
    e, valve = np.array(seen.e), np.array(seen.valve)
    assert valve.all() and (e > 0).all() and seen.travel_e == 0  # E only where the valve prints
    # the width a viewer computes from E (1.75 mm filament) is the road's
    from_e = e * FILAMENT_MM2 / (np.array(seen.length) * seen.height)
    assert np.average(from_e, weights=seen.length) == pytest.approx(
        machine.process.road_width_mm, rel=2e-3
    )
    assert np.sum(e) * FILAMENT_MM2 == pytest.approx(model_volume(toolpath), rel=5e-3)
    # the machine does the same: only E words, the E mode line and comments differ
    assert _machine_lines(nominal) == _machine_lines(plain)


def _has_e(text: str) -> bool:
    """Any E word outside comments."""
    return any(" E" in line.split(";")[0] for line in text.splitlines())


def _machine_lines(text: str) -> list[str]:
    bare = (line.split(";")[0].strip() for line in text.splitlines())
    return [
        " ".join(w for w in line.split() if w[0] != "E") for line in bare if line not in ("", "M83")
    ]


@pytest.mark.parametrize("mode", ["absolute", "relative"])
def test_nominal_e_passes_the_links_check_in_both_e_modes(mode):
    machine = load_machine("marlin_diw_pneumatic")
    text = _write(machine, fig1_toolpath(machine, layers=1), nominal_e=True, e_mode=mode)
    assert ("M82" in text) == (mode == "absolute") and ("M83" in text) == (mode == "relative")
    result = check_job(commands_from_lines(text.splitlines()), machine, source="job.gcode")
    assert result.moves > 100


def test_nominal_e_comes_from_the_profile_too():
    machine = load_machine("marlin_diw_pneumatic")
    toolpath = fig1_toolpath(machine, layers=1)
    keyed = replace(machine, tool=replace(machine.tool, nominal_e=True))
    assert _write(keyed, toolpath) == _write(machine, toolpath, nominal_e=True)
    assert not _has_e(_write(keyed, toolpath, nominal_e=False))


@pytest.mark.parametrize(
    ("name", "phrase"),
    [
        ("grbl_diw", "nominal E needs flavour marlin"),
        ("marlin_generic", "nominal E is for machines without an E axis"),
    ],
)
def test_nominal_e_is_refused_where_it_is_not_safe(name, phrase):
    machine = load_machine(name)
    with pytest.raises(FabkitError, match=phrase):
        gcode_bytes(fig1_toolpath(machine, layers=1), machine, GcodeOptions(nominal_e=True))


def test_nominal_e_rate_stays_within_the_e_limit():
    """A firmware with a working E axis would slow a road whose E rate is above its E
    limit (and so lay more material): nominal E is held to [limits] e_mm_s like real E."""
    machine = load_machine("marlin_diw_pneumatic")
    slow = replace(machine, limits=replace(machine.limits, e_mm_s=0.05))
    move = Move.make(PRINT, [[0, 0], [10, 0]], 0.3, 0.41, 8.0)
    toolpath = Toolpath((Layer(0.3, 0.3, (move,)),))
    gcode_bytes(toolpath, slow)  # without nominal E the limit does not apply
    with pytest.raises(FabkitError, match="E rate"):
        gcode_bytes(toolpath, slow, GcodeOptions(nominal_e=True))


def test_the_emulated_marlin_runs_nominal_e_on_the_valve_machine(tmp_path, run_cli):
    machine = load_machine("marlin_diw_pneumatic")
    path = tmp_path / "job.gcode"
    path.write_text(_write(machine, fig1_toolpath(machine, layers=1), nominal_e=True))
    code, out, err = run_cli(
        "send", path, "--port", "sim://marlin?baud=0&time_scale=0", "--machine", machine.name
    )
    assert code == 0, err
    assert "0 resends" in out + err
