"""Forward simulation of a sheet as it was made: its own director and features.

A design prescribes, on the flat sheet, the director n (the u-curves) and the features
eps; a fabricated sheet has a director and features of its own (read back from the
machine file by ``fabkit verify``). :class:`SheetFields` holds them as functions of the
flat-sheet position (design units) together with the region that was made.

The simulation reuses the design's material grid: its mesh (coarsened by ``stride``,
faces kept where the sheet was made) keeps every vertex's material coordinates (u, v),
so the distance to each target is measured exactly as ``fabkit simulate`` does
(:func:`fabkit.mechanics.compare.compare`). The reference metric at a stimulus is the
material's: stretches lambda1 along the *fabricated* director and lambda2 across it, at
the *fabricated* features, in flat-sheet coordinates,

    a = R(theta) diag(lambda1^2, lambda2^2) R(theta)^T,

pulled back to (u, v) by the flat map's Jacobian J = [alpha n0, beta t0] (n0 the
designed flat director, t0 perpendicular to it with the orientation of the v-curves):
A = J^T a J. Each mesh edge's reference length follows by the trapezoidal rule in (u, v)
as for a design (:func:`~fabkit.mechanics.simulate.design_metrics`); with the design's
own director and features A is diag((alpha lambda1)^2, (beta lambda2)^2) and the metrics
are the design's. The sheet as made is unstretched (the flat sheet's stimulus gives
lambda = 1), so the ramp starts from J^T J, the designed flat metric.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import shapely

from fabkit.design.design import Design
from fabkit.errors import FabkitError
from fabkit.field.part import Part
from fabkit.mechanics.mesh import DesignMesh, counter_clockwise, design_mesh
from fabkit.mechanics.metric import length_system, metric_from_lengths
from fabkit.mechanics.simulate import (
    DesignSimulation,
    Settings,
    Simulation,
    default_thickness,
    diameter,
    simulate,
)

PointFunction = Callable[[np.ndarray], np.ndarray]
"""A function of (n, 2) flat-sheet points (design units)."""


@dataclass(frozen=True)
class SheetFields:
    """A flat sheet as made, as functions of (n, 2) flat-sheet points in design units.

    ``theta`` gives the director angle (n,) (radians, mod pi), ``features`` the features
    (N, n) in the order of the design's spec, ``made`` whether each point was made
    (n,) bool.
    """

    theta: PointFunction
    features: PointFunction
    made: PointFunction


def design_fields(design: Design) -> SheetFields:
    """The design's own fields, made wherever it is solved (the sheet as designed):
    interpolated linearly between the design's grid points on the flat sheet, exact at
    them."""
    from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator

    mesh = design_mesh(design)
    n0 = mesh.sample(design.n[0])
    angle = np.arctan2(n0[:, 1], n0[:, 0])
    eps = mesh.sample(np.moveaxis(design.eps, 0, -1)).reshape(len(angle), -1)
    values = np.column_stack([np.cos(2 * angle), np.sin(2 * angle), eps])
    linear = LinearNDInterpolator(mesh.points, values)
    nearest = NearestNDInterpolator(mesh.points, values)

    def sample(points: np.ndarray) -> np.ndarray:
        out = linear(points)
        missing = ~np.isfinite(out).all(axis=1)
        if missing.any():
            out[missing] = nearest(points[missing])
        return out

    def theta(points: np.ndarray) -> np.ndarray:
        tensor = sample(points)
        return 0.5 * np.arctan2(tensor[:, 1], tensor[:, 0])

    return SheetFields(
        theta=theta,
        features=lambda points: sample(points)[:, 2:].T,
        made=lambda points: np.ones(len(points), dtype=bool),
    )


def coarsened(design: Design, stride: int) -> Design:
    """The design on every ``stride``-th grid line (the lines through u = 0, v = 0 kept)."""
    if stride < 1:
        raise FabkitError(f"stride must be a positive integer, got {stride}")
    if stride == 1:
        return design
    i0 = int(np.argmin(np.abs(design.u))) % stride
    j0 = int(np.argmin(np.abs(design.v))) % stride
    rows, cols = slice(i0, None, stride), slice(j0, None, stride)
    return replace(
        design,
        u=design.u[rows],
        v=design.v[cols],
        valid=design.valid[rows, cols],
        alpha=design.alpha[rows, cols],
        beta=design.beta[rows, cols],
        eps=design.eps[:, rows, cols],
        r=design.r[:, rows, cols],
        n=design.n[:, rows, cols],
    )


def made_mesh(mesh: DesignMesh, made: PointFunction) -> DesignMesh:
    """A design's ``mesh`` with only the faces whose centroid was made (unused vertices
    dropped); a one-line error if nothing is left."""
    centroids = mesh.points[mesh.triangles].mean(axis=1)
    return _faces(mesh, np.asarray(made(centroids), dtype=bool))


def _faces(mesh: DesignMesh, keep: np.ndarray) -> DesignMesh:
    """``mesh`` with the faces ``keep`` only (unused vertices dropped)."""
    if not keep.any():
        raise FabkitError("no face of the design's mesh lies on the sheet as made")
    triangles = mesh.triangles[keep]
    used = np.unique(triangles)
    index = np.full(len(mesh.points), -1)
    index[used] = np.arange(len(used))
    points = mesh.points[used]
    return DesignMesh(points, counter_clockwise(points, index[triangles]), mesh.grid[used])


def sheet_metrics(
    design: Design, mesh: DesignMesh, surface: int, theta: np.ndarray, eps: np.ndarray
) -> np.ndarray:
    """Per-face reference metrics (F, 2, 2) at surface ``surface``'s stimulus for the
    director angles ``theta`` (V,) and features ``eps`` (N, V) at the mesh's vertices
    (a one-line error where a face's edge lengths make no metric)."""
    return metric_from_lengths(
        mesh.points, mesh.triangles, _edge_lengths(design, mesh, surface, theta, eps)
    )


def _edge_lengths(
    design: Design,
    mesh: DesignMesh,
    surface: int,
    theta: np.ndarray,
    eps: np.ndarray,
    jacobian: np.ndarray | None = None,
) -> np.ndarray:
    """Reference lengths (F, 3) of every face's edges, design units (module docstring);
    ``jacobian``: :func:`_flat_jacobian` of the design and mesh, if known.

    An edge step s in (u, v) has the length |diag(lambda1, lambda2) R(theta)^T J s| at a
    vertex, the square root of s^T A s taken as the norm of a vector: summing the two
    squares never cancels, where s^T A s itself comes out below zero by rounding when
    one stretch is negligible beside the other (NaN lengths, a warning)."""
    lambda1, lambda2 = _stretches(design, surface, eps)
    along = np.column_stack([np.cos(theta), np.sin(theta)])
    across = np.column_stack([-along[:, 1], along[:, 0]])
    scaled = np.stack([lambda1[:, None] * along, lambda2[:, None] * across], axis=1)
    if jacobian is None:
        jacobian = _flat_jacobian(design, mesh)
    to_flat = scaled @ jacobian  # (V, 2, 2): (u, v) step -> stretched
    start, end = mesh.triangles[:, [1, 2, 0]], mesh.triangles[:, [2, 0, 1]]
    steps = design.step / mesh.refine * (mesh.grid[end] - mesh.grid[start])  # (F, 3, 2)
    speed = [
        np.linalg.norm(np.einsum("feij,fej->fei", to_flat[k], steps), axis=-1) for k in (start, end)
    ]
    return 0.5 * (speed[0] + speed[1])


FEATURE_STEP = 1e-6
"""Central-difference step of a feature in the material law's stretches."""


def sheet_metrics_gradient(
    design: Design,
    mesh: DesignMesh,
    surface: int,
    theta: np.ndarray,
    eps: np.ndarray,
    metric_gradient: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The gradient of a quantity J through :func:`sheet_metrics`: given dJ/dm (F, 3)
    (components a11, a12, a22 of each face's metric, a12 both off-diagonal places), dJ/d
    ``theta`` (V,) and dJ/d ``eps`` (N, V) at the mesh's vertices. Exact but for the
    material law's derivative in the features (a central difference)."""
    system = length_system(mesh.points, mesh.triangles)
    lengths = _edge_lengths(design, mesh, surface, theta, eps)
    per_square = np.linalg.solve(np.swapaxes(system, 1, 2), metric_gradient[..., None])[..., 0]
    per_length = 2 * lengths * per_square  # dJ/dl (F, 3)

    lambda1, lambda2 = _stretches(design, surface, eps)
    along = np.column_stack([np.cos(theta), np.sin(theta)])
    across = np.column_stack([-along[:, 1], along[:, 0]])
    jacobian = _flat_jacobian(design, mesh)
    start, end = mesh.triangles[:, [1, 2, 0]], mesh.triangles[:, [2, 0, 1]]
    steps = design.step / mesh.refine * (mesh.grid[end] - mesh.grid[start])
    d_theta = np.zeros(len(theta))
    d_lambda = np.zeros((2, len(theta)))
    for ends in (start, end):
        flat = np.einsum("feij,fej->fei", jacobian[ends], steps)  # J s: the flat-sheet step
        a = np.einsum("fei,fei->fe", along[ends], flat)
        b = np.einsum("fei,fei->fe", across[ends], flat)
        l1, l2 = lambda1[ends], lambda2[ends]
        speed = np.sqrt((l1 * a) ** 2 + (l2 * b) ** 2)
        weight = 0.5 * per_length / np.maximum(speed, np.finfo(float).tiny)
        np.add.at(d_theta, ends, weight * (l1**2 - l2**2) * a * b)
        np.add.at(d_lambda[0], ends, weight * l1 * a * a)
        np.add.at(d_lambda[1], ends, weight * l2 * b * b)
    d_eps = np.zeros_like(eps, dtype=float)
    for i in range(len(eps)):
        change = np.zeros_like(eps, dtype=float)
        change[i] = FEATURE_STEP
        up, down = (
            _stretches(design, surface, eps + change),
            _stretches(design, surface, eps - change),
        )
        for k in range(2):
            d_eps[i] += d_lambda[k] * (up[k] - down[k]) / (2 * FEATURE_STEP)
    return d_theta, d_eps


MIN_STRETCH_RATIO = float(np.sqrt(np.finfo(float).eps))
"""Smallest ratio of the smaller stretch to the larger that still makes a metric in double
precision (1.5e-8): below it the squared length across the director is lost in the
rounding of the one along it, and the sheet would collapse to its director's lines."""


def _stretches(design: Design, surface: int, eps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The material's stretches lambda1, lambda2 (V,) at the features ``eps`` (N, V) under
    surface ``surface``'s stimulus; a one-line error where they make no metric: not
    finite, not positive, or one below :data:`MIN_STRETCH_RATIO` of the other (features
    outside the material law's range: a design file edited by hand, a material law that
    vanishes)."""
    spec = design.problem
    response = spec.material.response(eps, design.stimuli[surface : surface + 1])
    lambda1, lambda2 = response.lambda1[0], response.lambda2[0]
    larger = np.maximum(np.abs(lambda1), np.abs(lambda2))
    usable = (
        np.isfinite(larger)
        & (lambda1 > MIN_STRETCH_RATIO * larger)
        & (lambda2 > MIN_STRETCH_RATIO * larger)
    )
    if usable.all():
        return lambda1, lambda2
    first = int(np.argmin(usable))
    features = zip(spec.material.features, eps[:, first], strict=True)
    at = ", ".join(f"{name} = {value:.6g}" for name, value in features)
    raise FabkitError(
        f"the material makes no metric at {np.count_nonzero(~usable)} of {len(usable)} "
        f"points of the sheet under the stimulus of '{spec.targets[surface].name}': "
        f"lambda1 = {lambda1[first]:.3g}, lambda2 = {lambda2[first]:.3g} at {at} (a stretch "
        f"must be positive, finite and at least {MIN_STRETCH_RATIO:.1e} of the other): the "
        "features are outside the material law's range"
    )


def _flat_jacobian(design: Design, mesh: DesignMesh) -> np.ndarray:
    """(V, 2, 2) Jacobian of the flat map r0(u, v) at the vertices: columns alpha n0 and
    beta t0, t0 perpendicular to n0 on the side of the v-curves."""
    n0 = mesh.sample(design.n[0])
    n0 /= np.linalg.norm(n0, axis=1, keepdims=True)
    perp = np.column_stack([-n0[:, 1], n0[:, 0]])
    alpha, beta = mesh.sample(design.alpha), mesh.sample(design.beta)
    return np.stack([alpha[:, None] * n0, _v_side(design) * beta[:, None] * perp], axis=-1)


def _v_side(design: Design) -> float:
    """+1 if the v-curves run to the left of the flat director (counter-clockwise), else -1."""
    r0, n0 = design.r[0], design.n[0]
    both = design.valid[:, 1:] & design.valid[:, :-1]
    dv = (r0[:, 1:] - r0[:, :-1])[both]
    n = n0[:, :-1][both]
    cross = n[:, 0] * dv[:, 1] - n[:, 1] * dv[:, 0]
    return 1.0 if np.median(cross) >= 0 else -1.0


@dataclass(frozen=True)
class SheetProblem:
    """A sheet to simulate under one target's stimulus, as plain data: the ``coarse``
    design it is compared against, its ``mesh`` (where it was made), the per-layer
    reference metrics as made (``start_metrics``) and under the stimulus (``metrics``),
    each (F, 2, 2) or (L, F, 2, 2) bottom first, and its ``thickness`` (design units).
    ``patch_size`` (design units) is the diameter of the target's patch over the whole
    part, made or not: the base of every distance's percentage, the same for the sheet
    as designed and as fabricated (None for a target with no 3D embedding). ``outline``
    is the part's (flat-sheet coordinates; None: no part), up to which its shapes are
    drawn."""

    surface: int
    name: str
    coarse: Design
    mesh: DesignMesh
    start_metrics: np.ndarray
    metrics: np.ndarray
    thickness: float
    poisson: float
    patch_size: float | None = None
    outline: shapely.Geometry | None = field(default=None, repr=False, compare=False)

    def simulation(self, result: Simulation) -> DesignSimulation:
        """``result`` of simulating this problem, as a design simulation whose
        ``metrics`` are the layers' mean."""
        metrics = self.metrics
        mean = metrics if metrics.ndim == 3 else metrics.mean(axis=0)
        return DesignSimulation(self.surface, self.name, self.mesh, mean, self.thickness, result)

    def run(
        self, settings: Settings, progress: Callable[[int, int], None] | None = None
    ) -> Simulation:
        """Simulate from the flat sheet as made (seeded as ``settings`` says)."""
        mesh = self.mesh
        return simulate(
            mesh.points,
            mesh.triangles,
            self.metrics,
            self.thickness,
            self.poisson,
            settings,
            start_metrics=self.start_metrics,
            progress=progress,
        )


def sheet_problem(
    design: Design,
    fields: SheetFields | Sequence[SheetFields],
    surface: int,
    thickness: float | None = None,
    poisson: float = 0.5,
    part: Part | None = None,
    stride: int = 1,
) -> SheetProblem:
    """The sheet of ``fields`` (one, or one per equal layer, bottom first) under surface
    ``surface``'s stimulus, ready to simulate (:func:`sheet_problems` of one surface)."""
    return sheet_problems(design, fields, [surface], thickness, poisson, part, stride)[0]


def sheet_problems(
    design: Design,
    fields: SheetFields | Sequence[SheetFields],
    surfaces: Sequence[int],
    thickness: float | None = None,
    poisson: float = 0.5,
    part: Part | None = None,
    stride: int = 1,
) -> list[SheetProblem]:
    """The sheet of ``fields`` (one, or one per equal layer, bottom first) under each of
    the ``surfaces``' stimuli, ready to simulate; the mesh, the fields at its vertices and
    the reference lengths under each stimulus are worked out once for all of them.

    The mesh is the design's grid coarsened by ``stride`` (its cells in ``part``, as in
    :func:`~fabkit.mechanics.mesh.design_mesh`), restricted to where the first layer was
    made and to the faces whose edge lengths make a metric at every stimulus.
    ``thickness`` (the whole sheet's, design units) defaults to 1 % of the diameter of the
    design's whole solved flat domain (as ``fabkit simulate``).
    """
    layers = [fields] if isinstance(fields, SheetFields) else list(fields)
    coarse = coarsened(design, stride)
    whole = design_mesh(coarse, part)
    mesh = made_mesh(whole, layers[0].made)
    if thickness is None:
        thickness = default_thickness(design)
    lengths = _LayerLengths(coarse, mesh, layers)
    ok = np.ones(len(mesh.triangles), dtype=bool)
    for s in range(len(design.stimuli)):
        for layer in range(len(layers)):
            a, b, c = lengths.at(s, layer).T
            ok &= (a < b + c) & (b < c + a) & (c < a + b)
    if not ok.all():
        mesh = _faces(mesh, ok)
        lengths = _LayerLengths(coarse, mesh, layers)

    def metrics_at(s: int) -> np.ndarray:
        stacked = lengths.metrics(s)
        return stacked[0] if len(stacked) == 1 else stacked

    start = metrics_at(0)
    return [
        SheetProblem(
            surface,
            design.problem.targets[surface].name,
            coarse,
            mesh,
            start,
            metrics_at(surface),
            thickness,
            poisson,
            patch_size(coarse, surface, whole),
            None if part is None else part.outline,
        )
        for surface in surfaces
    ]


class _LayerLengths:
    """Every layer's reference edge lengths (F, 3) on ``mesh`` under each stimulus, each
    worked out when first asked for (:func:`_edge_lengths`), and the metrics they make."""

    def __init__(self, design: Design, mesh: DesignMesh, layers: Sequence[SheetFields]) -> None:
        self._design, self._mesh = design, mesh
        self._sampled = _sampled(layers, mesh)
        self._jacobian = _flat_jacobian(design, mesh)
        self._known: dict[tuple[int, int], np.ndarray] = {}

    def at(self, surface: int, layer: int) -> np.ndarray:
        key = (surface, layer)
        if key not in self._known:
            theta, eps = self._sampled[layer]
            self._known[key] = _edge_lengths(
                self._design, self._mesh, surface, theta, eps, self._jacobian
            )
        return self._known[key]

    def metrics(self, surface: int) -> np.ndarray:
        """Every layer's per-face metrics (L, F, 2, 2) under surface ``surface``'s stimulus
        (:func:`sheet_metrics` of each layer)."""
        mesh = self._mesh
        return np.stack([
            metric_from_lengths(mesh.points, mesh.triangles, self.at(surface, layer))
            for layer in range(len(self._sampled))
        ])  # fmt: skip


def _sampled(
    layers: Sequence[SheetFields], mesh: DesignMesh
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Every layer's director angles (V,) and features (N, V) at the mesh's vertices."""
    sampled = []
    for layer in layers:
        theta = np.asarray(layer.theta(mesh.points), dtype=float)
        eps = np.asarray(layer.features(mesh.points), dtype=float)
        sampled.append((theta, eps.reshape(-1, len(mesh.points))))
    return sampled


def turned_over(problem: SheetProblem, designed: Sequence[SheetFields]) -> SheetProblem:
    """``problem``'s sheet with the print's error turned over: its metrics as made and under
    the stimulus reflected about those of the ``designed`` layers (one per layer of the
    sheet, bottom first) on the same mesh, 2 designed - made (the designed metric where
    that is no metric). It stands for another print whose every error is this one's
    negated: a side that the design programs holds on both, a side that the print's error
    chose flips (:mod:`fabkit.mechanics.verdict`)."""
    lengths = _LayerLengths(problem.coarse, problem.mesh, designed)

    def reflected(made: np.ndarray, surface: int) -> np.ndarray:
        stacked = lengths.metrics(surface)
        own = stacked[0] if made.ndim == 3 else stacked
        if own.shape != made.shape:
            raise FabkitError(
                f"turned over: {len(designed)} designed layers for a sheet of "
                f"{1 if made.ndim == 3 else len(made)}"
            )
        mirror = 2 * own - made
        metric = np.all(np.linalg.eigvalsh(mirror) > 0, axis=-1)
        return np.where(metric[..., None, None], mirror, own)

    return replace(
        problem,
        start_metrics=reflected(problem.start_metrics, 0),
        metrics=reflected(problem.metrics, problem.surface),
    )


def patch_size(design: Design, surface: int, mesh: DesignMesh) -> float | None:
    """The diameter (design units) of target ``surface``'s patch over the design's
    ``mesh`` (the whole part, made or not) at the design's grid points; None when the
    target has no 3D embedding."""
    chart = mesh.sample(design.r[surface])[mesh.nodes]
    points = design.problem.targets[surface].surface.embed(chart)
    return None if points is None else diameter(points)


def simulate_sheet(
    design: Design,
    fields: SheetFields | Sequence[SheetFields],
    surface: int,
    thickness: float | None = None,
    poisson: float = 0.5,
    settings: Settings | None = None,
    part: Part | None = None,
    stride: int = 1,
    progress: Callable[[int, int], None] | None = None,
) -> tuple[Design, DesignSimulation]:
    """Simulate the sheet of ``fields`` under surface ``surface``'s stimulus from one
    start (:func:`sheet_problem`; ``settings.seed``). Returns the coarsened design
    (compare against it) and the simulation, whose ``metrics`` are the layers' mean.
    ``progress(done, total)`` is called after each ramp step.
    """
    problem = sheet_problem(design, fields, surface, thickness, poisson, part, stride)
    result = problem.run(settings or Settings(), progress)
    return problem.coarse, problem.simulation(result)
