"""What the design pictures show, as plain data: :func:`scene` gathers it from a design.

It is the one step of the pictures that needs the parsed spec (the 3D curves on every
target); the drawings (:mod:`fabkit.plot.design`) take a :class:`Scene` and can run in
another process (``fabkit run`` draws beside its later stages, :mod:`fabkit.background`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree

from fabkit.design.check import ResidualMaps, residual_maps
from fabkit.design.design import Design
from fabkit.field.part import Part, PartRules, make_part, solved_nodes

CURVES = 24
"""About this many u-curves and v-curves are drawn on each picture."""


@dataclass(frozen=True)
class SurfaceView:
    """One target as its 3D panel shows it, in design units: ``title``; the patch's
    ``u_curves`` and ``v_curves`` on the target (polylines (n, 3)); ``backdrop`` the target
    surface near the patch ((40, 40, 3), NaN where cut away; None without one); ``box`` the
    cube the panel shows ((3,) centre, half side; None for an empty patch)."""

    title: str
    u_curves: tuple[np.ndarray, ...]
    v_curves: tuple[np.ndarray, ...]
    backdrop: np.ndarray | None
    box: tuple[np.ndarray, float] | None


@dataclass(frozen=True)
class Scene:
    """What the design pictures show: the ``design``'s arrays (its spec is not parsed
    again), the names of its ``features``, the ``part`` that is made, the check's residual
    ``maps`` and a :class:`SurfaceView` of every target with an embedding."""

    design: Design
    features: tuple[str, ...]
    part: Part
    maps: tuple[ResidualMaps, ...]
    surfaces: tuple[SurfaceView, ...]


def scene(
    design: Design, part: Part | None = None, maps: tuple[ResidualMaps, ...] | None = None
) -> Scene:
    """The :class:`Scene` of ``design``: the flat sheet with its ``part`` (default: the
    margin outline of :func:`fabkit.field.part.make_part` without a trim or minimum width)
    and the check's residual ``maps`` (computed here if not given)."""
    return Scene(
        design=replace(design),  # the arrays and the JSON: a copy without the parsed spec
        features=tuple(design.problem.material.features),
        part=part or make_part(design, PartRules()),
        maps=residual_maps(design) if maps is None else maps,
        surfaces=surface_views(design),
    )


def curve_stride(design: Design, axis: int) -> int:
    """Grid stride between drawn curves along ``axis`` (0: u-curves, 1: v-curves)."""
    spread = np.nonzero(design.valid.any(axis=axis))[0]
    extent = np.ptp(spread) + 1 if len(spread) else 1
    return max(1, int(extent // CURVES))


def grid_lines(points: np.ndarray, valid: np.ndarray, axis: int, stride: int) -> list[np.ndarray]:
    """Polylines of grid lines along ``axis`` (0: u-curves, 1: v-curves), every stride-th."""
    lines = []
    count = points.shape[1 - axis]
    for k in range(0, count, stride):
        line = points[:, k] if axis == 0 else points[k, :]
        mask = valid[:, k] if axis == 0 else valid[k, :]
        for run in true_runs(mask):
            if len(run) > 1:
                lines.append(line[run])
    return lines


def true_runs(mask: np.ndarray) -> list[np.ndarray]:
    """Index arrays of the consecutive True runs of a 1D mask."""
    edges = np.diff(np.concatenate([[0], mask.astype(int), [0]]))
    starts, stops = np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0]
    return [np.arange(a, b) for a, b in zip(starts, stops, strict=True)]


def surface_views(design: Design) -> tuple[SurfaceView, ...]:
    """A :class:`SurfaceView` of every target of ``design`` with an embedding in 3D."""
    views = []
    patch = solved_nodes(design)  # the initial curves' valid nodes run past the patch
    for j, target in enumerate(design.problem.targets):
        if j == 0 or target.surface.embed(target.start[None]) is None:
            continue
        chart = design.r[j]
        box = _cube(target.surface.embed(chart[patch]))
        u_curves, v_curves = (
            tuple(
                target.surface.embed(line)
                for line in grid_lines(chart, patch, axis, curve_stride(design, axis))
            )
            for axis in (0, 1)
        )
        stimulus = ", ".join(f"{s:g}" for s in target.stimulus)
        title = f"{target.name} (stimulus {stimulus})\nu-curves red, v-curves blue"
        backdrop = _surface_backdrop(target.surface, chart[patch], box)
        views.append(SurfaceView(title, u_curves, v_curves, backdrop, box))
    return tuple(views)


BACKDROP_MARGIN = 0.08
"""How far the target surface is drawn around the patch, as a share of the patch's
extent in its chart."""
BACKDROP_POINTS = 90
"""Chart points along each side of the backdrop (its edge steps are this fine)."""


def _cube(points: np.ndarray) -> tuple[np.ndarray, float] | None:
    """(centre (3,), half side) of the cube around ``points`` (n, 3); None if empty."""
    if len(points) == 0:
        return None
    low, high = points.min(axis=0), points.max(axis=0)
    return (low + high) / 2, float((high - low).max() / 2 * 1.05 + 1e-9)


def _surface_backdrop(surface, chart_points: np.ndarray, box) -> np.ndarray | None:
    """The target surface around the patch ((n, n, 3), n = :data:`BACKDROP_POINTS`): over
    the patch's chart bounding box, NaN farther than :data:`BACKDROP_MARGIN` of that box
    from the patch (a patch that curls, as the sphere's does, drew the whole box: an open
    band around the sphere), outside the surface and outside ``box`` (matplotlib does not
    clip 3D surfaces)."""
    if len(chart_points) == 0 or box is None:
        return None
    low, high = chart_points.min(axis=0), chart_points.max(axis=0)
    span = high - low + 1e-9
    margin = BACKDROP_MARGIN * span
    a, b = np.meshgrid(
        np.linspace(low[0] - margin[0], high[0] + margin[0], BACKDROP_POINTS),
        np.linspace(low[1] - margin[1], high[1] + margin[1], BACKDROP_POINTS),
        indexing="ij",
    )
    grid = np.stack([a, b], -1)
    near, _ = cKDTree(chart_points / span).query(grid / span)
    inside = surface.contains(grid) & (near <= BACKDROP_MARGIN)
    xyz = surface.embed(np.where(inside[..., None], grid, np.nan))
    centre, half = box
    with np.errstate(invalid="ignore"):
        outside = (np.abs(xyz - centre) > half).any(axis=-1)
    return np.where(outside[..., None], np.nan, xyz)
