"""Print lines that follow the director: stripe lines, clipped, trimmed and extended.

:func:`print_lines` turns a :class:`~fabkit.field.flat.FlatField` into polylines (mm) that are
evenly spaced (``spacing``, normally the road width w), follow the director, and fill the
outline:

1. the stripe pattern (:mod:`fabkit.toolpath.stripes`) gives evenly spaced lines whose
   ends sit where the field diverges and a new line must start;
2. lines are resampled to w/4 and clipped to the outline shrunk by ``end_inset * w``
   (default 0.45 w: a road's round end reaches at most 0.05 w past the outline, which
   halves the unfilled corners between neighbouring road ends; 0.5 keeps every road
   strictly inside);
3. lines are *stopped where they come closer than* ``close * w`` to another line: of two
   lines too close, the shorter one is cut (a line also may not run back onto itself), and
   line ends that turn more than ``end_angle`` off the director are cut;
4. line ends are *extended along the director* (RK2, all ends at once) into the gaps that
   open ahead of them, while they stay ``close * w`` away from every other line and inside
   the outline;
5. *new lines are started where gaps remain* (``gap_rounds`` times): seeds wherever a
   point of the shrunk outline is ``close * w`` from every line (one per 2 ``close * w``
   cell, the farthest), grown both ways along the director like the line ends of step 4;
6. *edge lines*: where the outline runs along the director (within ``edge_angle``) and the
   strip along it is still uncovered (``edge_close * w`` from every line, i.e. a sliver
   wider than w/2, where a road fills more than it overlaps), a line follows the shrunk
   outline itself;
7. lines shorter than ``min_length * w`` are dropped.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import shapely
from scipy.spatial import cKDTree

from fabkit.field.flat import FlatField, director_angle
from fabkit.toolpath.stripe_lines import stripe_lines
from fabkit.toolpath.stripes import Spacing, StripePattern, StripeSettings, solve_stripes

PIN_MARGIN = 0.05
"""Lines along the outline are pinned this much (in w) further in than line ends are clipped,
so that clipping never catches them."""


@dataclass(frozen=True)
class LineSettings:
    """How lines are trimmed and extended (lengths as multiples of the road width w).

    ``close``: lines stop where closer than ``close * w`` to another line. ``end_angle_deg``:
    line ends turning more than this off the director are cut. ``extend``: longest
    extension of a line end, in w. ``end_inset``: line ends stay this far inside the
    outline. ``min_length``: shorter lines are dropped. ``sample``: vertex spacing.
    ``gap_rounds``: rounds of starting new lines in the gaps left. ``edge_close`` and
    ``edge_angle_deg``: edge lines (step 6) need this clearance, and an outline within this
    angle of the director.
    """

    close: float = 0.75
    end_angle_deg: float = 25.0
    extend: float = 4.0
    end_inset: float = 0.45
    min_length: float = 1.0
    sample: float = 0.25
    gap_rounds: int = 2
    edge_close: float = 0.55
    edge_angle_deg: float = 15.0
    stripes: StripeSettings = field(default_factory=StripeSettings)


def print_lines(
    flat: FlatField,
    road_width: float,
    spacing: Spacing | None = None,
    settings: LineSettings = LineSettings(),
    phases: tuple[float, ...] = (0.0,),
) -> list[list[np.ndarray]]:
    """Print lines (lists of (n, 2) polylines, mm) of ``flat``, one list per stripe phase.

    ``spacing`` (mm, constant or a function of points) defaults to ``road_width``; a phase
    of pi gives the lines halfway between those of phase 0 (staggered layers).
    """
    spacing = road_width if spacing is None else spacing
    pin_offset = (settings.end_inset + PIN_MARGIN) * road_width
    pattern = solve_stripes(flat, spacing, pin_offset, settings.stripes)
    return [lines_from_pattern(pattern, flat, road_width, settings, phase) for phase in phases]


def lines_from_pattern(
    pattern: StripePattern,
    flat: FlatField,
    road_width: float,
    settings: LineSettings,
    phase: float = 0.0,
) -> list[np.ndarray]:
    """Steps 2 to 5 of the module docstring for the stripe lines of ``pattern``."""
    w = road_width
    step = settings.sample * w
    raw = stripe_lines(pattern, flat.outline, settings.stripes.subdivisions, phase)
    inner = flat.outline.buffer(-settings.end_inset * w)
    if inner.is_empty:
        return []
    lines = [resample(line, step) for line in clip_lines(raw, inner)]
    lines = [line for line in lines if len(line) >= 2]
    lines = trim_lines(lines, flat, settings.close * w, np.radians(settings.end_angle_deg), step)
    lines = extend_lines(lines, flat, inner, settings.close * w, settings.extend * w, step)
    for _ in range(settings.gap_rounds):
        lines = fill_gaps(lines, flat, inner, settings.close * w, step, settings.min_length * w)
    lines += boundary_lines(lines, flat, inner, settings, w)
    return [line for line in lines if polyline_length(line) >= settings.min_length * w]


def turned_lines(
    lines: list[np.ndarray], base: FlatField, own: FlatField, settings: LineSettings, w: float
) -> list[np.ndarray]:
    """``lines``, planned along ``base``'s director, turned to follow ``own``'s: every
    segment turned by the difference of the two directors at its middle (rad), each line
    held at its middle vertex (a closed line closed again by spreading its gap along it),
    then clipped to ``own``'s outline shrunk by ``end_inset * w`` (mm) as print lines are.

    The layers of a layered design differ by a turn of a fraction of a degree: printed
    along lines turned from one set, they share that set's wander from the director (a
    degree or so, which lines planned apart would not share) and differ by the turn.
    """
    if not lines:
        return []
    segments = [np.diff(line, axis=0) for line in lines]
    middles = np.concatenate([line[:-1] + 0.5 * d for line, d in zip(lines, segments, strict=True)])
    turn = director_angle(own.theta(middles) - base.theta(middles))
    cos, sin = np.cos(turn), np.sin(turn)
    out, start = [], 0
    for line, d in zip(lines, segments, strict=True):
        c, s = cos[start : start + len(d)], sin[start : start + len(d)]
        start += len(d)
        step = np.column_stack([c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1]])
        if is_closed(line):
            lengths = np.linalg.norm(d, axis=1)
            step -= np.outer(lengths / lengths.sum(), step.sum(axis=0))
        path = np.vstack([np.zeros(2), np.cumsum(step, axis=0)])
        middle = len(line) // 2
        out.append(path + (line[middle] - path[middle]))
    inner = own.outline.buffer(-settings.end_inset * w)
    return [line for line in clip_lines(out, inner) if len(line) >= 2]


def polyline_length(line: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(line, axis=0), axis=1).sum())


def is_closed(line: np.ndarray) -> bool:
    return len(line) > 3 and bool(np.all(line[0] == line[-1]))


def resample(line: np.ndarray, step: float) -> np.ndarray:
    """The polyline with vertices evenly spaced at about ``step`` (mm), ends kept."""
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(line, axis=0), axis=1))])
    if arc[-1] <= 0:
        return line[:1]
    count = max(int(np.ceil(arc[-1] / step)), 1) + 1
    samples = np.linspace(0.0, arc[-1], count)
    return np.column_stack(
        [np.interp(samples, arc, line[:, 0]), np.interp(samples, arc, line[:, 1])]
    )


def smooth(line: np.ndarray, passes: int) -> np.ndarray:
    """``passes`` rounds of (1/4, 1/2, 1/4) averaging of the vertices; open ends stay put,
    closed loops are smoothed all round."""
    line = line.copy()
    closed = is_closed(line)
    for _ in range(passes):
        if closed:
            ring = line[:-1]
            ring = 0.5 * ring + 0.25 * (np.roll(ring, 1, axis=0) + np.roll(ring, -1, axis=0))
            line = np.vstack([ring, ring[:1]])
        elif len(line) > 2:
            line[1:-1] = 0.5 * line[1:-1] + 0.25 * (line[:-2] + line[2:])
    return line


def clip_lines(lines: list[np.ndarray], region: shapely.Geometry) -> list[np.ndarray]:
    """The parts of ``lines`` inside ``region`` (vectorised shapely intersection)."""
    if not lines:
        return []
    geometries = shapely.linestrings(
        np.concatenate(lines), indices=np.repeat(np.arange(len(lines)), [len(x) for x in lines])
    )
    shapely.prepare(region)
    inside = shapely.contains(region, geometries)
    pieces = [line for line, keep in zip(lines, inside, strict=True) if keep]
    crossing = geometries[~inside & shapely.intersects(region, geometries)]
    parts = shapely.get_parts(shapely.intersection(crossing, region))
    parts = parts[shapely.get_type_id(parts) == shapely.GeometryType.LINESTRING]
    coordinates, index = shapely.get_coordinates(parts, return_index=True)
    if len(coordinates):
        pieces.extend(np.split(coordinates, np.flatnonzero(np.diff(index)) + 1))
    return pieces


def trim_lines(
    lines: list[np.ndarray], flat: FlatField, distance: float, max_angle: float, step: float
) -> list[np.ndarray]:
    """Cut lines where closer than ``distance`` (mm) to another line; the shorter one yields.

    A line also yields to its own far part (more than 3 ``distance`` away along it), and its
    ends are cut back while they turn more than ``max_angle`` (rad) off the director.
    """
    if not lines:
        return []
    counts = np.array([len(x) for x in lines])
    owner = np.repeat(np.arange(len(lines)), counts)
    position = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    points = np.concatenate(lines)
    closed = np.array([is_closed(x) for x in lines])
    rank = np.argsort(np.argsort(counts, kind="stable"), kind="stable")  # longer wins
    first, second = cKDTree(points).query_pairs(distance, output_type="ndarray").T
    mine, theirs = owner[first], owner[second]
    first_yields = (rank[mine] < rank[theirs]) | ((rank[mine] == rank[theirs]) & (mine < theirs))
    along = np.abs(position[second] - position[first]) * step
    length = counts[mine] * step
    along = np.where(closed[mine], np.minimum(along, length - along), along)
    own_far = (mine == theirs) & (along > 3 * distance)
    too_close = np.zeros(len(points), bool)
    too_close[first[(mine != theirs) & first_yields]] = True
    too_close[second[(mine != theirs) & ~first_yields]] = True
    too_close[np.maximum(first, second)[own_far]] = True  # the later part of the same line
    bad_angle = _angle_error(lines, flat) > max_angle
    result = []
    for index, line in enumerate(lines):
        start, stop = np.cumsum(counts)[index] - counts[index], np.cumsum(counts)[index]
        cut = too_close[start:stop].copy()
        if not closed[index]:
            cut |= _end_runs(bad_angle[start:stop])
        result.extend(_kept_runs(line, cut, bool(closed[index])))
    return result


def _angle_error(lines: list[np.ndarray], flat: FlatField) -> np.ndarray:
    """Per vertex, the larger |angle| (rad) between its two segments and the director."""
    errors = []
    for line in lines:
        segment = np.diff(line, axis=0)
        middle = line[:-1] + 0.5 * segment
        tangent = np.arctan2(segment[:, 1], segment[:, 0])
        error = np.abs(director_angle(tangent - flat.theta(middle)))
        errors.append(
            np.maximum(np.concatenate([error[:1], error]), np.concatenate([error, error[-1:]]))
        )
    return np.concatenate(errors)


def _end_runs(flag: np.ndarray) -> np.ndarray:
    """Only the runs of ``flag`` touching either end of the array."""
    out = np.zeros_like(flag)
    head = np.argmin(flag) if not flag.all() else len(flag)
    tail = np.argmin(flag[::-1]) if not flag.all() else len(flag)
    out[:head] = True
    out[len(flag) - tail :] = True
    return out


def _kept_runs(line: np.ndarray, cut: np.ndarray, closed: bool) -> list[np.ndarray]:
    """The runs of vertices not cut (at least 2 vertices); a closed line stays closed if
    nothing is cut, else is opened at a cut vertex."""
    if closed:
        if not cut.any():
            return [line]
        shift = int(np.argmax(cut))
        line = np.vstack([line[shift:-1], line[: shift + 1]])
        cut = np.concatenate([cut[shift:-1], cut[: shift + 1]])
    edges = np.flatnonzero(np.diff(np.concatenate([[1], cut.astype(int), [1]])))
    return [line[a:b] for a, b in zip(edges[::2], edges[1::2], strict=True) if b - a >= 2]


def extend_lines(
    lines: list[np.ndarray],
    flat: FlatField,
    region: shapely.Geometry,
    distance: float,
    max_length: float,
    step: float,
) -> list[np.ndarray]:
    """Grow open line ends along the director while they stay ``distance`` (mm) from other
    lines (and from each other's growth) and inside ``region``; at most ``max_length``."""
    open_lines = [i for i, line in enumerate(lines) if not is_closed(line)]
    if not open_lines:
        return lines
    counts = np.array([len(x) for x in lines])
    owner = np.repeat(np.arange(len(lines)), counts)
    tree = cKDTree(np.concatenate(lines))
    heads, directions, line_of, at_end = [], [], [], []
    for i in open_lines:
        for end, (tip, before) in enumerate(
            ((lines[i][0], lines[i][1]), (lines[i][-1], lines[i][-2]))
        ):
            heads.append(tip)
            directions.append(tip - before)
            line_of.append(i)
            at_end.append(end)
    head = np.array(heads)
    direction = np.array(directions)
    direction /= np.maximum(np.linalg.norm(direction, axis=1), 1e-12)[:, None]
    line_of = np.array(line_of)
    active = np.ones(len(head), bool)
    grown: list[list[np.ndarray]] = [[] for _ in range(len(head))]
    grown_points, grown_owner = np.zeros((0, 2)), np.zeros(0, int)
    shapely.prepare(region)
    for _ in range(int(max_length / step)):
        moving = np.flatnonzero(active)
        if len(moving) == 0:
            break
        first = _aligned(flat.director(head[moving]), direction[moving])
        second = _aligned(flat.director(head[moving] + 0.5 * step * first), first)
        target = head[moving] + step * second
        blocked = ~shapely.contains_xy(region, target[:, 0], target[:, 1])
        blocked |= (second * direction[moving]).sum(axis=1) < np.cos(np.radians(30))
        blocked |= _near_others(tree, owner, target, line_of[moving], distance)
        if len(grown_points):
            blocked |= _near_others(cKDTree(grown_points), grown_owner, target, moving, distance)
        blocked |= _near_each_other(target, distance)
        go = moving[~blocked]
        for index, point in zip(go, target[~blocked], strict=True):
            grown[index].append(point)
        head[go], direction[go] = target[~blocked], second[~blocked]
        grown_points = np.vstack([grown_points, target[~blocked]])
        grown_owner = np.concatenate([grown_owner, go])
        active[moving[blocked]] = False
    result = list(lines)
    for k, i in enumerate(line_of):
        if not grown[k]:
            continue
        extra = np.array(grown[k])
        line = result[i]
        result[i] = np.vstack([extra[::-1], line]) if at_end[k] == 0 else np.vstack([line, extra])
    return result


def fill_gaps(
    lines: list[np.ndarray],
    flat: FlatField,
    region: shapely.Geometry,
    distance: float,
    step: float,
    min_length: float,
) -> list[np.ndarray]:
    """Start new lines in ``region`` wherever a point is ``distance`` (mm) from every line."""
    low_x, low_y, high_x, high_y = region.bounds
    spacing = 0.75 * distance
    xs = np.arange(low_x + spacing / 2, high_x, spacing)
    ys = np.arange(low_y + spacing / 2, high_y, spacing)
    grid = np.stack(np.meshgrid(xs, ys, indexing="ij"), axis=-1).reshape(-1, 2)
    shapely.prepare(region)
    grid = grid[shapely.contains_xy(region, grid[:, 0], grid[:, 1])]
    if lines:  # only points farther than ``distance`` matter: bounded queries are quick
        tree = cKDTree(np.concatenate(lines))
        grid = grid[~np.isfinite(tree.query(grid, distance_upper_bound=distance)[0])]
        clearance = tree.query(grid)[0]
    else:
        clearance = np.ones(len(grid))
    if len(grid) == 0:
        return lines
    cell = np.floor((grid - [low_x, low_y]) / (2 * distance)).astype(np.int64)
    key = cell[:, 0] * (cell[:, 1].max() + 1) + cell[:, 1]
    order = np.lexsort((-clearance, key))
    first = order[np.concatenate([[True], np.diff(key[order]) != 0])]
    seeds = grid[first]
    direction = flat.director(seeds) * (0.5 * step)
    starts = [np.vstack([p - d, p + d]) for p, d in zip(seeds, direction, strict=True)]
    longest = 2 * float(np.hypot(high_x - low_x, high_y - low_y))
    grown = extend_lines(lines + starts, flat, region, distance, longest, step)
    new = [line for line in grown[len(lines) :] if polyline_length(line) >= min_length]
    if not new:
        return lines
    angle = np.radians(90.0)  # the stripe lines' ends were cut already; only resolve clashes
    return trim_lines(lines + new, flat, distance, angle, step)


def boundary_lines(
    lines: list[np.ndarray],
    flat: FlatField,
    region: shapely.Geometry,
    settings: LineSettings,
    road_width: float,
) -> list[np.ndarray]:
    """Pieces of ``region``'s boundary that run along the director through uncovered strips."""
    step = settings.sample * road_width
    rings = [resample(np.asarray(ring.coords), step) for ring in _rings(region)]
    rings = [ring for ring in rings if len(ring) > 3]
    if not rings or not lines:
        return []
    tree = cKDTree(np.concatenate(lines))
    found = []
    for ring in rings:
        tangent = np.roll(ring[:-1], -1, axis=0) - np.roll(ring[:-1], 1, axis=0)
        tangent /= np.maximum(np.linalg.norm(tangent, axis=1), 1e-12)[:, None]
        along = np.abs((flat.director(ring[:-1]) * tangent).sum(axis=1))
        clear = tree.query(ring[:-1])[0] >= settings.edge_close * road_width
        keep = (along >= np.cos(np.radians(settings.edge_angle_deg))) & clear
        closed = np.vstack([ring[:-1], ring[:1]])
        found.extend(_kept_runs(closed, ~np.append(keep, keep[0]), True))
    return [line for line in found if polyline_length(line) >= settings.min_length * road_width]


def _rings(region: shapely.Geometry) -> list[shapely.LinearRing]:
    rings = []
    for polygon in shapely.get_parts(region):
        rings.append(polygon.exterior)
        rings.extend(polygon.interiors)
    return rings


def _aligned(vectors: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """``vectors`` with their sign flipped where they point against ``reference``."""
    flip = (vectors * reference).sum(axis=1) < 0
    return np.where(flip[:, None], -vectors, vectors)


def _near_others(
    tree: cKDTree, owner: np.ndarray, points: np.ndarray, mine: np.ndarray, distance: float
) -> np.ndarray:
    """Whether each point is within ``distance`` of a tree point owned by someone else."""
    neighbours = min(16, tree.n)
    gap, index = tree.query(points, k=neighbours, distance_upper_bound=distance)
    found = np.isfinite(gap)
    index = np.where(found, index, 0)
    return (found & (owner[index] != mine[:, None])).any(axis=1)


def _near_each_other(points: np.ndarray, distance: float) -> np.ndarray:
    """Whether each point is within ``distance`` of another of ``points``."""
    if len(points) < 2:
        return np.zeros(len(points), bool)
    pairs = cKDTree(points).query_pairs(distance, output_type="ndarray")
    near = np.zeros(len(points), bool)
    near[pairs.ravel()] = True
    return near
