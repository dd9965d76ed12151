"""A casting mould for baromorph channels: a plate with ribs, as a watertight STL.

Polarity: the mould is the *negative* of the cast part. Its ribs (raised,
``channel_depth_mm`` high) are the part's channels; the rim around the outline
(``part_thickness_mm`` high) holds the cast. Pour elastomer into the tray up to the rim,
cure, demould: the part's lower face carries the channels as open grooves. Bond a flat
skin over that face to close them (the inlet groove reaches the part's edge, where a
tube goes in).

Layers, from z = 0 (mm): the plate (the outline grown by ``border_mm``, ``plate_mm``
thick); on it the rim (plate outline minus the sheet outline) and the ribs (the channel
network inside the outline). Solids are built and joined with manifold3d, so the mesh
is closed and manifold by construction; the result is checked with trimesh.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import manifold3d
import numpy as np
import shapely

from fabkit.errors import FabkitError
from fabkit.files.atomic import atomic_path
from fabkit.toolpath.baromorph import BaromorphSettings, ChannelLayout

if TYPE_CHECKING:  # trimesh (and networkx under it) loads in 0.2 s: only a baromorph needs it
    import trimesh

POLARITY = (
    "mould = negative of the part: ribs are the channels, the rim holds the cast; the cast "
    "part's lower face carries the channels as grooves, closed by bonding a flat skin"
)
SIMPLIFY_MM = 0.005
"""Outlines are simplified to this tolerance (mm) so that no two mesh vertices nearly
coincide (which would break the mesh when an STL reader merges close vertices)."""


def mould_mesh(layout: ChannelLayout, settings: BaromorphSettings) -> trimesh.Trimesh:
    """The mould of ``layout`` (mm, z up, cavity open at the top)."""
    import trimesh

    plate_outline = layout.outline.buffer(settings.border_mm).simplify(SIMPLIFY_MM)
    ribs = layout.network.intersection(layout.outline).simplify(SIMPLIFY_MM)
    rim = plate_outline.difference(layout.outline).simplify(SIMPLIFY_MM)
    solids = [
        _extrude(plate_outline, 0.0, settings.plate_mm),
        _extrude(rim, settings.plate_mm - 1e-3, settings.part_thickness_mm + 1e-3),
        _extrude(ribs, settings.plate_mm - 1e-3, settings.channel_depth_mm + 1e-3),
    ]
    solid = manifold3d.Manifold.batch_boolean(solids, manifold3d.OpType.Add)
    mesh = solid.to_mesh()
    result = trimesh.Trimesh(
        vertices=np.asarray(mesh.vert_properties)[:, :3],
        faces=np.asarray(mesh.tri_verts),
        process=True,
    )
    if not result.is_watertight:
        raise FabkitError("the mould mesh is not watertight (degenerate channel geometry?)")
    return result


def save_mould(mesh: trimesh.Trimesh, path: str | Path) -> None:
    """Write the mould as binary STL, atomically."""
    with atomic_path(path) as tmp:
        mesh.export(tmp, file_type="stl")


def _extrude(region: shapely.Geometry, z0: float, height: float) -> manifold3d.Manifold:
    """The polygons of ``region`` extruded from ``z0`` by ``height`` (mm)."""
    contours = []
    for polygon in shapely.get_parts(region):
        if isinstance(polygon, shapely.Polygon) and polygon.area > 0:
            rings = [polygon.exterior, *polygon.interiors]
            contours.extend(np.asarray(ring.coords)[:-1] for ring in rings)
    section = manifold3d.CrossSection(contours, manifold3d.FillRule.EvenOdd)
    return section.extrude(height).translate((0.0, 0.0, z0))
