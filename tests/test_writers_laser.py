"""Laser-writer patterns: every domain pixel in exactly one mask, binning error within half
a bin, a manifest that validates against the documented schema, maps that decode back,
and scan lines that cover the domain once with the right wave-plate angle and power."""

from __future__ import annotations

import json
import math
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from PIL import Image

from fabkit.calibration import Calibration
from fabkit.errors import FabkitError
from fabkit.field.design_field import field_from_design
from fabkit.gcode.read import read_job
from fabkit.link.host.preflight import check_job
from fabkit.machines import load_machine
from fabkit.process import Encode, Process
from fabkit.toolpath.exposure import DirectorGrid, LaserSettings, bin_angles, sample_field
from fabkit.writers.laser import write_laser
from tests.test_writers_common import ROOT, baromorph, fig1_design_path, replay

SCHEMA = json.loads((ROOT / "docs" / "laser-manifest.schema.json").read_text())


def _dose(eps: tuple[float, float], dose: tuple[float, float], clip: bool = False) -> Process:
    """A process whose one channel sets the alignment dose of the feature eps."""
    channel = Encode(("eps",), Calibration("dose_mj_cm2", eps, dose, clip))
    return Process(1.0, 1.0, 1.0, 1.0, (channel,), "test dose")


def _wrap_deg(angle: np.ndarray) -> np.ndarray:
    return np.mod(angle + 90.0, 180.0) - 90.0


def _read(path: Path) -> np.ndarray:
    return np.array(Image.open(path))


def _fig1_grid() -> DirectorGrid:
    return sample_field(field_from_design(fig1_design_path(), size_mm=5.0), 0.02)


def _baromorph_grid(pitch: float = 0.25) -> DirectorGrid:
    """Director along the channels (azimuthal) on the 20 mm baromorph disc."""
    n = int(40 / pitch)
    x = -20 + pitch * (np.arange(n) + 0.5)
    xx, yy = np.meshgrid(x, x[::-1])
    mask = np.hypot(xx, yy) <= 20.0
    theta = np.arctan2(yy, xx) + np.pi / 2
    eps = 0.1 + 0.2 * np.hypot(xx, yy) / 20
    assert baromorph().outline.contains(baromorph().inlet)
    return DirectorGrid(theta, mask, {"eps": eps}, pitch, (-20.0, -20.0))


def _check_masks(folder: Path, manifest: dict, grid: DirectorGrid) -> np.ndarray:
    """Every domain pixel in exactly one mask; returns each pixel's exposure index."""
    masks = np.stack([_read(folder / e["file"]) for e in manifest["exposures"]])
    assert masks.dtype == bool
    assert (masks.sum(axis=0) == grid.mask).all()
    assert [e["pixels"] for e in manifest["exposures"]] == masks.sum(axis=(1, 2)).tolist()
    assert sum(e["pixels"] for e in manifest["exposures"]) == manifest["domain_pixels"]
    assert [e["order"] for e in manifest["exposures"]] == list(range(1, len(masks) + 1))
    return np.where(grid.mask, masks.argmax(axis=0), -1)


@pytest.mark.slow
def test_fig1_masks_partition_the_domain_within_half_a_bin(tmp_path):
    grid = _fig1_grid()
    machine = load_machine("dmd_photoalign")
    eps = grid.features["eps"][grid.mask]
    process = _dose((float(eps.min()), float(eps.max())), (500.0, 2000.0))
    settings = LaserSettings.for_machine(machine, process=process, bins=18, dose_levels=4)
    summary = write_laser(grid, tmp_path / "fig1", machine, settings)
    folder = tmp_path / "fig1"
    manifest = json.loads((folder / "manifest.json").read_text())
    jsonschema.validate(manifest, SCHEMA)
    assert manifest == json.loads(json.dumps(summary.manifest))
    index = _check_masks(folder, manifest, grid)

    angle = _read(folder / "angle.png")
    assert angle.dtype == np.uint16 and angle.shape == grid.shape
    theta = angle * np.pi / 65536
    quantum = 180 / 65536  # degrees per 16-bit step
    decoded = _wrap_deg(np.degrees(theta - grid.theta))[grid.mask]
    np.testing.assert_allclose(decoded, 0.0, atol=quantum / 2 + 1e-9)
    director = np.array([e["director_deg"] for e in manifest["exposures"]])[index]
    error = np.abs(_wrap_deg(np.degrees(grid.theta) - director))[grid.mask]
    assert manifest["binning_error_deg"]["bound"] == 90 / 18
    assert error.max() <= 90 / 18 + 1e-9
    assert error.max() == pytest.approx(manifest["binning_error_deg"]["max"], abs=1e-6)
    assert (_read(folder / "mask.png") > 0).tolist() == grid.mask.tolist()

    sidecar = json.loads((folder / "angle.json").read_text())
    assert "y down" in sidecar["convention"] and "counter-clockwise" in sidecar["convention"]
    dose = _read(folder / "dose.png") * sidecar["dose"]["scale"] / 65535
    expected = np.interp(grid.features["eps"], (eps.min(), eps.max()), (500.0, 2000.0))
    np.testing.assert_allclose(dose[grid.mask], expected[grid.mask], rtol=1e-4)
    mask_dose = np.array([e["dose_mj_cm2"] for e in manifest["exposures"]])[index]
    half_level = (expected[grid.mask].max() - expected[grid.mask].min()) / 4 / 2
    assert np.abs(mask_dose - expected)[grid.mask].max() <= half_level * (1 + 1e-9)
    preview = Image.open(folder / "preview.png")
    assert preview.mode == "RGB" and max(preview.size) >= 400
    assert manifest["files"]["scan"] is None and not (folder / "scan.gcode").exists()


@pytest.mark.slow
def test_image_rows_go_down_and_angles_go_counter_clockwise(tmp_path):
    theta = np.zeros((4, 3))
    theta[:2] = np.radians(30)  # top rows = largest y
    theta[2:] = np.radians(120)
    grid = DirectorGrid(theta, np.ones((4, 3)), {}, 0.5, (1.0, 2.0))
    x, y = grid.centres()
    assert x.tolist() == [1.25, 1.75, 2.25] and y.tolist() == [3.75, 3.25, 2.75, 2.25]
    summary = write_laser(
        grid,
        tmp_path / "p",
        load_machine("dmd_photoalign"),
        LaserSettings(bins=6),
        offset_mm=(10.0, 20.0),
    )
    angle = _read(tmp_path / "p" / "angle.png").astype(float) * 180 / 65536
    np.testing.assert_allclose(angle[0], 30, atol=1e-2)
    np.testing.assert_allclose(angle[-1], 120, atol=1e-2)
    assert summary.origin_mm == (11.0, 22.0)


@pytest.mark.slow
@pytest.mark.parametrize(("relation", "offset"), [("perpendicular", 90.0), ("parallel", 0.0)])
def test_polariser_and_half_wave_plate_follow_the_relation(tmp_path, relation, offset):
    grid = _baromorph_grid(pitch=1.0)
    settings = LaserSettings(
        bins=12, relation=relation, input_polarisation_deg=20.0, ignore=("eps",)
    )
    summary = write_laser(grid, tmp_path / "b", load_machine("dmd_photoalign"), settings)
    for exposure in summary.manifest["exposures"]:
        polariser = exposure["polariser_deg"]
        assert _wrap_deg(polariser - exposure["director_deg"] - offset) == pytest.approx(0)
        output = 2 * exposure["half_wave_plate_deg"] - 20.0
        assert _wrap_deg(output - polariser) == pytest.approx(0, abs=1e-9)
    assert summary.exposures == 12  # one dose: a mask per angle bin


def test_the_profiles_light_table_and_dose_calibration_apply(tmp_path):
    text = Path(load_machine("dmd_photoalign").path).read_text()
    path = tmp_path / "parallel.toml"
    path.write_text(text.replace('relation = "perpendicular"', 'relation = "parallel"'))
    machine = load_machine(path)
    settings = LaserSettings.for_machine(machine)
    assert settings.relation == "parallel" and settings.intensity_mw_cm2 == 10
    table = settings.process.encodes[0].table
    assert table.parameter == "dose_mj_cm2"
    assert table.encode(np.array(table.eps))[0] == pytest.approx(table.value)
    assert LaserSettings.for_machine(machine, relation="perpendicular").relation == "perpendicular"


@pytest.mark.slow
def test_baromorph_scan_lines_cover_every_pixel_once(tmp_path):
    machine = load_machine("scan_photoalign")
    grid = _baromorph_grid()
    settings = LaserSettings.for_machine(
        machine,
        process=_dose((0.0, 0.5), (400.0, 1600.0)),
        dose_levels=4,
        scan_speed_mm_s=5.0,
        max_power_mw=50.0,
    )
    summary = write_laser(grid, tmp_path / "baro", machine, settings, image_format="tiff")
    folder = tmp_path / "baro"
    manifest = json.loads((folder / "manifest.json").read_text())
    jsonschema.validate(manifest, SCHEMA)
    assert manifest["files"]["angle_map"] == "angle.tif" and (folder / "angle.tif").is_file()
    index = _check_masks(folder, manifest, grid)

    run = replay((folder / "scan.gcode").read_text())
    for k, axis in enumerate("xy"):
        lo, hi = machine.envelope.axis(axis)
        assert lo <= np.nanmin(run.position[:, k]) and np.nanmax(run.position[:, k]) <= hi
    body = (folder / "scan.gcode").read_text().splitlines()
    lines = [
        ln for ln in body if (" A" in ln and ln[:2] == "G0") or (" S" in ln and ln[:2] == "G1")
    ]
    words = [dict((w[0], float(w[1:])) for w in ln.split()[1:]) for ln in lines]
    origin, pitch = np.array(manifest["origin_mm"]), grid.pixel_mm
    covered = np.zeros(grid.shape, dtype=int)
    plate = [e["half_wave_plate_deg"] for e in manifest["exposures"]]
    dose = [e["dose_mj_cm2"] for e in manifest["exposures"]]
    for travel, scan in zip(words[0::2], words[1::2], strict=True):
        row = int(round(grid.shape[0] - 0.5 - (travel["Y"] - origin[1]) / pitch))
        a, b = sorted((travel["X"], scan["X"]))
        cols = slice(int(round((a - origin[0]) / pitch)), int(round((b - origin[0]) / pitch)))
        covered[row, cols] += 1
        (exposure,) = np.unique(index[row, cols])
        assert travel["A"] == pytest.approx(plate[exposure], abs=1e-3)
        assert scan["S"] == pytest.approx(dose[exposure] * pitch * 5.0 / 100, abs=1e-3)
        assert scan["F"] == 300.0
    assert (covered == grid.mask).all()
    assert summary.scan_lines > len(words)
    assert summary.max_binning_error_deg <= 5.0
    job = check_job(read_job(folder / "scan.gcode"), machine)  # what fabkit send checks
    assert job.moves == len(lines) + 1  # and the end G-code's G0 X0 Y0


def test_scan_power_above_the_limit_is_refused(tmp_path):
    machine = load_machine("scan_photoalign")
    settings = LaserSettings.for_machine(machine, max_power_mw=0.01)
    with pytest.raises(FabkitError, match="scan power .* above the limit 0.01 mW"):
        write_laser(_baromorph_grid(1.0), tmp_path / "out", machine, settings)
    assert not (tmp_path / "out").exists()


def test_refusals_leave_nothing_behind(tmp_path):
    machine = load_machine("dmd_photoalign")  # 50 x 50 mm
    big = _baromorph_grid(1.0)
    with pytest.raises(FabkitError, match="outside the envelope of dmd_photoalign"):
        write_laser(big, tmp_path / "out", machine, offset_mm=(30.0, 0.0))
    assert not (tmp_path / "out").exists() and not list(tmp_path.iterdir())
    calibrated = LaserSettings(process=_dose((0.0, 0.2), (100.0, 200.0)))
    with pytest.raises(FabkitError, match=r"outside the calibrated range \[0, 0.2\] of dose"):
        write_laser(big, tmp_path / "out", machine, calibrated)
    with pytest.raises(FabkitError, match="laser patterns need a laser_writer profile"):
        write_laser(big, tmp_path / "out", load_machine("marlin_generic"))
    taken = tmp_path / "taken"
    taken.mkdir()
    (taken / "notes.txt").write_text("mine")
    with pytest.raises(FabkitError, match="not written by fabkit"):
        write_laser(big, taken, machine)
    assert (taken / "notes.txt").read_text() == "mine"


@pytest.mark.slow
def test_rewriting_a_pattern_directory_replaces_it(tmp_path):
    machine = load_machine("dmd_photoalign")
    write_laser(
        _baromorph_grid(1.0), tmp_path / "out", machine, LaserSettings(bins=12, ignore=("eps",))
    )
    write_laser(
        _baromorph_grid(1.0), tmp_path / "out", machine, LaserSettings(bins=4, ignore=("eps",))
    )
    assert len(list((tmp_path / "out" / "masks").iterdir())) == 4
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


def test_grid_and_settings_validation():
    with pytest.raises(FabkitError, match="same shape|one shape"):
        DirectorGrid(np.zeros((2, 2)), np.ones((3, 2)), {}, 0.1)
    with pytest.raises(FabkitError, match="selects no pixel"):
        DirectorGrid(np.zeros((2, 2)), np.zeros((2, 2)), {}, 0.1)
    with pytest.raises(FabkitError, match="pixel pitch"):
        DirectorGrid(np.zeros((2, 2)), np.ones((2, 2)), {}, 0.0)
    with pytest.raises(FabkitError, match="eps must have the shape"):
        DirectorGrid(np.zeros((2, 2)), np.ones((2, 2)), {"eps": np.zeros(3)}, 0.1)
    with pytest.raises(FabkitError, match="relation"):
        LaserSettings(relation="diagonal")


@pytest.mark.parametrize("bins", [1, 2, 7, 18, 90])
def test_binning_error_is_at_most_half_a_bin(bins):
    rng = np.random.default_rng(bins)
    theta = rng.uniform(-4, 4, (30, 40))
    binning = bin_angles(DirectorGrid(theta, np.ones(theta.shape), {}, 0.1), bins)
    assert binning.max_error <= math.pi / (2 * bins) + 1e-12
    assert set(np.unique(binning.label)) <= set(range(bins))
