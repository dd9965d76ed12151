"""Fields on the flat sheet, in millimetres: the director angle theta, eps, and the outline.

A :class:`FlatField` is what the toolpath stage needs from a design: the domain outline
(a shapely polygon, mm), the director angle ``theta(x, y)`` (radians, defined mod pi,
defined on the whole plane so that line generation may look a little past the outline)
and every designable feature ``eps_i(x, y)``, by name (a design's features are named in
its spec; a director file's single ``eps`` is the feature ``eps``).

It comes from one of three sources:

* :func:`~fabkit.field.design_field.field_from_design` -- a solved ``design.npz``
  (:mod:`fabkit.field.design_field`: theta and eps interpolated along the design's grid).
* :func:`field_from_expression` -- ``theta(x, y)`` as a safe expression on a named shape
  (``disc:10``, ``square:20``, ...), for standard patterns without a solve.
* :func:`field_from_grid` -- a theta grid and mask (and optional eps grid) in mm.

A director file (``.toml``) gives either of the last two
(:func:`~fabkit.field.director_file.load_director_file`).

Director angles are interpolated as the tensor ``(cos 2 theta, sin 2 theta)`` so that the
head-tail symmetry of the director is respected.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import contourpy
import numpy as np
import shapely
import shapely.affinity
import shapely.errors
from scipy.interpolate import RegularGridInterpolator
from scipy.spatial import cKDTree

from fabkit.errors import FabkitError
from fabkit.field.outlines import polygonal
from fabkit.field.part import Part
from fabkit.files.tomlfile import real
from fabkit.problem.expr import parse, shorten

PlaneFunction = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""A vectorised function of x and y (mm, broadcast arrays) returning an array of their shape."""

EXPRESSION_NAMES = ("x", "y", "r", "phi")
"""Names allowed in director and eps expressions: x, y (mm), r = hypot(x, y) (mm) and
phi = arctan2(y, x) (radians). ``arctan2(a, b)`` may also be called with two arguments."""


def director_angle(angle: np.ndarray) -> np.ndarray:
    """A director angle, or the difference of two (radians), taken mod pi into
    (-pi/2, pi/2]: a director has no head or tail."""
    return np.pi / 2 - np.mod(np.pi / 2 - angle, np.pi)


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
        return director_angle(angles)

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
        theta = director_angle(theta)
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
