"""fabkit run --layers: the layers program every target's side; the verdict says which forms.

The paper's Fig. 3 sheet, programmed by its metric alone, buckles into the wavy sheet's
mirror image or an isometric neighbour of it, and takes the sphere's and the face's
mirror images from some starts. Two layers programmed with every target's curvature give
every target its side from every start, as designed and as fabricated (read back layer by
layer from the G-code and simulated at the printed thickness), three of the starts on the
sheet with the print's error turned over; every target is formed by each of two prints
(``--prints 2``: the machine file's and one with the lines shifted half their spacing: a
verdict that one print's roads decided would not hold on both; ``--prints 3`` forms them
all too, docs/layers.md), the face since the layers are printed along one set of lines
(their roads wandered apart before, a twist that missed it). The run's last line is that
verdict (tests/test_solve_layers.py: one layer, --strict, solve --layers).
"""

from __future__ import annotations

import contextlib
import io
import json

import numpy as np
import pytest

from fabkit.design.design import Design
from fabkit.machines import load_machine
from fabkit.verify.read_gcode import read_gcode
from tests.conftest import EXAMPLES, validate_report

THREE = EXAMPLES / "three_shapes.toml"


@pytest.fixture(scope="module")
def layered_run(folder, request):
    """The acceptance run: Fig. 3, two layers, the default size and machine, two prints."""
    from fabkit.cli import main

    out = folder / "three_layered"
    said = io.StringIO()
    args = ["run", str(THREE), "--layers", "2", "--prints", "2", "--no-pictures"]
    with contextlib.redirect_stdout(said):
        code = main([*args, "--out", str(out)])
    assert code == 0
    (folder / "three_layered.said.txt").write_text(said.getvalue())  # not in the run
    return out


@pytest.mark.slow
def test_every_target_formed_ends_the_run_without_a_remedy(layered_run):
    """Every target formed by every print: the run's last line says so, and no line before
    the verdict's suggests --refine (tests/test_run_prints.py: a run that misses one)."""
    from fabkit.commands.run import NOT_REFINED

    figures = json.loads((layered_run / "report.json").read_text())
    assert figures["verdict"]["formed"] and not figures["layers"]["refined"]
    lines = (layered_run.parent / "three_layered.said.txt").read_text().splitlines()
    assert lines[-1].startswith("done: the sheet as fabricated forms every target")
    count = len(figures["verdict"]["lines"])  # the verdict's lines end the run, as ever
    assert [line.strip() for line in lines[-count - 1 : -1]] == figures["verdict"]["lines"]
    assert lines[-count - 2].strip() == "the sheet as fabricated:"
    assert NOT_REFINED not in (line.strip() for line in lines)


@pytest.mark.slow
def test_two_layers_form_the_wavy_sheet_as_fabricated_from_every_start_and_print(layered_run):
    figures = json.loads((layered_run / "report.json").read_text())
    verify = figures["verify"]
    wavy = next(t for t in verify["verdict"]["targets"] if t["target"] == "wavy")
    assert wavy["formed"] and wavy["formed_starts"] == 6 and wavy["rms_pct"] < 3.0, wavy
    assert verify["simulation"]["thickness_mm"] == pytest.approx(0.6)  # 2 x 0.3 mm, printed
    for layer in verify["layers"]:  # issue 16's limits, every layer
        assert layer["director_mean_deg"] <= 3.0
        assert all(f["rms_pct"] <= 2.0 for f in layer["features"])
    assert figures["layers"]["weights"] == {"sphere": 1.0, "face": 1.0, "wavy": 1.0}
    assert figures["layers"]["share"] == 1.0  # the whole layering forms Fig. 3 as designed
    assert figures["as designed"]["formed"]
    # every side programmed: no start ends as a mirror image, the print's error turned over
    # or not, as designed and as fabricated; the sphere is formed as fabricated too
    for verdict in (figures["as designed"], verify["verdict"]):
        for target in verdict["targets"]:
            assert not any(s["mirror_image"] for s in target["starts"]), target["line"]
    turned = [s["start"] for s in wavy["starts"] if s["error_turned_over"]]
    assert turned == ["dome-down", "saddle-down", "random-2"]
    sphere = next(t for t in verify["verdict"]["targets"] if t["target"] == "sphere")
    assert sphere["formed"]
    # the layers: as designed, formed from all six, near it (its metric alone misses it,
    # docs/layers.md)
    designed = next(t for t in figures["as designed"]["targets"] if t["target"] == "wavy")
    assert designed["formed"] and designed["formed_starts"] == 6 and designed["rms_pct"] < 1.5
    # the layers keep the design's mean metric at nearly every point (second order)
    assert figures["layers"]["metric_error_p99"] < 0.01
    # a target is formed only when every start formed it, and its figures are the worst's
    for target in verify["verdict"]["targets"]:
        starts = target["starts"]
        assert len(starts) == 6 and target["formed"] == all(s["formed"] for s in starts)
        largest = max(s["rms_pct"] for s in starts)  # of ends in one state, the first
        assert target["rms_pct"] == pytest.approx(largest, abs=1e-4) or not target["formed"]
    # formed by every print: the machine file's and the two with their lines shifted
    prints = figures["prints"]
    assert [p["file"] for p in prints] == ["the machine file", "in memory"]
    combined = {t["target"]: t for t in figures["verdicts"][-1]["targets"]}
    for name in ("sphere", "face", "wavy"):
        assert combined[name]["formed"], combined[name]["line"]
    assert figures["verdict"]["formed"] == all(p["formed"] for p in prints)
    validate_report(figures)


@pytest.mark.slow
def test_the_file_prints_each_layer_with_its_own_features(layered_run):
    design = Design.load(layered_run / "design.npz")
    assert design.layers == 2 and design.layering.thickness > 0
    printed = read_gcode(layered_run / "sheet.gcode", load_machine("marlin_diw_pneumatic"))
    assert printed.layers == 2
    heights = np.round(printed.start[:, 2], 6)
    low, high = np.unique(heights)
    speed = [np.nanmean(printed.feed[heights == z]) for z in (low, high)]
    mix = [np.mean(printed.ink[heights == z]) for z in (low, high)]
    assert speed[0] != speed[1] or mix[0] != mix[1]  # the layers differ, on purpose


@pytest.mark.slow
def test_a_dxf_of_the_layered_toolpath_reads_back_layer_by_layer(layered_run, tmp_path, run_cli):
    # every writer carries the layers: a DXF draws each road at its layer's height
    dxf = tmp_path / "sheet.dxf"
    toolpath = layered_run / "toolpath" / "toolpath.npz"
    code, _, err = run_cli(
        "export", toolpath, "--format", "dxf", "--machine", "marlin_diw_pneumatic", "--out", dxf
    )
    assert code == 0, err
    code, text, err = run_cli("verify", layered_run / "design.npz", dxf, "--no-simulate", "--json")
    assert code == 0, err
    figures = json.loads(text)
    assert [layer["layer"] for layer in figures["layers"]] == [1, 2]
    for layer in figures["layers"]:
        assert layer["director_mean_deg"] <= 3.0
        assert all(f["rms_pct"] <= 2.0 for f in layer["features"])
    # the first figures are the bottom layer's, and the text says so
    assert figures["empty_fraction"] == figures["layers"][0]["empty_fraction"]
    code, text, err = run_cli("verify", layered_run / "design.npz", dxf, "--no-simulate")
    assert code == 0, err
    bottom = (
        f"  coverage (layer 1 of 2, the bottom one): empty {100 * figures['empty_fraction']:.2f} %"
    )
    assert bottom in text and "\n  layer 2: empty" in text


@pytest.mark.slow
def test_the_verdict_as_fabricated_on_a_coarser_simulation_mesh(layered_run, run_cli):
    """The run simulates on about 800 triangles (every second grid line here); on every
    third line every target still ends on its own side from every start and converges,
    and the sphere is formed on both. The wavy sheet's "formed" hangs on the mesh: on the
    coarser one the three starts with the print's error turned over end 3.25 % from it
    (the others 2.43 %; on the run's mesh 2.50 and 1.68 %, docs/layers.md), and the
    verdict names them."""
    figures = json.loads((layered_run / "report.json").read_text())
    default = {t["target"]: t for t in figures["verify"]["verdict"]["targets"]}
    design, gcode = layered_run / "design.npz", layered_run / "sheet.gcode"
    code, text, err = run_cli("verify", design, gcode, "--stride", "3", "--json")
    assert code == 0, err
    coarser = {t["target"]: t for t in json.loads(text)["verdict"]["targets"]}
    for target in coarser.values():
        assert target["converged"] and not any(s["mirror_image"] for s in target["starts"])
    assert coarser["sphere"]["formed"] and default["sphere"]["formed"]
    assert default["wavy"]["formed"]
    wavy = coarser["wavy"]
    missed = [s["start"] for s in wavy["starts"] if s["rms_pct"] > wavy["limit_pct"]]
    verb = "ends" if len(missed) == 1 else "end"
    assert wavy["formed"] or f"{verb} farther than the limit ({', '.join(missed)})" in wavy["line"]


@pytest.mark.slow
def test_the_manifest_lists_every_file_once(layered_run):
    """A layered run writes design.npz twice (solved, then with its layers): its manifest
    (``.fabkit-files``, what --overwrite removes) lists it, like every file, once."""
    listed = (layered_run / ".fabkit-files").read_text().splitlines()
    assert "design.npz" in listed and len(listed) == len(set(listed)), listed
    written = {p.relative_to(layered_run).as_posix() for p in layered_run.rglob("*")}
    assert set(listed) == {name for name in written if (layered_run / name).is_file()} - {
        ".fabkit-files"
    }


@pytest.mark.slow
def test_every_verdict_measures_a_target_against_one_patch_diameter(layered_run):
    """As designed and as fabricated (a mesh of the cells
    that were made), every percentage of one target is a share of one patch diameter:
    the target's patch over the whole part (issue 37: the bump's was 80.1 mm as designed
    and 78.1 mm as fabricated)."""
    figures = json.loads((layered_run / "report.json").read_text())
    verdicts = [
        figures["as designed"],
        figures["verify"]["verdict"],
    ]
    for name in ("sphere", "face", "wavy"):
        diameters = {
            next(t for t in v["targets"] if t["target"] == name)["patch_diameter_mm"]
            for v in verdicts
        }
        assert len(diameters) == 1, (name, diameters)
