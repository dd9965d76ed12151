"""DXF writer: toolpaths and sheet geometry as a drawing for CAD, cutters and plotters.

One DXF (R2010, units mm) with five layers:

========= ====== =============================================================
layer     colour content
========= ====== =============================================================
PATHS     7      every print move, an open LWPOLYLINE at its height (elevation)
TRAVEL    8      every travel move, an open LWPOLYLINE (DASHED)
CHANNELS  1      channel boundaries (baromorphs), closed LWPOLYLINEs
OUTLINE   5      the sheet outline, closed LWPOLYLINEs
INLET     3      inlets: a CIRCLE of ``inlet_radius_mm`` per point, or closed polylines
========= ====== =============================================================

Channels, outline and inlet are plain shapely geometry (polygons, multipolygons, rings,
lines, points, or lists of them), in the sheet frame like the toolpath;
:func:`layout_layers` takes them from a baromorph channel layout. A polygon gives
one closed polyline per ring (holes included). A print move whose height varies (not
planar) is written as a 3-D POLYLINE instead. With a machine, everything is placed as
the G-code would be (centred on the bed unless an offset is given) and checked against
the envelope; without one, coordinates stay in the sheet frame (plus any offset).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import ezdxf
import numpy as np
import shapely
from ezdxf import units
from ezdxf.document import Drawing

from fabkit.atomic import atomic_path
from fabkit.errors import FabkitError
from fabkit.machines import MachineProfile
from fabkit.toolpath.model import PRINT, Toolpath
from fabkit.writers.common import check_inside, placement_offset

LAYERS = {
    "PATHS": (7, "CONTINUOUS"),
    "TRAVEL": (8, "DASHED"),
    "CHANNELS": (1, "CONTINUOUS"),
    "OUTLINE": (5, "CONTINUOUS"),
    "INLET": (3, "CONTINUOUS"),
}
"""Layer name -> (ACI colour, linetype)."""
DEFAULT_INLET_RADIUS_MM = 0.5

Geometry = shapely.Geometry | Iterable[shapely.Geometry] | None
"""Shapely geometry, a list of geometries, or nothing."""


@dataclass(frozen=True)
class DxfSummary:
    """Entities written per layer, and the sheet-to-drawing offset (mm)."""

    entities: dict[str, int]
    offset_mm: tuple[float, float, float]


def write_dxf(
    path: str | Path,
    toolpath: Toolpath | None = None,
    *,
    outline: Geometry = None,
    channels: Geometry = None,
    inlet: Geometry = None,
    machine: MachineProfile | None = None,
    offset_mm: tuple[float, ...] | None = None,
    inlet_radius_mm: float = DEFAULT_INLET_RADIUS_MM,
) -> DxfSummary:
    """Write the drawing at ``path`` atomically (see the module docstring)."""
    doc, summary = dxf_document(
        toolpath,
        outline=outline,
        channels=channels,
        inlet=inlet,
        machine=machine,
        offset_mm=offset_mm,
        inlet_radius_mm=inlet_radius_mm,
    )
    with atomic_path(path) as tmp:
        doc.saveas(tmp)
    return summary


def dxf_document(
    toolpath: Toolpath | None = None,
    *,
    outline: Geometry = None,
    channels: Geometry = None,
    inlet: Geometry = None,
    machine: MachineProfile | None = None,
    offset_mm: tuple[float, ...] | None = None,
    inlet_radius_mm: float = DEFAULT_INLET_RADIUS_MM,
) -> tuple[Drawing, DxfSummary]:
    """The drawing (audited, no errors) and its summary; nothing is written."""
    if not inlet_radius_mm > 0:
        raise FabkitError(f"inlet radius must be > 0 mm, got {inlet_radius_mm}")
    shapes = {
        name: _parts(g, name)
        for name, g in (("OUTLINE", outline), ("CHANNELS", channels), ("INLET", inlet))
    }
    moves = [m for _, m in toolpath.moves()] if toolpath is not None else []
    if not moves and not any(shapes.values()):
        raise FabkitError("nothing to draw: no toolpath moves, outline, channels or inlet")
    shift = _offset(moves, shapes, machine, offset_mm, inlet_radius_mm)
    doc = ezdxf.new("R2010", setup=True)
    doc.units = units.MM
    doc.header["$MEASUREMENT"] = 1
    for name, (colour, linetype) in LAYERS.items():
        doc.layers.add(name, color=colour, linetype=linetype)
    msp = doc.modelspace()
    counts = dict.fromkeys(LAYERS, 0)
    for move in moves:
        layer = "PATHS" if move.kind == PRINT else "TRAVEL"
        xyz = move.xyz + shift
        if np.ptp(xyz[:, 2]) > 1e-9:
            msp.add_polyline3d(xyz.tolist(), dxfattribs={"layer": layer})
        else:
            msp.add_lwpolyline(
                xyz[:, :2].tolist(), dxfattribs={"layer": layer, "elevation": float(xyz[0, 2])}
            )
        counts[layer] += 1
    for layer, parts in shapes.items():
        for part in parts:
            counts[layer] += _add_geometry(msp, part, layer, shift, inlet_radius_mm)
    auditor = doc.audit()
    if auditor.has_errors:
        raise FabkitError(f"DXF audit found {len(auditor.errors)} error(s): {auditor.errors[0]}")
    return doc, DxfSummary(counts, tuple(shift.tolist()))


def layout_layers(layout: Any) -> dict[str, shapely.Geometry]:
    """The ``outline``, ``channels`` and ``inlet`` layers of a baromorph channel layout.

    ``layout`` is anything with ``outline`` (polygon), ``network`` (the union of channels,
    manifold and inlet channel: what a cutter cuts) and ``inlet`` ((x, y) or a point), as
    :class:`fabkit.toolpath.baromorph.ChannelLayout` has; pass the result to
    :func:`write_dxf` as keyword arguments.
    """
    inlet = layout.inlet
    if not isinstance(inlet, shapely.Geometry):
        inlet = shapely.Point(*inlet)
    return {"outline": layout.outline, "channels": layout.network, "inlet": inlet}


def _parts(geometry: Geometry, name: str) -> list[shapely.Geometry]:
    """The single-part, non-empty geometries of ``geometry``."""
    if geometry is None:
        return []
    items = [geometry] if isinstance(geometry, shapely.Geometry) else list(geometry)
    parts: list[shapely.Geometry] = []
    for item in items:
        if not isinstance(item, shapely.Geometry):
            raise FabkitError(
                f"{name.lower()}: expected shapely geometry, got {type(item).__name__}"
            )
        if item.is_empty:
            continue
        if isinstance(
            item,
            shapely.GeometryCollection
            | shapely.MultiPolygon
            | shapely.MultiLineString
            | shapely.MultiPoint,
        ):
            parts += _parts(list(shapely.get_parts(item)), name)
        else:
            parts.append(item)
    return parts


def _offset(
    moves: list[Any],
    shapes: dict[str, list[shapely.Geometry]],
    machine: MachineProfile | None,
    offset_mm: tuple[float, ...] | None,
    radius: float,
) -> np.ndarray:
    """The (3,) sheet-to-drawing offset; with a machine, also the envelope check."""
    points = [m.xyz[:, :2] for m in moves]
    for layer, parts in shapes.items():
        pad = radius if layer == "INLET" else 0.0
        for part in parts:
            x0, y0, x1, y1 = part.bounds
            points.append(np.array([[x0 - pad, y0 - pad], [x1 + pad, y1 + pad]]))
    xy = np.concatenate(points)
    if machine is None:
        return placement_offset(xy.min(axis=0), xy.max(axis=0), None, offset_mm or (0.0, 0.0))
    shift = placement_offset(xy.min(axis=0), xy.max(axis=0), machine, offset_mm)
    check_inside(xy + shift[:2], machine, "DXF drawing")
    if moves:
        check_inside(np.concatenate([m.xyz for m in moves]) + shift, machine, "DXF toolpath")
    return shift


def _add_geometry(
    msp: Any, part: shapely.Geometry, layer: str, shift: np.ndarray, radius: float
) -> int:
    """Add one single-part geometry; returns the number of entities added."""
    attribs = {"layer": layer}
    if isinstance(part, shapely.Point):
        if layer != "INLET":
            raise FabkitError(f"{layer.lower()}: points are only allowed for the inlet")
        centre = (part.x + shift[0], part.y + shift[1])
        msp.add_circle(centre, radius, dxfattribs=attribs)
        return 1
    if isinstance(part, shapely.Polygon):
        rings = [part.exterior, *part.interiors]
        for ring in rings:
            msp.add_lwpolyline(_xy(ring, shift)[:-1], close=True, dxfattribs=attribs)
        return len(rings)
    closed = isinstance(part, shapely.LinearRing)
    points = _xy(part, shift)
    msp.add_lwpolyline(points[:-1] if closed else points, close=closed, dxfattribs=attribs)
    return 1


def _xy(line: shapely.Geometry, shift: np.ndarray) -> list[tuple[float, float]]:
    return [tuple(p) for p in (np.asarray(line.coords)[:, :2] + shift[:2]).tolist()]
