"""DXF writer: audit-clean drawings whose entities and coordinates match the toolpath and
the sheet geometry, and that LibreCAD opens (when it is installed)."""

from __future__ import annotations

import os
import shutil
import subprocess
from types import SimpleNamespace

import ezdxf
import numpy as np
import pytest
import shapely

from fabkit.errors import FabkitError
from fabkit.machines import load_machine
from fabkit.toolpath import PRINT, TRAVEL, Layer, Move, Toolpath
from fabkit.writers.dxf import LAYERS, dxf_document, layout_layers, write_dxf
from tests.test_writers_common import baromorph, baromorph_toolpath, fig1_toolpath


def _by_layer(doc: ezdxf.document.Drawing) -> dict[str, list]:
    out: dict[str, list] = {name: [] for name in LAYERS}
    for entity in doc.modelspace():
        out[entity.dxf.layer].append(entity)
    return out


def _assert_moves_match(entities: list, moves: list[Move], shift: np.ndarray) -> None:
    assert len(entities) == len(moves)
    for entity, move in zip(entities, moves, strict=True):
        assert entity.dxftype() == "LWPOLYLINE" and not entity.closed
        points = np.array(entity.get_points("xy"))
        np.testing.assert_allclose(points, move.xyz[:, :2] + shift[:2], atol=1e-9)
        assert entity.dxf.elevation == pytest.approx(move.xyz[0, 2] + shift[2])


def test_fig1_toolpath_reads_back_with_matching_entities(tmp_path):
    machine = load_machine("marlin_generic")
    toolpath = fig1_toolpath(machine)
    out = tmp_path / "fig1.dxf"
    summary = write_dxf(out, toolpath, machine=machine)
    doc = ezdxf.readfile(out)
    assert len(doc.audit().errors) == 0
    assert doc.units == ezdxf.units.MM and doc.header["$INSUNITS"] == 4
    assert {layer.dxf.name for layer in doc.layers} >= set(LAYERS)
    layers = _by_layer(doc)
    moves = [m for _, m in toolpath.moves()]
    shift = np.array(summary.offset_mm)
    _assert_moves_match(layers["PATHS"], [m for m in moves if m.kind == PRINT], shift)
    _assert_moves_match(layers["TRAVEL"], [m for m in moves if m.kind == TRAVEL], shift)
    assert summary.entities["PATHS"] == len(layers["PATHS"])
    centre = np.mean([machine.envelope.x_mm, machine.envelope.y_mm], axis=1)
    low, high = toolpath.bounds()
    np.testing.assert_allclose((low[:2] + high[:2]) / 2 + shift[:2], centre)


def test_baromorph_channels_outline_and_inlet(tmp_path):
    plate = baromorph()
    toolpath = baromorph_toolpath(load_machine("marlin_diw_pneumatic"))
    out = tmp_path / "baromorph.dxf"
    summary = write_dxf(
        out,
        toolpath,
        outline=plate.outline,
        channels=plate.channels,
        inlet=plate.inlet,
        inlet_radius_mm=0.6,
    )
    doc = ezdxf.readfile(out)
    assert len(doc.audit().errors) == 0
    layers = _by_layer(doc)
    (channel,) = layers["CHANNELS"]
    assert channel.dxftype() == "LWPOLYLINE" and channel.closed
    ring = np.asarray(plate.channels.exterior.coords)[:-1]
    np.testing.assert_allclose(np.array(channel.get_points("xy")), ring, atol=1e-9)
    (outline,) = layers["OUTLINE"]
    assert outline.closed
    assert shapely.Polygon(outline.get_points("xy")).area == pytest.approx(plate.outline.area)
    (inlet,) = layers["INLET"]
    assert inlet.dxftype() == "CIRCLE" and inlet.dxf.radius == 0.6
    assert (inlet.dxf.center.x, inlet.dxf.center.y) == (plate.inlet.x, plate.inlet.y)
    assert summary.entities == {
        "PATHS": 4, "TRAVEL": 2, "CHANNELS": 1, "OUTLINE": 1, "INLET": 1, "MANIFOLD": 0
    }  # fmt: skip


def test_polygons_with_holes_lists_and_lines():
    square = shapely.box(0, 0, 10, 10).difference(shapely.box(4, 4, 6, 6))
    lines = [shapely.LineString([(0, 0), (5, 5)]), shapely.LinearRing([(1, 1), (2, 1), (2, 2)])]
    doc, summary = dxf_document(channels=[square, *lines], inlet=shapely.box(1, 1, 2, 2))
    layers = _by_layer(doc)
    closed = [e.closed for e in layers["CHANNELS"]]
    assert closed == [True, True, False, True]  # exterior, hole, open line, ring
    assert summary.entities["INLET"] == 1 and layers["INLET"][0].closed


def test_non_planar_moves_become_3d_polylines():
    xyz = np.array([[0, 0, 0.2], [5, 0, 0.4], [10, 0, 0.6]])
    move = Move(PRINT, xyz, 0.4, 10.0, 1.0)
    doc, _ = dxf_document(Toolpath((Layer(0.2, 0.2, (move,)),)))
    (entity,) = _by_layer(doc)["PATHS"]
    assert entity.dxftype() == "POLYLINE" and entity.is_3d_polyline
    np.testing.assert_allclose([v.dxf.location for v in entity.vertices], xyz)


def test_refusals(tmp_path):
    with pytest.raises(FabkitError, match="nothing to draw"):
        dxf_document()
    with pytest.raises(FabkitError, match="points are only allowed for the inlet"):
        dxf_document(outline=shapely.Point(0, 0))
    with pytest.raises(FabkitError, match="expected shapely geometry"):
        dxf_document(channels=[[(0, 0), (1, 1)]])
    out = tmp_path / "big.dxf"
    big = shapely.Point(0, 0).buffer(300)
    with pytest.raises(FabkitError, match="outside the envelope of laser_cutter"):
        write_dxf(out, outline=big, machine=load_machine("laser_cutter"))
    assert not out.exists()


@pytest.mark.skipif(shutil.which("librecad") is None, reason="LibreCAD is not installed")
def test_librecad_opens_and_prints_the_drawing(tmp_path):
    plate = baromorph()
    toolpath = baromorph_toolpath(load_machine("marlin_generic"))
    dxf = tmp_path / "baromorph.dxf"
    write_dxf(dxf, toolpath, outline=plate.outline, channels=plate.channels, inlet=plate.inlet)
    pdf = tmp_path / "baromorph.pdf"
    env = {**os.environ, "QT_QPA_PLATFORM": "offscreen", "XDG_RUNTIME_DIR": str(tmp_path)}
    result = subprocess.run(
        ["librecad", "dxf2pdf", "-a", "-o", str(pdf), str(dxf)],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    output = result.stdout + result.stderr
    assert result.returncode == 0 and "ERROR" not in output, output
    assert pdf.read_bytes().startswith(b"%PDF") and pdf.stat().st_size > 5000


def test_channel_layout_gives_the_four_sheet_layers():
    plate = baromorph()
    ring = shapely.Point(0, 0).buffer(19.0).difference(shapely.Point(0, 0).buffer(18.0))
    inlet_channel = shapely.box(18.5, -0.5, 21.0, 0.5)  # overlaps the ring
    layout = SimpleNamespace(
        outline=plate.outline,
        network=plate.channels.union(ring).union(inlet_channel),
        manifold=shapely.GeometryCollection([ring, inlet_channel]),
        inlet=(2.0, 0.0),
    )
    doc, summary = dxf_document(**layout_layers(layout))
    assert summary.entities["OUTLINE"] == 1 and summary.entities["INLET"] == 1
    rings = 1 + len(layout.network.interiors)
    assert summary.entities["CHANNELS"] == rings
    assert all(e.closed for e in _by_layer(doc)["CHANNELS"])
    # the manifold as one region (the overlap does not cancel in even-odd), never plotted
    manifold = [shapely.Polygon(e.get_points("xy")) for e in _by_layer(doc)["MANIFOLD"]]
    region = manifold[0]
    for polygon in manifold[1:]:
        region = region.symmetric_difference(polygon)
    assert region.area == pytest.approx(ring.union(inlet_channel).area, rel=1e-6)
    assert doc.layers.get("MANIFOLD").dxf.plot == 0 and doc.layers.get("CHANNELS").dxf.plot == 1
