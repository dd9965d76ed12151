"""Attack rows of issue 16: every feature reaches the machine, and the print is checked.

Each row is a bad input of ``run``, ``toolpath``, ``export`` or ``verify`` about channels:
a feature no channel encodes, a feature or parameter encoded twice, a joint table that
folds, a channel a writer cannot carry, a machine file that does not say where the sheet
sits. Each must be one line naming the problem, exit 2, nothing written (tests/attack.py).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from fabkit.toolpath.job import ToolpathJob, run_job
from fabkit.toolpath.model import PRINT, Layer, Move, Toolpath, save_toolpath
from fabkit.writers.export import export
from tests.attack import assert_refused, case, edited, write_texts
from tests.conftest import ROOT, coarse_design

pytestmark = pytest.mark.filterwarnings("error")  # a warning would be a second line on stderr

SETTINGS = (
    "[process]\nroad_width_mm = 0.4\nlayer_height_mm = 0.3\nprint_speed_mm_s = 8\n"
    "travel_speed_mm_s = 30\n"
)


def _encode(feature: str, parameter: str, eps: str, value: str) -> str:
    return (
        f"[[process.encode]]\nfeature = {feature}\nparameter = '{parameter}'\n"
        f"eps = {eps}\nvalue = {value}\n"
    )


SPEED = _encode("'eps1'", "print_speed_mm_s", "[0, 1]", "[16, 2]")
FRACTION = _encode("'eps2'", "ink_fraction", "[-1, 1]", "[0, 1]")

CASES = [
    case(
        "run {three} --out {out} --process {speed_only}",
        "encodes no channel for feature",
        "eps2",
        "--ignore-feature eps2",
        id="features-run-missing",
    ),
    case(
        "run {spec} --out {out} --machine klipper_generic",
        "encodes no channel for feature",
        "machine klipper_generic",
        "machines whose process encodes every feature: ",
        id="features-run-machine-without-channels",
    ),
    case(
        "run {spec} --out {out} --ignore-feature eps7",
        "not a feature of the design",
        "--ignore-feature eps7",
        id="features-run-ignore-unknown",
    ),
    case(
        "run {three} --out {out} --process {twice}",
        "is encoded twice",
        "eps1",
        id="features-twice",
    ),
    case(
        "run {three} --out {out} --process {same_parameter}",
        "encodes two channels",
        "print_speed_mm_s",
        id="features-same-parameter",
    ),
    case(
        "run {three} --out {out} --process {folded}",
        "cannot be inverted",
        "process.joint[0]",
        id="features-joint-folds",
    ),
    case(
        "run {three} --out {out} --process {joint_shape}",
        "each measured eps table needs",
        "2 rows of 3 numbers",
        id="features-joint-shape",
    ),
    case(
        "toolpath --director 0 --shape disc:3 --eps 0.2 --machine {mixing_valves} --out {out}",
        "mixing needs a Marlin-like mixing extruder",
        id="features-mixing-without-e",
    ),
    case(
        "export {temperature_toolpath} --machine marlin_diw_pneumatic --format gcode "
        "-o {out}/sheet.gcode",
        "cannot carry the",
        "temperature_c channel",
        "no nozzle heater",
        id="features-gcode-temperature-without-heater",
    ),
    case(
        "export {temperature_toolpath} --machine grbl_diw --format gcode -o {out}/sheet.gcode",
        "cannot carry the",
        "temperature_c channel",
        "GRBL has no temperature command",
        id="features-gcode-temperature-grbl",
    ),
    case(
        "export {dose_toolpath} --machine laser_cutter --format dxf -o {out}/sheet.dxf",
        "the DXF writer cannot carry the",
        "dose_mj_cm2 channel",
        id="features-dxf-dose",
    ),
    case(
        "export {dose_toolpath} --machine marlin_generic --format gcode -o {out}/sheet.gcode",
        "cannot carry the",
        "dose_mj_cm2 channel",
        "laser writer",
        id="features-gcode-dose",
    ),
    case(
        "export {design} --machine dmd_photoalign --format laser --size 5 "
        "--process {speed_first} -o {out}",
        "the laser writer cannot expose the",
        "print_speed_mm_s channel",
        id="features-laser-print-channel",
    ),
    case(
        "export {design3} --machine scan_photoalign --format laser --size 5 "
        "--process {two_doses} -o {out}",
        "cannot expose the cure_dose_mj_cm2 channel",
        "one polarised beam",
        id="features-scan-cure",
    ),
    case(
        "verify {design} {missing}.gcode",
        "machine file",
        "does not exist",
        outputs=(),
        id="features-verify-missing",
    ),
    case(
        "verify {design} {bare_gcode} --no-simulate",
        "does not record where the sheet was placed",
        "--offset",
        outputs=(),
        id="features-verify-no-placement",
    ),
    case(
        "verify {design} {bare_gcode} --offset 100,100 --no-simulate",
        "does not record the sheet's scale",
        "--size",
        outputs=(),
        id="features-verify-no-scale",
    ),
    case(
        "verify {design} {arc_gcode}",
        "verify does not follow arcs",
        outputs=(),
        id="features-verify-arc",
    ),
    case(
        "verify {design} {gcode} --offset 1000,1000 --no-simulate",
        "no cell of the machine file lies on the design's flat sheet",
        outputs=(),
        id="features-verify-off-sheet",
    ),
    case(
        "verify {design} {bad_laser}",
        "not a fabkit laser manifest",
        outputs=(),
        id="features-verify-bad-manifest",
    ),
    case(
        "verify {design} {gcode} --cell 0",
        "expected a positive finite number",
        "--cell",
        outputs=(),
        id="features-verify-cell",
    ),
    case(
        "verify {design} {gcode} --stride 0",
        "expected an integer >= 1",
        "--stride 0",
        outputs=(),
        id="features-verify-stride",
    ),
]


@pytest.fixture(scope="module")
def places(folder) -> dict[str, str]:
    """Coarse Fig. 1 and Fig. 3 designs, a G-code file of Fig. 1, process files, machine
    profiles and toolpaths with channels some writers cannot carry."""
    designs = {}
    for name, example in (("design", "two_shapes.toml"), ("design3", "three_shapes.toml")):
        path = folder / f"{name}.npz"
        coarse_design(example).save(path)
        designs[name] = str(path)
    run_job(ToolpathJob(inputs=(designs["design"],), size_mm=20, out=str(folder / "tp")))
    export(folder / "tp" / "toolpath.npz", "marlin_diw_pneumatic", "gcode", folder / "s.gcode")
    body = [line for line in (folder / "s.gcode").read_text().splitlines() if line[:1] != ";"]
    (folder / "bare.gcode").write_text("\n".join(body) + "\n")
    (folder / "arc.gcode").write_text("G21\nG90\nG1 X10 Y10 F600\nG2 X20 Y10 I5 J0\n")
    processes = {
        "speed_only": SETTINGS + SPEED,
        "twice": SETTINGS + SPEED + FRACTION + SPEED.replace("[16, 2]", "[15, 3]"),
        "same_parameter": SETTINGS
        + SPEED
        + FRACTION.replace("ink_fraction", "print_speed_mm_s").replace("[0, 1]", "[2, 16]"),
        "folded": SETTINGS
        + "[[process.joint]]\nfeatures = ['eps1', 'eps2']\n"
        + "parameters = ['print_speed_mm_s', 'pressure_kpa']\n"
        + "grid1 = [4, 8]\ngrid2 = [100, 200]\n"
        + "measured1 = [[0.0, 1.0], [1.0, 0.0]]\nmeasured2 = [[0.0, 1.0], [0.0, 1.0]]\n",
        "joint_shape": SETTINGS
        + "[[process.joint]]\nfeatures = ['eps1', 'eps2']\n"
        + "parameters = ['print_speed_mm_s', 'pressure_kpa']\n"
        + "grid1 = [4, 8]\ngrid2 = [100, 200, 300]\n"
        + "measured1 = [[0.0, 1.0], [1.0, 0.0]]\nmeasured2 = [[0.0, 1.0], [0.0, 1.0]]\n",
        "speed_first": SETTINGS + SPEED.replace("'eps1'", "0"),
        "two_doses": SETTINGS
        + _encode("0", "dose_mj_cm2", "[0, 1]", "[200, 1500]")
        + _encode("1", "cure_dose_mj_cm2", "[-1, 1]", "[100, 1200]"),
    }
    profile = (ROOT / "machines" / "marlin_diw_pneumatic.toml").read_text()
    tomls = {
        **processes,
        "mixing_valves": edited(profile, 'method = "alternate"', 'method = "mixing"'),
    }
    line = np.array([[0.0, 0.0], [5.0, 0.0]])
    toolpaths = {}
    for name, parameter in (("temperature", "temperature_c"), ("dose", "dose_mj_cm2")):
        move = Move.make(PRINT, line, 0.2, 0.4, 5.0, 1.0, {parameter: 210.0})
        path = folder / f"{name}.json"
        save_toolpath(Toolpath((Layer(0.2, 0.2, (move,)),), {parameter: "eps"}), path)
        toolpaths[f"{name}_toolpath"] = str(path)
    bad_laser = folder / "laser"
    bad_laser.mkdir()
    (bad_laser / "manifest.json").write_text(
        json.dumps({"format": "other", "machine": "dmd_photoalign"})
    )
    return {
        **designs,
        **toolpaths,
        **write_texts(folder, tomls, ".toml"),
        "gcode": str(folder / "s.gcode"),
        "bare_gcode": str(folder / "bare.gcode"),
        "arc_gcode": str(folder / "arc.gcode"),
        "bad_laser": str(bad_laser),
    }


@pytest.mark.parametrize("bad", CASES)
def test_feature_and_verify_refusals(bad, places, run_cli, tmp_path):
    assert_refused(bad, places, tmp_path, run_cli)
