"""The sheet as fabricated, simulated under every target's stimulus, and its verdict.

:func:`sheet_fields` turns the read-back director and features (on the grid of
:mod:`fabkit.verify.raster`, decoded by
:func:`fabkit.verify.compare_fields.decode_features`) into fields of the flat sheet,
averaged over a physical length; :func:`simulate_targets`
simulates the sheet they make (:func:`fabkit.mechanics.fabricated.simulate_sheet`) under
every target's stimulus and reports its distance to the target as ``fabkit simulate``
does (RMS and max after rigid alignment, % of the patch diameter), and, if asked, the
sheet as designed on the same mesh; :func:`fabricated_verdict` is the verdict on it
(:mod:`fabkit.mechanics.verdict`). Called by :func:`fabkit.verify.machine_file.verify`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import ndimage

from fabkit.design.design import Design
from fabkit.field.part import Part
from fabkit.mechanics.fabricated import SheetFields, design_fields
from fabkit.mechanics.simulate import STARTS, Settings, ramp_words
from fabkit.mechanics.verdict import (
    FORM_TOLERANCE,
    Shape,
    Verdict,
    embedded_targets,
    share_progress,
    target_shapes,
    turned_starts,
)
from fabkit.process import Resolution
from fabkit.verify.compare_fields import ComparedSheet, decode_features
from fabkit.verify.raster import Readback


@dataclass(frozen=True)
class TargetDistance:
    """The sheet as fabricated against one target: RMS and max distance, % of the patch
    diameter; the sheet as designed on the same mesh when asked (else None)."""

    target: str
    surface: int
    rms_pct: float
    max_pct: float
    mirrored: bool
    converged: bool
    triangles: int
    seconds: float
    designed_rms_pct: float | None = None
    designed_max_pct: float | None = None
    designed_converged: bool | None = None


def fabricated_verdict(
    shapes: tuple[Shape, ...], layers: int, thickness_mm: float
) -> Verdict | None:
    """The verdict on the sheet as fabricated, from the shapes it takes under every
    target's stimulus (None when it was not simulated)."""
    if not shapes:
        return None
    return Verdict("as fabricated", shapes, layers, thickness_mm)


def simulation_figures(
    smoothing: float, readback: Readback, thickness_mm: float, layers: int = 1
) -> dict[str, Any]:
    """What the simulations of the sheet as fabricated used (report.json's ``simulation``)."""
    settings = Settings()
    return {
        "smoothing_mm": smoothing,
        "road_width_mm": readback.width_mm,
        "thickness_mm": thickness_mm,
        "layers": layers,
        "seed": ", ".join(STARTS),
        "path": f"flat sheet as made -> each target's stimulus, {ramp_words(settings)}",
        "error_turned_over": ", ".join(turned_starts()) if layers > 1 else "",
        "solver": "damped Newton (exact Hessian, Levenberg-Marquardt)",
    }


def simulation_note(figures: dict[str, Any]) -> str:
    return (
        f"simulated with the read-back fields averaged over a Gaussian of "
        f"{figures['smoothing_mm']:.3g} mm (road width {figures['road_width_mm']:.3g} mm, "
        f"sheet thickness {figures['thickness_mm']:.3g} mm: {figures['layers']} printed "
        f"layer{'s' if figures['layers'] > 1 else ''}), from each start ({figures['seed']}"
        f"{_turned_words(figures)}), path {figures['path']}"
    )


def _turned_words(figures: dict[str, Any]) -> str:
    """Which starts ran with the print's error turned over ("" for one layer: its error
    bends the sheet to no side)."""
    turned = figures.get("error_turned_over")
    if not turned:
        return ""
    return f"; {turned} with the print's error turned over: a side the error chose flips there"


def sheet_fields(
    readback: Readback,
    resolution: Resolution,
    sheet: ComparedSheet,
    scale: float,
    names: tuple[str, ...],
    smoothing_mm: float,
) -> SheetFields:
    """The read-back director and features as functions of flat-sheet points in design
    units, made where the printed region (covered cells, gaps narrower than a road
    closed) is.

    Each uncovered cell takes its nearest covered cell's values; the director (as the
    tensor (cos 2 theta, sin 2 theta)) and the features are then averaged over a Gaussian
    of standard deviation ``smoothing_mm`` and sampled bilinearly. The average is the
    physics, not a cosmetic: a road's director and features are one per road, so cell
    to cell differences below a road width are the reading's, not the sheet's; and a
    sheet of thickness h cannot resolve a reference metric that varies on scales below h
    (plate theory's metric is the average over a few h). Sampled raw at the mesh's
    vertices, that noise frustrates the metric: on Fig. 1 (60 mm) it triples the bump's
    residual energy and leaves several equilibria of equal energy 3.2 to 4.3 % from the
    target, where the fields averaged over the thickness (0.6 mm) give one, 2.6 %.
    """
    decoded = decode_features(readback, resolution)
    covered = readback.hits > 0
    made = ndimage.binary_closing(covered, _disc(readback.width_mm / readback.cell_mm))
    made |= covered
    nearest = ndimage.distance_transform_edt(~covered, return_distances=False, return_indices=True)
    grids = [np.cos(2 * readback.theta), np.sin(2 * readback.theta)]
    grids += [decoded[name] for name in names]
    sigma = smoothing_mm / readback.cell_mm
    filled = [ndimage.gaussian_filter(g[tuple(nearest)], sigma, mode="nearest") for g in grids]

    def cells(points: np.ndarray) -> np.ndarray:
        """(2, n) fractional cell coordinates of design-unit points."""
        mm = np.asarray(points, dtype=float) * scale
        return ((mm - np.asarray(readback.origin)) / readback.cell_mm - 0.5).T

    def sample(points: np.ndarray) -> list[np.ndarray]:
        where = cells(points)
        return [ndimage.map_coordinates(g, where, order=1, mode="nearest") for g in filled]

    def theta(points: np.ndarray) -> np.ndarray:
        cos2, sin2, *_ = sample(points)
        return 0.5 * np.arctan2(sin2, cos2)

    def features(points: np.ndarray) -> np.ndarray:
        return np.array(sample(points)[2:])

    def is_made(points: np.ndarray) -> np.ndarray:
        index = np.rint(cells(points)).astype(int)
        inside = (index >= 0).all(axis=0) & (index[0] < made.shape[0]) & (index[1] < made.shape[1])
        out = np.zeros(index.shape[1], dtype=bool)
        out[inside] = made[index[0, inside], index[1, inside]]
        return out

    return SheetFields(theta, features, is_made)


def _disc(radius: float) -> np.ndarray:
    reach = max(1, int(math.ceil(radius)))
    offsets = np.arange(-reach, reach + 1)
    return offsets[:, None] ** 2 + offsets[None, :] ** 2 <= max(radius, 1.0) ** 2


def simulate_targets(
    design: Design,
    fields: list[SheetFields],
    part: Part | None,
    thickness_mm: float,
    mm_per_unit: float,
    *,
    stride: int | None,
    max_iterations: int,
    with_reference: bool,
    tolerance: float = FORM_TOLERANCE,
    progress: Callable[[int, int], None] | None = None,
) -> tuple[tuple[TargetDistance, ...], tuple[Shape, ...]]:
    """The sheet of ``fields`` (one per layer, bottom first) on the cells of ``part``,
    ``thickness_mm`` thick in all, under every target's stimulus from every start (and,
    ``with_reference``, the sheet as designed on the same mesh), at ``mm_per_unit`` mm
    per design unit, on the design's grid coarsened by ``stride`` (None: about
    :data:`~fabkit.mechanics.verdict.TARGET_TRIANGLES` triangles), ``max_iterations``
    per ramp step; ``progress`` over all their ramp steps. Returns the distance to every
    target (the worst start's) and the shape the sheet takes there
    (:func:`~fabkit.mechanics.verdict.target_shapes`, held to ``tolerance``)."""
    settings = Settings(max_iterations=max_iterations)
    if design.layering is None:
        own = [design_fields(design)] * len(fields)
    else:
        own = [design_fields(design.layer(k)) for k in range(design.layers)]
    own = [SheetFields(o.theta, o.features, fields[0].made) for o in own]
    sheets = [fields, own] if with_reference else [fields]
    surfaces = embedded_targets(design)
    found = [
        target_shapes(
            design,
            sheet,
            surfaces,
            thickness_mm / mm_per_unit,
            tolerance=tolerance,
            part=part,
            stride=stride,
            settings=settings,
            mm_per_unit=mm_per_unit,
            progress=share_progress(progress, j, len(sheets)),
            designed=own if j == 0 else None,
        )
        for j, sheet in enumerate(sheets)
    ]
    designed = found[1] if with_reference else [None] * len(surfaces)
    distances = tuple(
        _distance(made, surface, reference)
        for made, surface, reference in zip(found[0], surfaces, designed, strict=True)
    )
    return distances, tuple(found[0])


def _distance(made: Shape, surface: int, designed: Shape | None) -> TargetDistance:
    """The figures of the sheet as fabricated against one target (and of the sheet as
    designed on the same mesh), the worst start's."""
    return TargetDistance(
        target=made.target,
        surface=surface,
        rms_pct=100 * made.rms,
        max_pct=100 * made.max,
        mirrored=made.mirrored,
        converged=made.converged,
        triangles=len(made.mesh.triangles) if made.mesh is not None else 0,
        seconds=made.seconds,
        designed_rms_pct=100 * designed.rms if designed else None,
        designed_max_pct=100 * designed.max if designed else None,
        designed_converged=designed.converged if designed else None,
    )
