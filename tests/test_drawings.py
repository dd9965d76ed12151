"""The drawings fabkit run has its worker make, in memory: the design pictures
(:func:`fabkit.plot.draw_design`) and the toolpath preview
(:func:`fabkit.toolpath.preview.preview_images`)."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import shapely

from fabkit.machines import load_machine
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
