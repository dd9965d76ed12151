"""A user outline (``--outline``): the same region from a shape, a polygon file or a
drawing, and the part cut to it."""

from __future__ import annotations

import json
import math

import ezdxf
import numpy as np
import pytest
import shapely

from fabkit.field.outlines import read_outline
from fabkit.field.part import PartOptions, print_part, scale_for_size, solved_region
from tests.conftest import coarse_design

SQUARE = [(-5.0, -3.0), (5.0, -3.0), (5.0, 7.0), (-5.0, 7.0)]
"""A 10 mm square, off the origin, in the sheet frame (mm, y up)."""


def _same(region: shapely.Geometry, expected: shapely.Geometry, tolerance: float) -> None:
    assert region.symmetric_difference(expected).area <= tolerance * expected.area


def test_a_square_reads_the_same_from_every_format(tmp_path):
    expected = shapely.Polygon(SQUARE)
    csv = tmp_path / "square.csv"
    csv.write_text("x_mm,y_mm\n" + "".join(f"{x},{y}\n" for x, y in SQUARE))
    geojson = tmp_path / "square.geojson"
    ring = [list(p) for p in [*SQUARE, SQUARE[0]]]
    feature = {"type": "Feature", "geometry": {"type": "Polygon", "coordinates": [ring]}}
    geojson.write_text(json.dumps({"type": "FeatureCollection", "features": [feature]}))
    dxf = tmp_path / "square.dxf"
    drawing = ezdxf.new()
    drawing.modelspace().add_lwpolyline(SQUARE, close=True)
    drawing.saveas(dxf)
    svg = tmp_path / "square.svg"  # SVG's y points down: the reader turns it up
    path = " ".join(f"{'M' if i == 0 else 'L'} {x} {-y}" for i, (x, y) in enumerate(SQUARE))
    svg.write_text(f'<svg xmlns="http://www.w3.org/2000/svg"><path d="{path} z"/></svg>')
    svg_rect = tmp_path / "rect.svg"
    svg_rect.write_text(
        '<svg xmlns="http://www.w3.org/2000/svg"><g transform="translate(-5, -7)">'
        '<rect x="0" y="0" width="10" height="10"/></g></svg>'
    )
    for source in (csv, geojson, dxf, svg, svg_rect):
        _same(read_outline(str(source)), expected, 1e-9)
    _same(read_outline("rect:10,10"), shapely.box(-5, -5, 5, 5), 1e-9)


def test_curves_are_flattened_and_rings_combine_even_odd(tmp_path):
    dxf = tmp_path / "ring.dxf"
    drawing = ezdxf.new()
    drawing.modelspace().add_circle((0, 0), 10)
    drawing.modelspace().add_circle((0, 0), 4)  # inside the first: a hole
    drawing.saveas(dxf)
    region = read_outline(str(dxf))
    assert region.area == pytest.approx(math.pi * (100 - 16), rel=1e-3)
    assert not region.contains(shapely.Point(0, 0)) and region.contains(shapely.Point(7, 0))
    svg = tmp_path / "disc.svg"
    svg.write_text(
        '<svg xmlns="http://www.w3.org/2000/svg">'
        '<path d="M 10 0 A 10 10 0 0 1 -10 0 A 10 10 0 0 1 10 0 z"/></svg>'
    )
    assert read_outline(str(svg)).area == pytest.approx(math.pi * 100, rel=1e-3)


@pytest.fixture(scope="module")
def fig1():
    design = coarse_design()
    solved = solved_region(design)
    return design, solved, scale_for_size(solved, 20.0)


def test_the_part_lies_in_the_user_outline_and_says_so(fig1):
    design, solved, scale = fig1
    whole = print_part(design, scale, PartOptions(road_width_mm=0.4), solved)
    cut = print_part(design, scale, PartOptions(road_width_mm=0.4, outline="disc:4"), solved)
    disc = read_outline("disc:4")
    assert cut.outline_mm().difference(disc).area <= 1e-9 * disc.area
    assert cut.outline_mm().area < whole.outline_mm().area
    steps = dict(cut.removed)
    assert steps["outline"] > 0 and "outline -" in cut.summary()
    assert cut.to_dict()["outline"] == "disc:4"
    # the minimum width applies inside the user's outline too: no sliver along its edge
    road = 0.4
    opened = cut.outline_mm().buffer(-2 * road).buffer(2 * road)
    assert opened.area >= 0.995 * cut.outline_mm().area


def test_the_part_is_in_mm_at_the_sheet_scale(fig1):
    design, solved, scale = fig1
    part = print_part(design, scale, PartOptions(min_width_mm=0.0, trim=0.0), solved)
    low_x, low_y, high_x, high_y = part.solved.bounds
    assert max(high_x - low_x, high_y - low_y) * scale == pytest.approx(20.0)
    assert part.outline_mm().area == pytest.approx(part.outline.area * scale**2)
    assert np.all(part.contains(np.array([part.outline.representative_point().coords[0]])))
    assert [step for step, _ in part.removed] == ["margin"]
