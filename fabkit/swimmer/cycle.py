"""The swimmer's stroke: stations along the stimulus path, equilibrium shapes, net motion.

The path is a polygon in stimulus space; each leg gets ``stations`` evenly spaced
stimuli. At every station the forward simulator (:mod:`fabkit.mechanics.simulate`) finds
the bilayer's equilibrium, starting from the previous station's shape and metrics, so
the sheet follows one branch as a quasi-static sheet would. The first shape is
simulated from the flat sheet without a seed, so the layers' mismatch picks the
direction the sheet bends (a single layer has no mismatch and gets the simulator's
seed). An unactuated sheet (every metric the identity) is the flat sheet itself.

A stimulus met again (a closed cycle's last corner, a path walked back) is given the
shape it had before when the new equilibrium agrees with it to ``SAME_BRANCH`` x radius:
then a closed cycle closes exactly and a reciprocal path retraces its shapes bit for
bit. When it does not agree the sheet has changed branch (hysteresis); the new shape is
kept and :attr:`Shapes.closure` says by how much the shapes differ.

The Stokeslet points (:func:`~fabkit.swimmer.stokes.disc_points`) are material points:
fixed barycentric coordinates in the elastic mesh's flat triangles, carried to every
shape. The increments between stations give the net motion (:func:`~fabkit.swimmer.motion.swim`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from fabkit.errors import FabkitError
from fabkit.mechanics.mesh import disc_mesh
from fabkit.mechanics.metric import edge_lengths, metric_from_director, metric_from_lengths
from fabkit.mechanics.simulate import Settings, simulate
from fabkit.swimmer.motion import Trajectory, align, swim
from fabkit.swimmer.spec import Layer, SwimmerSpec
from fabkit.swimmer.stokes import disc_points

SAME_BRANCH = 1e-3
"""Largest vertex distance / radius between two equilibria at one stimulus taken as one shape."""

UNSTRETCHED = 1e-12
"""Largest metric entry difference from the identity of an unactuated layer."""
MM3_TO_M3 = 1e-9
"""Energies come in Young's modulus x mm^3; times Pa and this, in J."""
KEY_DIGITS = 9
"""Stimuli equal to this many decimals are one stimulus (legs walked back meet again)."""

Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class Path:
    """Stations along the stimulus polygon.

    ``stimuli`` (M + 1, k) the stimulus at each station; ``parameter`` (M + 1,) the leg
    coordinate: leg index plus the fraction walked along it (0 ... number of legs).
    """

    stimuli: np.ndarray
    parameter: np.ndarray


def stations(path: np.ndarray, per_leg: int) -> Path:
    """``per_leg`` evenly spaced stations on every leg of the polygon ``path`` (P, k)."""
    fractions = np.arange(per_leg) / per_leg
    legs = len(path) - 1
    starts, steps = path[:-1], np.diff(path, axis=0)
    stimuli = starts[:, None, :] + fractions[None, :, None] * steps[:, None, :]
    stimuli = np.concatenate([stimuli.reshape(-1, path.shape[1]), path[-1:]])
    parameter = np.concatenate([(np.arange(legs)[:, None] + fractions).ravel(), [legs]])
    return Path(stimuli, parameter)


@dataclass(frozen=True)
class Sheet:
    """The flat bilayer disc: elastic mesh and the Stokeslet points embedded in it.

    ``points`` (V, 2) and ``triangles`` (F, 3) the elastic mesh (mm); ``stokes`` (N, 2)
    the Stokeslet points; ``host`` (N,) the triangle carrying each and ``weights``
    (N, 3) its barycentric coordinates there (linear extrapolation just outside the
    mesh, whose boundary is a polygon inscribed in the disc).
    """

    points: np.ndarray
    triangles: np.ndarray
    stokes: np.ndarray
    host: np.ndarray
    weights: np.ndarray

    @classmethod
    def build(cls, radius: float, mesh_rings: int, stokes_rings: int) -> Sheet:
        points, triangles = disc_mesh(radius, mesh_rings)
        stokes = disc_points(radius, stokes_rings)
        host, weights = barycentric(points, triangles, stokes)
        return cls(points, triangles, stokes, host, weights)

    def carry(self, positions: np.ndarray) -> np.ndarray:
        """Stokeslet points (N, 3) on the shape with mesh vertices at ``positions`` (V, 3)."""
        corners = positions[self.triangles[self.host]]
        return np.einsum("nc,ncd->nd", self.weights, corners)

    def metrics(self, layers: tuple[Layer, ...], stimulus: np.ndarray) -> np.ndarray:
        """Reference metric of every layer on every face (L, F, 2, 2) at ``stimulus`` (k,)."""
        return np.stack([self._layer_metric(layer, stimulus) for layer in layers])

    def _layer_metric(self, layer: Layer, stimulus: np.ndarray) -> np.ndarray:
        along, across = layer.stretches(stimulus)
        if not (along > 0 and across > 0):
            raise FabkitError(
                f"layer '{layer.name}': stretches must be positive, got lambda1 = {along:g}, "
                f"lambda2 = {across:g} at stimulus {list(stimulus)}"
            )

        def metric(p: np.ndarray) -> np.ndarray:
            theta = layer.theta(p[..., 0], p[..., 1])
            director = np.stack([np.cos(theta), np.sin(theta)], -1)
            ones = np.ones(p.shape[:-1])
            return metric_from_director(director, along * ones, across * ones)

        lengths = edge_lengths(self.points, self.triangles, metric)
        return metric_from_lengths(self.points, self.triangles, lengths)


def barycentric(
    points: np.ndarray, triangles: np.ndarray, queries: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Host triangle (Q,) and barycentric weights (Q, 3) of ``queries`` (Q, 2).

    A query outside the mesh takes the triangle with the nearest centroid (weights
    then extrapolate linearly).
    """
    from matplotlib.tri import Triangulation  # matplotlib loads only for a swimmer

    finder = Triangulation(points[:, 0], points[:, 1], triangles).get_trifinder()
    host = np.asarray(finder(queries[:, 0], queries[:, 1]))
    outside = host < 0
    if outside.any():
        centroids = points[triangles].mean(axis=1)
        gaps = queries[outside, None, :] - centroids[None, :, :]
        host[outside] = np.argmin(np.einsum("qfd,qfd->qf", gaps, gaps), axis=1)
    corners = points[triangles[host]]
    sides = np.stack([corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]], -1)
    local = np.linalg.solve(sides, (queries - corners[:, 0])[..., None])[..., 0]
    return host, np.column_stack([1.0 - local.sum(axis=1), local])


@dataclass(frozen=True)
class Shapes:
    """Equilibria along a path.

    ``positions`` (M + 1, V, 3) mesh vertices; ``energies`` (M + 1,) elastic energy
    (J, with the spec's Young's modulus); ``converged`` (M + 1,) solver flags;
    ``closure`` the largest vertex distance / radius between a re-met stimulus's old
    and new equilibria (0 when none is re-met); ``seconds`` wall time.
    """

    positions: np.ndarray
    energies: np.ndarray
    converged: np.ndarray
    closure: float
    seconds: float


def equilibria(
    spec: SwimmerSpec, sheet: Sheet, stimuli: np.ndarray, progress: Progress | None = None
) -> Shapes:
    """Follow the path ``stimuli`` (M + 1, k) with the forward simulator (see module)."""
    started = time.perf_counter()
    flat = np.column_stack([sheet.points, np.zeros(len(sheet.points))])
    settings = Settings()
    state, metrics = flat, None
    seen: dict[bytes, int] = {}
    positions, energies, converged, closure = [], [], [], 0.0
    for index, stimulus in enumerate(stimuli):
        target = sheet.metrics(spec.layers, stimulus)
        if np.allclose(target, np.eye(2), rtol=0.0, atol=UNSTRETCHED):
            shape, energy, done = flat, 0.0, True  # the sheet as made: stress-free and flat
        else:
            result = simulate(
                sheet.points,
                sheet.triangles,
                target,
                spec.thickness,
                spec.mechanics.poisson,
                settings,
                initial=None if state is flat and len(spec.layers) == 1 else state,
                start_metrics=metrics,
            )
            shape, done = result.positions, result.converged
            energy = result.energy * spec.mechanics.young * MM3_TO_M3
        key = np.round(np.asarray(stimulus, dtype=float), KEY_DIGITS).tobytes()
        if key in seen:
            before = positions[seen[key]]
            gap = _shape_distance(shape, before) / spec.radius
            closure = max(closure, gap)
            if gap <= SAME_BRANCH:
                shape, energy = before, energies[seen[key]]
        seen.setdefault(key, index)
        positions.append(shape)
        energies.append(energy)
        converged.append(done)
        state, metrics = shape, target
        if progress is not None:
            progress(index + 1, len(stimuli))
    return Shapes(
        np.array(positions),
        np.array(energies),
        np.array(converged),
        closure,
        time.perf_counter() - started,
    )


def _shape_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Largest vertex distance between two shapes (V, 3) after the best rigid fit."""
    return float(np.max(np.linalg.norm(align(a, b) - (b - b.mean(axis=0)), axis=1)))


@dataclass(frozen=True)
class Stroke:
    """One walk along the stimulus path: shapes, Stokeslet points and the net motion.

    ``path`` the stations; ``sheet`` the flat disc; ``shapes`` the equilibria;
    ``trajectory`` the swimmer's poses (mm, rad) over the Stokeslet points;
    ``epsilon`` the regularisation (mm); ``seconds`` the hydrodynamics' wall time.
    """

    spec: SwimmerSpec
    path: Path
    sheet: Sheet
    shapes: Shapes
    trajectory: Trajectory
    epsilon: float
    seconds: float

    @property
    def displacement(self) -> np.ndarray:
        """Net displacement (3,) in disc radii; z is the disc's axis (bottom -> top layer)."""
        return self.trajectory.displacement / self.spec.radius

    @property
    def rotation(self) -> np.ndarray:
        """Net rotation vector (3,) in rad."""
        return self.trajectory.rotation

    def refined(
        self, stokes_rings: int, stride: int = 1, progress: Progress | None = None
    ) -> Stroke:
        """The same shapes with another Stokeslet point set and every ``stride``-th station.

        ``stride`` must divide the stations per leg (corners are kept). No simulation is
        repeated: this is how the hydrodynamic convergence is measured. ``progress`` as in
        :func:`flow`.
        """
        if self.spec.stations % stride:
            raise FabkitError(f"stride {stride} does not divide {self.spec.stations} stations")
        keep = slice(None, None, stride)
        path = Path(self.path.stimuli[keep], self.path.parameter[keep])
        shapes = Shapes(
            self.shapes.positions[keep],
            self.shapes.energies[keep],
            self.shapes.converged[keep],
            self.shapes.closure,
            self.shapes.seconds,
        )
        sheet = Sheet.build(self.spec.radius, self.spec.mechanics.rings, stokes_rings)
        return flow(self.spec, path, sheet, shapes, progress)


def run_stroke(
    spec: SwimmerSpec,
    shapes_progress: Progress | None = None,
    flow_progress: Progress | None = None,
) -> Stroke:
    """Simulate the shapes along ``spec``'s path and sum the rigid motion over them."""
    path = stations(spec.path, spec.stations)
    sheet = Sheet.build(spec.radius, spec.mechanics.rings, spec.hydrodynamics.rings)
    shapes = equilibria(spec, sheet, path.stimuli, shapes_progress)
    return flow(spec, path, sheet, shapes, flow_progress)


def flow(
    spec: SwimmerSpec,
    path: Path,
    sheet: Sheet,
    shapes: Shapes,
    progress: Progress | None = None,
) -> Stroke:
    """The net motion over ``shapes`` with ``sheet``'s Stokeslet points."""
    started = time.perf_counter()
    hydro = spec.hydrodynamics
    epsilon = hydro.epsilon_ratio * spec.radius * np.sqrt(np.pi / len(sheet.stokes))
    points = [sheet.carry(p) for p in shapes.positions]
    trajectory = swim(points, epsilon, hydro.viscosity, progress)
    return Stroke(spec, path, sheet, shapes, trajectory, epsilon, time.perf_counter() - started)


POINT_ORDER = 0.6
"""Measured order of the displacement per cycle in the Stokeslet spacing h: error ~ h^0.6
(``benchmarks/swimmer.py``, docs/swimmer.md), slowed by the force singularity at the
sheet's edge."""
COARSENING = 1.5
"""Ratio of Stokeslet rings between a stroke and its coarse re-solve."""


@dataclass(frozen=True)
class Convergence:
    """A stroke re-solved with ``COARSENING`` times fewer Stokeslet rings (``coarse``) and
    with every other station (``half_stations``, None when the stations per leg are odd).
    """

    stroke: Stroke
    coarse: Stroke
    half_stations: Stroke | None

    @property
    def extrapolated(self) -> np.ndarray:
        """Displacement per cycle (3,) in radii, Richardson-extrapolated to h -> 0 from
        ``coarse`` and ``stroke`` with error ~ h^POINT_ORDER, h = sqrt(area / points)."""
        fine, coarse = self.stroke, self.coarse
        ratio = (len(fine.sheet.stokes) / len(coarse.sheet.stokes)) ** (POINT_ORDER / 2)
        return fine.displacement + (fine.displacement - coarse.displacement) / (ratio - 1)


def convergence(
    stroke: Stroke,
    coarse_progress: Progress | None = None,
    half_progress: Progress | None = None,
) -> Convergence:
    """Re-solve ``stroke``'s hydrodynamics coarser (see :class:`Convergence`); no new shapes.

    ``coarse_progress`` and ``half_progress`` follow the two re-solves, as in :func:`flow`.
    """
    rings = stroke.spec.hydrodynamics.rings
    coarse = stroke.refined(max(2, round(rings / COARSENING)), progress=coarse_progress)
    even = stroke.spec.stations % 2 == 0
    half = stroke.refined(rings, 2, half_progress) if even else None
    return Convergence(stroke, coarse, half)
