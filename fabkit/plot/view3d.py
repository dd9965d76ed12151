"""report.html's 3D view: each target and the sheet under its stimulus, to turn and zoom.

One plotly figure (plotly.js is embedded once in the page, :mod:`fabkit.plot.html`; the
page still loads nothing from elsewhere): per target, the target as a grey surface and the
sheet as a surface coloured by its distance to the target (mm), in mm with equal scales on
every axis, the colours on each target's own scale; one target is shown at a time, a
button per target switches (the first is shown first). The data are the verdict's meshes,
as the pictures and the PLY files have them (:class:`~fabkit.plot.page.Shape3D`).
"""

from __future__ import annotations

import json

import numpy as np
import plotly.graph_objects as go

from fabkit.mechanics.verdict import Verdict
from fabkit.plot.page import Shape3D, View3D

COLOURS = "Viridis"
"""The colour scale of the distance (the pictures' viridis)."""
HEIGHT_PX = 640


def shapes_3d(verdict: Verdict) -> tuple[Shape3D, ...]:
    """The shapes of ``verdict`` that have a mesh (the worst start's), titled with the
    verdict's words."""
    out = []
    for shape in verdict.shapes:
        if shape.mesh is None:
            continue
        words = f"formed: {shape.target}" if shape.formed else f"NOT formed: {shape.miss()}"
        title = f"{words}; the sheet {verdict.what} (the worst start), coloured by its distance"
        mesh = shape.mesh
        out.append(
            Shape3D(
                shape.target, mesh.target_mm, mesh.vertices_mm, mesh.triangles,
                mesh.distance_mm, title,
            )
        )  # fmt: skip
    return tuple(out)


def view_html(view: View3D, element_id: str) -> str:
    """The view as an HTML fragment (a ``div`` with ``element_id`` and its script;
    plotly.js itself not included)."""
    figure = go.Figure()
    for k, shape in enumerate(view.shapes):
        top = float(np.max(shape.distance_mm)) or 1.0  # its own scale: a sphere's 0.5 mm
        i, j, m = (shape.triangles[:, c] for c in range(3))
        figure.add_trace(_mesh(shape.target_mm, i, j, m, k == 0, name=f"{shape.name}: target"))
        figure.add_trace(
            _mesh(shape.sheet_mm, i, j, m, k == 0, name=f"{shape.name}: the sheet", top=top,
                  distance=shape.distance_mm)
        )  # fmt: skip
    buttons = [
        {
            "label": shape.name,
            "method": "update",
            "args": [
                {"visible": [n // 2 == k for n in range(2 * len(view.shapes))]},
                {"title.text": shape.title},
            ],
        }
        for k, shape in enumerate(view.shapes)
    ]
    figure.update_layout(
        title={"text": view.shapes[0].title, "font": {"size": 14}},
        height=HEIGHT_PX,
        margin={"l": 0, "r": 0, "t": 70, "b": 0},
        scene={
            "aspectmode": "data",
            **{f"{axis}axis": {"title": {"text": f"{axis} (mm)"}} for axis in "xyz"},
        },
        updatemenus=[{"buttons": buttons, "direction": "right", "type": "buttons", "x": 0,
                      "xanchor": "left", "y": 1.0, "yanchor": "bottom"}],
        showlegend=False,
    )  # fmt: skip
    data = json.dumps(figure.to_plotly_json(), separators=(",", ":"))
    return (
        f'<div id="{element_id}" class="view3d" style="height:{HEIGHT_PX}px"></div>\n'
        f"<script>(function () {{ const f = {data};\n"
        f"Plotly.newPlot({json.dumps(element_id)}, f.data, f.layout,"
        " {displaylogo: false, responsive: true}); })();</script>"
    )


def _mesh(
    vertices: np.ndarray,
    i: np.ndarray,
    j: np.ndarray,
    k: np.ndarray,
    visible: bool,
    *,
    name: str,
    top: float = 1.0,
    distance: np.ndarray | None = None,
) -> go.Mesh3d:
    """One surface: grey and half transparent (the target) or coloured by ``distance``
    (mm, 0 to ``top``, the target's own largest: a scale shared with a target 14 mm off
    drew a sphere's sub-mm distances in one colour)."""
    x, y, z = np.round(vertices, 3).T
    common = {"x": x, "y": y, "z": z, "i": i, "j": j, "k": k, "name": name, "visible": visible}
    if distance is None:
        return go.Mesh3d(**common, color="lightgrey", opacity=0.45, hoverinfo="skip")
    return go.Mesh3d(
        **common,
        intensity=np.round(distance, 3),
        colorscale=COLOURS,
        cmin=0.0,
        cmax=top,
        colorbar={"title": {"text": "distance to<br>the target (mm)"}},
        hovertemplate="%{intensity:.2f} mm<extra></extra>",
    )
