"""Writers' shared parts (line formatting, placement) and the examples the writer tests use.

Examples: the Fig. 1 design (solved once per session) with roads along its u-curves,
which follow the director, and a baromorph: a disc with one spiral channel and an inlet.
The G-code replay runs the independent parser ``gcodeparser`` and keeps the machine state.
"""

from __future__ import annotations

import atexit
import functools
import math
import shutil
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import shapely
from gcodeparser import parse_gcode_lines

from fabkit.design.design import Design
from fabkit.design.solver import solve
from fabkit.errors import FabkitError
from fabkit.machines import MachineProfile, load_machine
from fabkit.problem.spec import load_spec
from fabkit.toolpath import PRINT, TRAVEL, Layer, Move, Toolpath
from fabkit.writers.common import check_inside, placement_offset
from fabkit.writers.line_table import Word, render

ROOT = Path(__file__).resolve().parent.parent
FIG1_SIZE_MM = 40.0


# --------------------------------------------------------------------------- examples


@functools.cache
def fig1_design_path() -> Path:
    """The Fig. 1 design, solved once (about 1 s) into a temporary folder."""
    folder = Path(tempfile.mkdtemp(prefix="fabkit-writers-"))
    atexit.register(shutil.rmtree, folder, True)
    path = folder / "design.npz"
    solve(load_spec(ROOT / "examples" / "two_shapes.toml")).design.save(path)
    return path


def fig1_toolpath(machine: MachineProfile, layers: int = 2) -> Toolpath:
    """Roads along the u-curves of the Fig. 1 sheet (40 mm), eps encoded through the
    machine's calibration (speed or flow), serpentine order, explicit travels."""
    design = Design.load(fig1_design_path())
    points = design.r[0]
    extent = np.ptp(points[design.valid], axis=0).max()
    scale = FIG1_SIZE_MM / extent
    eps = design.eps[0]
    low, high = np.nanmin(eps[design.valid]), np.nanmax(eps[design.valid])
    roads = []
    for j in range(points.shape[1]):
        run = np.flatnonzero(design.valid[:, j])
        if len(run) >= 2 and np.all(np.diff(run) == 1):
            roads.append((points[run, j] * scale, eps[run, j]))
    process = machine.process
    table = process.encodes[0].table if process.encodes else None
    result = []
    for k in range(layers):
        z = process.layer_height_mm * (k + 1)
        moves, last = [], None
        for n, (xy, e) in enumerate(roads[:: 1 if k % 2 == 0 else -1]):
            if n % 2:
                xy, e = xy[::-1], e[::-1]
            speed, flow, value = np.full(len(xy), process.print_speed_mm_s), 1.0, math.nan
            channels = {}
            if table is not None:
                machine_eps = table.eps[0] + (table.eps[-1] - table.eps[0]) * (e - low) / (
                    high - low
                )
                value = np.interp(machine_eps, table.eps, table.value)
                if table.parameter == "print_speed_mm_s":
                    speed = value
                elif table.parameter == "extrusion_multiplier":
                    flow = value
                channels = {table.parameter: value}
            if last is not None:
                hop = [last, xy[0]]
                nothing = {name: math.nan for name in channels}
                moves.append(Move.make(TRAVEL, hop, z, 0.0, process.travel_speed_mm_s, 0, nothing))
            moves.append(Move.make(PRINT, xy, z, process.road_width_mm, speed, flow, channels))
            last = xy[-1]
        result.append(Layer(z, process.layer_height_mm, tuple(moves)))
    named = {table.parameter: "eps"} if table is not None else {}
    return Toolpath(tuple(result), named, {"source": "fig1 test"})


@dataclass(frozen=True)
class Baromorph:
    """A baromorph plate: a 20 mm disc, one spiral channel (1.5 mm wide), an inlet."""

    outline: shapely.Polygon
    channels: shapely.Polygon
    inlet: shapely.Point


@functools.cache
def baromorph() -> Baromorph:
    phi = np.linspace(0, 4 * 2 * np.pi, 400)
    radius = 2.0 + 4.0 * phi / (2 * np.pi)
    centre_line = shapely.LineString(np.column_stack([radius * np.cos(phi), radius * np.sin(phi)]))
    return Baromorph(
        outline=shapely.Point(0, 0).buffer(20.0, quad_segs=32),
        channels=centre_line.buffer(0.75, quad_segs=4),
        inlet=shapely.Point(2.0, 0.0),
    )


def baromorph_toolpath(machine: MachineProfile, layers: int = 2) -> Toolpath:
    """Walls of the baromorph: the outline and the channel boundaries, as closed roads."""
    plate = baromorph()
    rings = [plate.outline.exterior, plate.channels.exterior, *plate.channels.interiors]
    process = machine.process
    result = []
    for k in range(layers):
        z = process.layer_height_mm * (k + 1)
        moves, last = [], None
        for ring in rings:
            xy = np.asarray(ring.coords)
            if last is not None:
                moves.append(Move.make(TRAVEL, [last, xy[0]], z, 0.0, process.travel_speed_mm_s, 0))
            moves.append(Move.make(PRINT, xy, z, process.road_width_mm, process.print_speed_mm_s))
            last = xy[-1]
        result.append(Layer(z, process.layer_height_mm, tuple(moves)))
    return Toolpath(tuple(result), "", {"source": "baromorph test"})


def reprap_machine(folder: Path, filament_diameter_mm: float) -> MachineProfile:
    """marlin_generic as the RepRap-flavoured profile reprap_test (relative E in the
    profile, ``filament_diameter_mm`` filament), written into ``folder``."""
    text = (
        Path(load_machine("marlin_generic").path)
        .read_text()
        .replace('flavour = "marlin"', 'flavour = "reprap"')
        .replace('name = "marlin_generic"', 'name = "reprap_test"')
        .replace(
            "filament_diameter_mm = 1.75",
            f'filament_diameter_mm = {filament_diameter_mm}\ne_mode = "relative"',
        )
    )
    path = folder / "reprap_test.toml"
    path.write_text(text)
    return load_machine(path)


def model_volume(toolpath: Toolpath) -> float:
    """Sum of length x width x layer height x flow over print segments, mm^3."""
    total = 0.0
    for layer in toolpath.layers:
        for move in layer.prints:
            lengths = np.linalg.norm(np.diff(move.xyz, axis=0), axis=1)
            total += float((lengths * move.width[1:] * move.flow[1:]).sum()) * layer.height_mm
    return total


# --------------------------------------------------------------------------- G-code replay


@dataclass(frozen=True)
class ReadLine:
    """One line of a G-code file as parsed by ``gcodeparser``, with the machine state after
    it: ``comment`` the text of a comment line (None on a command line), ``name`` the
    command (G1, M83, ...), ``position`` (3,) mm, ``step`` (3,) mm moved by this line,
    ``feed`` mm/s, ``e_step`` the E increment, ``flowing`` whether the material flow
    (flow-on command) is on."""

    comment: str | None
    name: str
    position: np.ndarray
    step: np.ndarray
    feed: float
    e_step: float
    flowing: bool


def read_lines(text: str, flow_on: str = "", flow_off: str = "") -> Iterator[ReadLine]:
    """Every line of ``text`` in order, the machine state kept from line to line (E
    absolute until M83, position unknown (NaN) until an axis is given)."""
    position = np.full(3, np.nan)
    e, feed, absolute_e, flowing = 0.0, math.nan, True, False
    source = text.splitlines()
    for line in parse_gcode_lines(text, include_comments=True):
        name = line.command_str
        if line.command[0] == ";":
            yield ReadLine(line.comment, name, position.copy(), np.zeros(3), feed, 0.0, flowing)
            continue
        text_line = source[line.line_index].split(";")[0].strip()
        if flow_on and text_line == flow_on:
            flowing = True
        elif flow_off and text_line == flow_off:
            flowing = False
        start, e_step = position.copy(), 0.0
        if name in ("M82", "M83"):
            absolute_e = name == "M82"
        elif name == "G92" and "E" in line.params:
            e = float(line.params["E"])
        elif name in ("G0", "G1"):
            for k, axis in enumerate("XYZ"):
                if axis in line.params:
                    position[k] = float(line.params[axis])
            feed = float(line.params.get("F", feed * 60)) / 60
            if "E" in line.params:
                value = float(line.params["E"])
                e_step = value - e if absolute_e else value
                e = value if absolute_e else e + value
        step = position - start if name in ("G0", "G1") else np.zeros(3)
        yield ReadLine(None, name, position.copy(), step, feed, e_step, flowing)


@dataclass(frozen=True)
class Replay:
    """Every motion line of a G-code file as parsed by ``gcodeparser``, with the state
    after it: code (G0/G1), position (n, 3), step (n, 3), feed mm/s, E increment, and
    whether the material flow (flow-on command) was on; plus the comments."""

    code: np.ndarray
    position: np.ndarray
    step: np.ndarray
    feed: np.ndarray
    e_step: np.ndarray
    flowing: np.ndarray
    comments: list[str]
    commands: list[str]


def replay(text: str, flow_on: str = "", flow_off: str = "") -> Replay:
    lines = list(read_lines(text, flow_on, flow_off))
    moves = [line for line in lines if line.name in ("G0", "G1")]
    return Replay(
        code=np.array([move.name for move in moves]),
        position=np.array([move.position for move in moves]).reshape(-1, 3),
        step=np.array([move.step for move in moves]).reshape(-1, 3),
        feed=np.array([move.feed for move in moves]),
        e_step=np.array([move.e_step for move in moves]),
        flowing=np.array([move.flowing for move in moves], dtype=bool),
        comments=[line.comment for line in lines if line.comment is not None],
        commands=[line.name for line in lines if line.comment is None],
    )


# --------------------------------------------------------------------------- tests


def _python_format(value: float, decimals: int) -> str:
    text = f"{value:.{decimals}f}"
    if "." in text:
        text = text.rstrip("0").rstrip(".")
    return text[1:] if text.startswith("-") and float(text) == 0 else text


def test_render_matches_python_formatting():
    rng = np.random.default_rng(1)
    values = np.concatenate(
        [
            rng.uniform(-500, 500, 3000),
            rng.uniform(-1, 1, 3000),
            rng.uniform(-1e7, 1e7, 300),
            [0.0, -0.0, 1e-9, -1e-9, 1000.0, 999.9994, 1234567.891, 1000000.0],
        ]
    )
    present = rng.random(len(values)) > 0.2
    for decimals in (0, 1, 3, 5):
        text = render(
            np.zeros(len(values), int),
            ["G1"],
            values[:, None],
            present[:, None],
            [Word(" X", decimals)],
        ).decode()
        expected = [
            f"G1 X{_python_format(v, decimals)}" if p else "G1"
            for v, p in zip(values, present, strict=True)
        ]
        assert text.splitlines() == expected


def test_render_mixes_prefixes_and_words():
    values = np.array([[1.5, np.nan], [np.nan, 3.0], [np.nan, np.nan]])
    text = render(
        np.array([0, 1, 2]),
        ["G1", ";LAYER:", "M42 P4 S255\nG4 P100"],
        values,
        np.isfinite(values),
        [Word(" X", 3), Word("", 0)],
    )
    assert text == b"G1 X1.5\n;LAYER:3\nM42 P4 S255\nG4 P100\n"


def test_render_refuses_non_finite_present_values():
    with pytest.raises(FabkitError, match="non-finite"):
        render(
            np.zeros(1, int), ["G1"], np.array([[np.inf]]), np.ones((1, 1), bool), [Word(" X", 3)]
        )


def test_placement_centres_on_the_bed_or_takes_the_offset():
    machine = load_machine("marlin_generic")  # 220 x 220
    shift = placement_offset(np.array([-10.0, -5.0]), np.array([10.0, 5.0]), machine, None)
    assert shift.tolist() == [110.0, 110.0, 0.0]
    assert placement_offset(np.zeros(2), np.ones(2), machine, (1, 2)).tolist() == [1, 2, 0]
    with pytest.raises(FabkitError, match="offset"):
        placement_offset(np.zeros(2), np.ones(2), machine, (1.0,))


def test_check_inside_names_axis_and_machine():
    machine = load_machine("marlin_generic")
    check_inside(np.array([[0.0, 220.0, 0.0]]), machine, "test")
    with pytest.raises(FabkitError, match=r"test: Y = 230.000 mm is outside .*marlin_generic"):
        check_inside(np.array([[10.0, 230.0, 1.0]]), machine, "test")
