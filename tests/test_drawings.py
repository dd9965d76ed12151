"""The drawings fabkit run has its worker make, in memory: the design pictures
(:func:`fabkit.plot.draw_design`), the toolpath preview
(:func:`fabkit.toolpath.preview.preview_images`) and the shapes the sheet takes
(:func:`fabkit.plot.shapes.shape_pictures`)."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import shapely
from scipy.spatial import Delaunay

from fabkit.machines import load_machine
from fabkit.mechanics.compare import FormedShape
from fabkit.mechanics.verdict import Shape
from fabkit.plot import DESIGN_PICTURES, draw_design
from fabkit.plot.scene import scene
from fabkit.toolpath.preview import preview_images
from tests.conftest import coarse_design
from tests.test_writers_common import baromorph, baromorph_toolpath

PNG = b"\x89PNG\r\n\x1a\n"


def test_every_design_picture_is_drawn_as_png_bytes_from_plain_data():
    shown = scene(coarse_design())
    assert "problem" not in vars(shown.design)  # the worker gets no parsed spec
    pictures = draw_design(shown)
    assert [p.name for p in pictures] == [name for name, _ in DESIGN_PICTURES]
    for picture in pictures:
        assert picture.png.startswith(PNG) and len(picture.png) > 10_000, picture.name


def test_the_toolpath_preview_is_drawn_as_png_and_svg_bytes():
    toolpath = baromorph_toolpath(load_machine("marlin_generic"))
    outline = shapely.Polygon(baromorph().outline.exterior)
    images = preview_images(toolpath, [outline], ("png", "svg"), dpi=50)
    assert images["png"].startswith(PNG)
    assert ET.fromstring(images["svg"]).tag.endswith("svg")


def test_a_shape_picture_per_target_from_plain_arrays():
    """A cap (mm) and a sheet that stayed flatter: one PNG per target, the mirror image's
    too (its title says so)."""
    from fabkit.plot.shapes import shape_pictures

    grid = np.stack(np.meshgrid(*[np.linspace(-10.0, 10.0, 9)] * 2), -1).reshape(-1, 2)
    cap = np.column_stack([grid, 4.0 - (grid**2).sum(axis=1) / 50])
    sheet = cap * [1.0, 1.0, 0.5]
    triangles = Delaunay(grid).simplices
    distance = np.linalg.norm(sheet - cap, axis=1)
    mesh = FormedShape("cap", sheet, cap, triangles, distance, 28.3)
    shapes = tuple(
        Shape("cap", 0.02, 0.05, mirrored, True, 0.03, 1.0, 28.3, mesh)
        for mirrored in (False, True)
    )
    pictures = shape_pictures("as fabricated", shapes)
    assert len(pictures) == 2
    for picture in pictures:
        assert picture.startswith(PNG) and len(picture) > 10_000


def test_a_mirror_image_s_picture_quotes_the_verdict_s_distance_as_the_verdict_writes_it():
    """Drawn as it is, a mirror image is coloured by its distance to the target itself;
    the title quotes the verdict's distance to the mirror image, the same number as the
    verdict's line (one figure, one source)."""
    from fabkit.plot.shapes import sheet_title

    grid = np.stack(np.meshgrid(*[np.linspace(-10.0, 10.0, 5)] * 2), -1).reshape(-1, 2)
    cap = np.column_stack([grid, 4.0 - (grid**2).sum(axis=1) / 50])
    mesh = FormedShape("cap", cap * [1, 1, -1], cap, Delaunay(grid).simplices, cap[:, 2], 46.9)
    for mirrored in (True, False):
        shape = Shape("cap", 0.012532, 0.05, mirrored, True, 0.03, 1.0, 46.9, mesh)
        verdict_mm = shape.line().split("% (")[1].split(" mm)")[0]  # "0.588"
        assert (f"({verdict_mm} mm RMS from it" in sheet_title("as fabricated", shape)) == mirrored
