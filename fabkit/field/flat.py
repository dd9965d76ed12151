"""Fields on the flat sheet, in millimetres: the director angle theta, eps, and the outline.

A :class:`FlatField` is what the toolpath stage needs from a design: the domain outline
(a shapely polygon, mm), the director angle ``theta(x, y)`` (radians, defined mod pi,
defined on the whole plane so that line generation may look a little past the outline)
and every designable feature ``eps_i(x, y)``, by name (a design's features are named in
its spec; a director file's single ``eps`` is the feature ``eps``).

It comes from one of three sources:

* :func:`field_from_design` -- a solved ``design.npz``. The solved map ``r[0](u, v)`` sends
  the material grid to the flat sheet; the outline is the union of the images of the valid
  grid cells, and theta and eps are interpolated *along the grid*: a point is located in
  the image of a grid triangle and interpolated barycentrically from its three corners
  (never across the domain). Where the image overlaps itself, the preimage nearest to the
  design origin (smallest ``|u| + |v|``) wins.
* :func:`field_from_expression` -- ``theta(x, y)`` as a safe expression on a named shape
  (``disc:10``, ``square:20``, ...), for standard patterns without a solve.
* :func:`field_from_grid` -- a theta grid and mask (and optional eps grid) in mm.

Director angles are interpolated as the tensor ``(cos 2 theta, sin 2 theta)`` so that the
head-tail symmetry of the director is respected.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, NoReturn

import contourpy
import numpy as np
import shapely
import shapely.affinity
import shapely.errors
from scipy.interpolate import RegularGridInterpolator
from scipy.spatial import cKDTree

from fabkit.design.design import Design
from fabkit.errors import FabkitError
from fabkit.field.outlines import parse_shape, polygonal
from fabkit.field.part import Part, PartOptions, print_part, scale_for_size, solved_region
from fabkit.npzfile import ArrayHeader, read_npz
from fabkit.problem.expr import parse, shorten
from fabkit.shipped import user_or_example
from fabkit.tomlfile import Table, expected, read_toml, real

PlaneFunction = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""A vectorised function of x and y (mm, broadcast arrays) returning an array of their shape."""

EXPRESSION_NAMES = ("x", "y", "r", "phi")
"""Names allowed in director and eps expressions: x, y (mm), r = hypot(x, y) (mm) and
phi = arctan2(y, x) (radians). ``arctan2(a, b)`` may also be called with two arguments."""

DESIGN_KEYS = ("u", "v", "valid", "eps", "r", "n")


@dataclass(frozen=True, eq=False)
class FlatField:
    """A director field and its features on the flat sheet; lengths in mm, angles in rad.

    ``theta_fn(x, y)`` and every function of ``features`` (feature name -> eps(x, y), in
    the design's order) take broadcast arrays of mm coordinates and return arrays of
    their shape; theta is defined mod pi. ``keys`` names where theta (key ``"theta"``)
    and each feature came from (an option, a key, a file), for error messages.
    ``mm_per_unit``: the scale of a design's field (mm per design unit), None for fields
    given in mm. ``joint_fn`` (optional) gives [theta, *features] at once, cheaper than
    one call each (a design locates each point in its mesh once). ``part``: a design's
    :class:`~fabkit.field.part.Part`, whose outline (in mm) is ``outline``.
    """

    outline: shapely.Polygon | shapely.MultiPolygon
    theta_fn: PlaneFunction
    features: Mapping[str, PlaneFunction]
    source: str
    keys: Mapping[str, str] = field(default_factory=dict)
    mm_per_unit: float | None = None
    joint_fn: Callable[[np.ndarray, np.ndarray], list[np.ndarray]] | None = None
    part: Part | None = None

    def theta(self, points: np.ndarray) -> np.ndarray:
        """Director angle (n,) in (-pi/2, pi/2] at (n, 2) points.

        Finite everywhere: theta is an error where it is not finite on the sheet, and
        continued from the nearest edge point of the sheet where it is not finite beyond
        it (see :func:`_finite_values`).
        """
        points = np.asarray(points, dtype=float).reshape(-1, 2)
        angles = _finite_values(self.theta_fn, points, self.outline, self.key("theta"))
        return np.pi / 2 - np.mod(np.pi / 2 - angles, np.pi)

    def director(self, points: np.ndarray) -> np.ndarray:
        """Unit director (n, 2) at (n, 2) points (sign arbitrary)."""
        angles = self.theta(points)
        return np.column_stack([np.cos(angles), np.sin(angles)])

    def key(self, name: str) -> str:
        """Where theta (``"theta"``) or a feature came from, for messages."""
        return self.keys.get(name, name)

    @property
    def names(self) -> tuple[str, ...]:
        """The feature names, in order."""
        return tuple(self.features)

    @property
    def has_eps(self) -> bool:
        return bool(self.features)

    def feature(self, name: str, points: np.ndarray) -> np.ndarray:
        """Feature ``name`` (n,) at (n, 2) points, finite as theta is (see :meth:`theta`)."""
        if name not in self.features:
            known = ", ".join(self.features) or "none"
            raise FabkitError(f"{self.source}: has no feature '{name}' (features: {known})")
        points = np.asarray(points, dtype=float).reshape(-1, 2)
        return _finite_values(self.features[name], points, self.outline, self.key(name))

    def sample(self, points: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Director angle (n,) (as :meth:`theta`) and every feature (n,) at (n, 2) points."""
        points = np.asarray(points, dtype=float).reshape(-1, 2)
        if self.joint_fn is None:
            return self.theta(points), {name: self.feature(name, points) for name in self.names}
        theta, *values = self.joint_fn(points[:, 0], points[:, 1])
        theta = np.pi / 2 - np.mod(np.pi / 2 - theta, np.pi)
        return theta, dict(zip(self.names, values, strict=True))

    def eps(self, points: np.ndarray) -> np.ndarray:
        """The field's only feature (n,) at (n, 2) points; an error unless it has one."""
        if len(self.features) != 1:
            count = f"{len(self.features)} features ({', '.join(self.features)})"
            raise FabkitError(
                f"{self.source}: needs one eps feature, it has {count if self.features else 'none'}"
            )
        return self.feature(self.names[0], points)

    def clipped(self, clip: shapely.Geometry) -> FlatField:
        """The same field on the outline intersected with ``clip`` (mm)."""
        outline = polygonal(shapely.intersection(self.outline, clip))
        if outline.is_empty:
            raise FabkitError(f"{self.source}: the clip outline does not overlap the domain")
        return replace(self, outline=outline)


# --------------------------------------------------------------------------- expressions


def _finite_values(
    function: PlaneFunction, points: np.ndarray, outline: shapely.Geometry, where: str
) -> np.ndarray:
    """``function`` at (n, 2) points (mm), all finite, or a FabkitError naming ``where``.

    A point where the value is not finite is an error if it lies on the sheet (inside
    the outline or on its edge). Beyond the sheet (line planning looks a little past
    the edge) it takes the value at the nearest point of the sheet, nudged inside by
    1e-9 of the sheet's size; if that is not finite either, it is an error too.
    """
    values = np.asarray(function(points[:, 0], points[:, 1]), dtype=float).reshape(len(points))
    bad = np.flatnonzero(~np.isfinite(values))
    if len(bad) == 0:
        return values
    distance = shapely.distance(outline, shapely.points(points[bad]))
    on_sheet = bad[~(distance > 0)]
    if len(on_sheet):
        raise FabkitError(
            f"{where}: not finite at {len(on_sheet)} of {len(points)} points on the sheet "
            f"(first at x = {points[on_sheet[0], 0]:.6g}, y = {points[on_sheet[0], 1]:.6g} mm)"
        )
    lines = shapely.shortest_line(outline, shapely.points(points[bad]))
    edge = shapely.get_coordinates(lines).reshape(-1, 2, 2)[:, 0]
    low_x, low_y, high_x, high_y = outline.bounds
    inward = edge - points[bad]
    inward *= 1e-9 * max(high_x - low_x, high_y - low_y) / np.linalg.norm(inward, axis=1)[:, None]
    nearest = np.asarray(function(*(edge + inward).T), dtype=float).reshape(len(bad))
    if not np.all(np.isfinite(nearest)):
        first = points[bad[np.argmin(np.isfinite(nearest))]]
        raise FabkitError(
            f"{where}: not finite at the edge of the sheet near x = {first[0]:.6g}, "
            f"y = {first[1]:.6g} mm"
        )
    values[bad] = nearest
    return values


def check_finite_on_sheet(
    function: PlaneFunction, outline: shapely.Geometry, where: str, text: str = ""
) -> None:
    """Refuse a field that is not finite somewhere on the sheet, before anything uses it.

    Samples the outline's bounding box on a 101 x 101 grid (points inside the outline)
    and the outline's vertices moved 1e-9 of its size inwards; a value that is NaN or
    infinite at any of them is a FabkitError naming ``where``, the count and a point.
    """
    low_x, low_y, high_x, high_y = outline.bounds
    xs, ys = np.meshgrid(np.linspace(low_x, high_x, 101), np.linspace(low_y, high_y, 101))
    inside = shapely.contains_xy(outline, xs, ys)
    size = max(high_x - low_x, high_y - low_y)
    edge = shapely.get_coordinates(outline.buffer(-1e-9 * size, quad_segs=2).boundary)
    points = np.concatenate([np.column_stack([xs[inside], ys[inside]]), edge])
    with np.errstate(all="ignore"):
        values = np.asarray(function(points[:, 0], points[:, 1]), dtype=float)
    bad = np.flatnonzero(~np.isfinite(values.reshape(len(points))))
    if len(bad):
        shown = f": '{shorten(text)}'" if text else ""
        raise FabkitError(
            f"{where}: not finite at {len(bad)} of {len(points)} points of the sheet (first at "
            f"x = {points[bad[0], 0]:.6g}, y = {points[bad[0], 1]:.6g} mm){shown}"
        )


def planar_expression(text: Any, where: str) -> PlaneFunction:
    """Parse a safe expression in x, y, r, phi (see :data:`EXPRESSION_NAMES`) with the
    whitelist parser (``arctan2(y, x)`` included); nothing is ever ``eval``-ed."""
    if not isinstance(text, str | int | float) or isinstance(text, bool):
        raise FabkitError(f"{where}: expected an expression string, got {text!r}")
    expression = parse(str(text), EXPRESSION_NAMES, where)

    def evaluate(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        return expression(x, y, np.hypot(x, y), np.arctan2(y, x))

    return evaluate


def field_from_expression(
    theta: str,
    outline: shapely.Geometry,
    eps: str | float | Mapping[str, Any] | None = None,
    where: str | None = None,
) -> FlatField:
    """A director field ``theta(x, y)`` (radians) on ``outline`` (mm), with features:
    ``eps`` one expression (the feature ``eps``), a mapping name -> expression, or None.

    ``where`` names the table they come from (errors name ``<where>.theta`` and
    ``<where>.eps``); None means the command-line options ``--director`` and ``--eps``.
    Every field must be finite on the whole sheet (:func:`check_finite_on_sheet`).
    """
    theta_key = "--director" if where is None else f"{where}.theta"
    eps_key = "--eps" if where is None else f"{where}.eps"
    theta_fn = planar_expression(theta, theta_key)
    texts: dict[str, Any] = {}
    keys = {"theta": theta_key}
    if isinstance(eps, Mapping):
        if not eps:
            raise FabkitError(f"{eps_key}: give at least one feature = expression")
        for name in eps:
            check_feature_name(name, eps_key)
            texts[str(name)], keys[str(name)] = eps[name], f"{eps_key}.{name}"
    elif eps is not None:
        texts["eps"], keys["eps"] = eps, eps_key
    features = {name: planar_expression(text, keys[name]) for name, text in texts.items()}
    outline = polygonal(outline)
    if outline.is_empty or outline.area <= 0:
        raise FabkitError(f"{where or '--shape'}: the outline is empty")
    check_finite_on_sheet(theta_fn, outline, theta_key, str(theta))
    for name, function in features.items():
        check_finite_on_sheet(function, outline, keys[name], str(texts[name]))
    return FlatField(outline, theta_fn, features, f"theta = {theta}", keys)


def check_feature_name(name: Any, where: str) -> None:
    """A feature name: an identifier (letters, digits, underscores; not a digit first)."""
    if not (isinstance(name, str) and name.isidentifier() and name.isascii()):
        raise FabkitError(f"{where}: feature name {name!r} must be an identifier like eps1")


# --------------------------------------------------------------------------- grids


def field_from_grid(
    theta: np.ndarray,
    mask: np.ndarray,
    pixel_mm: float,
    origin: tuple[float, float] = (0.0, 0.0),
    eps: np.ndarray | Mapping[str, np.ndarray] | None = None,
    source: str = "theta grid",
) -> FlatField:
    """A director field from an (nx, ny) theta grid (radians) and boolean mask.

    Node ``(i, j)`` sits at ``origin + pixel_mm * (i, j)`` (mm). The outline is the mask's
    0.5 contour; theta (as a tensor) and the features are interpolated bilinearly, and
    extended by the nearest masked node outside the mask. ``eps``: one grid (the feature
    ``eps``) or a mapping name -> grid.
    """
    theta = np.asarray(theta, dtype=float)
    mask = np.asarray(mask, dtype=bool)
    if theta.ndim != 2 or mask.shape != theta.shape or min(theta.shape) < 2:
        raise FabkitError(f"{source}: theta and mask must be 2-D arrays of one shape (>= 2 x 2)")
    grids = {} if eps is None else dict(eps) if isinstance(eps, Mapping) else {"eps": eps}
    for name, grid in grids.items():
        if np.shape(grid) != theta.shape:
            raise FabkitError(f"{source}: {name} must have the shape of theta {theta.shape}")
    if not mask.any():
        raise FabkitError(f"{source}: the mask selects no point")
    for label, values in (("theta", theta), *grids.items()):
        bad = np.argwhere(mask & ~np.isfinite(np.asarray(values, dtype=float)))
        if len(bad):
            raise FabkitError(
                f"{source}: {label} is not finite at {len(bad)} of {int(mask.sum())} nodes of "
                f"the mask (first at node {tuple(int(i) for i in bad[0])}); mask them out"
            )
    pixel_mm = real(pixel_mm, f"{source}: pixel_mm", positive=True)
    xs = origin[0] + pixel_mm * np.arange(theta.shape[0])
    ys = origin[1] + pixel_mm * np.arange(theta.shape[1])
    filled = _fill_nearest(mask, np.cos(2 * theta), np.sin(2 * theta))
    cos2, sin2 = (RegularGridInterpolator((xs, ys), f, bounds_error=False) for f in filled[:2])
    theta_fn = _tensor_angle(cos2, sin2, xs, ys)
    features = {}
    for name, grid in grids.items():
        (filled_grid,) = _fill_nearest(mask, np.asarray(grid, dtype=float))
        features[name] = _clamped(RegularGridInterpolator((xs, ys), filled_grid), xs, ys)
    outline = _mask_outline(mask.astype(float), xs, ys)
    if outline.is_empty:
        raise FabkitError(f"{source}: the mask has no area (needs 2 x 2 neighbouring points)")
    keys = {"theta": f"{source}: theta", **{name: f"{source}: {name}" for name in features}}
    return FlatField(outline, theta_fn, features, source, keys)


def _fill_nearest(mask: np.ndarray, *grids: np.ndarray) -> list[np.ndarray]:
    """Each grid with its unmasked nodes set to the value at the nearest masked node."""
    inside = np.argwhere(mask)
    _, nearest = cKDTree(inside).query(np.argwhere(np.ones_like(mask)))
    source = inside[nearest]
    return [g[source[:, 0], source[:, 1]].reshape(mask.shape) for g in grids]


def _clamped(interpolator: RegularGridInterpolator, xs: np.ndarray, ys: np.ndarray):
    def evaluate(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        points = np.stack([np.clip(x, xs[0], xs[-1]), np.clip(y, ys[0], ys[-1])], axis=-1)
        return interpolator(points)

    return evaluate


def _tensor_angle(cos2, sin2, xs: np.ndarray, ys: np.ndarray) -> PlaneFunction:
    cos2, sin2 = _clamped(cos2, xs, ys), _clamped(sin2, xs, ys)

    def evaluate(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return 0.5 * np.arctan2(sin2(x, y), cos2(x, y))

    return evaluate


def _mask_outline(values: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> shapely.Geometry:
    padded = np.pad(values, 1)
    step_x, step_y = xs[1] - xs[0], ys[1] - ys[0]
    px = np.concatenate([[xs[0] - step_x], xs, [xs[-1] + step_x]])
    py = np.concatenate([[ys[0] - step_y], ys, [ys[-1] + step_y]])
    generator = contourpy.contour_generator(px, py, padded.T, fill_type="OuterOffset")
    polygons, offsets = generator.filled(0.5, 2.0)
    shells = []
    for points, offset in zip(polygons, offsets, strict=True):
        rings = [points[a:b] for a, b in zip(offset[:-1], offset[1:], strict=True)]
        shells.append(shapely.Polygon(rings[0], rings[1:]))
    return polygonal(shapely.union_all(shells))


# --------------------------------------------------------------------------- designs


def field_from_design(
    source: Design | str | Path,
    size_mm: float | None = None,
    mm_per_unit: float | None = None,
    part: Part | PartOptions | None = None,
    name: str | None = None,
) -> FlatField:
    """The flat-sheet field of a solved design (or ``design.npz``) on its part, scaled to
    millimetres; ``name`` is the field's source in messages (default: the file, or
    "design" for a value).

    ``part``: a :class:`~fabkit.field.part.Part` made already (its scale is the field's; then give
    neither size nor scale), or the options to make one (default :class:`PartOptions`: the
    smooth margin outline only). Otherwise give exactly one of ``size_mm`` (the longest
    side of the solved region's bounding box, mm) and ``mm_per_unit`` (mm per design unit).
    Every feature of the design is carried, named as in its spec.
    """
    design, path = _design_and_name(source, name)
    if isinstance(part, Part):
        if part.mm_per_unit is None:
            raise FabkitError(f"{path}: the part has no scale in mm")
        if size_mm is not None or mm_per_unit is not None:
            raise FabkitError(f"{path}: the part sets the scale; give no --size or --scale")
        scale = part.mm_per_unit
    else:
        if (size_mm is None) == (mm_per_unit is None):
            raise FabkitError(
                "design: give the size (--size MM, longest side) or --scale MM_PER_UNIT"
            )
        solved = solved_region(design, str(path))
        if size_mm is not None:
            mm_per_unit = scale_for_size(solved, real(size_mm, "--size", positive=True))
        scale = real(mm_per_unit, "--scale", positive=True)
        part = print_part(design, scale, part or PartOptions(), solved, str(path))
    arrays = {key: getattr(design, key) for key in DESIGN_KEYS}
    names = feature_names(design, str(path))
    mesh = _DesignMesh.build(arrays, scale, str(path))
    features = {name: mesh.feature_function(k) for k, name in enumerate(names)}
    keys = {"theta": f"{path}: theta", **{name: f"{path}: {name}" for name in names}}
    return FlatField(
        part.outline_mm(), mesh.theta, features, f"{path}", keys, scale, mesh.everything, part
    )


def _design_and_name(source: Design | str | Path, name: str | None) -> tuple[Design, str]:
    """The design, and the name its messages give (``name``, else the file, or "design")."""
    if isinstance(source, Design):
        return source, name or "design"
    return Design.load(source), name or str(source)


def feature_names(design: Design, where: str = "design") -> tuple[str, ...]:
    """The names of a design's features, from the spec it carries (``material.features``)."""
    try:
        names = json.loads(design.spec)["material"]["features"]
    except (ValueError, KeyError, TypeError):
        names = None
    count = design.eps.shape[0]
    if not (
        isinstance(names, list) and len(names) == count and all(isinstance(n, str) for n in names)
    ):
        raise FabkitError(
            f"{where}: its spec does not name its {count} feature(s) (material.features)"
        )
    return tuple(names)


@dataclass(frozen=True, eq=False)
class _DesignMesh:
    """The valid grid cells of a design, mapped to the flat sheet and split in triangles.

    ``points`` (V, 2) flat-sheet positions of valid grid nodes; ``triangles`` (T, 3) node
    indices, ordered by distance of the cell from the design origin (smallest |u|+|v| first);
    ``cos2``, ``sin2`` (V,) and ``eps_values`` (N, V) per-node values.
    """

    points: np.ndarray
    triangles: np.ndarray
    cos2: np.ndarray
    sin2: np.ndarray
    eps_values: np.ndarray
    where: str
    locator: TriangleLocator
    nodes: cKDTree

    @classmethod
    def build(cls, arrays: Mapping[str, np.ndarray], scale: float, where: str) -> _DesignMesh:
        """The mesh of ``arrays`` (a design file's contents) with positions times ``scale``."""
        valid = arrays["valid"].astype(bool)
        r0, n0, eps = arrays["r"][0], arrays["n"][0], arrays["eps"]
        valid &= np.isfinite(r0).all(axis=-1) & np.isfinite(n0).all(axis=-1)
        valid &= np.isfinite(eps).all(axis=0)
        cells = valid[:-1, :-1] & valid[1:, :-1] & valid[1:, 1:] & valid[:-1, 1:]
        if not cells.any():
            raise FabkitError(f"{where}: the design has no valid grid cell")
        ci, cj = np.nonzero(cells)
        order = np.argsort(
            np.abs(arrays["u"][ci] + arrays["u"][ci + 1])
            + np.abs(arrays["v"][cj] + arrays["v"][cj + 1]),
            kind="stable",
        )
        ci, cj = ci[order], cj[order]
        node = np.full(valid.shape, -1)
        node[valid] = np.arange(valid.sum())
        a, b, c, d = node[ci, cj], node[ci + 1, cj], node[ci + 1, cj + 1], node[ci, cj + 1]
        triangles = np.stack([np.column_stack([a, b, c]), np.column_stack([a, c, d])], axis=1)
        angle = np.arctan2(n0[valid][:, 1], n0[valid][:, 0])
        points = r0[valid].astype(float) * scale
        triangles = triangles.reshape(-1, 3)
        return cls(
            points=points,
            triangles=triangles,
            cos2=np.cos(2 * angle),
            sin2=np.sin(2 * angle),
            eps_values=eps[:, valid].astype(float),
            where=where,
            locator=TriangleLocator(points, triangles),
            nodes=cKDTree(points),
        )

    def theta(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        cos2, sin2 = self._interpolate(x, y, self.cos2, self.sin2)
        return 0.5 * np.arctan2(sin2, cos2)

    def everything(self, x: np.ndarray, y: np.ndarray) -> list[np.ndarray]:
        """[theta, *features] at x, y (mm), each point located once."""
        cos2, sin2, *values = self._interpolate(x, y, self.cos2, self.sin2, *self.eps_values)
        return [0.5 * np.arctan2(sin2, cos2), *values]

    def feature_function(self, index: int) -> PlaneFunction:
        """Feature ``index`` as a function of x, y (mm)."""

        def evaluate(x: np.ndarray, y: np.ndarray) -> np.ndarray:
            return self._interpolate(x, y, self.eps_values[index])[0]

        return evaluate

    def _interpolate(self, x: np.ndarray, y: np.ndarray, *values: np.ndarray) -> list[np.ndarray]:
        """Barycentric interpolation in the containing image triangle; nearest node outside."""
        x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        points = np.column_stack([x.ravel(), y.ravel()])
        triangle, weights = self.locator.locate(points)
        found = triangle >= 0
        corners = self.triangles[triangle[found]]
        results = []
        _, nearest = self.nodes.query(points[~found])
        for v in values:
            out = np.empty(len(points))
            out[found] = (v[corners] * weights[found]).sum(axis=1)
            out[~found] = v[nearest]
            results.append(out.reshape(x.shape))
        return results


class TriangleLocator:
    """Find the first triangle (lowest index) of a planar mesh containing each query point.

    Triangles are binned into a uniform grid of buckets about the median triangle
    size; a query tests only the triangles of its bucket, vectorised over all points.
    """

    def __init__(self, points: np.ndarray, triangles: np.ndarray):
        self.points, self.triangles = points, triangles
        corners = points[triangles]  # (T, 3, 2)
        low, high = corners.min(axis=1), corners.max(axis=1)
        size = float(np.median(np.max(high - low, axis=1))) or 1.0
        self.origin, self.size = low.min(axis=0), size
        self.shape = np.floor((high.max(axis=0) - self.origin) / size).astype(int) + 1
        i0, j0 = self._bucket(low).T
        i1, j1 = self._bucket(high).T
        counts = (i1 - i0 + 1) * (j1 - j0 + 1)
        owner = np.repeat(np.arange(len(triangles)), counts)
        local = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        width = (i1 - i0 + 1)[owner]
        bucket = (i0[owner] + local % width) * self.shape[1] + j0[owner] + local // width
        order = np.lexsort((owner, bucket))
        self.members = owner[order]
        self.starts = np.searchsorted(bucket[order], np.arange(self.shape.prod() + 1))

    def _bucket(self, points: np.ndarray) -> np.ndarray:
        cells = np.floor((points - self.origin) / self.size).astype(int)
        return np.clip(cells, 0, self.shape - 1)

    def locate(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(n,) triangle index (-1 if none) and (n, 3) barycentric weights."""
        points = np.asarray(points, dtype=float)
        cells = np.floor((points - self.origin) / self.size).astype(int)
        inside = ((cells >= 0) & (cells < self.shape)).all(axis=1)
        bucket = np.where(inside, cells[:, 0] * self.shape[1] + cells[:, 1], 0)
        counts = np.where(inside, self.starts[bucket + 1] - self.starts[bucket], 0)
        query = np.repeat(np.arange(len(points)), counts)
        offset = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        candidate = self.members[self.starts[bucket[query]] + offset]
        weights = _barycentric(points[query], self.points[self.triangles[candidate]])
        hit = np.flatnonzero((weights >= -1e-9).all(axis=1))
        # per query point, the containing triangle of lowest index (members are sorted)
        first = hit[np.concatenate([[True], np.diff(query[hit]) != 0])] if len(hit) else hit
        triangle = np.full(len(points), -1)
        triangle[query[first]] = candidate[first]
        result = np.zeros((len(points), 3))
        result[query[first]] = weights[first]
        return triangle, result


def _barycentric(points: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """(n, 3) barycentric coordinates of (n, 2) points in (n, 3, 2) triangles."""
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    v0, v1, v2 = b - a, c - a, points - a
    det = v0[:, 0] * v1[:, 1] - v0[:, 1] * v1[:, 0]
    det = np.where(np.abs(det) > 1e-300, det, np.nan)
    l1 = (v2[:, 0] * v1[:, 1] - v2[:, 1] * v1[:, 0]) / det
    l2 = (v0[:, 0] * v2[:, 1] - v0[:, 1] * v2[:, 0]) / det
    weights = np.column_stack([1 - l1 - l2, l1, l2])
    return np.where(np.isfinite(weights), weights, -1.0)


# --------------------------------------------------------------------------- files


def load_director_file(path: str | Path) -> FlatField:
    """A director field from a TOML file (see ``docs/toolpath.md``)::

    [director]
    theta = "phi + pi/2"      # radians; names x, y, r, phi; arctan2(a, b) allowed
    shape = "disc:10"         # or outline = [[x, y], ...] (mm)
    eps = "0.3"               # optional: the feature eps; or { eps1 = "...", eps2 = "..." }
    # or, instead of theta/eps: grid = "theta.npz" with theta, mask, pixel_mm (, eps)
    """
    path = user_or_example(path)
    top = Table(read_toml(path, "director"), str(path))
    top.check_keys({"director"})
    director = top.table("director")
    where = director.at()
    director.check_keys({"theta", "shape", "outline", "eps", "grid"})
    if "grid" in director:
        return _grid_file(path.parent / str(director["grid"]), where)
    director.require(("theta",), "an expression in x, y, r and phi (or grid, an .npz file)")
    if ("shape" in director) == ("outline" in director):
        given = [key for key in ("shape", "outline") if key in director]
        director.expected(None, "exactly one of shape and outline", given)
    if "shape" in director:
        outline = parse_shape(director["shape"], director.at("shape"))
    else:
        outline = _outline_points(director["outline"], director.at("outline"))
    field = field_from_expression(director["theta"], outline, director.get("eps"), where)
    return replace(field, source=f"{path}")


def _outline_points(value: Any, where: str) -> shapely.Polygon:
    try:
        points = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        points = np.zeros((0,))
    if points.ndim != 2 or points.shape[1] != 2 or len(points) < 3 or not np.isfinite(points).all():
        _refuse_points(value, where)
    polygon = shapely.Polygon(points)
    if not polygon.is_valid:
        polygon = polygonal(shapely.make_valid(polygon))
    return polygon


def _refuse_points(value: Any, where: str) -> NoReturn:
    """Refuse an outline that is not at least 3 [x, y] points, naming the first bad item."""
    if isinstance(value, list) and len(value) >= 3:
        for i, point in enumerate(value):
            if not isinstance(point, list) or len(point) != 2:
                expected(f"{where}[{i}]", "an [x, y] point (mm)", point)
            for j, coordinate in enumerate(point):
                try:
                    finite = bool(np.isfinite(float(coordinate)))
                except (TypeError, ValueError):
                    finite = False
                if not finite:
                    expected(f"{where}[{i}][{j}]", "a finite number", coordinate)
    expected(where, "a list of at least 3 [x, y] points (mm)", value)


GRID_ARRAYS = {"theta": 2, "mask": 2, "pixel_mm": 0, "eps": 2, "origin": 1}
"""Arrays of a director grid file (.npz) by name, with their number of dimensions."""
MAX_GRID_NODES = 25_000_000
"""Most nodes of a director grid file's theta (5000 x 5000)."""


def _grid_file(path: Path, where: str) -> FlatField:
    """A director grid file: theta (nx, ny) rad, mask (nx, ny), pixel_mm, optional eps
    (nx, ny) and origin (2,) mm; every array is checked before it is used."""
    if not path.is_file():
        raise FabkitError(f"{where}.grid: file '{path}' does not exist")
    label = f"{where}.grid: '{path}'"
    arrays = read_npz(
        path,
        f"{where}.grid: cannot read '{path}'",
        check=lambda headers: _check_grid_headers(headers, label),
    )
    missing = [k for k in ("theta", "mask", "pixel_mm") if k not in arrays]
    if missing:
        raise FabkitError(f"{label} has no '{missing[0]}' array")
    origin = np.asarray(arrays.get("origin", np.zeros(2)), dtype=float)
    if origin.shape != (2,) or not np.all(np.isfinite(origin)):
        raise FabkitError(f"{label}: origin must be 2 finite numbers (mm)")
    return field_from_grid(
        arrays["theta"],
        arrays["mask"],
        float(arrays["pixel_mm"]),
        (float(origin[0]), float(origin[1])),
        arrays.get("eps"),
        str(path),
    )


def _check_grid_headers(headers: Mapping[str, ArrayHeader], where: str) -> None:
    """Refuse a director grid file from its headers: known arrays only, each real or
    boolean, of the expected dimensions, and at most MAX_GRID_NODES nodes."""
    for key, header in headers.items():
        if key not in GRID_ARRAYS:
            raise FabkitError(f"{where}: unknown array '{key}' (expected {', '.join(GRID_ARRAYS)})")
        if len(header.shape) != GRID_ARRAYS[key] or header.dtype.kind not in "biuf":
            raise FabkitError(
                f"{where}: '{key}' must be a {GRID_ARRAYS[key]}-D array of real numbers, got "
                f"shape {header.shape} of {header.dtype}"
            )
        nodes = int(np.prod(header.shape))
        if nodes > MAX_GRID_NODES:
            raise FabkitError(f"{where}: '{key}' has {nodes} nodes, more than {MAX_GRID_NODES}")
