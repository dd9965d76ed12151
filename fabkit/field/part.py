"""The part: the region of a design's flat sheet that is made, one value for every stage.

The solver leaves a union of grid cells (the *solved* region); its image on the flat sheet
has a saw-tooth edge, lone cells and slivers along the initial curves, and arms that are
too narrow for the sheet's thickness to take their shape (``docs/mechanics.md``).
:func:`make_part` cuts the part out of it once, in design units (the flat sheet r[0]),
and every later stage takes that :class:`Part`: the toolpath, channels and laser patterns
(through :func:`fabkit.field.design_field.field_from_design`), the simulations (the mesh's
cells whose centre lies in the part), ``fabkit verify`` and the pictures. The steps, each recorded
with the area it removed:

1. **margin** -- a smooth outline at sub-grid resolution, inside the solved cells. Every
   node of a solved cell gets its *depth*: the distance, in grid steps, to the nearest node
   that is no corner of a solved cell. Interpolated bilinearly inside solved cells only
   (cells with an outside corner are masked) and contoured at :data:`MARGIN_DEPTH`, just
   past sqrt(2), the depth of the staircase's inner corners, it runs through the inner
   corners and cuts the teeth; its vertices lie on cell edges, where r[0] is linear, so
   its image is inside the solved region. Lone solved points (no cell) are gone with it.
2. **outline** -- the user's outline (mm, ``--outline``), if any.
3. **trim** -- regions narrower than ``trim`` bending lengths are removed by a
   morphological opening with a disc of that diameter (skipped, and said, when it would
   keep less than :data:`TRIM_LEAST` of the part). The bending length is
   sqrt(h R): h the sheet's thickness, R = 1 / sqrt(K) with K the problem's curvature
   scale (the largest 95th percentile of |K| over the targets, as ``fabkit check``).
4. **min width** -- with a minimum width d: a closing with a disc of diameter d (inside the
   solved region and the user's outline) and an opening with the same disc. No part of
   the result is narrower than d, convex corners are arcs of radius d / 2 and concave
   ones fillets of the same radius (so the outline turns by at most 1 / (d / 2) radians per
   unit length: with d = 4 road widths, 28.6 degrees per road width), except at corners
   of the solved region or the user's outline themselves. Before the closing, the margin
   outline is kept :data:`INSET` d / 2 inside the solved region, so that the fillets fit.

The result is never outside the solved cells (a final intersection guarantees it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import contourpy
import numpy as np
import shapely
import shapely.affinity
import shapely.errors
from scipy import ndimage

from fabkit.design.design import Design
from fabkit.errors import FabkitError
from fabkit.field.outlines import polygonal, read_outline

MARGIN_DEPTH = 1.415
"""Depth (grid steps to the nearest node outside the solved cells) of the margin contour:
just past sqrt(2), the depth of the inner corners of a staircase edge."""
MIN_WIDTH_ROADS = 4.0
"""Default minimum width of the part, in road widths (when the road width is known)."""
MIN_WIDTH_PITCHES = 2.0
"""Default minimum width of a baromorph's part, in channel pitches (two channels across;
4 pitches, 12 mm, cut a fifth of the example's 22 mm wide sheet and its channel reading
lost the narrow ends: eps 15.6 % RMS against 1.5 %)."""
TRIM_BENDING_LENGTHS = 4.0
"""Default trim: regions narrower than this many bending lengths sqrt(h R) are removed."""
TRIM_LEAST = 0.25
"""The trim is skipped (the summary says so) when it would keep less than this share of
the part: nearly all of the sheet is then too narrow for its thickness, and trimming
would leave nothing to make (the baromorph example: a cast 2.5 mm thick, 22 mm wide)."""
INSET = 0.3
"""The margin outline is kept this fraction of the smoothing radius inside the solved
region before the closing (a fillet of radius rho in a right-angled notch reaches
(1 - 1/sqrt(2)) rho = 0.29 rho towards its corner)."""
QUAD_SEGS = 32
"""Segments per quarter circle of the buffers (2.8 degrees each)."""
SIMULATE_THICKNESS = 0.01
"""``fabkit check``'s thickness for its verdict: this fraction of the solved flat domain's
diameter (design units)."""


@dataclass(frozen=True, eq=False)
class PartRules:
    """How the part is cut, in design units.

    ``min_width`` (0: none) as step 4, ``thickness`` of the sheet (None: no trim) and
    ``trim`` in bending lengths (0: none) as step 3, ``outline`` the user's region in
    design units (None: none) and ``outline_source`` its text, for the report.
    """

    min_width: float = 0.0
    thickness: float | None = None
    trim: float = 0.0
    outline: shapely.Geometry | None = None
    outline_source: str = ""


@dataclass(frozen=True)
class PartRequest:
    """What the user asks of the part: ``outline`` (the ``--outline`` text), ``min_width_mm``
    (``--min-width``) and ``trim`` in bending lengths (``--trim``); None: the defaults.
    Every command that cuts a part from a design takes one."""

    outline: str | None = None
    min_width_mm: float | None = None
    trim: float | None = None

    def check(self) -> None:
        """Refuse bad part options before any work: lengths negative or not finite, an
        outline that cannot be read."""
        if self.min_width_mm is not None:
            _check_length(self.min_width_mm, "--min-width")
        if self.trim is not None:
            _check_length(self.trim, "--trim")
        if self.outline is not None:
            read_outline(self.outline)

    def for_process(
        self,
        road_width_mm: float | None,
        thickness_mm: float | None,
        roads: float = MIN_WIDTH_ROADS,
    ) -> PartOptions:
        """The options for a process of this road width (mm) making a sheet this thick
        (mm), by default no narrower than ``roads`` road widths."""
        return PartOptions(
            self.min_width_mm, self.trim, self.outline, road_width_mm, thickness_mm, roads
        )


@dataclass(frozen=True)
class PartOptions:
    """What a command is told about the part, in mm (see :func:`print_part`).

    ``min_width_mm`` None: :data:`MIN_WIDTH_ROADS` road widths (none when the road width
    is unknown), 0: none; ``trim`` in bending lengths (None: :data:`TRIM_BENDING_LENGTHS`,
    0: none) of a sheet ``thickness_mm`` thick (None: no trim); ``outline``: the user's
    ``--outline`` text.
    ``road_width_mm`` and ``thickness_mm`` come from the process: the road width, and the
    layers' total height; ``roads`` is the default minimum width in road widths (a
    baromorph's: :data:`MIN_WIDTH_PITCHES` channel pitches).
    """

    min_width_mm: float | None = None
    trim: float | None = None
    outline: str | None = None
    road_width_mm: float | None = None
    thickness_mm: float | None = None
    roads: float = MIN_WIDTH_ROADS


@dataclass(frozen=True, eq=False)
class Part:
    """The part of a design's flat sheet that is made (module docstring).

    ``outline`` and ``solved`` are polygonal geometries in design units (flat-sheet
    coordinates r[0]); ``mm_per_unit`` the scale (None for a part cut in design units
    only, as ``fabkit check`` does); ``removed`` the area each step removed, in order
    (design units squared); ``bending_length`` (design units, None without a trim).
    """

    outline: shapely.Polygon | shapely.MultiPolygon
    solved: shapely.Polygon | shapely.MultiPolygon
    rules: PartRules
    removed: tuple[tuple[str, float], ...]
    mm_per_unit: float | None = None
    bending_length: float | None = None

    def __post_init__(self) -> None:
        shapely.prepare(self.outline)

    @property
    def kept(self) -> float:
        """The part's area as a fraction of the solved region's."""
        return self.outline.area / self.solved.area

    def outline_mm(self) -> shapely.Polygon | shapely.MultiPolygon:
        """The outline in mm (an error for a part without a scale)."""
        if self.mm_per_unit is None:
            raise FabkitError("the part has no scale in mm")
        scale = self.mm_per_unit
        return shapely.affinity.scale(self.outline, scale, scale, origin=(0, 0))

    def contains(self, points: np.ndarray) -> np.ndarray:
        """Whether each of the (n, 2) flat-sheet points (design units) is in the part."""
        points = np.asarray(points, dtype=float).reshape(-1, 2)
        return shapely.contains_xy(self.outline, points[:, 0], points[:, 1])

    def to_dict(self) -> dict[str, Any]:
        """Key figures (areas in % of the solved region, lengths in mm when scaled)."""
        unit = self.mm_per_unit or 1.0
        length = "mm" if self.mm_per_unit else "design units"
        figures: dict[str, Any] = {
            "extent": [float(side) for side in self.extent()],
            "kept_pct": round(100 * self.kept, 2),
            "solved_area": self.solved.area * unit**2,
            "area": self.outline.area * unit**2,
            "units": f"{length} (areas squared)",
            "removed_pct": {
                step: round(100 * area / self.solved.area, 2) for step, area in self.removed
            },
            "min_width": self.rules.min_width * unit,
            "trim_bending_lengths": self.rules.trim,
        }
        if self.bending_length is not None:
            figures["thickness"] = self.rules.thickness * unit
            figures["bending_length"] = self.bending_length * unit
            figures["trim_width"] = self.rules.trim * self.bending_length * unit
        if self.rules.outline_source:
            figures["outline"] = self.rules.outline_source
        return figures

    def extent(self) -> tuple[float, float]:
        """The part's width and height along x and y (its outline's bounding box), mm when
        scaled, else design units: the size of what is made."""
        low_x, low_y, high_x, high_y = self.outline.bounds
        unit = self.mm_per_unit or 1.0
        return (high_x - low_x) * unit, (high_y - low_y) * unit

    def summary(self) -> str:
        """One line: the part's size, the kept area and what removed what."""
        unit = self.mm_per_unit or 1.0
        length = " mm" if self.mm_per_unit else " design units"
        parts = []
        for step, area in self.removed:
            share = 100 * area / self.solved.area
            if step.startswith("trim") and self.bending_length is not None:
                width = self.rules.trim * self.bending_length * unit
                under = f"under {self.rules.trim:g} bending lengths, {width:.3g}{length}"
                if step == "trim skipped":
                    parts.append(f"trim skipped: nearly all of it is {under} across")
                    continue
                step = f"trim ({under})"
            elif step == "min width":
                step = f"min width {self.rules.min_width * unit:.3g}{length}"
            parts.append(f"{step} -{share:.1f} %")
        area = f"{self.outline.area * unit**2:.4g} of {self.solved.area * unit**2:.4g}"
        area += " mm2" if self.mm_per_unit else " design units squared"
        size = " x ".join(f"{side:.3g}" for side in self.extent()) + length
        kept = f"{100 * self.kept:.1f} % of the solved area kept ({area}; {', '.join(parts)})"
        return f"part: {size}, {kept}"


def solved_region(design: Design, where: str = "design") -> shapely.Polygon | shapely.MultiPolygon:
    """The union of the images of the solved grid cells on the flat sheet (design units)."""
    cells = solved_cells(design)
    if not cells.any():
        raise FabkitError(f"{where}: the design has no valid grid cell")
    i, j = np.nonzero(cells)
    r0 = design.r[0]
    quads = np.stack([r0[i, j], r0[i + 1, j], r0[i + 1, j + 1], r0[i, j + 1]], axis=1)
    polygons = shapely.polygons(quads.astype(float))
    polygons = polygons[shapely.area(polygons) > 0]
    try:  # cheap and exact when the image does not overlap itself
        region = shapely.coverage_union_all(polygons)
        overlaps = abs(region.area - float(shapely.area(polygons).sum())) > 1e-9 * region.area
    except shapely.errors.GEOSException:
        overlaps = True
    if overlaps:
        region = shapely.union_all(shapely.make_valid(polygons))
    region = polygonal(region)
    if region.is_empty:
        raise FabkitError(f"{where}: the design's flat-sheet image has no area")
    return region


def solved_cells(design: Design) -> np.ndarray:
    """(nu - 1, nv - 1) bool: the grid cells whose four corners are solved (finite r[0])."""
    valid = design.valid & np.isfinite(design.r[0]).all(axis=-1)
    return valid[:-1, :-1] & valid[1:, :-1] & valid[1:, 1:] & valid[:-1, 1:]


def solved_nodes(design: Design) -> np.ndarray:
    """(nu, nv) bool: the grid nodes that are a corner of a solved cell (an initial curve's
    valid nodes beside no solved cell are not)."""
    cells = solved_cells(design)
    nodes = np.zeros(design.valid.shape, dtype=bool)
    for di, dj in ((0, 0), (1, 0), (0, 1), (1, 1)):
        nodes[di : di + cells.shape[0], dj : dj + cells.shape[1]] |= cells
    return nodes


def scale_for_size(solved: shapely.Geometry, size_mm: float) -> float:
    """mm per design unit that makes the longest side of ``solved``'s bounding box
    ``size_mm`` long."""
    low_x, low_y, high_x, high_y = solved.bounds
    return size_mm / max(high_x - low_x, high_y - low_y)


DEFAULT_SIZE_MM = 60.0
"""The part's longest side when no size or scale is given (mm): ``fabkit run``'s,
``toolpath``'s, ``export``'s and the API's."""
SIZE_TOLERANCE = 0.002
"""A part is of the size asked when its longest side is within this share below it."""
SIZE_ITERATIONS = 12
"""Most parts cut while looking for the scale of a size (each about 0.07 s)."""


def part_of_size(
    design: Design,
    size_mm: float,
    options: PartOptions,
    solved: shapely.Geometry | None = None,
    where: str = "design",
) -> Part:
    """The part of ``design`` whose longest side (its bounding box's, mm) is ``size_mm``:
    within :data:`SIZE_TOLERANCE`, never longer. The trim and the minimum width are
    lengths in mm that remove more of a smaller sheet, so the scale is found by
    iteration from the one that gives the solved region that size (the part is never
    larger than the solved region); where no scale reaches it within
    :data:`SIZE_ITERATIONS` parts, the longest part below it. With an ``--outline`` (a
    shape in mm, which bounds the part whatever the scale) ``size_mm`` is the solved
    region's longest side."""
    solved = solved_region(design, where) if solved is None else solved
    scale = scale_for_size(solved, size_mm)
    if options.outline is not None:
        return print_part(design, scale, options, solved, where)
    best, low, high = None, 0.0, math.inf  # the first part is never longer than asked
    for _ in range(SIZE_ITERATIONS):
        part = print_part(design, scale, options, solved, where)
        longest = max(part.extent())
        if longest > size_mm:
            high = scale
        else:
            low = scale
            best = part if best is None or longest > max(best.extent()) else best
            if longest >= (1 - SIZE_TOLERANCE) * size_mm:
                break
        guess = scale * size_mm / longest
        scale = guess if low < guess < high else (low + high) / 2
    return best


def bending_length(design: Design, thickness: float) -> float | None:
    """sqrt(h R) (design units) for thickness h; None when every target is flat, or the
    design carries no spec with targets (a design made by other means than the solver:
    nothing to say how curved it becomes)."""
    try:
        spec = design.problem
    except FabkitError:
        return None
    scales = [
        np.percentile(np.abs(target.surface.curvature(design.r[j][design.valid])), 95)
        for j, target in enumerate(spec.targets)
    ]
    curvature = float(max(scales, default=0.0))
    if not (curvature > 0 and math.isfinite(curvature)):
        return None
    return math.sqrt(thickness / math.sqrt(curvature))


def make_part(
    design: Design,
    rules: PartRules,
    mm_per_unit: float | None = None,
    solved: shapely.Geometry | None = None,
    where: str = "design",
) -> Part:
    """Cut the part out of ``design``'s solved region by ``rules`` (module docstring)."""
    solved = solved_region(design, where) if solved is None else solved
    radius = rules.min_width / 2
    limit = solved if rules.outline is None else polygonal(solved.intersection(rules.outline))
    removed = []
    region = margin_outline(design)
    removed.append(("margin", solved.area - region.area))
    if rules.outline is not None:
        before = region.area
        region = polygonal(region.intersection(rules.outline))
        removed.append(("outline", before - region.area))
    length = None
    if rules.thickness is not None and rules.trim > 0:
        length = bending_length(design, rules.thickness)
        if length is not None:
            before = region.area
            trimmed = _opening(region, rules.trim * length / 2)
            if trimmed.area >= TRIM_LEAST * before:
                region = trimmed
                removed.append(("trim", before - region.area))
            else:
                removed.append(("trim skipped", 0.0))
    if radius > 0:
        before = region.area
        region = polygonal(region.intersection(limit.buffer(-INSET * radius, quad_segs=QUAD_SEGS)))
        region = _closing(region, radius).intersection(limit)
        region = _opening(polygonal(region), radius)
        removed.append(("min width", before - region.area))
    region = polygonal(region.intersection(limit))
    if region.is_empty:
        steps = ", ".join(f"{step} -{100 * area / solved.area:.0f} %" for step, area in removed)
        hint = "smaller --min-width or --trim, or a larger --size"
        if rules.outline is not None:
            hint += ", or an --outline that overlaps the sheet (mm, sheet frame)"
        raise FabkitError(
            f"{where}: nothing of the solved domain is left for the part ({steps}): give a {hint}"
        )
    return Part(region, solved, rules, tuple(removed), mm_per_unit, length)


def margin_outline(design: Design) -> shapely.Polygon | shapely.MultiPolygon:
    """Step 1: the contour of the nodes' depth at MARGIN_DEPTH, on the flat sheet."""
    nodes = solved_nodes(design)
    depth = ndimage.distance_transform_edt(np.pad(nodes, 1))[1:-1, 1:-1]
    nu, nv = nodes.shape
    generator = contourpy.contour_generator(
        np.arange(nu, dtype=float),
        np.arange(nv, dtype=float),
        np.ma.masked_array(depth, ~nodes).T,
        fill_type="OuterOffset",
        corner_mask=False,
    )
    polygons, offsets = generator.filled(MARGIN_DEPTH, np.inf)
    r0 = np.nan_to_num(design.r[0].astype(float))
    shells = []
    for points, offset in zip(polygons, offsets, strict=True):
        flat = _bilinear(r0, points)
        rings = [flat[a:b] for a, b in zip(offset[:-1], offset[1:], strict=True)]
        shells.append(shapely.make_valid(shapely.Polygon(rings[0], rings[1:])))
    region = polygonal(shapely.union_all(shells)) if shells else shapely.Polygon()
    return region


def _bilinear(r0: np.ndarray, points: np.ndarray) -> np.ndarray:
    """r0 (nu, nv, 2) at fractional grid indices (n, 2), bilinear in the containing cell."""
    nu, nv = r0.shape[:2]
    low = np.clip(np.floor(points).astype(int), 0, [nu - 2, nv - 2])
    fraction = points - low
    out = np.zeros((len(points), 2))
    for di, dj in ((0, 0), (1, 0), (0, 1), (1, 1)):
        weight = np.abs(1 - di - fraction[:, 0]) * np.abs(1 - dj - fraction[:, 1])
        out += weight[:, None] * r0[low[:, 0] + di, low[:, 1] + dj]
    return out


def _opening(region: shapely.Geometry, radius: float) -> shapely.Geometry:
    """Morphological opening by a disc of ``radius`` (removes what is narrower than 2 r)."""
    if radius <= 0 or region.is_empty:
        return region
    inner = region.buffer(-radius, quad_segs=QUAD_SEGS)
    return polygonal(inner.buffer(radius, quad_segs=QUAD_SEGS)) if not inner.is_empty else inner


def _closing(region: shapely.Geometry, radius: float) -> shapely.Geometry:
    """Morphological closing by a disc of ``radius`` (fills notches narrower than 2 r)."""
    if radius <= 0 or region.is_empty:
        return region
    return region.buffer(radius, quad_segs=QUAD_SEGS).buffer(-radius, quad_segs=QUAD_SEGS)


def print_part(
    design: Design,
    mm_per_unit: float,
    options: PartOptions,
    solved: shapely.Geometry | None = None,
    where: str = "design",
) -> Part:
    """The part of a sheet made at ``mm_per_unit`` (mm per design unit) by ``options``:
    the lengths and the user's outline converted to design units."""
    road = options.road_width_mm
    min_width = options.min_width_mm
    if min_width is None:
        min_width = options.roads * road if road else 0.0
    trim = TRIM_BENDING_LENGTHS if options.trim is None else options.trim
    _check_length(min_width, "--min-width")
    _check_length(trim, "--trim")
    outline = None
    if options.outline is not None:
        outline = shapely.affinity.scale(
            read_outline(options.outline), 1 / mm_per_unit, 1 / mm_per_unit, origin=(0, 0)
        )
    thickness = None if options.thickness_mm is None else options.thickness_mm / mm_per_unit
    rules = PartRules(
        min_width=min_width / mm_per_unit,
        thickness=thickness,
        trim=trim,
        outline=outline,
        outline_source=options.outline or "",
    )
    return make_part(design, rules, mm_per_unit, solved, where)


def simulation_part(
    design: Design, thickness: float | None, trim: float | None = None
) -> tuple[Part, float]:
    """The part ``fabkit check`` simulates, and the thickness (design units; default
    :data:`SIMULATE_THICKNESS` of the solved region's diameter): no minimum width (no
    road width is known), trimmed to ``trim`` bending lengths (None:
    :data:`TRIM_BENDING_LENGTHS`, 0: not trimmed)."""
    trim = TRIM_BENDING_LENGTHS if trim is None else trim
    _check_length(trim, "--trim")
    solved = solved_region(design)
    if thickness is None:
        thickness = SIMULATE_THICKNESS * diameter(solved)
    if not (math.isfinite(thickness) and thickness > 0):
        raise FabkitError(f"--thickness {thickness:g}: thickness must be positive and finite")
    part = make_part(design, PartRules(thickness=thickness, trim=trim), None, solved)
    return part, thickness


def diameter(region: shapely.Geometry) -> float:
    """The largest distance between two points of a region (its units)."""
    hull = np.asarray(shapely.get_coordinates(region.convex_hull), dtype=float)
    differences = hull[:, None, :] - hull[None, :, :]
    return float(np.sqrt(np.max(np.einsum("ijk,ijk->ij", differences, differences))))


def _check_length(value: float, name: str, positive: bool = False) -> None:
    if not (math.isfinite(value) and (value > 0 if positive else value >= 0)):
        sign = "positive" if positive else "non-negative"
        raise FabkitError(f"{name} {value:g}: expected a {sign} finite number")
