"""How well a simulated sheet realises its target: distances, metric residuals, curvature.

Every simulated vertex carries its material coordinates (u, v), so it corresponds to
the point r_s(u, v) of target s embedded in 3D. The simulated sheet is aligned to those
points by the best rigid motion (Kabsch), and by the best rigid motion combined with a
mirror image (the flat sheet cannot tell a shape from its mirror image when it buckles
without a preferred side); the better of the two is reported. Distances are divided by
the patch size: the largest distance between two target points.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np
import shapely

from fabkit.design.design import Design
from fabkit.errors import FabkitError
from fabkit.mechanics.outline import on_outline
from fabkit.mechanics.simulate import DesignSimulation, diameter


@dataclass(frozen=True)
class Alignment:
    """``aligned`` (n, 3) source points after the rigid motion (and mirror if ``mirrored``);
    ``rms`` and ``max`` distances to the target points (their units)."""

    aligned: np.ndarray
    mirrored: bool
    rms: float
    max: float


def align(source: np.ndarray, target: np.ndarray, mirror: bool = True) -> Alignment:
    """Best rigid motion of ``source`` (n, 3) onto corresponding ``target`` (n, 3).

    With ``mirror`` the mirror image of ``source`` is tried too and the better is kept.
    """
    candidates = [_kabsch(source, target)]
    if mirror:
        candidates.append(_kabsch(source * np.array([1.0, 1.0, -1.0]), target))
    best = min(candidates, key=lambda points: _rms(points, target))
    distances = np.linalg.norm(best - target, axis=1)
    return Alignment(
        best,
        best is not candidates[0],
        float(np.sqrt(np.mean(distances**2))),
        float(np.max(distances)),
    )


def _kabsch(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Source moved by the proper rotation and translation minimising the RMS distance."""
    return _rigid_motion(source, target)(source)


def proper_rotation(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The proper rotation R (3, 3) that, with the centroids matched, best fits ``source``
    (n, 3) to ``target`` (n, 3) in RMS: (source - its mean) @ R + target's mean (Kabsch)."""
    covariance = (source - source.mean(0)).T @ (target - target.mean(0))
    left, _, right = np.linalg.svd(covariance)
    sign = np.sign(np.linalg.det(left @ right)) or 1.0
    return left @ np.diag([1.0, 1.0, sign]) @ right


def _rigid_motion(source: np.ndarray, target: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """The proper rotation and translation that minimise the RMS distance from ``source``
    (n, 3) to ``target`` (n, 3), as a function moving any points (m, 3)."""
    source_mean, target_mean = source.mean(0), target.mean(0)
    rotation = proper_rotation(source, target)
    return lambda points: (points - source_mean) @ rotation + target_mean


def _rms(points: np.ndarray, target: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((points - target) ** 2, axis=1))))


def metric_strain(
    positions: np.ndarray, points: np.ndarray, triangles: np.ndarray, metrics: np.ndarray
) -> np.ndarray:
    """Largest principal strain |stretch - 1| of every face (F,) against its reference metric.

    ``positions`` (V, 3) deformed, ``points`` (V, 2) flat, ``metrics`` (F, 2, 2).
    """
    corners, flat = positions[triangles], points[triangles]
    jac = np.stack([corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]], -1)
    sides = np.stack([flat[:, 1] - flat[:, 0], flat[:, 2] - flat[:, 0]], -1)
    jac = jac @ np.linalg.inv(sides)
    metric = np.einsum("fck,fcl->fkl", jac, jac)
    root = np.linalg.cholesky(np.linalg.inv(metrics))
    ratio = np.einsum("fki,fkl,flj->fij", root, metric, root)
    stretches = np.sqrt(np.clip(np.linalg.eigvalsh(ratio), 0.0, None))
    return np.max(np.abs(stretches - 1.0), axis=1)


def angle_defects(positions: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """2 pi minus the sum of triangle angles at every vertex (V,) (meaningful inside)."""
    total = np.zeros(len(positions))
    for k in range(3):
        a, b, c = (positions[triangles[:, (k + i) % 3]] for i in range(3))
        u, v = b - a, c - a
        angle = np.arctan2(np.linalg.norm(np.cross(u, v), axis=1), np.einsum("fi,fi->f", u, v))
        total += np.bincount(triangles[:, k], weights=angle, minlength=len(positions))
    return 2 * np.pi - total


def boundary_vertices(triangles: np.ndarray, count: int) -> np.ndarray:
    """Boolean mask (count,) of vertices on an edge used by one triangle only."""
    edges = np.sort(triangles[:, [[1, 2], [2, 0], [0, 1]]].reshape(-1, 2), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    mask = np.zeros(count, dtype=bool)
    mask[unique[counts == 1].ravel()] = True
    return mask


def integrated_curvature(positions: np.ndarray, triangles: np.ndarray) -> float:
    """Integrated Gaussian curvature of the mesh's interior: its summed angle defects."""
    inside = ~boundary_vertices(triangles, len(positions))
    return float(np.sum(angle_defects(positions, triangles)[inside]))


@dataclass(frozen=True)
class Comparison:
    """A simulated design against its target.

    ``size`` is the target patch's diameter (design units); ``rms`` and ``max`` are
    distances at the design's grid points after alignment divided by ``size``;
    ``strain_median``, ``strain_p95``, ``strain_max`` summarise :func:`metric_strain`
    over the faces.
    """

    name: str
    surface: int
    thickness: float
    triangles: int
    size: float
    rms: float
    max: float
    mirrored: bool
    strain_median: float
    strain_p95: float
    strain_max: float
    energy: float
    iterations: int
    converged: bool
    seconds: float

    def to_dict(self) -> dict:
        return asdict(self)

    def table(self, mm_per_unit: float | None = None) -> str:
        """A short human summary; lengths in mm at ``mm_per_unit`` (None: design units)."""
        mirror = " (mirror image)" if self.mirrored else ""
        scale, unit = (1.0, "") if mm_per_unit is None else (mm_per_unit, " mm")
        return "\n".join(
            [
                f"surface {self.surface} '{self.name}': {self.triangles} triangles, "
                f"thickness {self.thickness * scale:.4g}{unit}",
                f"  distance to target / patch diameter {self.size * scale:.4g}{unit}: "
                f"RMS {100 * self.rms:.3f} %, max {100 * self.max:.3f} %{mirror}",
                f"  metric strain: median {self.strain_median:.2e}, p95 {self.strain_p95:.2e}, "
                f"max {self.strain_max:.2e}",
                f"  Newton iterations {self.iterations}, converged {self.converged}, "
                f"energy {self.energy:.4g} Y, {self.seconds:.1f} s",
            ]
        )


def target_points(design: Design, simulation: DesignSimulation) -> np.ndarray:
    """The target points (V, 3) r_s(u, v) of the simulated vertices, embedded in 3D.

    On a refined mesh the chart points between the design's grid points are
    interpolated bilinearly in (u, v) (they lie on the target surface).
    """
    surface = design.problem.targets[simulation.surface].surface
    embedded = surface.embed(simulation.mesh.sample(design.r[simulation.surface]))
    if embedded is None:
        raise FabkitError(
            f"surface '{simulation.name}' is intrinsic (metric only): no 3D target to compare"
        )
    return embedded


def compare(design: Design, simulation: DesignSimulation, size: float | None = None) -> Comparison:
    """Align a design simulation with its target and measure the differences.

    Distances are measured at the design's own grid points (the refined mesh's other
    vertices are left out, so the figures compare across refinements), as shares of
    ``size``, the patch diameter (design units; default: the diameter of the target
    points of the simulated mesh).
    """
    result, mesh = simulation.result, simulation.mesh
    nodes = mesh.nodes
    target = target_points(design, simulation)[nodes]
    alignment = align(result.positions[nodes], target)
    size = diameter(target) if size is None else size
    strain = metric_strain(result.positions, mesh.points, mesh.triangles, simulation.metrics)
    return Comparison(
        simulation.name,
        simulation.surface,
        simulation.thickness,
        len(mesh.triangles),
        size,
        alignment.rms / size,
        alignment.max / size,
        alignment.mirrored,
        float(np.median(strain)),
        float(np.percentile(strain, 95)),
        float(np.max(strain)),
        result.energy,
        result.iterations,
        result.converged,
        result.seconds,
    )


@dataclass(frozen=True, eq=False)
class FormedShape:
    """The shape a simulated sheet takes under one target's stimulus, beside that target,
    in mm (for pictures and mesh files; every array is plain numpy).

    ``vertices_mm`` (V, 3): the simulated sheet moved by the rotation and translation
    (never a mirror image) that best fit it to the target at the design's grid points;
    ``target_mm`` (V, 3): the target's points at the same material points (u, v);
    ``triangles`` (F, 3) index both; ``distance_mm`` (V,): from each vertex to its target
    point; ``diameter_mm``: the target patch's diameter (what the verdict's percentages
    are shares of). A sheet that takes the target's mirror image is shown as it is, so
    its distances here are those to the target itself (no smaller than the verdict's,
    which are measured after the better of the motion and the mirrored one).
    """

    name: str
    vertices_mm: np.ndarray
    target_mm: np.ndarray
    triangles: np.ndarray
    distance_mm: np.ndarray
    diameter_mm: float


def formed_shape(
    design: Design,
    simulation: DesignSimulation,
    mm_per_unit: float,
    size: float | None = None,
    outline: shapely.Geometry | None = None,
) -> FormedShape:
    """The simulated sheet fitted to its target (:class:`FormedShape`), at ``mm_per_unit``
    mm per design unit; the fit, as :func:`compare`'s, uses the design's grid points, and
    ``size`` is the patch diameter as there. With the part's ``outline`` (flat-sheet
    coordinates) the mesh is drawn up to it (:func:`~fabkit.mechanics.outline.on_outline`)
    rather than along its grid cells."""
    nodes = simulation.mesh.nodes
    positions = simulation.result.positions
    target = target_points(design, simulation)
    moved = _rigid_motion(positions[nodes], target[nodes])(positions)
    size = diameter(target[nodes]) if size is None else size
    triangles = np.asarray(simulation.mesh.triangles)
    if outline is not None:
        drawn = on_outline(design, simulation.mesh, moved, target, simulation.surface, outline)
        moved, target, triangles = drawn.sheet, drawn.target, drawn.triangles
    return FormedShape(
        simulation.name,
        moved * mm_per_unit,
        target * mm_per_unit,
        triangles,
        np.linalg.norm(moved - target, axis=1) * mm_per_unit,
        size * mm_per_unit,
    )
