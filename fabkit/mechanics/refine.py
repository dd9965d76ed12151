"""A layered sheet's layers refined against the simulation.

The first-order layering (:mod:`fabkit.design.layers`) asks each target's curvature of
the layers' spread: the director turn t and the feature slopes s per unit height. It
ignores that the sheet is one body: the metric is met only to first order, targets that
share a lever get a compromise, and bending and stretching trade. Here the turn and
slopes are corrected by smooth fields (polynomials in the flat sheet's coordinates, of
degree :data:`DEGREE`, one set per field) that minimise

    sum over targets of (RMS_s / limit)^4  + penalties,

RMS_s the distance of the simulated sheet to target s (its proper side, never the mirror
image) and the limit the verdict's (the fourth power weighs the farthest target most).
The penalties keep every layer's features inside the process's ranges, its director
within :data:`MAX_TURN` of the design's, and every target's side at least as favoured
as the first-order layering favoured it (:meth:`_Model.side`: the energy of the sheet
held at the target less that held at its mirror image; without it the refinement traded
a target's side for its distance, and every start then ended as its mirror image).

Gradients come from the adjoint method (:mod:`fabkit.mechanics.adjoint`: one linear
solve per target and evaluation) chained through the material law
(:func:`~fabkit.mechanics.fabricated.sheet_metrics_gradient`). A sheet has several
equilibria, and the one followed by small changes from the last need not be the one a
ramp from the flat sheet reaches. So the descent (L-BFGS-B, every equilibrium followed
from the best so far) runs in rounds of :data:`EVALUATIONS` within a trust radius, and a
round is kept only if the sheet simulated as a verdict simulates it (the ramp from the
dome start) is nearer every target by the objective (else half the round's step, or a
quarter: :data:`BACKTRACK`); the next radius follows the step kept (:data:`RADIUS`). A
trial whose equilibrium cannot be followed within :data:`FOLLOW_ITERATIONS` (the sheet
snaps far away) is refused like one with no metric: the descent steps shorter. Every
case of an evaluation (a target, as designed or with the print's error) is followed in a
worker of its own (:func:`follow`, over the cores).

What is refined is then judged as everything else, from every start
(:func:`~fabkit.mechanics.verdict.design_verdict`).
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import minimize
from threadpoolctl import threadpool_limits

from fabkit.background import parallel_map
from fabkit.design.design import Design, Layering
from fabkit.design.layers import SHARED_TURN_DEG, slope_room
from fabkit.errors import FabkitError
from fabkit.field.flat import director_angle
from fabkit.field.part import Part
from fabkit.mechanics.adjoint import aligned_distance, energy_difference, metric_gradient
from fabkit.mechanics.fabricated import (
    PointFunction,
    SheetFields,
    design_fields,
    sheet_metrics,
    sheet_metrics_gradient,
    sheet_problems,
)
from fabkit.mechanics.shell import Sheet, build_shell, flat_sheet
from fabkit.mechanics.simulate import Settings, minimise
from fabkit.mechanics.verdict import FORM_TOLERANCE, RAMP_PART, embedded_targets, grid_stride

FOLLOW = "fabkit.mechanics.refine:follow"
"""The worker function that follows one case (:func:`follow`)."""
WARM = ("fabkit.mechanics.refine",)
"""What a worker imports before its first case."""
DEGREE = 4
"""Largest total degree of the correction polynomials (15 terms per field)."""
MAX_TURN = math.radians(SHARED_TURN_DEG) / 2
"""Largest director turn (rad) of any layer from the design's director: the outer layers
within :data:`~fabkit.design.layers.SHARED_TURN_DEG` of each other, so that the layers
are printed along one set of lines. It was 0.35 rad (stop 53): the refined layers turned
up to 40 degrees apart, were planned apart, and each print's roads wandered apart again
(Fig. 1, --refine: 265 s, three prints; capped, 104 s, two; ball_hypar's hypar formed from
the first print, 100 s, 632 s before)."""
EVALUATIONS = 10
"""Most evaluations (a followed equilibrium of every target) per round of descent."""
FOLLOW_ITERATIONS = 40
"""Most Newton iterations to follow an equilibrium to a trial's metrics. A trial that
makes the sheet snap far away needs hundreds (L-BFGS-B's first step of a round, 180-410
on Fig. 1: three quarters of a round's time); it is refused, and the descent tries a
shorter step. A followed step converges in 4-19."""
ROUNDS = 4
"""Rounds of descent. Each ends with every target simulated along the ramp from the
dome start (as a verdict does), and is kept only if that is nearer: the followed
equilibrium may not be the one the ramp reaches (a sheet has several)."""
RADIUS = 0.1
"""The first round's trust radius (units of :data:`UNIT`, per unknown); the next round's
is twice the largest change of an unknown the last round kept, or a quarter of the one
it tried when it kept none."""
BACKTRACK = (1.0, 0.5, 0.25)
"""The shares of a round's step whose ramp is tried, in turn, until one is nearer: a
sheet whose side is barely programmed may take another shape along the ramp at the
round's end (ball_hypar.toml at 60 mm: the ball at 2.06 % with three quarters of the
step, 22 % with all of it, as the followed ball stayed at 2.1 %)."""
SIDE_PENALTY = 10.0
"""Weight of the squared loss of side preference (as a share of the first-order
layering's, :meth:`_Model.side`) in the objective."""
SIDE_FLOOR = 1e-12
"""Least scale of a side preference (energy, Young's modulus x length^3)."""
FAILED = 10.0
"""An evaluation whose layers make no metric counts this many times the best value."""
UNIT = 0.1
"""What one unit of an unknown changes: the layers' difference in turn (rad) or in a
feature (a share of its range, or the feature's own units where it has no range)."""
LIMIT = 10.0
"""Largest unknown (units of :data:`UNIT`)."""
TOLERANCE = FORM_TOLERANCE
"""The distance (a share of the patch's diameter) the objective counts in: a target's
term is (RMS / TOLERANCE)^4, 1 at the verdict's limit; the fourth power weighs the
farthest target most (the verdict asks every one to be within the limit)."""
PENALTY = 10.0
"""Weight of the squared bound violations (features as shares of their range, turns in
rad) in the objective."""


@dataclass(frozen=True)
class Refined:
    """A layered design refined against the simulation: ``design`` (its layering
    corrected); per embedded target (``targets``, their names) the RMS distance
    ``before`` and ``after`` (shares of each patch's diameter, the sheet simulated along
    the ramp from the dome start); the ``simulations`` made (equilibria of every target)
    and the ``seconds`` it took."""

    design: Design
    targets: tuple[str, ...]
    before: tuple[float, ...]
    after: tuple[float, ...]
    simulations: int
    seconds: float

    def summary(self) -> str:
        """``refined in 98 simulations (30 s), from the dome start: sphere 0.65 -> 0.33 %,
        bump 5.17 -> 0.28 % RMS``."""
        changes = ", ".join(
            f"{name} {100 * a:.2f} -> {100 * b:.2f} %"
            for name, a, b in zip(self.targets, self.before, self.after, strict=True)
        )
        return (
            f"refined in {self.simulations} simulations ({self.seconds:.0f} s), from the dome "
            f"start: {changes} RMS"
        )

    def to_dict(self) -> dict:
        """report.json's ``layers.refinement``."""
        return {
            "targets": list(self.targets),
            "rms_pct_before": [100 * r for r in self.before],
            "rms_pct_after": [100 * r for r in self.after],
            "simulations": self.simulations,
            "seconds": self.seconds,
        }


def refine_layering(
    design: Design,
    bounds: np.ndarray,
    part: Part | None = None,
    stride: int | None = None,
    evaluations: int = EVALUATIONS,
    degree: int = DEGREE,
    fabricated: Sequence[tuple[Design, Sequence[SheetFields]]] = (),
) -> Refined:
    """``design`` (layered) with its turn and slopes corrected to bring every embedded
    target's simulated shape nearer (module docstring); ``bounds`` (N, 2) the features'
    ranges, the sheet simulated on ``part`` at grid ``stride`` (default: the verdict's).
    ``fabricated``: prints, each a design printed (``design`` or one before it) and its
    layers as read back (bottom first): the sheet is then refined as printed, every
    print's error (its layers less its design's) added and turned over (each must form
    every target, as the verdict on a printed sheet asks), that error taken to stay what it
    was when the design changes a little; several prints' errors ask the design to form
    whichever of them the next print makes."""
    started = time.perf_counter()
    layering = design.layering
    if layering is None:
        raise ValueError("refine_layering: the design has no layers")
    stride = stride or grid_stride(design)
    fields = [design_fields(design.layer(k)) for k in range(layering.count)]
    if fabricated:  # meshed where every print made its first layer, as the verdict meshes one
        made = [layers[0].made for _, layers in fabricated]
        fields = [replace(f, made=_everywhere(made)) for f in fields]
    surfaces = embedded_targets(design)
    thickness = layering.thickness
    problems = sheet_problems(design, fields, surfaces, thickness, part=part, stride=stride)
    model = _Model.build(design, problems, bounds, degree, fabricated)
    c = np.zeros(model.size)
    states = model.ramped(c)
    first = model.worst(states)
    verified, radius, simulations = model.objective(c, states), RADIUS, 1
    with threadpool_limits(limits=1, user_api="blas"):  # as every simulation
        for _ in range(ROUNDS):
            trial, count = _descend(model, c, states, evaluations, radius)
            simulations += count
            step, kept = trial - c, None
            for share in BACKTRACK:  # the ramp may reach another shape than the one followed
                simulations += 1
                try:
                    ramped = model.ramped(c + share * step)
                    value = model.objective(c + share * step, ramped)
                except FabkitError:  # the ramp's metrics break where the followed ones did not
                    value = np.inf
                if value < verified:
                    verified, c, states, kept = value, c + share * step, ramped, share
                    break
            taken = float(np.max(np.abs(step))) or radius
            radius = taken / 4 if kept is None else min(2 * kept * taken, LIMIT)
    chosen = c
    after = model.worst(states)
    refined = design.with_layering(model.layering(chosen))
    names = tuple(p.name for p in problems)
    seconds = time.perf_counter() - started
    return Refined(refined, names, first, after, simulations * len(model.cases), seconds)


class _Spent(Exception):
    """A round's evaluations are spent (raised inside L-BFGS-B to stop it)."""


def _descend(
    model: _Model, c: np.ndarray, states: list, evaluations: int, radius: float
) -> tuple[np.ndarray, int]:
    """L-BFGS-B from ``c`` within ``radius`` of it, every equilibrium followed from the
    best one so far (from ``states`` at first): the best unknowns and the evaluations
    made."""
    best = {"value": np.inf, "states": states, "c": c}
    count = 0

    def objective(trial: np.ndarray) -> tuple[float, np.ndarray]:
        nonlocal count
        if count == evaluations:  # L-BFGS-B checks its budget only between iterations
            raise _Spent
        count += 1
        try:
            value, gradient, reached = model.evaluate(trial, best["states"])
        except FabkitError:  # no metric there: refuse the step
            return FAILED * max(best["value"], 1e-6), np.zeros_like(trial)
        if value < best["value"]:
            best.update(value=value, states=reached, c=trial.copy())
        return value, gradient

    with contextlib.suppress(_Spent):
        minimize(
            objective,
            c,
            jac=True,
            method="L-BFGS-B",
            bounds=np.clip(np.stack([c - radius, c + radius], 1), -LIMIT, LIMIT),
            options={"maxfun": evaluations, "maxiter": evaluations},
        )
    return best["c"], count


def _vertex_index(design: Design, coarse: Design, mesh) -> tuple[np.ndarray, np.ndarray]:
    """Where each vertex of a mesh of the ``coarse`` design (every stride-th grid line of
    ``design``, not refined) sits on ``design``'s grid: (rows, columns), each (V,)."""
    rows = np.searchsorted(design.u, coarse.u[mesh.grid[:, 0]])
    columns = np.searchsorted(design.v, coarse.v[mesh.grid[:, 1]])
    return rows, columns


@dataclass(frozen=True)
class _Model:
    """The refinement's unknowns and how they act: ``basis`` (V, B) polynomials at the
    mesh's vertices, ``grid_basis`` (nu, nv, B) at the design's grid points; the vertices'
    designed angle ``theta`` (V,), features ``eps`` (N, V), turn (V,) and slopes (N, V);
    the layers' ``heights`` (L,)."""

    design: Design
    problems: list
    sheet: Sheet
    targets: list
    basis: np.ndarray
    grid_basis: np.ndarray
    theta: np.ndarray
    eps: np.ndarray
    turn: np.ndarray
    slope: np.ndarray
    heights: np.ndarray
    bounds: np.ndarray
    spread: float
    errors: tuple = ()
    cases: list = field(default_factory=list)
    sides: list = field(default_factory=list)

    @classmethod
    def build(
        cls,
        design: Design,
        problems: list,
        bounds: np.ndarray,
        degree: int,
        fabricated: Sequence[tuple[Design, Sequence[SheetFields]]] = (),
    ) -> _Model:
        first = problems[0]
        mesh, coarse = first.mesh, first.coarse
        layering = design.layering
        at = _vertex_index(design, coarse, mesh)
        n0 = design.n[0][at]
        theta = np.arctan2(n0[:, 1], n0[:, 0])
        centre = mesh.points.mean(0)
        radius = float(np.max(np.linalg.norm(mesh.points - centre, axis=1)))
        grid_points = np.nan_to_num(design.r[0])
        basis = _polynomials((mesh.points - centre) / radius, degree)
        _, upper = np.linalg.qr(basis)
        scale = np.linalg.inv(upper) * np.sqrt(len(basis))  # columns orthonormal, RMS 1
        targets = [
            p.coarse.problem.targets[p.surface].surface.embed(mesh.sample(p.coarse.r[p.surface]))
            for p in problems
        ]
        model = cls(
            design,
            problems,
            Sheet.build(mesh.points, mesh.triangles),
            targets,
            basis @ scale,
            _polynomials((grid_points - centre) / radius, degree) @ scale,
            theta,
            design.eps[(slice(None), *at)],
            layering.turn[at],
            layering.slope[(slice(None), *at)],
            layering.heights,
            np.asarray(bounds, dtype=float),
            float(layering.heights[-1] - layering.heights[0]),
        )
        model = replace(model, errors=tuple(_error(d, mesh, made) for d, made in fabricated))
        modes = [(kind, k) for k in range(len(model.errors)) for kind in ("printed", "turned")]
        modes = modes or [("designed", None)]
        model.cases.extend((p, mode) for mode in modes for p in range(len(problems)))
        for problem, target, mode in model._each():
            metrics = model._case_metrics(np.zeros(model.size), problem, mode)
            held = (model.sheet, metrics, problem.thickness, problem.poisson, target)
            side, _ = side_preference(*held)
            model.sides.append((min(side, 0.0), max(abs(side), SIDE_FLOOR)))
        return model

    def _each(self) -> list[tuple]:
        """Every case simulated: (problem, its target points, its mode: (``designed``,
        None), or (``printed``, k) (print k's error added) and (``turned``, k) (that error
        turned over))."""
        return [(self.problems[p], self.targets[p], mode) for p, mode in self.cases]

    def _parts(self, c: np.ndarray, mode: tuple) -> list[tuple[float, list]]:
        """The layers whose metrics make a case's, with their weights: the designed
        layers; the printed ones (the error added); or, turned over as the verdict turns
        a print's error (:func:`~fabkit.mechanics.fabricated.turned_over`), twice the
        designed metrics less the printed ones."""
        kind, k = mode
        if kind == "designed":
            return [(1.0, self._layers(c))]
        printed = self._layers(c, self.errors[k])
        return [(1.0, printed)] if kind == "printed" else [(2.0, self._layers(c)), (-1.0, printed)]

    def _case_metrics(self, c: np.ndarray, problem, mode: tuple, surface: int | None = None):
        """A case's per-layer metrics (L, F, 2, 2) under ``surface``'s stimulus (default:
        the problem's target's); a turned-over metric that is no metric is the designed
        one, as in the verdict."""
        surface = problem.surface if surface is None else surface
        parts = [
            (weight, self._metrics(layers, problem, surface))
            for weight, layers in self._parts(c, mode)
        ]
        metrics = sum(weight * m for weight, m in parts)
        if mode[0] == "turned":
            ok = np.all(np.linalg.eigvalsh(metrics) > 0, axis=-1)
            metrics = np.where(ok[..., None, None], metrics, parts[0][1])
        return metrics

    @property
    def size(self) -> int:
        return (1 + len(self.eps)) * self.basis.shape[1]

    @property
    def units(self) -> np.ndarray:
        """(1 + N, 1) what one unit of each field's unknowns changes (:data:`UNIT`), per
        unit height."""
        low, high = self.bounds[:, 0], self.bounds[:, 1]
        span = np.where(np.isfinite(high - low), high - low, 1.0)
        return (UNIT * np.concatenate([[1.0], span]) / self.spread)[:, None]

    def _corrections(self, c: np.ndarray) -> np.ndarray:
        """(1 + N, V) corrections of the turn and slopes at the vertices (per unit height)."""
        return (c.reshape(-1, self.basis.shape[1]) @ self.basis.T) * self.units

    def _layers(self, c: np.ndarray, error: tuple | None = None) -> list[tuple]:
        """Every layer's angle (V,) and features (N, V) at the vertices, with the print's
        ``error`` (angles (L, V), features (L, N, V)) added."""
        change = self._corrections(c)
        turn, slope = self.turn + change[0], self.slope + change[1:]
        layers = [(self.theta + z * turn, self.eps + z * slope) for z in self.heights]
        if error is None:
            return layers
        return [(t + error[0][k], e + error[1][k]) for k, (t, e) in enumerate(layers)]

    def _metrics(self, layers, problem, surface: int) -> np.ndarray:
        mesh, coarse = problem.mesh, problem.coarse
        return np.stack([sheet_metrics(coarse, mesh, surface, t, e) for t, e in layers])

    def _penalty(self, c: np.ndarray) -> tuple[float, np.ndarray]:
        """The bound violations' squared sum and its gradient in c."""
        change = self._corrections(c)
        turn, slope = self.turn + change[0], self.slope + change[1:]
        low, high = self.bounds[:, :1], self.bounds[:, 1:]
        span = np.where(np.isfinite(high - low), high - low, 1.0)
        value, d_turn, d_slope = 0.0, np.zeros_like(turn), np.zeros_like(slope)
        count = len(turn)
        for z in self.heights:
            eps = self.eps + z * slope
            over = np.maximum(eps - high, 0.0) / span - np.maximum(low - eps, 0.0) / span
            value += PENALTY * float(np.sum(over**2)) / count
            d_slope += PENALTY * 2 * over / span * z / count
            turned = z * turn
            excess = np.sign(turned) * np.maximum(np.abs(turned) - MAX_TURN, 0.0)
            value += PENALTY * float(np.sum(excess**2)) / count
            d_turn += PENALTY * 2 * excess * z / count
        return value, self._chain(np.vstack([d_turn, d_slope]))

    def _chain(self, per_vertex: np.ndarray) -> np.ndarray:
        """A gradient in the turn and slopes at the vertices (1 + N, V) as one in c."""
        return ((per_vertex @ self.basis) * self.units).ravel()

    def evaluate(self, c: np.ndarray, states: list) -> tuple[float, np.ndarray, list]:
        """The objective, its gradient and the equilibria reached from ``states``; the
        cases followed side by side (:func:`follow`, over the cores)."""
        value, gradient = self._penalty(c)
        sheet = self.sheet
        metrics = [self._case_metrics(c, problem, mode) for problem, _, mode in self._each()]
        cases = zip(self._each(), metrics, states, self.sides, strict=True)
        calls = [
            (sheet.points, sheet.triangles, m, p.thickness, p.poisson, x, target, p.patch_size, b)
            for (p, target, _), m, x, b in cases
        ]
        followed = parallel_map(FOLLOW, calls, WARM)
        reached = []
        for (problem, _, mode), (term, d_metric, x) in zip(self._each(), followed, strict=True):
            value += term
            reached.append(x)
            per_vertex = np.zeros((1 + len(self.eps), len(self.theta)))
            for weight, layers in self._parts(c, mode):
                for z, (t, e), d_m in zip(self.heights, layers, d_metric, strict=True):
                    d_theta, d_eps = sheet_metrics_gradient(
                        problem.coarse, problem.mesh, problem.surface, t, e, weight * d_m
                    )
                    per_vertex[0] += z * d_theta
                    per_vertex[1:] += z * d_eps
            gradient = gradient + self._chain(per_vertex)
        return value, gradient, reached

    def distances(self, states: list) -> tuple[float, ...]:
        """RMS distance per case (shares of the patch) at the equilibria ``states``."""
        return tuple(
            aligned_distance(x, target, p.patch_size).rms
            for (p, target, _), x in zip(self._each(), states, strict=True)
        )

    def worst(self, states: list) -> tuple[float, ...]:
        """RMS distance per target, the worst over the print's errors."""
        worst = np.zeros(len(self.problems))
        for (p, _), rms in zip(self.cases, self.distances(states), strict=True):
            worst[p] = max(worst[p], rms)
        return tuple(float(r) for r in worst)

    def objective(self, c: np.ndarray, states: list) -> float:
        """The objective at ``c`` with the sheet at ``states`` (no equilibrium sought)."""
        value = self._penalty(c)[0] + sum((r / TOLERANCE) ** 4 for r in self.distances(states))
        for (problem, target, mode), bound in zip(self._each(), self.sides, strict=True):
            metrics = self._case_metrics(c, problem, mode)
            held = (self.sheet, metrics, problem.thickness, problem.poisson, target)
            value += _side_penalty(*held, bound)[0]
        return value

    def ramped(self, c: np.ndarray) -> list:
        """The equilibria (V, 3) under every target's stimulus at ``c``, each simulated as
        a verdict's from the dome start, along the slow ramp from the flat sheet as made
        (the cases side by side, over the cores)."""
        mesh = self.problems[0].mesh
        calls = [
            (
                mesh.points,
                mesh.triangles,
                self._case_metrics(c, problem, mode),
                problem.thickness,
                problem.poisson,
                Settings(),
                None,
                self._case_metrics(c, problem, mode, surface=0),
                0,
                None,
            )
            for problem, _, mode in self._each()
        ]
        return [end.positions for end in parallel_map(RAMP_PART, calls, WARM)]

    def layering(self, c: np.ndarray) -> Layering:
        """The design's layering with the corrections ``c`` on its whole grid."""
        layering = self.design.layering
        change = np.moveaxis(self.grid_basis @ c.reshape(-1, self.basis.shape[1]).T, -1, 0)
        change *= self.units[:, :, None]
        valid = self.design.valid
        turn = np.where(valid, layering.turn + change[0], np.nan)
        slope = layering.slope + change[1:]
        reach = float(np.max(np.abs(self.heights)))
        room = slope_room(self.design.eps, self.bounds, reach, slope)
        slope = np.where(valid, np.sign(slope) * np.minimum(np.abs(slope), room), np.nan)
        turn = np.clip(turn, -MAX_TURN / reach, MAX_TURN / reach)
        return Layering(layering.count, layering.thickness, turn, slope)


def follow(
    points: np.ndarray,
    triangles: np.ndarray,
    metrics: np.ndarray,
    thickness: float,
    poisson: float,
    state: np.ndarray,
    target: np.ndarray,
    patch_size: float,
    bound: tuple[float, float],
) -> tuple[float, np.ndarray, np.ndarray]:
    """One case of the objective (module docstring): the sheet (``points`` (V, 2),
    ``triangles`` (F, 3)) under per-layer ``metrics`` (L, F, 2, 2) followed from ``state``
    (V, 3) to its equilibrium x; returns its term (RMS to ``target`` (V, 3) over the
    patch's diameter ``patch_size`` over :data:`TOLERANCE`, to the fourth, plus the side
    penalty against ``bound``), that term's derivative in the metrics (L, F, 3) and x.
    Raises :class:`FabkitError` when x is not reached within :data:`FOLLOW_ITERATIONS`.
    Plain data in and out: run in a worker (:func:`fabkit.background.parallel_map`)."""
    sheet = flat_sheet(points, np.asarray(triangles, dtype=np.int64))
    with threadpool_limits(limits=1, user_api="blas"):  # as every simulation
        shell = build_shell(sheet, metrics, thickness, poisson)
        tolerance = Settings().tolerance * sheet.edge_length()
        x, _, converged = minimise(shell, state, tolerance, FOLLOW_ITERATIONS, exact=True)
        if not converged:  # snapped far away: the step is refused, not followed there
            raise FabkitError("refine: the followed equilibrium ran away")
        distance = aligned_distance(x, target, patch_size)
        side, d_side = _side_penalty(sheet, metrics, thickness, poisson, target, bound)
        share = distance.value / TOLERANCE**2
        d_distance = 2 * share / TOLERANCE**2 * distance.gradient
        d_metric = metric_gradient(sheet, metrics, thickness, poisson, x, d_distance)
    return share**2 + side, d_side + d_metric, x


def side_preference(
    sheet: Sheet,
    metrics: np.ndarray,
    thickness: float,
    poisson: float,
    target: np.ndarray,
    gradient: bool = False,
) -> tuple[float, np.ndarray | None]:
    """The energy of the sheet (``thickness`` in design units, ``poisson`` ratio) held at
    its ``target`` (V, 3) less that held at the target's mirror image (< 0: the layers
    favour the target's side), and with ``gradient`` its derivative in the metrics
    (L, F, 3). Only the terms odd in the curvature differ: the layers' natural curvature
    against the target's."""
    mirror = target * np.array([1.0, 1.0, -1.0])
    return energy_difference(sheet, metrics, thickness, poisson, target, mirror, gradient)


def _side_penalty(
    sheet: Sheet,
    metrics: np.ndarray,
    thickness: float,
    poisson: float,
    target: np.ndarray,
    bound: tuple[float, float],
) -> tuple[float, np.ndarray]:
    """The squared excess of :func:`side_preference` over ``bound`` (limit, scale): the
    layers may favour the target's side no less than the first-order layering did. Its
    gradient is computed only where it is not zero."""
    limit, scale = bound
    held = (sheet, metrics, thickness, poisson, target)
    side, _ = side_preference(*held)
    excess = max(side - limit, 0.0) / scale
    if excess == 0.0:
        return 0.0, np.zeros((*metrics.shape[:2], 3))
    _, gradient = side_preference(*held, gradient=True)
    return SIDE_PENALTY * excess**2, SIDE_PENALTY * 2 * excess / scale * gradient


def _polynomials(points: np.ndarray, degree: int) -> np.ndarray:
    """The monomials x^i y^j, i + j <= ``degree``, at ``points`` (..., 2): (..., terms)."""
    x, y = points[..., 0], points[..., 1]
    return np.stack(
        [x**i * y ** (total - i) for total in range(degree + 1) for i in range(total + 1)], -1
    )


def _everywhere(made: list) -> PointFunction:
    """Where every one of the ``made`` functions (of (n, 2) points) says made."""
    return lambda points: np.logical_and.reduce([m(points) for m in made])


def _error(
    design: Design, mesh, fabricated: Sequence[SheetFields]
) -> tuple[np.ndarray, np.ndarray]:
    """A print's error at the mesh's vertices: the read-back layers' director angles
    (L, V) and features (L, N, V) less those of the layers of ``design``, the design
    printed."""
    count = design.layering.count
    if len(fabricated) != count:
        raise FabkitError(f"refine: {len(fabricated)} layers read back for a sheet of {count}")
    d_theta, d_eps = [], []
    for k, made in enumerate(fabricated):
        own = design_fields(design.layer(k))
        turn = made.theta(mesh.points) - own.theta(mesh.points)
        d_theta.append(director_angle(turn))
        d_eps.append(made.features(mesh.points) - own.features(mesh.points))
    return np.array(d_theta), np.array(d_eps)
