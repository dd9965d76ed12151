"""DXF writer: toolpaths and sheet geometry as a drawing for CAD, cutters and plotters.

One DXF (R2010, units mm) with six layers:

========= ====== =============================================================
layer     colour content
========= ====== =============================================================
PATHS     7      every print move, an open LWPOLYLINE at its height (elevation)
TRAVEL    8      every travel move, an open LWPOLYLINE (DASHED)
CHANNELS  1      channel boundaries (baromorphs), closed LWPOLYLINEs
OUTLINE   5      the sheet outline, closed LWPOLYLINEs
INLET     3      inlets: a CIRCLE of ``inlet_radius_mm`` per point, or closed polylines
MANIFOLD  4      a baromorph's manifold ring, inlet channel and connectors (part of the
                 channels), closed LWPOLYLINEs on a layer that is not plotted: a cutter
                 skips it, the read-back (:mod:`fabkit.verify.read_dxf`) reads no width
                 there
========= ====== =============================================================

Every print move's polyline has the road width as its constant width and carries the
toolpath's channels (one per encoded feature: print speed, flow, pressure, temperature,
ink fraction, line spacing) as extended data of the application ``FABKIT``: for each
channel a string with its name (1000) followed by one real (1040) per vertex. Moves of
more than :data:`XDATA_VERTICES` vertices are split into consecutive polylines (sharing
their end vertex), so that no entity's extended data exceeds the 16 kB limit of DXF.
The header's custom properties ``fabkit_offset_mm`` (x,y,z) and ``fabkit_mm_per_unit``
record where the sheet was placed and its scale. Dose channels are refused (the laser
writer exposes them).

Channels, outline, inlet and manifold are plain shapely geometry (polygons, multipolygons, rings,
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
from typing import TYPE_CHECKING, Any

import numpy as np
import shapely

from fabkit.calibration import PRINT_PARAMETERS
from fabkit.errors import FabkitError
from fabkit.files.atomic import atomic_path
from fabkit.machines import MachineProfile
from fabkit.toolpath.model import PRINT, Toolpath
from fabkit.writers.common import check_inside, placement_offset

if TYPE_CHECKING:
    from ezdxf.document import Drawing

LAYERS = {
    "PATHS": (7, "CONTINUOUS"),
    "TRAVEL": (8, "DASHED"),
    "CHANNELS": (1, "CONTINUOUS"),
    "OUTLINE": (5, "CONTINUOUS"),
    "INLET": (3, "CONTINUOUS"),
    "MANIFOLD": (4, "CONTINUOUS"),
}
"""Layer name -> (ACI colour, linetype)."""
NOT_PLOTTED = ("MANIFOLD",)
"""Layers drawn for the record, which a plotter or cutter skips."""
DEFAULT_INLET_RADIUS_MM = 0.5
APP_ID = "FABKIT"
"""The registered application of the channels' extended data."""
XDATA_VERTICES = 400
"""Vertices per polyline at most when channels ride along (16 kB of extended data)."""
DRAWN_CHANNELS = PRINT_PARAMETERS
"""Channels a DXF carries: every print-road parameter (extended data, or the road positions
for the line spacing)."""

Geometry = shapely.Geometry | Iterable[shapely.Geometry] | None
"""Shapely geometry, a list of geometries, or nothing."""


@dataclass(frozen=True)
class DxfSummary:
    """Entities written per layer, and the sheet-to-drawing offset (mm)."""

    entities: dict[str, int]
    offset_mm: tuple[float, float, float]


def write_dxf(path: str | Path, toolpath: Toolpath | None = None, **options: Any) -> DxfSummary:
    """Write the drawing of :func:`dxf_document` (``toolpath`` and its keyword ``options``:
    outline, channels, inlet, machine, ...) at ``path`` atomically (see the module docstring)."""
    doc, summary = dxf_document(toolpath, **options)
    with atomic_path(path) as tmp:
        doc.saveas(tmp)
    return summary


def dxf_document(
    toolpath: Toolpath | None = None,
    *,
    outline: Geometry = None,
    channels: Geometry = None,
    inlet: Geometry = None,
    manifold: Geometry = None,
    machine: MachineProfile | None = None,
    offset_mm: tuple[float, ...] | None = None,
    inlet_radius_mm: float = DEFAULT_INLET_RADIUS_MM,
    mm_per_unit: float | None = None,
) -> tuple[Drawing, DxfSummary]:
    """The drawing (audited, no errors) and its summary; nothing is written.

    ``mm_per_unit`` (the design's scale) is recorded in the header; a toolpath's own
    (its ``meta``) is used when not given.
    """
    if not inlet_radius_mm > 0:
        raise FabkitError(f"inlet radius must be > 0 mm, got {inlet_radius_mm}")
    shapes = {
        name: _parts(g, name)
        for name, g in (
            ("OUTLINE", outline),
            ("CHANNELS", channels),
            ("INLET", inlet),
            ("MANIFOLD", manifold),
        )
    }
    moves = [m for _, m in toolpath.moves()] if toolpath is not None else []
    if not moves and not any(shapes.values()):
        raise FabkitError("nothing to draw: no toolpath moves, outline, channels or inlet")
    channels = tuple(toolpath.channels) if toolpath is not None else ()
    for name in channels:
        if name not in DRAWN_CHANNELS:
            raise FabkitError(
                f"the DXF writer cannot carry the {name} channel ({toolpath.channels[name]}): "
                "it draws roads; a dose is exposed by the laser writer (--format laser)"
            )
    shift = _offset(moves, shapes, machine, offset_mm, inlet_radius_mm)
    import ezdxf  # here, not at the top: a run that writes no DXF does not load it (0.2 s)
    from ezdxf import units

    doc = ezdxf.new("R2010", setup=True)
    doc.units = units.MM
    doc.header["$MEASUREMENT"] = 1
    doc.header.custom_vars.append("fabkit_offset_mm", ",".join(f"{v:.6f}" for v in shift))
    scale = mm_per_unit
    if scale is None and toolpath is not None:
        scale = toolpath.meta.get("mm_per_unit")
    if isinstance(scale, int | float) and not isinstance(scale, bool):
        doc.header.custom_vars.append("fabkit_mm_per_unit", f"{scale:.9g}")
    doc.appids.new(APP_ID)
    for name, (colour, linetype) in LAYERS.items():
        layer = doc.layers.add(name, color=colour, linetype=linetype)
        if name in NOT_PLOTTED:
            layer.dxf.plot = 0
    msp = doc.modelspace()
    counts = dict.fromkeys(LAYERS, 0)
    for move in moves:
        counts["PATHS" if move.kind == PRINT else "TRAVEL"] += _add_move(msp, move, shift, channels)
    for layer, parts in shapes.items():
        for part in parts:
            counts[layer] += _add_geometry(msp, part, layer, shift, inlet_radius_mm)
    auditor = doc.audit()
    if auditor.has_errors:
        raise FabkitError(f"DXF audit found {len(auditor.errors)} error(s): {auditor.errors[0]}")
    return doc, DxfSummary(counts, tuple(shift.tolist()))


def _add_move(msp: Any, move: Any, shift: np.ndarray, channels: tuple[str, ...]) -> int:
    """Draw one move (split so that its channels' extended data stays small); returns
    the number of entities added."""
    layer = "PATHS" if move.kind == PRINT else "TRAVEL"
    xyz = move.xyz + shift
    count = len(xyz)
    step = XDATA_VERTICES - 1 if channels and move.kind == PRINT else count
    added = 0
    for a in range(0, count - 1, step):
        part = slice(a, min(a + step, count - 1) + 1)
        points = xyz[part]
        if np.ptp(points[:, 2]) > 1e-9:
            entity = msp.add_polyline3d(points.tolist(), dxfattribs={"layer": layer})
        else:
            attribs = {"layer": layer, "elevation": float(points[0, 2])}
            if move.kind == PRINT:
                attribs["const_width"] = float(np.max(move.width))
            entity = msp.add_lwpolyline(points[:, :2].tolist(), dxfattribs=attribs)
        if channels and move.kind == PRINT:
            tags = []
            for name in channels:
                tags.append((1000, name))
                tags += [(1040, float(v)) for v in move.channels[name][part]]
            entity.set_xdata(APP_ID, tags)
        added += 1
    return added


def layout_layers(layout: Any) -> dict[str, shapely.Geometry]:
    """The ``outline``, ``channels``, ``inlet`` and ``manifold`` layers of a baromorph
    channel layout.

    ``layout`` is anything with ``outline`` (polygon), ``network`` (the union of channels,
    manifold and inlet channel: what a cutter cuts), ``manifold`` (the ring, inlet channel
    and connectors) and ``inlet`` ((x, y) or a point), as
    :class:`fabkit.toolpath.baromorph.ChannelLayout` has; pass the result to
    :func:`write_dxf` as keyword arguments.
    """
    inlet = layout.inlet
    if not isinstance(inlet, shapely.Geometry):
        inlet = shapely.Point(*inlet)
    return {
        "outline": layout.outline,
        "channels": layout.network,
        "inlet": inlet,
        "manifold": shapely.union_all(layout.manifold),  # one region: no overlap cancels
    }


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
