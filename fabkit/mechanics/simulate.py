"""Forward simulation: the sheet's equilibrium shape for given reference metrics.

:func:`simulate` takes a flat mesh and per-face reference metrics (one or more layers),
ramps the metrics from the flat sheet's (identity) to the target along a continuation
path (:func:`ramp`: from 1/256 of the way, each step 4x the last), and at every step
minimises the :class:`~fabkit.mechanics.shell.Shell` energy by
Newton's method in two regimes. Projected Newton (the positive semi-definite Hessian
model, its factorisation reused as a CG preconditioner, Armijo backtracking) while it
converges fast; once it creeps (a full step more than half the full step before it),
damped Newton on the exact Hessian (Levenberg-Marquardt: H + mu I, mu adapted to how
well the quadratic model predicted the last step), with a projected step wherever a
damped step is no descent or predicts badly. The exact Hessian is what makes it
converge: near an equilibrium the soft modes of a sheet (near-isometric bending) have
curvatures set by the fold-angle and compressive-stress terms that the projected model
leaves out, so projected Newton alone only creeps along them (linearly, at 0.99 per
iteration on the Fig. 1 bump as fabricated). An exact step costs about three times a
projected one (an exact Hessian and a fresh factorisation: banded Cholesky where the
matrix is positive definite, else SuperLU's LU, :mod:`fabkit.mechanics.factor`), hence
projected Newton first; each simulation runs on one BLAS thread (several run side by
side). The rigid motions are projected out of every
system. The flat state is a symmetric stationary point, so the start is seeded with a
small dome (or saddle) out of plane.

The ramp follows the sheet. A sheet with a natural curvature (layers that differ) is
ramped slowly, as a lab actuates it: at the first small share of the stimulus it relaxes
to a near-flat state whatever shape it started from, and it buckles later to the side its
natural curvature favours (a layered sheet's programmed curvature, or a print's errors);
any natural curvature, however small, wins over the start. A sheet without one (one
layer, or equal layers) has no side of its own: ramped slowly it would relax to flat to
round-off, and round-off would pick its side and its shape (the same sheet read back by
``run`` and by ``verify`` then ended 2.70 and 2.98 % from Fig. 1's bump); it is ramped
in two equal steps, and its start decides, as before stop 46 (docs/layers.md).

:func:`simulate_design` builds all of that from a design file at one of its stimuli.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sparse
import scipy.sparse.linalg as splinalg
from threadpoolctl import threadpool_limits

from fabkit.design.design import Design
from fabkit.errors import FabkitError
from fabkit.field.part import SIMULATE_THICKNESS, Part
from fabkit.mechanics.factor import factorise
from fabkit.mechanics.mesh import DesignMesh, design_mesh, disc_mesh
from fabkit.mechanics.metric import grid_edge_lengths, metric_from_lengths
from fabkit.mechanics.shell import Shell, build_shell, flat_sheet

STARTS = ("dome", "dome-down", "saddle", "saddle-down", "random-1", "random-2")
"""The shapes a simulation can start from (:func:`seeded`): the flat sheet lifted out of
plane by a dome bulging up or down, a saddle of either sign, or a smooth random bump of
two fixed seeds. A verdict starts from every one of them."""
MIRRORED = {"dome-down": "dome", "saddle-down": "saddle"}
"""Starts that are the mirror image (z -> -z) of another: a sheet without natural
curvature ends, from one, in the mirror image of where it ends from the other."""
SEEDS = STARTS
ARMIJO = 1e-4
"""Sufficient-decrease constant of the line search."""
SHIFT = 1e-10
"""Diagonal shift of the Newton matrix, relative to its mean diagonal (rigid motions)."""
DAMPING = (1e-12, 1e-4, 1.0)
"""Levenberg-Marquardt damping mu relative to the mean diagonal: least, first, largest."""
DAMPING_CONVERGED = 1e-8
"""A step counts as a full Newton step when mu is at most this (relative): below the
softest bending modes' curvature (1e-6 of the mean diagonal on Fig. 1 at h = 1 %)."""
ROUND_OFF = 1e-16
"""A damped step refused although it predicted a fall below this share of the energy
per face (the energy is a sum over the faces) was refused by round-off: the sheet is at
equilibrium to machine precision."""
ROUND_OFF_MOVE = 1e3
"""Such a step, if it moves no vertex more than this many times the step tolerance (a
thousandth of an edge at the default tolerance), is converged: what is left is noise
along a soft (near-isometric) mode, no change of shape. The Fig. 3 face as fabricated
(two layers) stopped so with a step of 4e-7 against a tolerance of 2.6e-7, 2e-8 of its
diameter, and was called not converged."""
CREEP = 0.5
"""Projected Newton creeps (converges linearly along soft modes) when a full step is more
than this share of the full step before it: the damped exact Newton takes over."""
TRUST = 0.25
"""A damped step is taken when the energy falls by at least this share of the fall the
quadratic model predicted."""


@dataclass(frozen=True)
class Settings:
    """Solver settings.

    ``steps``: ramp steps from the flat metric to the target (None: the sheet's own,
    :data:`SLOW_STEPS` for a sheet with natural curvature, :data:`EQUAL_STEPS` without);
    the stimulus's share grows
    geometrically from ``first_step`` to 1 on a sheet with natural curvature, in equal
    steps on one without (:func:`ramp`);
    ``tolerance``: converged
    when a full Newton step moves no vertex more than this times the mean edge length;
    ``ramp_tolerance``: the same for the intermediate ramp steps; ``max_iterations``:
    Newton iterations per ramp step (2000: a saddle-shaped target from a random start
    needs up to 827 in its first step, the sheet crossing from the random bump to the
    saddle, and the same saddle programmed in two layers 1160 in its second; the Fig. 3
    face needed 337-360 over its two steps and stopped unconverged at 100, 0.7 design
    units RMS away from the equilibrium it then reaches; a simulation that converges
    stops long before, so the cap costs only those that do not);
    ``seed``: the start, one of
    :data:`STARTS`; ``seed_height``: its height relative to the sheet's radius.
    """

    steps: int | None = None
    first_step: float = 1 / 256
    tolerance: float = 1e-6
    ramp_tolerance: float = 1e-3
    max_iterations: int = 2000
    seed: str = "dome"
    seed_height: float = 0.05


@dataclass(frozen=True)
class Simulation:
    """Result of :func:`simulate`.

    ``positions`` (V, 3) equilibrium vertices; ``energy`` the final energy (Young's
    modulus x length^3); ``iterations`` Newton iterations over all ramp steps;
    ``converged`` whether the last step met the tolerance; ``seconds`` wall time.
    """

    positions: np.ndarray
    energy: float
    iterations: int
    converged: bool
    seconds: float


def simulate(
    points: np.ndarray,
    triangles: np.ndarray,
    metrics: np.ndarray,
    thickness: float,
    poisson: float = 0.5,
    settings: Settings = Settings(),
    initial: np.ndarray | None = None,
    start_metrics: np.ndarray | None = None,
    progress: Callable[[int, int], None] | None = None,
    shares: Sequence[float] | None = None,
) -> Simulation:
    """Equilibrium of a sheet with reference metrics ``metrics``.

    ``points`` (V, 2) flat sheet (design units); ``triangles`` (F, 3); ``metrics``
    (F, 2, 2) one layer or (L, F, 2, 2) equal layers bottom to top, in flat-sheet
    coordinates; ``thickness`` H (design units). The ramp starts from ``start_metrics``
    (default identity: the sheet as made) at ``initial`` positions (V, 3) (default: the
    flat sheet plus the seed); pass the previous state and its metrics to follow a
    stimulus path. ``progress(done, total)`` is called after each ramp step. ``shares``:
    the ramp steps to take (default :func:`ramp`'s), e.g. its first alone, then the rest
    from where that ended: the same steps, the same result, bit for bit
    (:func:`ramp_part`).
    """
    started = time.perf_counter()
    if settings.seed not in SEEDS:
        raise FabkitError(f"seed: expected one of {', '.join(SEEDS)}, got {settings.seed!r}")
    if settings.steps is not None and settings.steps < 1:
        raise FabkitError("steps: at least one ramp step is needed")
    if not 0 < settings.first_step <= 1:
        raise FabkitError(
            f"first step: expected a share of the stimulus in (0, 1], got {settings.first_step:g}"
        )
    if settings.max_iterations < 1:
        raise FabkitError("max_iterations: at least one Newton iteration per step is needed")
    sheet = flat_sheet(points, triangles)
    target = np.asarray(metrics, dtype=float)
    target = target[None] if target.ndim == 3 else target
    start = np.broadcast_to(np.eye(2), target.shape) if start_metrics is None else start_metrics
    x = seeded(sheet.points, settings) if initial is None else np.array(initial, dtype=float)
    scale = sheet.edge_length()
    total, converged, shell = 0, False, None
    with threadpool_limits(limits=1, user_api="blas"):  # factor.py: one core per simulation
        shares = ramp(settings, curved(target)) if shares is None else np.asarray(shares)
        for step, fraction in enumerate(shares, 1):
            metrics_now = (1 - fraction) * start + fraction * target
            shell = build_shell(sheet, metrics_now, thickness, poisson)
            last = step == len(shares)
            tolerance = settings.tolerance if last else settings.ramp_tolerance
            x, iterations, converged = minimise(
                shell, x, tolerance * scale, settings.max_iterations
            )
            total += iterations
            if progress is not None:
                progress(step, len(shares))
    elapsed = time.perf_counter() - started
    return Simulation(x, shell.energy(x), total, converged, elapsed)


def warm_kernels() -> float:
    """Compile the shell's numba kernels (or load them from numba's cache beside the
    package) by simulating a small disc of two layers, one stretched: a first run after
    an install compiles them here, in a worker beside the command (``fabkit run``), while
    the command solves, and its own simulations then load them (about 6 s of compiling
    on a 2-core machine). Returns the seconds it took."""
    started = time.perf_counter()
    points, triangles = disc_mesh(1.0, 2)
    faces = len(triangles)
    layers = np.array([np.eye(2), 1.1 * np.eye(2)])  # bottom, top
    simulate(points, triangles, np.repeat(layers[:, None], faces, axis=1), 0.05)
    return time.perf_counter() - started


SLOW_STEPS, EQUAL_STEPS = 5, 2
"""Ramp steps by default: a sheet with natural curvature (slowly, from
:attr:`Settings.first_step`), and one without (equal steps)."""


def ramp_part(
    points: np.ndarray,
    triangles: np.ndarray,
    metrics: np.ndarray,
    thickness: float,
    poisson: float,
    settings: Settings,
    initial: np.ndarray | None,
    start_metrics: np.ndarray | None,
    first: int,
    last: int | None,
) -> Simulation:
    """:func:`simulate` through ramp steps ``first`` to ``last`` (0-based, ``last``
    excluded; None: to the end) of the sheet's own ramp, from ``initial`` (None: the
    seeded flat sheet): positional arguments, for a pool of workers."""
    shares = ramp(settings, curved(np.asarray(metrics)))
    return simulate(
        points,
        triangles,
        metrics,
        thickness,
        poisson,
        settings,
        initial,
        start_metrics,
        shares=shares[first:last],
    )


def curved(metrics: np.ndarray) -> bool:
    """Whether layers with the reference metrics ``metrics`` ((F, 2, 2) one layer, or
    (L, F, 2, 2)) have a natural curvature: more than one layer, not all equal."""
    return metrics.ndim == 4 and len(metrics) > 1 and not bool((metrics == metrics[:1]).all())


def ramp(settings: Settings, natural: bool = True) -> np.ndarray:
    """The stimulus's share at every ramp step (steps,) of a sheet with (``natural``) or
    without a natural curvature (module docstring): geometric from
    ``settings.first_step`` to 1, or equal steps (one step: the whole stimulus at
    once)."""
    steps = settings.steps or (SLOW_STEPS if natural else EQUAL_STEPS)
    if steps == 1:
        return np.ones(1)
    if not natural:
        return np.arange(1, steps + 1) / steps
    return np.geomspace(settings.first_step, 1.0, steps)


def ramp_words(settings: Settings) -> str:
    """The ramps as the reports write them: ``5 ramp steps from 1/256 of the stimulus, each
    4x the last (2 equal steps for a sheet without natural curvature)``."""
    shares = ramp(settings)
    flat = len(ramp(settings, natural=False))
    if len(shares) == 1:
        return "1 ramp step"
    growth = float(shares[1] / shares[0])
    return (
        f"{len(shares)} ramp steps from 1/{1 / shares[0]:.4g} of the stimulus, each "
        f"{growth:.3g}x the last ({flat} equal steps for a sheet without natural curvature)"
    )


def seeded(points: np.ndarray, settings: Settings) -> np.ndarray:
    """The flat sheet (V, 3) lifted out of plane by the start ``settings.seed``
    (:data:`STARTS`), its largest height ``settings.seed_height`` times the sheet's
    radius about its centroid."""
    offset = points - points.mean(0)
    radius = np.max(np.linalg.norm(offset, axis=1))
    x, y = offset[:, 0] / radius, offset[:, 1] / radius
    shapes = {
        "dome": -(x**2 + y**2),
        "dome-down": x**2 + y**2,
        "saddle": x**2 - y**2,
        "saddle-down": y**2 - x**2,
    }
    if settings.seed in shapes:
        height = shapes[settings.seed]
    else:
        height = _random_bump(x, y, int(settings.seed.rsplit("-", 1)[1]))
    height = height / max(float(np.max(np.abs(height))), np.finfo(float).tiny)
    return np.concatenate([points, (settings.seed_height * radius * height)[:, None]], 1)


def mirrored(result: Simulation) -> Simulation:
    """``result`` reflected in the flat sheet's plane (z -> -z): where a sheet without
    natural curvature (one layer, or layers with equal metrics: its energy does not change
    under the reflection) ends from the mirror image of ``result``'s start."""
    positions = result.positions * np.array([1.0, 1.0, -1.0])
    return Simulation(positions, result.energy, result.iterations, result.converged, 0.0)


def _random_bump(x: np.ndarray, y: np.ndarray, seed: int) -> np.ndarray:
    """A smooth bump of random shape (fixed by ``seed``) at the points (x, y) of the unit
    disc: quadratic and cubic terms and one oblique wave."""
    c = np.random.default_rng(seed).normal(size=7)
    height = c[0] * x * x + c[1] * x * y + c[2] * y * y + c[3] * x**3 + c[4] * x * y * y
    return height + c[5] * np.sin(3 * x + c[6] * y)


def minimise(
    shell: Shell,
    x: np.ndarray,
    step_tolerance: float,
    max_iterations: int,
    exact: bool = False,
) -> tuple[np.ndarray, int, bool]:
    """Projected Newton from x (V, 3) while it converges fast; damped exact Newton once it
    creeps (full steps shrinking by less than :data:`CREEP` per iteration), with a
    projected Newton step wherever a damped step fails (module docstring). ``exact``:
    exact Newton from the first iteration, its damping starting at the least that counts
    as a full step (x near an equilibrium already).

    Stops when a full (undamped) Newton step moves no vertex more than ``step_tolerance``
    (design units); returns the positions, the iterations used and whether that happened.
    """
    energy, damping, previous = shell.energy(x), Damping(), math.inf
    if exact:  # near an equilibrium: a full step is likely to be taken
        damping.mu = DAMPING_CONVERGED
    projected = NewtonSystem()
    for iteration in range(1, max_iterations + 1):
        gradient = shell.gradient(x).ravel()
        if exact:
            move, fall = damped_step(shell, x, gradient, damping.mu)
            if move is not None:
                trial = shell.energy(x + move)
                if trial - energy <= TRUST * fall:
                    full = damping.mu <= DAMPING_CONVERGED
                    damping.success((trial - energy) / fall)
                    x, energy = x + move, trial
                    if full and _largest(move) <= step_tolerance:
                        return x, iteration, True
                    continue
                if -fall <= ROUND_OFF * len(shell.rest) * abs(energy):  # a sum over faces
                    return x, iteration, bool(_largest(move) <= ROUND_OFF_MOVE * step_tolerance)
            damping.failure()
        direction = projected.direction(shell.hessian(x, projected=True), gradient, x)
        slope = float(gradient @ direction)
        if slope >= 0:  # no descent left at round-off level
            return x, iteration, True
        move = direction.reshape(-1, 3)
        size = _largest(move)
        length, trial = 1.0, shell.energy(x + move)
        if size <= step_tolerance:  # converged; the energy change may be round-off alone
            return (x + move if trial <= energy else x), iteration, True
        while trial > energy + ARMIJO * length * slope and length > 1e-8:
            length *= 0.5
            trial = shell.energy(x + length * move)
        if trial > energy:
            return x, iteration, False
        x, energy = x + length * move, trial
        exact = exact or (length == 1.0 and size > CREEP * previous)
        previous = size if length == 1.0 else math.inf
    return x, max_iterations, False


class Damping:
    """The Levenberg-Marquardt damping mu (relative to the mean diagonal, :data:`DAMPING`),
    by Nielsen's rule (H. B. Nielsen, "Damping parameter in Marquardt's method", IMM DTU
    1999): after a step taken, mu times max(1/3, 1 - (2 r - 1)^3), r the actual over the
    predicted energy fall; after a failure, mu times nu, nu doubling with every failure in
    a row. The rule it replaced (mu / 10 after a well predicted step, x 10 after a
    failure) cycled between a mu whose step was refused and one ten times larger on
    saddle-shaped targets: 600 iterations without converging where this rule takes 356-405
    (the bowl and saddle of tests/test_mechanics_newton.py)."""

    def __init__(self) -> None:
        self.mu = DAMPING[1]
        self.growth = 2.0

    def success(self, ratio: float) -> None:
        """After a step taken; ``ratio`` is the actual over the predicted energy fall."""
        self.mu = max(DAMPING[0], self.mu * max(1.0 / 3.0, 1.0 - (2.0 * ratio - 1.0) ** 3))
        self.growth = 2.0

    def failure(self) -> None:
        self.mu = min(DAMPING[2], self.growth * self.mu)
        self.growth *= 2.0


def damped_step(
    shell: Shell, x: np.ndarray, gradient: np.ndarray, mu: float
) -> tuple[np.ndarray | None, float]:
    """The step (V, 3) solving (H + mu d I) s = -g orthogonally to the rigid motions, H the
    exact Hessian at x (V, 3), d its mean diagonal; and the energy change the quadratic
    model predicts for it (< 0). ``(None, 0.0)`` when it is no descent step for the model
    (H + mu d I is then indefinite).

    Solved by a fresh factorisation every time (:func:`~fabkit.mechanics.factor.factorise`):
    MINRES preconditioned with the projected Newton
    matrix's factorisation resolves the soft modes, where the two matrices differ, too
    poorly (the Fig. 1 bump then took more iterations than it saved time).
    """
    hessian = shell.hessian(x, projected=False)
    diagonal = float(np.mean(np.abs(hessian.diagonal()))) or np.finfo(float).tiny
    matrix = hessian + sparse.diags(np.full(hessian.shape[0], (mu + SHIFT) * diagonal))
    modes = rigid_modes(x)
    right = -(gradient - modes @ (modes.T @ gradient))
    try:
        step = factorise(matrix).solve(right)
    except RuntimeError:  # exactly singular
        return None, 0.0
    step -= modes @ (modes.T @ step)
    slope = float(gradient @ step)
    fall = slope + 0.5 * float(step @ (hessian @ step))
    if not (slope < 0 and fall < 0 and np.isfinite(fall)):
        return None, 0.0
    return step.reshape(-1, 3), fall


class NewtonSystem:
    """Solves (H + mu I) d = -g for successive Newton matrices H (semi-definite).

    Rigid motions carry no energy (H is singular along them), so the system is solved
    orthogonally to the six rigid modes at the current positions. The factorisation
    (:func:`~fabkit.mechanics.factor.factorise`) is the expensive part and is
    reused: each system is solved by conjugate gradients preconditioned with the last
    factorisation, refactorised when that needs more than ``CG_ITERATIONS`` iterations.
    After a failed attempt the next attempts are skipped, twice as many after each
    further failure (a sheet that is still buckling changes too fast for reuse).
    ``factorisations`` counts the factorisations.
    """

    CG_ITERATIONS = 12
    CG_TOLERANCE = 1e-4

    def __init__(self) -> None:
        self.factor = None
        self.factorisations = 0
        self.backoff = 1
        self.wait = 0

    def direction(
        self, hessian: sparse.csr_matrix, gradient: np.ndarray, x: np.ndarray
    ) -> np.ndarray:
        """Newton direction (3V,) for Hessian (3V, 3V) and gradient (3V,) at x (V, 3)."""
        diagonal = hessian.diagonal()
        shift = SHIFT * max(float(np.mean(diagonal)), np.finfo(float).tiny)
        matrix = hessian + sparse.diags(np.full(len(diagonal), shift))
        modes = rigid_modes(x)

        def project(vector: np.ndarray) -> np.ndarray:
            return vector - modes @ (modes.T @ vector)

        right = -project(gradient)
        self.wait -= 1
        if self.factor is not None and self.wait < 0:
            shape = matrix.shape
            operator = splinalg.LinearOperator(shape, lambda v: project(matrix @ project(v)))
            precondition = splinalg.LinearOperator(
                shape, lambda v: project(self.factor.solve(project(v)))
            )
            solution, info = splinalg.cg(
                operator,
                right,
                rtol=self.CG_TOLERANCE,
                maxiter=self.CG_ITERATIONS,
                M=precondition,
            )
            if info == 0:
                self.backoff = 1
                return project(solution)
            self.wait, self.backoff = self.backoff, 2 * self.backoff
        self.factor = factorise(matrix)
        self.factorisations += 1
        return project(self.factor.solve(right))


def rigid_modes(x: np.ndarray) -> np.ndarray:
    """Orthonormal basis (3V, 6) of the infinitesimal rigid motions of points x (V, 3)."""
    centred = x - x.mean(0)
    modes = []
    for axis in np.eye(3):
        modes.append(np.broadcast_to(axis, x.shape).ravel())
        modes.append(np.cross(axis, centred).ravel())
    return np.linalg.qr(np.stack(modes, 1))[0]


def _largest(move: np.ndarray) -> float:
    return float(np.max(np.linalg.norm(move, axis=1)))


@dataclass(frozen=True)
class DesignSimulation:
    """A design simulated at one stimulus.

    ``surface``: index of the surface whose stimulus was applied; ``mesh`` the flat
    domain; ``metrics`` (F, 2, 2) reference metrics; ``thickness`` (design units);
    ``result`` the :class:`Simulation`.
    """

    surface: int
    name: str
    mesh: DesignMesh
    metrics: np.ndarray
    thickness: float
    result: Simulation


def surface_index(design: Design, stimulus: str) -> int:
    """The surface selected by name or index (``"1"``, ``"sphere"``)."""
    spec = design.problem
    names = [t.name for t in spec.targets]
    if stimulus in names:
        return names.index(stimulus)
    if stimulus.lstrip("-").isdigit() and 0 <= int(stimulus) < len(names):
        return int(stimulus)
    raise FabkitError(
        f"--stimulus {stimulus}: expected a surface name ({', '.join(names)}) "
        f"or an index 0..{len(names) - 1}"
    )


def design_metrics(design: Design, mesh: DesignMesh, surface: int) -> np.ndarray:
    """Per-face reference metric (F, 2, 2) at surface ``surface``'s stimulus
    (:func:`stimulus_metrics`)."""
    return stimulus_metrics(design, mesh, design.stimuli[surface])


def stimulus_metrics(design: Design, mesh: DesignMesh, stimulus: np.ndarray) -> np.ndarray:
    """Per-face reference metric (F, 2, 2) of the design's sheet at ``stimulus`` (one value
    per stimulus of the spec; any, not only a target's).

    The designed metric is (alpha lambda1)^2 du^2 + (beta lambda2)^2 dv^2, lambda1 along
    the flat-sheet director (the u-curves) and lambda2 across it, from the material at
    every vertex's eps. Edge lengths follow by the trapezoidal rule in (u, v); each face's
    metric in flat-sheet coordinates fits its three edge lengths.
    """
    spec = design.problem
    eps = np.moveaxis(mesh.sample(np.moveaxis(design.eps, 0, -1)), -1, 0)
    stimuli = np.asarray(stimulus, dtype=float).reshape(1, -1)
    response = spec.material.response(eps, stimuli)
    stretch_u = mesh.sample(design.alpha) * response.lambda1[0]
    stretch_v = mesh.sample(design.beta) * response.lambda2[0]
    step = design.step / mesh.refine
    lengths = grid_edge_lengths(mesh.triangles, mesh.grid, step, stretch_u, stretch_v)
    return metric_from_lengths(mesh.points, mesh.triangles, lengths)


def simulate_design(
    design: Design,
    surface: int,
    thickness: float | None = None,
    poisson: float = 0.5,
    settings: Settings = Settings(),
    part: Part | None = None,
    refine: int = 1,
    progress: Callable[[int, int], None] | None = None,
) -> DesignSimulation:
    """Simulate ``design``'s flat domain (the cells of ``part``, else every solved cell)
    under surface ``surface``'s stimulus.

    ``thickness`` defaults to 1 % of the diameter of the design's whole solved flat
    domain (design units; the part does not change it); ``part`` and ``refine`` as in
    :func:`~fabkit.mechanics.mesh.design_mesh`.
    """
    mesh = design_mesh(design, part, refine)
    if thickness is None:
        thickness = default_thickness(design)
    metrics, result = simulate_from_made(
        mesh,
        lambda s: design_metrics(design, mesh, s),
        surface,
        thickness,
        poisson,
        settings,
        progress,
    )
    name = design.problem.targets[surface].name
    return DesignSimulation(surface, name, mesh, metrics, thickness, result)


def simulate_from_made(
    mesh: DesignMesh,
    metrics_at: Callable[[int], np.ndarray],
    surface: int,
    thickness: float,
    poisson: float,
    settings: Settings,
    progress: Callable[[int, int], None] | None,
) -> tuple[np.ndarray, Simulation]:
    """The sheet on ``mesh`` ramped from its metrics as made (``metrics_at(0)``, the flat
    sheet's stimulus) to those under surface ``surface``'s stimulus (``metrics_at(surface)``,
    (F, 2, 2) or (L, F, 2, 2)); returns those metrics and the simulation."""
    metrics = metrics_at(surface)
    result = simulate(
        mesh.points,
        mesh.triangles,
        metrics,
        thickness,
        poisson,
        settings,
        start_metrics=metrics_at(0),
        progress=progress,
    )
    return metrics, result


def default_thickness(design: Design) -> float:
    """The simulated sheet's thickness (design units): :data:`~fabkit.part.SIMULATE_THICKNESS`
    of the diameter of the design's whole solved flat domain (as ``fabkit simulate``)."""
    return SIMULATE_THICKNESS * diameter(design_mesh(design).points)


def diameter(points: np.ndarray) -> float:
    """Largest distance between two of the points (n, d) (any units)."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        hull = points[ConvexHull(points, qhull_options="QJ").vertices]
    except (QhullError, ValueError):
        hull = points
    differences = hull[:, None, :] - hull[None, :, :]
    return float(np.sqrt(np.max(np.einsum("ijk,ijk->ij", differences, differences))))
