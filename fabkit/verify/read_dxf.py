"""Read a DXF back as a machine that takes drawings would: its roads and their settings.

The ``PATHS`` layer holds one polyline per printed road (or several consecutive ones for
a long road), drawn at the road's constant width, with the process values of every
vertex as extended data of the application ``FABKIT`` (a name, then one real per
vertex): a segment takes the values of the vertex it ends at. Polylines that start where
the previous one ended continue its road. The sheet's placement is read from the
header's custom properties ``fabkit_offset_mm`` and ``fabkit_mm_per_unit`` when the
drawing has them. Nothing of the writer is used.

A baromorph drawing (:func:`read_channels`) is read by its channels instead: their
direction is the director, their width the channel-width channel of the one feature.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import shapely
from scipy import ndimage
from scipy.spatial import cKDTree

from fabkit.errors import FabkitError
from fabkit.files.readfile import check_size
from fabkit.verify.raster import Readback
from fabkit.verify.read_gcode import Placement

APP_ID = "FABKIT"
PATHS = "PATHS"
DXF_BYTES = 256 << 20
"""Largest DXF verify reads."""


def read_dxf(
    path: str | Path, road_width_mm: float
) -> tuple[
    np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray], np.ndarray, Placement
]:
    """Segments of the drawing's roads (drawing frame, mm): start (n, 2), end (n, 2),
    width (n,) (``road_width_mm`` where a polyline has none), road (n,), values name ->
    (n,), the height each is drawn at (n,) (a polyline's elevation, mm: its layer), and
    the placement its header records."""
    document = _document(path)
    path = Path(path)
    parts: list[tuple[np.ndarray, float, dict[str, np.ndarray], float]] = []
    for entity in document.modelspace():
        if entity.dxf.get("layer") != PATHS or entity.dxftype() not in ("LWPOLYLINE", "POLYLINE"):
            continue
        if entity.dxftype() == "LWPOLYLINE":
            points = np.array([(p[0], p[1]) for p in entity.get_points("xy")], dtype=float)
            width = float(entity.dxf.get("const_width", 0.0)) or road_width_mm
            height = float(entity.dxf.get("elevation", 0.0))
        else:
            located = [tuple(v.dxf.location) for v in entity.vertices]
            points = np.array([p[:2] for p in located], dtype=float)
            width = road_width_mm
            height = float(located[0][2]) if located and len(located[0]) > 2 else 0.0
        if len(points) < 2:
            continue
        parts.append((points, width, _channels(entity, len(points), path), height))
    if not parts:
        raise FabkitError(f"{path}: no road on layer {PATHS} (nothing printed)")
    starts, ends, widths, roads, heights, values = [], [], [], [], [], {}
    names = sorted({name for _, _, channels, _ in parts for name in channels})
    road = -1
    last_end = None
    for points, width, channels, height in parts:
        if last_end is None or not np.allclose(points[0], last_end, atol=1e-6):
            road += 1
        last_end = points[-1]
        count = len(points) - 1
        starts.append(points[:-1])
        ends.append(points[1:])
        widths.append(np.full(count, width))
        roads.append(np.full(count, road))
        heights.append(np.full(count, height))
        for name in names:
            values.setdefault(name, []).append(channels.get(name, np.full(count + 1, np.nan))[1:])
    return (
        np.concatenate(starts),
        np.concatenate(ends),
        np.concatenate(widths),
        np.concatenate(roads),
        {name: np.concatenate(parts_) for name, parts_ in values.items()},
        np.concatenate(heights),
        _placement(document, path),
    )


def _document(path: str | Path):
    """The DXF document at ``path`` (at most DXF_BYTES); one-line errors."""
    import ezdxf
    from ezdxf.lldxf.const import DXFError

    check_size(path, "DXF file", DXF_BYTES)
    try:
        return ezdxf.readfile(path)
    except (OSError, DXFError, UnicodeDecodeError, ValueError) as exc:
        raise FabkitError(f"{path}: not a readable DXF ({exc})") from None


def _channels(entity, count: int, path: Path) -> dict[str, np.ndarray]:
    """The per-vertex values of the entity's FABKIT extended data."""
    if not entity.has_xdata(APP_ID):
        return {}
    out: dict[str, list[float]] = {}
    name = None
    for code, value in entity.get_xdata(APP_ID):
        if code == 1000:
            name = str(value)
            out[name] = []
        elif code == 1040 and name is not None:
            out[name].append(float(value))
    for name, values in out.items():
        if len(values) != count:
            raise FabkitError(
                f"{path}: a {PATHS} polyline has {count} vertices but {len(values)} values "
                f"of {name}"
            )
    return {name: np.array(values) for name, values in out.items()}


def _placement(document, path: Path) -> Placement:
    custom = document.header.custom_vars
    offset, scale = None, None
    if custom.has_tag("fabkit_offset_mm"):
        try:
            values = [float(v) for v in custom.get("fabkit_offset_mm").split(",")]
            offset = (values[0], values[1])
        except (ValueError, IndexError):
            offset = None
    if custom.has_tag("fabkit_mm_per_unit"):
        try:
            scale = float(custom.get("fabkit_mm_per_unit"))
        except ValueError:
            scale = None
    if scale is not None and not (math.isfinite(scale) and scale > 0):
        scale = None
    return Placement(offset, scale, f"{path.name} header")


CHANNELS = "CHANNELS"
OUTLINE = "OUTLINE"
MANIFOLD = "MANIFOLD"
WALL_TURN_DEG = 20.0
"""A cut one of whose ends meets a wall turned more than this from the channel's
direction (a channel's round end, two channels merging) is not read: there the cut's
length is not the channel's width."""
NEIGHBOURS = 24
"""Nearest wall points whose direction (as a tensor) gives a channel cell's direction."""
WIDEST_MARGIN = 0.05
"""A cut wider than the widest calibrated channel by more than this share is a junction
(channels merging, a connector, the manifold) and is not read."""


def read_channels(
    path: str | Path, pitch_mm: float, widest_mm: float, band_mm: float
) -> tuple[Readback, Placement]:
    """A baromorph drawing's channels on a grid of a sixth of a pitch (drawing frame, mm).

    The closed polylines of ``CHANNELS`` bound the channels (even-odd: a ring inside a
    ring is a hole, a wall). In every grid cell inside a channel, the channel direction
    is the mean direction (as a tensor) of the nearest walls (:data:`NEIGHBOURS` points
    a quarter cell apart), and the width the length of the cut through the cell
    perpendicular to it, within the channel (exact, from the polygons; a cut wider than
    the widest channel ``widest_mm``, at a junction, is not read).
    Walls take the values of the nearest channel cell within half a ``pitch_mm``; cells
    within ``band_mm`` of the ``OUTLINE`` (the manifold ring along the edge) are not read,
    nor, where the drawing has a ``MANIFOLD`` layer (:mod:`fabkit.writers.dxf`), the
    manifold's ring, inlet channel and connectors, nor a cut that runs into them: they
    are as wide as the manifold, not as a feature asks.
    """

    document = _document(path)
    path = Path(path)
    rings: dict[str, list[shapely.Polygon]] = {CHANNELS: [], OUTLINE: [], MANIFOLD: []}
    for entity in document.modelspace():
        layer = entity.dxf.get("layer")
        if layer in rings and entity.dxftype() == "LWPOLYLINE" and entity.closed:
            points = [(p[0], p[1]) for p in entity.get_points("xy")]
            if len(points) >= 3:
                rings[layer].append(shapely.make_valid(shapely.Polygon(points)))
    if not rings[CHANNELS]:
        raise FabkitError(f"{path}: no closed channel on layer {CHANNELS}")
    network = _even_odd(rings[CHANNELS])
    cell = pitch_mm / 6
    x0, y0, x1, y1 = network.bounds
    low = np.array([x0, y0]) - pitch_mm
    shape = np.ceil((np.array([x1, y1]) + pitch_mm - low) / cell).astype(int)
    if shape.prod() > 4_000_000:
        raise FabkitError(f"{path}: the drawing spans too many cells of {cell:g} mm to read")
    x = low[0] + cell * (np.arange(shape[0]) + 0.5)
    y = low[1] + cell * (np.arange(shape[1]) + 0.5)
    xx, yy = np.meshgrid(x, y, indexing="ij")
    channel = shapely.contains_xy(network, xx, yy)
    manifold = _even_odd(rings[MANIFOLD]) if rings[MANIFOLD] else None
    if manifold is not None:
        channel &= ~shapely.contains_xy(manifold.buffer(cell), xx, yy)
    points = np.column_stack([xx[channel], yy[channel]])
    direction, width = _cuts(network, points, 2 * widest_mm, cell, manifold)
    width[width > widest_mm * (1 + WIDEST_MARGIN)] = np.nan  # a junction, not a channel
    theta = np.full(shape, np.nan)
    widths = np.full(shape, np.nan)
    theta[channel], widths[channel] = direction, width
    read = np.isfinite(widths)
    distance, (near_i, near_j) = ndimage.distance_transform_edt(~read, return_indices=True)
    reach = distance * cell <= pitch_mm / 2
    region = None
    if rings[OUTLINE]:
        region = shapely.contains_xy(_even_odd(rings[OUTLINE]).buffer(-band_mm), xx, yy)
        reach &= region
    readback = Readback(
        origin=(float(low[0]), float(low[1])),
        cell_mm=cell,
        hits=reach.astype(float),
        theta=np.where(reach, theta[near_i, near_j], np.nan),
        values={"channel_width_mm": np.where(reach, widths[near_i, near_j], np.nan)},
        width_mm=pitch_mm,
        region=region,
        notes=(
            "channels: width and direction from cuts across every channel cell; a wall "
            "takes the values of the nearest channel cell within half a pitch; the "
            f"{band_mm:g} mm band along the outline (manifold) is not read",
        ),
    )
    return readback, _placement(document, path)


def _even_odd(polygons: list[shapely.Geometry]) -> shapely.Geometry:
    """The region inside an odd number of ``polygons``."""
    region = polygons[0]
    for polygon in polygons[1:]:
        region = shapely.symmetric_difference(region, polygon)
    return region


def _cuts(
    network: shapely.Geometry,
    points: np.ndarray,
    reach: float,
    step: float,
    manifold: shapely.Geometry | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Channel direction (rad) and width (mm) at points inside the channels: the nearest
    wall's direction, and the length of the cut perpendicular to it through the point
    (NaN where the cut runs into ``manifold``)."""
    boundary = shapely.segmentize(shapely.boundary(network), step / 4)
    lines = shapely.get_parts(boundary)
    vertices, tangents = [], []
    for line in lines:
        coords = np.asarray(line.coords)[:, :2]
        if len(coords) < 2:
            continue
        ahead = np.diff(coords, axis=0)
        vertices.append(coords[:-1])
        tangents.append(ahead)
    vertices, tangents = np.concatenate(vertices), np.concatenate(tangents)
    _, nearest = cKDTree(vertices).query(points, k=min(NEIGHBOURS, len(vertices)))
    doubled = 2 * np.arctan2(tangents[:, 1], tangents[:, 0])[nearest]  # (n, k)
    angle = 0.5 * np.arctan2(np.sin(doubled).sum(axis=1), np.cos(doubled).sum(axis=1))
    normal = np.column_stack([-np.sin(angle), np.cos(angle)])
    cuts = shapely.linestrings(np.stack([points - reach * normal, points + reach * normal], axis=1))
    pieces = shapely.intersection(cuts, network)
    width = np.full(len(points), np.nan)
    probes = shapely.points(points)
    ends = np.full((len(points), 2, 2), np.nan)
    for k, piece in enumerate(pieces):
        for part in shapely.get_parts(piece):
            if shapely.distance(part, probes[k]) < 1e-9:
                if part.length < reach and not (manifold and shapely.intersects(part, manifold)):
                    width[k] = part.length
                    ends[k] = np.asarray(part.coords)[[0, -1], :2]
                break
    cut = np.flatnonzero(np.isfinite(width))
    _, at_end = cKDTree(vertices).query(ends[cut].reshape(-1, 2))
    wall = np.arctan2(tangents[at_end, 1], tangents[at_end, 0]).reshape(-1, 2)
    turned = np.abs(np.sin(wall - angle[cut, None])) > np.sin(np.radians(WALL_TURN_DEG))
    width[cut[turned.any(axis=1)]] = np.nan
    return angle, width
