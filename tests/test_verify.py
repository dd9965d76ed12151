"""Every channel round-trips through every writer that carries it, read back as the
machine reads it (fabkit.verify, which shares no code with the writers); joint tables
invert; ``fabkit verify`` measures a sheet, and notices a sabotaged file."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from fabkit.calibration import Calibration, JointCalibration
from fabkit.errors import FabkitError
from fabkit.field.flat import field_from_expression
from fabkit.field.outlines import parse_shape
from fabkit.machines import load_machine
from fabkit.process import Encode, Process
from fabkit.toolpath.exposure import LaserSettings, sample_field
from fabkit.toolpath.model import PRINT, Toolpath
from fabkit.toolpath.plan import PlanSettings, plan_toolpath
from fabkit.verify.raster import Roads, rasterise
from fabkit.verify.read_dxf import read_dxf
from fabkit.verify.read_gcode import read_gcode
from fabkit.verify.read_laser import read_laser
from fabkit.writers.dxf import write_dxf
from fabkit.writers.gcode import write_gcode
from fabkit.writers.laser import write_laser
from tests.conftest import ROOT

FEATURES = {"eps1": "0.3 + 0.02*x", "eps2": "0.05*y"}
"""Two features on an 8 mm square: eps1 in [0.22, 0.38], eps2 in [-0.2, 0.2]."""
TABLES = {
    "print_speed_mm_s": ((0.0, 0.5), (16.0, 4.0)),
    "extrusion_multiplier": ((0.0, 0.5), (0.8, 1.3)),
    "pressure_kpa": ((-0.5, 0.5), (150.0, 450.0)),
    "temperature_c": ((-0.5, 0.5), (190.0, 230.0)),
    "ink_fraction": ((-0.5, 0.5), (0.0, 1.0)),
    "line_spacing_mm": ((0.0, 0.5), (0.35, 0.6)),
    "dose_mj_cm2": ((0.0, 0.5), (200.0, 1500.0)),
    "cure_dose_mj_cm2": ((-0.5, 0.5), (100.0, 1200.0)),
}
FEATURE_OF = {
    "print_speed_mm_s": "eps1",
    "extrusion_multiplier": "eps1",
    "line_spacing_mm": "eps1",
    "dose_mj_cm2": "eps1",
}


def _field():
    return field_from_expression("0.3*x/4", parse_shape("square:8"), FEATURES)


def _process(parameters: tuple[str, ...], road_width: float = 0.4) -> Process:
    """A process encoding ``parameters``, eps1 with the first and eps2 with the second."""
    features = ("eps1", "eps2")
    encodes = tuple(
        Encode((feature,), Calibration(name, *TABLES[name]))
        for feature, name in zip(features, parameters, strict=False)
    )
    return Process(road_width, 0.3, 8.0, 30.0, encodes, "test process")


def _profile(tmp_path: Path, base: str, edits: dict[str, str]) -> Path:
    text = (ROOT / "machines" / f"{base}.toml").read_text()
    for old, new in edits.items():
        assert old in text, old
        text = text.replace(old, new, 1)
    path = tmp_path / f"{base}_edited.toml"
    path.write_text(text)
    return path


MIXING = {
    "[process]": '[inks]\nmethod = "mixing"\n\n[process]',
}
"""marlin_generic with a mixing extruder."""

TOLERANCE = {
    "print_speed_mm_s": 0.05 / 60 * 1.01,  # F is written to 0.1 mm/min
    "pressure_kpa": 700 / 255 / 2 * 1.01,  # whole PWM steps of the regulator
    "temperature_c": 0.5 * 1.01,  # whole degrees
    "ink_fraction": 0.005 * 1.01,  # hundredths
    "extrusion_multiplier": 0.025,  # E over a 0.1 mm move written to 1 um: 1.4 % per move
}
# machine, edits of its profile, the parameters of eps1 and eps2 (one: eps2 ignored)
GCODE_CASES = [
    pytest.param("marlin_diw_pneumatic", {}, ("print_speed_mm_s", "pressure_kpa"), id="diw"),
    pytest.param("marlin_generic", {}, ("extrusion_multiplier", "temperature_c"), id="marlin"),
    pytest.param("marlin_generic", MIXING, ("print_speed_mm_s", "ink_fraction"), id="mixing"),
    pytest.param("klipper_generic", {}, ("print_speed_mm_s", "temperature_c"), id="klipper"),
    pytest.param("hyrel_pulse", {}, ("extrusion_multiplier",), id="hyrel"),
    pytest.param("grbl_diw", {}, ("print_speed_mm_s",), id="grbl"),
]


def _plan(parameters: tuple[str, ...], road_width: float = 0.4) -> Toolpath:
    plan = plan_toolpath([_field()], _process(parameters, road_width), PlanSettings())
    return plan.toolpath


def _vertex_values(toolpath: Toolpath, name: str) -> tuple[np.ndarray, np.ndarray]:
    """Print vertices (k >= 1) of the toolpath, (n, 2) mm, and their ``name`` values."""
    points, values = [], []
    for _, move in toolpath.moves():
        if move.kind == PRINT:
            points.append(move.xyz[1:, :2])
            values.append(move.channels[name][1:])
    return np.concatenate(points), np.concatenate(values)


@pytest.mark.parametrize(("base", "edits", "parameters"), GCODE_CASES)
def test_gcode_round_trip(tmp_path, base, edits, parameters):
    machine = load_machine(_profile(tmp_path, base, edits) if edits else base)
    ignore = ("eps2",) if len(parameters) == 1 else ()
    process = _process(parameters)
    toolpath = plan_toolpath([_field()], process, PlanSettings(ignore=ignore)).toolpath
    summary = write_gcode(toolpath, machine, tmp_path / "sheet.gcode")
    printed = read_gcode(tmp_path / "sheet.gcode", machine)
    assert printed.placement.offset_mm == pytest.approx(summary.offset_mm[:2], abs=1e-3)
    assert printed.placement.mm_per_unit is None  # a director field: no design scale
    ends = printed.end[:, :2] - np.array(summary.offset_mm[:2])
    length = np.linalg.norm(printed.end[:, :2] - printed.start[:, :2], axis=1)
    read = {
        "print_speed_mm_s": printed.feed,
        "pressure_kpa": printed.pressure,
        "temperature_c": printed.temperature,
        "ink_fraction": printed.mix,
        "extrusion_multiplier": printed.volume / (length * 0.4 * 0.3),
    }
    for name in parameters:
        points, wanted = _vertex_values(toolpath, name)
        distance, nearest = cKDTree(points).query(ends)
        assert distance.max() < 2e-3  # every deposit ends at a toolpath vertex
        assert len(ends) >= 0.99 * len(points)  # and (nearly) every print vertex is printed
        np.testing.assert_allclose(read[name], wanted[nearest], atol=TOLERANCE[name], rtol=1e-6)
        assert np.ptp(wanted) > 5 * TOLERANCE[name]  # the channel really varies


def test_flow_without_an_e_axis_is_read_from_the_feed(tmp_path):
    """A pneumatic machine writes the multiplier f as the feed speed / f: read back as the
    nominal speed over the feed."""
    machine = load_machine("marlin_diw_pneumatic")
    process = _process(("extrusion_multiplier", "pressure_kpa"))
    toolpath = plan_toolpath([_field()], process, PlanSettings()).toolpath
    summary = write_gcode(toolpath, machine, tmp_path / "sheet.gcode")
    printed = read_gcode(tmp_path / "sheet.gcode", machine)
    points, wanted = _vertex_values(toolpath, "extrusion_multiplier")
    _, nearest = cKDTree(points).query(printed.end[:, :2] - np.array(summary.offset_mm[:2]))
    flow = process.print_speed_mm_s / printed.feed
    np.testing.assert_allclose(flow, wanted[nearest], rtol=2e-4)


def _printed_roads(
    tmp_path: Path, parameters: tuple[str, ...], road_width: float = 0.4, unknown=()
):
    """``parameters`` planned at ``road_width`` (mm), written for marlin_diw_pneumatic and
    read back: the printed moves, and their roads in the sheet frame (mm), the parameters
    ``unknown`` NaN on every road (to be read from the road positions)."""
    machine = load_machine("marlin_diw_pneumatic")
    summary = write_gcode(_plan(parameters, road_width), machine, tmp_path / "sheet.gcode")
    printed = read_gcode(tmp_path / "sheet.gcode", machine)
    count = len(printed.start)
    roads = Roads(
        printed.start[:, :2],
        printed.end[:, :2],
        np.full(count, road_width),
        printed.road,
        {name: np.full(count, np.nan) for name in unknown},
        printed.ink,
    )
    return printed, roads.shifted(np.array(summary.offset_mm))


def test_alternating_inks_make_the_encoded_share(tmp_path):
    printed, roads = _printed_roads(tmp_path, ("print_speed_mm_s", "ink_fraction"), 0.41)
    readback = rasterise(roads, 0.41 / 4)
    x, y = readback.centres()
    inner = (np.abs(x) < 3) & (np.abs(y) < 3) & (readback.hits > 0)
    share = readback.values["ink_fraction"][inner]
    wanted = np.interp(0.05 * y[inner], *TABLES["ink_fraction"])  # the encoded fraction
    assert np.sqrt(np.mean((share - wanted) ** 2)) < 0.03
    runs = np.diff(np.flatnonzero(np.diff(np.concatenate([[-1], printed.ink, [-1]]))))
    assert np.isin(printed.ink, (0, 1)).all() and len(runs) > 20  # pieces of both inks
    text = (tmp_path / "sheet.gcode").read_text()
    assert text.count("M42 P5 S255") == text.count("M42 P5 S0") - 2  # start and end G-code


def test_line_spacing_is_read_from_the_road_positions(tmp_path):
    parameters = ("line_spacing_mm", "ink_fraction")
    _, roads = _printed_roads(tmp_path, parameters, unknown=("line_spacing_mm",))
    readback = rasterise(roads, 0.1)
    x, y = readback.centres()
    inner = (np.abs(x) < 3) & (np.abs(y) < 3) & (readback.hits > 0)
    spacing = readback.values["line_spacing_mm"][inner]
    wanted = np.interp(0.3 + 0.02 * x[inner], *TABLES["line_spacing_mm"])
    assert np.median(np.abs(spacing - wanted) / wanted) < 0.08
    assert np.ptp(wanted) > 0.05


@pytest.mark.parametrize(
    "parameters",
    [
        ("print_speed_mm_s", "pressure_kpa"),
        ("extrusion_multiplier", "temperature_c"),
        ("line_spacing_mm", "ink_fraction"),
    ],
)
def test_dxf_round_trip(tmp_path, parameters):
    toolpath = _plan(parameters)
    summary = write_dxf(tmp_path / "sheet.dxf", toolpath, machine=load_machine("laser_cutter"))
    start, end, width, road, values, _, placement = read_dxf(tmp_path / "sheet.dxf", 0.4)
    assert placement.offset_mm == pytest.approx(summary.offset_mm[:2])
    assert width == pytest.approx(0.4)
    shift = np.array(summary.offset_mm[:2])
    for name in parameters:
        points, wanted = _vertex_values(toolpath, name)
        _, nearest = cKDTree(points).query(end - shift)
        np.testing.assert_allclose(values[name], wanted[nearest], rtol=1e-12)
    prints = sum(1 for _, m in toolpath.moves() if m.kind == PRINT)
    assert road.max() + 1 == prints


@pytest.mark.slow
def test_laser_round_trip_of_both_doses(tmp_path):
    field = _field()
    machine = load_machine("dmd_photoalign")
    process = _process(("dose_mj_cm2", "cure_dose_mj_cm2"))
    grid = sample_field(field, 0.05)
    settings = LaserSettings.for_machine(machine, process=process, dose_levels=16)
    write_laser(grid, tmp_path / "laser", machine, settings, offset_mm=(5.0, 7.0))
    readback, placement, manifest = read_laser(tmp_path / "laser")
    assert manifest["channels"] == {"dose_mj_cm2": "eps1", "cure_dose_mj_cm2": "eps2"}
    assert placement.offset_mm == pytest.approx((5.0, 7.0))
    x, y = readback.centres()
    sheet = np.column_stack([x.ravel(), y.ravel()]) - np.array(placement.offset_mm)
    covered = readback.hits.ravel() > 0
    for name in ("dose_mj_cm2", "cure_dose_mj_cm2"):
        feature = "eps1" if name == "dose_mj_cm2" else "eps2"
        table = Calibration(name, *TABLES[name])
        wanted = table.encode(np.clip(field.feature(feature, sheet[covered]), *table.eps_range))[0]
        level = (wanted.max() - wanted.min()) / 16
        read = readback.values[name].ravel()[covered]
        inner = np.abs(sheet[covered]).max(axis=1) < 3.9
        assert np.abs(read - wanted)[inner].max() <= level / 2 + 1e-6
    director = np.degrees(readback.theta.ravel()[covered])
    wanted = np.degrees(field.theta(sheet[covered]))
    error = np.abs((director - wanted + 90) % 180 - 90)
    assert error[np.abs(sheet[covered]).max(axis=1) < 3.9].max() <= 5.0 + 1e-6  # half a bin


def _joint() -> JointCalibration:
    """A measured grid: speed and pressure each move both features (curved, one-to-one)."""
    speed = np.array([4.0, 8.0, 12.0, 16.0])
    pressure = np.array([150.0, 250.0, 350.0])
    s, p = np.meshgrid(speed, pressure, indexing="ij")
    eps1 = 0.6 - 0.03 * s + 0.0004 * p + 0.0005 * s * s
    eps2 = -0.4 + 0.002 * p + 0.01 * s
    return JointCalibration(
        ("print_speed_mm_s", "pressure_kpa"),
        tuple(speed),
        tuple(pressure),
        (tuple(map(tuple, eps1)), tuple(map(tuple, eps2))),
    )


def test_joint_table_inverts_to_the_measured_grid_and_between():
    table = _joint()
    first, second, eps = table._grid
    coded = table.invert(eps[..., 0].ravel(), eps[..., 1].ravel())
    s, p = np.meshgrid(first, second, indexing="ij")
    assert coded.values["print_speed_mm_s"] == pytest.approx(s.ravel(), abs=1e-9)
    assert coded.values["pressure_kpa"] == pytest.approx(p.ravel(), abs=1e-7)
    rng = np.random.default_rng(3)
    speed, pressure = rng.uniform(4, 16, 500), rng.uniform(150, 350, 500)
    e1, e2, _ = table.forward(speed, pressure)
    back = table.invert(e1, e2).values
    assert back["print_speed_mm_s"] == pytest.approx(speed, abs=1e-8)
    assert back["pressure_kpa"] == pytest.approx(pressure, abs=1e-6)
    channel = Encode(("eps1", "eps2"), table)
    decoded = channel.decode(back)
    assert decoded["eps1"] == pytest.approx(e1, abs=1e-12)


def test_joint_table_outside_and_clipped():
    table = _joint()
    with pytest.raises(FabkitError, match="outside what the joint table"):
        table.invert(np.array([5.0]), np.array([5.0]))
    clipped = dataclasses.replace(table, clip=True).invert(np.array([5.0]), np.array([5.0]))
    assert clipped.clipped_fraction == 1.0
    assert 4.0 <= clipped.values["print_speed_mm_s"][0] <= 16.0


@pytest.mark.parametrize(
    ("measured1", "message"),
    [
        (((0.0, 1.0), (1.0, 0.0)), "cannot be inverted"),  # the Jacobian changes sign
        (((0.0, 0.0), (0.0, 0.0)), "cannot be inverted"),  # no map at all
    ],
)
def test_joint_tables_that_fold_are_refused(measured1, message):
    with pytest.raises(FabkitError, match=message):
        JointCalibration(
            ("print_speed_mm_s", "pressure_kpa"),
            (4.0, 8.0),
            (100.0, 200.0),
            (measured1, ((0.0, 1.0), (0.0, 1.0))),
        )


def test_joint_channel_through_the_planner_and_the_gcode(tmp_path):
    table = _joint()
    channel = Encode(("eps1", "eps2"), table)
    field = field_from_expression(
        "0", parse_shape("square:6"), {"eps1": "0.45 + 0.01*x", "eps2": "0.3 + 0.02*y"}
    )
    process = Process(0.41, 0.3, 8.0, 30.0, (channel,), "joint")
    toolpath = plan_toolpath([field], process, PlanSettings()).toolpath
    assert toolpath.channels == {"print_speed_mm_s": "eps1+eps2", "pressure_kpa": "eps1+eps2"}
    machine = load_machine("marlin_diw_pneumatic")
    summary = write_gcode(toolpath, machine, tmp_path / "joint.gcode")
    printed = read_gcode(tmp_path / "joint.gcode", machine)
    decoded = channel.decode({"print_speed_mm_s": printed.feed, "pressure_kpa": printed.pressure})
    ends = printed.end[:, :2] - np.array(summary.offset_mm[:2])
    assert decoded["eps1"] == pytest.approx(field.feature("eps1", ends), abs=0.01)
    assert decoded["eps2"] == pytest.approx(field.feature("eps2", ends), abs=0.01)


@pytest.fixture(scope="module")
def fig1_run(tmp_path_factory):
    """Fig. 1 on a coarse grid in one layer, a part 18 mm long (what --size 40 made before
    --size was the part's longest side), verified by the run itself."""
    from fabkit.cli import main

    out = tmp_path_factory.mktemp("fig1") / "run"
    spec = ROOT / "examples" / "two_shapes.toml"
    arguments = ["run", str(spec), "--out", str(out), "--size", "18", "--layers", "1"]
    arguments += ["--no-pictures"]
    assert main([*arguments, "--step", "0.1", "--diagonals", "60"]) == 0
    return out


@pytest.mark.slow
def test_run_reports_the_verification(fig1_run):
    figures = json.loads((fig1_run / "report.json").read_text())
    verified = figures["verify"]
    assert verified["kind"] == "gcode" and verified["features"][0]["feature"] == "eps"
    assert verified["features"][0]["rms_pct"] < 2.0 and verified["director_mean_deg"] < 3.0
    assert [t["target"] for t in verified["targets"]] == ["sphere", "bump"]
    assert figures["channels"] == {"print_speed_mm_s": "eps"}
    page = (fig1_run / "report.html").read_text()
    assert "<th>director error, read back: mean / 95th percentile (deg)</th>" in page
    assert "<th>eps, as the print speed (mm/s), error: RMS / 95th percentile</th>" in page
    assert "NOT ENCODED" not in page


@pytest.mark.slow
def test_an_ignored_feature_is_the_reports_first_line(run_cli, tmp_path):
    out = tmp_path / "fig3"
    spec = ROOT / "examples" / "three_shapes.toml"
    code, text, err = run_cli(
        "run", spec, "--out", out, "--ignore-feature", "eps2",
        "--step", "0.1", "--diagonals", "30", "--size", "20", "--no-pictures",
    )  # fmt: skip
    assert code == 0, err
    assert text.splitlines()[0].strip().startswith("NOT ENCODED: feature eps2 left out")
    # and the last line, before the verdict on the sheet as designed
    assert text.splitlines()[-1].startswith("done: NOT ENCODED in the machine file (")
    figures = json.loads((out / "report.json").read_text())
    assert next(iter(figures)) == "notice" and "eps2" in figures["notice"]
    assert figures["channels"] == {"print_speed_mm_s": "eps1"}
    assert figures["verify"]["ignored"] == ["eps2"] and figures["verify"]["targets"] == []
    body = (out / "report.html").read_text().split("<body>", 1)[1]
    assert body.lstrip().startswith('<p class="notice">NOT ENCODED: feature eps2')
    gcode = (out / "sheet.gcode").read_text()
    assert ";fabkit channels: print_speed_mm_s (eps1)" in gcode


@pytest.mark.slow
def test_verify_reads_a_run_back_and_simulates_it(fig1_run, run_cli):
    design, gcode = fig1_run / "design.npz", fig1_run / "sheet.gcode"
    code, text, err = run_cli("verify", design, gcode, "--reference", "--json")
    assert code == 0, err
    report = json.loads(text)
    # the coverage read back from the G-code agrees with the planner's own measure
    (quality,) = json.loads((fig1_run / "toolpath" / "quality.json").read_text())["layers"]
    assert report["empty_fraction"] == pytest.approx(quality["empty_fraction"], abs=0.01)
    assert report["mean_overlap"] == pytest.approx(quality["mean_overlap"], abs=0.01)
    assert report["director_mean_deg"] == pytest.approx(quality["mean_angle_error_deg"], abs=0.5)
    (feature,) = report["features"]
    assert feature["feature"] == "eps" and feature["rms_pct"] < 2.0
    assert [t["target"] for t in report["targets"]] == ["sphere", "bump"]
    sphere = report["targets"][0]  # fabrication adds little to what the design does
    assert sphere["rms_pct"] < sphere["designed_rms_pct"] + 1.0


@pytest.mark.slow
def test_verify_notices_a_sabotaged_file(fig1_run, run_cli, tmp_path):
    lines = (fig1_run / "sheet.gcode").read_text().splitlines()
    slower = []
    for line in lines:
        if line.startswith("G1") and " F" in line:
            head, feed = line.rsplit(" F", 1)
            line = f"{head} F{float(feed) * 0.8:.1f}"
        slower.append(line)
    (tmp_path / "slow.gcode").write_text("\n".join(slower) + "\n")
    code, text, err = run_cli(
        "verify", fig1_run / "design.npz", tmp_path / "slow.gcode", "--no-simulate", "--json"
    )
    assert code == 0, err
    (feature,) = json.loads(text)["features"]
    assert feature["rms_pct"] > 5.0  # 20 % slower roads read as a different eps


@pytest.mark.slow
def test_verify_reads_with_the_machine_the_file_names(fig1_run, run_cli, tmp_path):
    """One rule (fabkit/writers/which_machine.py): --machine, else the file's header, else
    the default; a --machine the header contradicts is read as asked, and said."""
    design, gcode = fig1_run / "design.npz", fig1_run / "sheet.gcode"
    code, text, err = run_cli("verify", design, gcode, "--no-simulate")
    assert code == 0, err
    assert "machine marlin_diw_pneumatic" in text.splitlines()[0] and "file names" not in text
    renamed = tmp_path / "renamed.gcode"  # the same moves, its header naming another machine
    text = gcode.read_text().replace("for machine marlin_diw_pneumatic", "for machine grbl_diw", 1)
    renamed.write_text(text)
    machine = ("--machine", "marlin_diw_pneumatic")
    code, text, err = run_cli("verify", design, renamed, "--no-simulate", *machine)
    assert code == 0, err
    assert "read as machine marlin_diw_pneumatic reads it, but the file names grbl_diw" in text


@pytest.mark.slow
def test_the_thickness_is_the_files_and_a_process_that_disagrees_is_the_first_line(
    fig1_run, run_cli, tmp_path
):
    design, gcode = fig1_run / "design.npz", fig1_run / "sheet.gcode"
    machine = (ROOT / "machines" / "marlin_diw_pneumatic.toml").read_text()
    assert "layer_height_mm = 0.3\n" in machine
    thin = tmp_path / "thin.toml"  # the same process, but half the layer height
    thin.write_text(machine.replace("layer_height_mm = 0.3\n", "layer_height_mm = 0.15\n"))
    same = ["verify", design, gcode, "--no-simulate"]
    code, text, err = run_cli(*same, "--process", thin)
    assert code == 0, err
    first = text.splitlines()[0]
    assert first.startswith("THICKNESS FROM THE FILE: it prints 1 layer, 0.3 mm in all"), first
    assert "0.15 mm per layer" in first and str(thin) in first
    asked, plain = (
        json.loads(run_cli(*same, *more, "--json")[1]) for more in (["--process", thin], [])
    )
    assert asked["notice"] == asked["thickness_notice"] == first
    assert plain["thickness_notice"] == "" and "notice" not in plain
    # the features read back do not hang on the process's layer height
    assert asked["features"] == plain["features"]


def test_layer_thicknesses_step_from_the_bed():
    from fabkit.verify.machine_file import layer_thicknesses

    assert layer_thicknesses([0.3, 0.6], 0.2) == pytest.approx([0.3, 0.3])
    assert layer_thicknesses([0.2, 0.5, 0.6], 0.3) == pytest.approx([0.2, 0.3, 0.1])
    assert layer_thicknesses([0.0], 0.25) == [0.25]  # printed at the bed's height: the process's
