"""``fabkit export``: every format for the Fig. 1 example and a baromorph from the command
line, and one-line errors (exit 2, nothing written) for bad requests."""

from __future__ import annotations

import json

import ezdxf
import numpy as np
import pytest
import shapely
import shapely.affinity

from fabkit.field.design_field import field_from_design
from fabkit.field.part import SIZE_TOLERANCE, PartOptions
from fabkit.machines import load_machine
from fabkit.toolpath import load_toolpath, save_toolpath
from tests.test_writers_common import (
    baromorph,
    baromorph_toolpath,
    fig1_design_path,
    fig1_toolpath,
    model_volume,
    replay,
)


@pytest.fixture
def toolpaths(tmp_path):
    fig1 = tmp_path / "fig1.npz"
    save_toolpath(fig1_toolpath(load_machine("marlin_generic")), fig1)
    plate = tmp_path / "baromorph.json"
    save_toolpath(baromorph_toolpath(load_machine("grbl_diw")), plate)
    return fig1, plate


def test_gcode_for_both_examples(run_cli, tmp_path, toolpaths):
    fig1, plate = toolpaths
    code, out, err = run_cli(
        "export",
        fig1,
        "--machine",
        "marlin_generic",
        "--format",
        "gcode",
        "-o",
        tmp_path / "fig1.gcode",
        "--e-mode",
        "relative",
    )
    assert code == 0 and err == "" and "wrote" in out and "E relative, in filament units" in out
    run = replay((tmp_path / "fig1.gcode").read_text())
    volume = run.e_step.sum() * 3.141592653589793 * 1.75**2 / 4
    assert volume == pytest.approx(
        model_volume(fig1_toolpath(load_machine("marlin_generic"))), rel=5e-3
    )
    code, out, _ = run_cli(
        "export",
        plate,
        "--machine",
        "grbl_diw",
        "--format",
        "gcode",
        "-o",
        tmp_path / "plate.gcode",
        "--offset",
        "150,150",
    )
    assert code == 0 and "offset 150.00,150.00,0.00 mm" in out
    assert "M8" in (tmp_path / "plate.gcode").read_text().splitlines()


def test_dxf_for_both_examples(run_cli, tmp_path, toolpaths):
    fig1, plate = toolpaths
    code, out, _ = run_cli(
        "export",
        fig1_design_path(),
        "--machine",
        "laser_cutter",
        "--format",
        "dxf",
        "-o",
        tmp_path / "sheet.dxf",
        "--size",
        "40",
    )
    assert code == 0 and "OUTLINE 1" in out
    doc = ezdxf.readfile(tmp_path / "sheet.dxf")
    (outline,) = doc.modelspace().query("LWPOLYLINE[layer=='OUTLINE']")
    # the outline is the design's part, cut as export cuts it (40 mm its longest side)
    process = load_machine("laser_cutter").process
    options = PartOptions(road_width_mm=process.road_width_mm, thickness_mm=process.layer_height_mm)
    part = field_from_design(fig1_design_path(), 40.0, None, options)
    assert 40.0 * (1 - SIZE_TOLERANCE) <= max(part.part.extent()) <= 40.0
    drawn = shapely.Polygon(outline.get_points("xy"))  # placed on the machine's bed
    low = np.subtract(part.outline.bounds[:2], drawn.bounds[:2])
    drawn = shapely.affinity.translate(drawn, *low)
    assert drawn.symmetric_difference(part.outline).area <= 1e-3 * part.outline.area

    shapes = baromorph()
    geometry = tmp_path / "plate.geojson"
    features = [
        {
            "type": "Feature",
            "properties": {"layer": layer},
            "geometry": shapely.geometry.mapping(getattr(shapes, layer)),
        }
        for layer in ("outline", "channels", "inlet")
    ]
    geometry.write_text(json.dumps({"type": "FeatureCollection", "features": features}))
    code, out, _ = run_cli(
        "export",
        plate,
        "--machine",
        "laser_cutter",
        "--format",
        "dxf",
        "-o",
        tmp_path / "plate.dxf",
        "--geometry",
        geometry,
    )
    assert code == 0
    doc = ezdxf.readfile(tmp_path / "plate.dxf")
    assert len(doc.audit().errors) == 0
    counts = {
        layer: len(doc.modelspace().query(f"*[layer=='{layer}']"))
        for layer in ("PATHS", "TRAVEL", "CHANNELS", "OUTLINE", "INLET")
    }
    assert counts == {"PATHS": 4, "TRAVEL": 2, "CHANNELS": 1, "OUTLINE": 1, "INLET": 1}


@pytest.mark.slow
def test_laser_for_both_examples(run_cli, tmp_path):
    code, out, _ = run_cli(
        "export",
        fig1_design_path(),
        "--machine",
        "dmd_photoalign",
        "--format",
        "laser",
        "-o",
        tmp_path / "fig1",
        "--size",
        "5",
        "--pixel",
        "0.025",
        "--bins",
        "12",
    )
    assert code == 0 and "binning error max" in out
    manifest = json.loads((tmp_path / "fig1" / "manifest.json").read_text())
    assert manifest["bins"] == 12 and manifest["pixel_pitch_mm"] == 0.025
    director = tmp_path / "plate.toml"
    director.write_text('[director]\ntheta = "phi + pi/2"\nshape = "disc:20"\n')
    code, out, _ = run_cli(
        "export",
        director,
        "--machine",
        "dmd_photoalign",
        "--format",
        "laser",
        "-o",
        tmp_path / "plate",
        "--pixel",
        "0.5",
        "--relation",
        "parallel",
        "--dose",
        "800",
    )
    assert code == 0
    manifest = json.loads((tmp_path / "plate" / "manifest.json").read_text())
    assert manifest["director_relation"] == "parallel"
    assert {e["dose_mj_cm2"] for e in manifest["exposures"]} == {800.0}


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["DESIGN", "--format", "gcode"], "G-code is written from a toolpath"),
        (["FIG1", "--format", "laser"], "laser patterns are written from a director field"),
        (["DESIGN", "--format", "laser"], "give its size"),
        (["FIG1", "--format", "gcode", "--machine", "no_such_machine"], "unknown machine"),
        (["FIG1", "--format", "gcode", "--offset", "215,215"], "outside the envelope"),
        (["MISSING", "--format", "gcode"], "does not exist"),
        (["FIG1", "--format", "dxf", "--geometry", "MISSING"], "does not exist"),
    ],
)
def test_bad_requests_are_one_line_errors(run_cli, tmp_path, toolpaths, args, message):
    names = {"DESIGN": fig1_design_path(), "FIG1": toolpaths[0], "MISSING": tmp_path / "x.npz"}
    args = [str(names.get(a, a)) for a in args]
    if "--machine" not in args:
        args += ["--machine", "marlin_generic"]
    out = tmp_path / "out.file"
    code, stdout, err = run_cli("export", *args, "-o", out)
    assert code == 2 and stdout == ""
    assert err.startswith("fabkit: error: ") and message in err and err.count("\n") == 1
    assert not out.exists()


@pytest.mark.slow
@pytest.mark.parametrize(
    ("source", "machine"),
    [
        (["DESIGN", "--size", "20", "--clip-eps", "--layers", "2"], "marlin_generic"),
        (["--director", "phi + pi/2", "--shape", "disc:10"], "grbl_diw"),
    ],
)
def test_fabkit_toolpath_output_exports_to_gcode_and_dxf(run_cli, tmp_path, source, machine):
    """The real pipeline: ``fabkit toolpath`` (Fig. 1, and a disc with the director along
    baromorph-like circular channels), then ``fabkit export``."""
    args = [str(fig1_design_path()) if a == "DESIGN" else a for a in source]
    code, _, err = run_cli("toolpath", *args, "--machine", machine, "--out", tmp_path / "tp")
    assert code == 0, err
    toolpath_file = tmp_path / "tp" / "toolpath.npz"
    code, _, err = run_cli(
        "export",
        toolpath_file,
        "--machine",
        machine,
        "--format",
        "gcode",
        "-o",
        tmp_path / "job.gcode",
    )
    assert code == 0, err
    profile = load_machine(machine)
    flow_on = profile.gcode.flow_on_gcode.strip()
    run = replay((tmp_path / "job.gcode").read_text(), flow_on, profile.gcode.flow_off_gcode)
    for k, axis in enumerate("xyz"):
        lo, hi = profile.envelope.axis(axis)
        column = run.position[:, k][~np.isnan(run.position[:, k])]
        assert lo <= column.min() and column.max() <= hi
    toolpath = load_toolpath(toolpath_file)
    length = np.nan_to_num(np.linalg.norm(run.step, axis=1))
    if flow_on:
        laid = length[run.flowing & (run.code == "G1")].sum()
        assert laid == pytest.approx(toolpath.print_length_mm, rel=5e-3)
    else:
        volume = run.e_step.sum() * np.pi * 1.75**2 / 4
        assert volume == pytest.approx(model_volume(toolpath), rel=5e-3)
    code, _, err = run_cli(
        "export", toolpath_file, "--machine", machine, "--format", "dxf", "-o", tmp_path / "job.dxf"
    )
    assert code == 0, err
    doc = ezdxf.readfile(tmp_path / "job.dxf")
    assert len(doc.audit().errors) == 0
    prints = sum(1 for _, m in toolpath.moves() if m.kind == "print")
    assert len(doc.modelspace().query("*[layer=='PATHS']")) == prints
