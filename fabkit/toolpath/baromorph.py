"""Baromorph channels: channels along the director, separated by walls, fed by one inlet.

A baromorph sheet inflates along its channels; the local expansion set by eps is
programmed by the channel width (at a fixed pitch). :func:`layout_channels` lays out:

* **channels**: centrelines along the director ``pitch_mm`` apart (the stripe lines of
  :mod:`fabkit.toolpath.lines`), each a closed polygon whose width at every point is the
  calibrated width for the local eps (``[baromorph.calibration]``, monotone PCHIP, the
  same rules as the print encoding). Where two channels (or a channel and the manifold)
  would leave a wall thinner than ``min_wall_mm``, the lower-priority (shorter) channel
  is cut back;
* **manifold**: a ring channel ``manifold_width_mm`` wide, ``min_wall_mm`` inside the
  outline, into which the channel ends run; an inlet channel from the inlet point to the
  ring; and straight connectors from any channel group still isolated (closed loops,
  channels ending at defects on both ends) to the nearest part of the network;
* **walls**: the rest of the sheet.

:func:`check_channels` measures what matters: every polygon valid, the network in one
piece with the inlet, the thinnest wall between pieces that do not touch, and each
channel's width (cut perpendicular to its centreline) against the calibration.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import shapely
from scipy.spatial import cKDTree

from fabkit.calibration import CHANNEL_WIDTH, Calibration
from fabkit.errors import FabkitError
from fabkit.field.flat import FlatField
from fabkit.files.shipped import user_or_example
from fabkit.files.tomlfile import Table, read_toml
from fabkit.limits import MAGNITUDE
from fabkit.toolpath.lines import (
    LineSettings,
    is_closed,
    polyline_length,
    print_lines,
    resample,
    smooth,
)

CHANNEL_PARAMETER = CHANNEL_WIDTH
LENGTH_KEYS = (
    "pitch_mm",
    "min_wall_mm",
    "manifold_width_mm",
    "channel_depth_mm",
    "part_thickness_mm",
    "plate_mm",
    "border_mm",
)


@dataclass(frozen=True)
class BaromorphSettings:
    """Channel layout and mould settings (mm); ``calibration`` maps eps to channel width."""

    pitch_mm: float
    min_wall_mm: float
    manifold_width_mm: float
    inlet: tuple[float, float]
    calibration: Calibration
    channel_depth_mm: float = 1.0
    part_thickness_mm: float = 2.0
    plate_mm: float = 3.0
    border_mm: float = 4.0


@dataclass(frozen=True, eq=False)
class ChannelLayout:
    """The channel network on the flat sheet (mm).

    ``channels`` one polygon per channel, with its ``centrelines`` (n, 2), per-vertex
    ``widths`` and ``eps`` (n,); ``manifold`` the ring, inlet and connectors; ``network``
    the union of everything (one polygon); ``outline`` the sheet.
    """

    channels: tuple[shapely.Polygon, ...]
    centrelines: tuple[np.ndarray, ...]
    widths: tuple[np.ndarray, ...]
    eps: tuple[np.ndarray, ...]
    manifold: shapely.Geometry
    network: shapely.Geometry
    outline: shapely.Geometry
    inlet: tuple[float, float]


@dataclass(frozen=True)
class ChannelReport:
    """Checks of a layout: counts, validity, connectivity, thinnest wall, width errors."""

    channels: int
    valid: bool
    connected: bool
    min_wall_mm: float
    max_width_error: float
    mean_width_error: float
    width_samples: int

    def summary(self) -> str:
        return (
            f"channels {self.channels}  valid {self.valid}  connected {self.connected}  "
            f"thinnest wall {self.min_wall_mm:.3f} mm  width error max "
            f"{100 * self.max_width_error:.2f} % mean {100 * self.mean_width_error:.2f} % "
            f"({self.width_samples} cuts)"
        )


def load_baromorph(path: str | Path) -> BaromorphSettings:
    """Read the ``[baromorph]`` table of a TOML file (see ``docs/toolpath.md``); errors
    name the file and the key path (:mod:`fabkit.files.tomlfile`)."""
    path = user_or_example(path)
    top = Table(read_toml(path, "baromorph"), str(path))
    return _settings(top.table("baromorph"))


def _settings(t: Table) -> BaromorphSettings:
    t.check_keys({*LENGTH_KEYS, "inlet", "calibration"})
    t.require(("pitch_mm", "min_wall_mm", "manifold_width_mm"), "a positive length (mm)")
    t.require(("inlet",), "[x, y] in mm")
    t.require(("calibration",), "a table [baromorph.calibration]")
    lengths = {
        key: t.number(key, positive=True, bound=MAGNITUDE) for key in LENGTH_KEYS if key in t
    }
    x, y = t.numbers("inlet", length=2, bound=MAGNITUDE)
    calibration = _channel_calibration(t.table("calibration"))
    settings = BaromorphSettings(inlet=(x, y), calibration=calibration, **lengths)
    if settings.part_thickness_mm <= settings.channel_depth_mm:
        t.expected(
            "part_thickness_mm",
            f"more than channel_depth_mm = {settings.channel_depth_mm:g}",
            t.get("part_thickness_mm", settings.part_thickness_mm),
        )
    return settings


def _channel_calibration(t: Table) -> Calibration:
    t.check_keys({"parameter", "eps", "value", "clip"})
    t.text("parameter", (CHANNEL_PARAMETER,), default=CHANNEL_PARAMETER)
    t.require(("eps",), "an array of numbers")
    t.require(("value",), "an array of channel widths (mm)")
    clip = t.flag("clip", default=False)
    eps, value = (t.numbers(key, bound=MAGNITUDE) for key in ("eps", "value"))
    try:
        return Calibration(CHANNEL_PARAMETER, eps, value, clip)
    except FabkitError as exc:
        t.fail(str(exc))


# --------------------------------------------------------------------------- layout


def layout_channels(flat: FlatField, settings: BaromorphSettings) -> ChannelLayout:
    """Channels, manifold and inlet for ``flat`` (which must carry eps)."""
    if not flat.has_eps:
        raise FabkitError(f"{flat.source}: baromorph channels need an eps field")
    wall, manifold_width, pitch = (
        settings.min_wall_mm,
        settings.manifold_width_mm,
        settings.pitch_mm,
    )
    _check_pitch(flat, settings)
    ring_outer = flat.outline.buffer(-wall)
    ring_inner = flat.outline.buffer(-(wall + manifold_width))
    if ring_inner.is_empty:
        raise FabkitError("the sheet is too narrow for the manifold ring and its walls")
    ring = ring_outer.difference(ring_inner)
    inset = (wall + manifold_width / 2) / pitch
    line_settings = LineSettings(end_inset=inset, min_length=1.0)
    (lines,) = print_lines(flat, pitch, pitch, line_settings)
    step = 0.25 * float(min(settings.calibration.value))
    passes = int(np.ceil((0.5 * pitch / step) ** 2))  # smooths kinks over about pitch / 2
    lines = [smooth(resample(line, step), passes) for line in lines]
    widths = [_widths(flat, line, settings.calibration) for line in lines]
    lines, widths = _keep_walls(lines, widths, ring_inner, wall, step, pitch)
    eps = [flat.eps(line) for line in lines]
    channels = [_sausage(line, width) for line, width in zip(lines, widths, strict=True)]
    inlet = _inlet_channel(flat.outline, settings)
    network, bridges = _connect(shapely.union_all([ring, inlet, *channels]), flat.outline, settings)
    manifold = shapely.GeometryCollection([ring, inlet, *bridges])
    return ChannelLayout(
        channels=tuple(channels),
        centrelines=tuple(lines),
        widths=tuple(widths),
        eps=tuple(eps),
        manifold=manifold,
        network=network,
        outline=flat.outline,
        inlet=settings.inlet,
    )


def _check_pitch(flat: FlatField, settings: BaromorphSettings) -> None:
    """Refuse a pitch that cannot leave ``min_wall_mm`` between the widest channels."""
    low_x, low_y, high_x, high_y = flat.outline.bounds
    xs = np.linspace(low_x, high_x, 64)
    ys = np.linspace(low_y, high_y, 64)
    grid = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    grid = grid[shapely.contains_xy(flat.outline, grid[:, 0], grid[:, 1])]
    if len(grid) == 0:
        return
    widest = float(settings.calibration.encode(flat.eps(grid))[0].max())
    if settings.pitch_mm - widest < settings.min_wall_mm:
        raise FabkitError(
            f"[baromorph] pitch_mm {settings.pitch_mm:g} leaves walls of "
            f"{settings.pitch_mm - widest:.3g} mm between channels {widest:.3g} mm wide, "
            f"below min_wall_mm {settings.min_wall_mm:g}: increase pitch_mm"
        )


def _widths(flat: FlatField, line: np.ndarray, calibration: Calibration) -> np.ndarray:
    return calibration.encode(flat.eps(line))[0]


def _keep_walls(
    lines: list[np.ndarray],
    widths: list[np.ndarray],
    interior: shapely.Geometry,
    wall: float,
    step: float,
    pitch: float,
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Cut channels back where a wall would be thinner than ``wall`` (shorter one yields)."""
    counts = np.array([len(x) for x in lines])
    owner = np.repeat(np.arange(len(lines)), counts)
    position = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    points, width = np.concatenate(lines), np.concatenate(widths)
    rank = np.argsort(np.argsort(counts, kind="stable"), kind="stable")
    first, second = cKDTree(points).query_pairs(width.max() + wall, output_type="ndarray").T
    gap = np.linalg.norm(points[first] - points[second], axis=1)
    needed = 0.5 * (width[first] + width[second]) + wall
    mine, theirs = owner[first], owner[second]
    along = np.abs(position[first] - position[second]) * step
    closed = np.array([is_closed(line) for line in lines])
    loop = counts[mine] * step
    along = np.where(closed[mine], np.minimum(along, loop - along), along)
    far = along > 2 * needed
    thin = (gap < needed) & ((mine != theirs) | far)
    first_yields = (rank[mine] < rank[theirs]) | ((rank[mine] == rank[theirs]) & (mine < theirs))
    cut = np.zeros(len(points), bool)
    cut[first[thin & first_yields]] = True
    cut[second[thin & ~first_yields]] = True
    # a wall to the manifold ring: the channel either runs into the ring close by, or
    # keeps ``wall`` from it
    edge = shapely.distance(interior.boundary, shapely.points(points)) - 0.5 * width
    inside = shapely.contains_xy(interior, points[:, 0], points[:, 1])
    enters = _arc_to_nearest(~inside, owner, position, step) <= 2 * (wall + width)
    cut |= inside & (edge > 0) & (edge < wall) & ~enters
    kept_lines, kept_widths = [], []
    starts = np.cumsum(counts) - counts
    reach = int(np.ceil((width.max() + wall) / step))  # the two ends of a cut stay apart
    for index, (line, line_width) in enumerate(zip(lines, widths, strict=True)):
        flags = cut[starts[index] : starts[index] + counts[index]]
        if flags.any():
            flags = np.convolve(flags, np.ones(2 * reach + 1), mode="same") > 0
        if is_closed(line) and not flags.any():
            kept_lines.append(line)
            kept_widths.append(line_width)
            continue
        edges = np.flatnonzero(np.diff(np.concatenate([[1], flags.astype(int), [1]])))
        for a, b in zip(edges[::2], edges[1::2], strict=True):
            if b - a >= 2 and polyline_length(line[a:b]) >= pitch:
                kept_lines.append(line[a:b])
                kept_widths.append(line_width[a:b])
    return kept_lines, kept_widths


def _arc_to_nearest(
    flag: np.ndarray, owner: np.ndarray, position: np.ndarray, step: float
) -> np.ndarray:
    """Per vertex, the distance along its line (mm) to the nearest flagged vertex of that
    line (infinite if none)."""
    key = owner * (len(owner) + 1) + position  # increasing along each line
    flagged = key[flag]
    after = np.searchsorted(flagged, key)
    result = np.full(len(key), np.inf)
    for candidate in (after, after - 1):
        ok = (candidate >= 0) & (candidate < len(flagged))
        index = np.where(ok, candidate, 0)
        same = ok & (owner[flag][index] == owner) if len(flagged) else ok
        gap = np.abs(flagged[index] - key) * step if len(flagged) else np.inf
        result = np.where(same, np.minimum(result, gap), result)
    return result


def _sausage(line: np.ndarray, width: np.ndarray) -> shapely.Polygon:
    """The region within width/2 of the centreline, width varying along it (mm)."""
    discs = shapely.buffer(shapely.points(line), 0.5 * width, quad_segs=16)
    direction = np.diff(line, axis=0)
    direction /= np.maximum(np.linalg.norm(direction, axis=1), 1e-12)[:, None]
    normal = np.column_stack([-direction[:, 1], direction[:, 0]])
    half_a, half_b = 0.5 * width[:-1, None], 0.5 * width[1:, None]
    quads = np.stack(
        [
            line[:-1] + normal * half_a,
            line[1:] + normal * half_b,
            line[1:] - normal * half_b,
            line[:-1] - normal * half_a,
        ],
        axis=1,
    )
    shape = shapely.union_all(np.concatenate([discs, shapely.polygons(quads)]))
    return shapely.make_valid(shape) if not shape.is_valid else shape


def _inlet_channel(outline: shapely.Geometry, settings: BaromorphSettings) -> shapely.Geometry:
    """From the inlet point to the manifold ring's centreline, manifold width."""
    centre = outline.buffer(-(settings.min_wall_mm + settings.manifold_width_mm / 2)).boundary
    inlet = shapely.Point(settings.inlet)
    path = shapely.shortest_line(inlet, centre)
    return path.buffer(settings.manifold_width_mm / 2, quad_segs=16)


def _connect(
    network: shapely.Geometry, outline: shapely.Geometry, settings: BaromorphSettings
) -> tuple[shapely.Polygon, list[shapely.Geometry]]:
    """Join every isolated part of the network to the part holding the inlet, by straight
    connectors (shortest lines, manifold width); returns the network and the connectors."""
    inlet = shapely.Point(settings.inlet)
    interior = outline.buffer(-settings.min_wall_mm)
    bridges = []
    while True:
        parts = shapely.get_parts(network)
        if len(parts) == 1:
            return parts[0], bridges
        main = int(np.argmin(shapely.distance(parts, inlet)))
        gaps = shapely.distance(parts, parts[main])
        gaps[main] = np.inf
        nearest = int(np.argmin(gaps))
        link = shapely.shortest_line(parts[nearest], parts[main])
        bridge = link.buffer(settings.manifold_width_mm / 2, quad_segs=16).intersection(interior)
        joined = shapely.union_all([network, bridge])
        if len(shapely.get_parts(joined)) >= len(parts):
            raise FabkitError("cannot connect every channel to the inlet inside the outline")
        network = joined
        bridges.append(bridge)


# --------------------------------------------------------------------------- checks


def check_channels(layout: ChannelLayout, settings: BaromorphSettings) -> ChannelReport:
    """Validity, connectivity, thinnest wall and width-against-eps of ``layout``."""
    pieces = [*layout.channels, *shapely.get_parts(layout.manifold)]
    valid = bool(all(shapely.is_valid(p) for p in pieces) and shapely.is_valid(layout.network))
    network_parts = shapely.get_parts(layout.network)
    connected = bool(
        len(network_parts) == 1
        and layout.network.distance(shapely.Point(layout.inlet)) < 1e-9
        and all(layout.network.intersects(c) for c in layout.channels)
    )
    errors = _width_errors(layout, settings)
    return ChannelReport(
        channels=len(layout.channels),
        valid=valid,
        connected=connected,
        min_wall_mm=_thinnest_wall(
            pieces, layout.outline.difference(layout.network), settings.pitch_mm
        ),
        max_width_error=float(errors.max()) if len(errors) else 0.0,
        mean_width_error=float(errors.mean()) if len(errors) else 0.0,
        width_samples=len(errors),
    )


def _thinnest_wall(pieces: list[shapely.Geometry], walls: shapely.Geometry, reach: float) -> float:
    """Smallest gap between two pieces that do not touch, measured across the walls: the
    shortest line between them must run through the wall region (mm; ``reach`` if none)."""
    tree = shapely.STRtree(pieces)
    left, right = tree.query(pieces, predicate="dwithin", distance=reach)
    pairs = left < right
    geometries = np.asarray(pieces, dtype=object)
    left, right = geometries[left[pairs]], geometries[right[pairs]]
    apart = ~shapely.intersects(left, right)
    lines = shapely.shortest_line(left[apart], right[apart])
    middle = shapely.line_interpolate_point(lines, 0.5, normalized=True)
    shapely.prepare(walls)
    across = shapely.contains(walls, middle)
    gaps = shapely.length(lines[across])
    return float(gaps.min()) if len(gaps) else reach


def _width_errors(layout: ChannelLayout, settings: BaromorphSettings) -> np.ndarray:
    """|measured / calibrated - 1| for perpendicular cuts through each channel's middle part.

    Cuts are taken at vertices at least a channel width from the channel's ends, through
    the channel's own polygon; the calibrated width comes from eps at the vertex.
    """
    errors = []
    for line, channel, eps in zip(layout.centrelines, layout.channels, layout.eps, strict=True):
        expected = settings.calibration.encode(eps)[0]
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(line, axis=0), axis=1))])
        margin = float(expected.max())
        middle = np.flatnonzero((arc > margin) & (arc < arc[-1] - margin))[::4]
        middle = middle[(middle > 0) & (middle < len(line) - 1)]
        if len(middle) == 0:
            continue
        tangent = line[middle + 1] - line[middle - 1]
        tangent /= np.linalg.norm(tangent, axis=1)[:, None]
        normal = np.column_stack([-tangent[:, 1], tangent[:, 0]])
        reach = expected[middle, None]
        cuts = shapely.linestrings(
            np.stack([line[middle] - normal * reach, line[middle] + normal * reach], axis=1)
        )
        pieces = shapely.intersection(cuts, channel)
        measured = np.array(
            [
                _piece_through(piece, point)
                for piece, point in zip(pieces, line[middle], strict=True)
            ]
        )
        errors.append(np.abs(measured / expected[middle] - 1))
    return np.concatenate(errors) if errors else np.zeros(0)


def _piece_through(cut: shapely.Geometry, point: np.ndarray) -> float:
    """Length of the part of ``cut`` through ``point``."""
    centre = shapely.Point(point)
    for part in shapely.get_parts(cut):
        if part.distance(centre) < 1e-9:
            return float(part.length)
    return 0.0
