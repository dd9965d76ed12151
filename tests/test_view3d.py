"""report.html's 3D view (fabkit.plot.view3d): the figure it hands to plotly.js."""

from __future__ import annotations

import json
import re

import numpy as np

from fabkit.plot.page import Shape3D, View3D
from fabkit.plot.view3d import view_html


def _shape(name: str, largest_mm: float) -> Shape3D:
    points = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.5]])
    triangles = np.array([[0, 1, 2], [1, 3, 2]])
    distance = np.array([0.0, 0.2, 0.4, 1.0]) * largest_mm
    return Shape3D(name, points, points + 0.1, triangles, distance, f"{name}: title")


def test_each_target_is_coloured_on_its_own_scale():
    # issue 37: one scale for every target drew a sphere's sub-mm distances in one colour
    # beside a target 14 mm off
    view = View3D((_shape("sphere", 0.5), _shape("face", 14.0)), "caption")
    figure = json.loads(re.search(r"const f = (\{.*\});", view_html(view, "v")).group(1))
    sheets = [trace for trace in figure["data"] if "intensity" in trace]
    assert [trace["cmax"] for trace in sheets] == [0.5, 14.0]
    assert [trace["visible"] for trace in sheets] == [True, False]  # one target at a time
