"""The solver's initial data: exact values along the initial u- and v-curves and at the
origin, from which the march starts (:mod:`fabkit.design.march`).

Grid coordinates are arc length along the initial curves (alpha = 1 on the u-curve, beta = 1
on the v-curve), whatever parameter t the spec writes them in: :func:`arc_length_parameters`
measures it (composite Gauss-Legendre), kept for the last few curves. Initial data that is
not finite one step from the start, or a start point that cannot be solved, is refused.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from fabkit.design.batch import DET_M, FINE, ISOTROPIC, REASONS, Problem, State
from fabkit.errors import FabkitError
from fabkit.problem.expr import Expression
from fabkit.problem.spec import Spec


@dataclass(frozen=True)
class _Curve:
    """A plane curve of t and its first two derivatives, each differentiated once."""

    point: tuple[Expression, Expression]
    first: tuple[Expression, Expression]
    second: tuple[Expression, Expression]

    @classmethod
    def of(cls, curve: tuple[Expression, Expression]) -> _Curve:
        first = tuple(c.diff("t") for c in curve)
        return cls(curve, first, tuple(c.diff("t") for c in first))

    def speed(self, t: np.ndarray) -> np.ndarray:
        return np.linalg.norm(np.stack([c(t) for c in self.first], -1), axis=-1)


def _curve(curve: _Curve, t: np.ndarray):
    """Point, speed, unit tangent and signed curvature of a plane curve at parameters t."""
    point = np.stack([c(t) for c in curve.point], -1)
    first = np.stack([c(t) for c in curve.first], -1)
    second = np.stack([c(t) for c in curve.second], -1)
    speed = np.linalg.norm(first, axis=-1)
    cross = first[..., 0] * second[..., 1] - first[..., 1] * second[..., 0]
    return point, speed, first / speed[..., None], cross / speed**3


_GAUSS_NODES, _GAUSS_WEIGHTS = np.polynomial.legendre.leggauss(6)
PANELS = 4096
"""Panels of the composite Gauss-Legendre rule that measures arc length along initial curves."""


def arc_length_parameters(curve: _Curve, lengths: np.ndarray, where: str) -> np.ndarray:
    """Curve parameters t at which the arc length from t = 0 equals ``lengths`` (signed).

    The u- and v-coordinates are arc length along the initial curves (alpha = beta = 1
    there), whatever parameter t the spec writes them in. Where the curve's speed is not
    finite (``sqrt(1 - t)`` beyond t = 1), the curve ends: lengths beyond get t = NaN, and
    the solver stops there.
    """
    speed = curve.speed
    lengths = np.asarray(lengths, dtype=float)
    reach = float(np.max(np.abs(lengths), initial=0.0))
    direction = np.where(lengths < 0, -1.0, 1.0)
    speed0 = float(speed(np.array(0.0)))
    if not speed0 > 0:
        raise FabkitError(f"{where}: the curve has zero speed at t = 0")
    span = 1.5 * reach / speed0 + 1e-12
    result = np.zeros_like(lengths)
    for sign in (-1.0, 1.0):
        pick = direction == sign
        if not pick.any():
            continue
        for _ in range(40):
            edges = sign * np.linspace(0.0, span, PANELS + 1)
            pieces = _panel_lengths(speed, edges[:-1], edges[1:])
            finite = np.isfinite(pieces)
            defined = PANELS if finite.all() else int(np.argmin(finite))
            cumulative = np.concatenate([[0.0], np.cumsum(pieces[:defined])])
            if defined < PANELS or cumulative[-1] >= reach:
                break
            span *= 2
        else:
            raise FabkitError(f"{where}: the curve is shorter than the grid needs ({reach:g})")
        target = np.abs(lengths[pick])
        beyond = target > cumulative[-1]
        panel = np.clip(np.searchsorted(cumulative, target) - 1, 0, max(defined - 1, 0))
        t = edges[panel] + sign * (target - cumulative[panel]) / np.maximum(
            speed(edges[panel]), 1e-300
        )
        for _ in range(4):
            measured = cumulative[panel] + _panel_lengths(speed, edges[panel], t)
            t = t - sign * (measured - target) / speed(t)
        result[pick] = np.where(beyond, np.nan, t)
    return result


def _panel_lengths(speed, start: np.ndarray, end: np.ndarray) -> np.ndarray:
    """Arc length from start to end (arrays) by 6-point Gauss-Legendre; negative if end < start."""
    half, middle = (end - start) / 2, (end + start) / 2
    nodes = middle[..., None] + half[..., None] * _GAUSS_NODES
    return np.abs(half) * (speed(nodes) @ _GAUSS_WEIGHTS)


CURVE_CACHE = 32
"""Curves whose arc-length parameters a process keeps (a search varies few of them)."""
_curves: dict[tuple, tuple[np.ndarray, ...]] = {}


def _curve_geometry(curve: tuple[Expression, Expression], lengths: np.ndarray, where: str):
    """Parameters t at arc lengths ``lengths`` (Q, L) along a curve, and there its point,
    speed, unit tangent and signed curvature.

    Kept for the last :data:`CURVE_CACHE` curves by their expression trees (with the
    constants they hold) and the lengths: the candidates of a search often share a curve,
    and measuring arc length is the costliest part of a small solve. The arrays returned
    are read-only.
    """
    key = (tuple(_tree_key(c.tree) for c in curve), lengths.shape, lengths.tobytes())
    if key not in _curves:
        parts = _Curve.of(curve)
        t = arc_length_parameters(parts, lengths, where)
        found = (t, *_curve(parts, t))
        for array in found:
            array.setflags(write=False)
        if len(_curves) >= CURVE_CACHE:
            del _curves[next(iter(_curves))]
        _curves[key] = found
    return _curves[key]


def _tree_key(node) -> tuple:
    """A hashable copy of an expression tree: equal for trees that compute the same way."""
    return (node.kind, node.value, node.index, tuple(_tree_key(a) for a in node.args))


def curve_data(problem: Problem, spec: Spec) -> tuple[State, State]:
    """Exact data along the initial u-curve (index i) and v-curve (index j), (R, 2D+1, ...),
    for the problem of the one spec ``spec``.

    Grid coordinates are arc length along the curves, so alpha = 1 on the u-curve and
    beta = 1 on the v-curve. The data is computed once at the fine step; the coarse rows
    take every other point (the same arc lengths), NaN past their last diagonal.
    """
    initial = spec.initial
    fine = problem.march == FINE
    h, diagonals = problem.step[fine][0, 0], problem.diagonals[FINE]
    index = np.arange(diagonals + 1)
    slopes = [e.diff("t") for e in initial.eps]
    data = []
    for curve, sign, name in (
        (initial.u_curve, problem.sign_u[fine], "initial.u_curve"),
        (initial.v_curve, problem.sign_v[fine], "initial.v_curve"),
    ):
        t, point, speed, tangent, curvature = _curve_geometry(curve, sign * index * h, name)
        eps = np.stack([e(t) for e in initial.eps], -1)
        eps_s = np.stack([e(t) for e in slopes], -1) / speed[..., None]
        slope = np.stack([e(t) for e in initial.slope], -1)
        _refuse_first_step(problem, name, t, (point, curvature), eps, eps_s, slope)
        data.append(tuple(_both_marches(x) for x in (point, tangent, curvature, eps, eps_s, slope)))
    point, tangent, curvature, eps, eps_s, slope = data[0]
    ones = np.ones_like(curvature)
    u_data = {
        "alpha": ones,
        "b": curvature,
        "eps": eps,
        "q": slope,
        "p": eps_s,
        "r0": point,
        "n0": tangent,
    }
    point, tangent, curvature, eps, eps_s, slope = data[1]
    v_data = {
        "beta": ones,
        "s": curvature,
        "eps": eps,
        "p": slope,
        "q": eps_s,
        "r0": point,
        "n0": np.stack([tangent[..., 1], -tangent[..., 0]], -1),
    }
    return u_data, v_data


def _both_marches(fine: np.ndarray) -> np.ndarray:
    """Rows of both marches from the fine march's curve data (Q, 2D+1, ...): the coarse
    rows take every other point, NaN past their last one."""
    coarse = np.full_like(fine, np.nan)
    every_other = fine[:, ::2]
    coarse[:, : every_other.shape[1]] = every_other
    return np.concatenate([coarse, fine])


def _refuse_first_step(problem: Problem, name: str, t, curve_parts, eps, eps_s, slope) -> None:
    """Refuse initial data that is not finite one grid step from the start in some
    quadrant: that quadrant could not begin. Beyond the first step, non-finite data is the
    end of the data (the solver stops there, a "non-finite values" stop)."""
    carrier = name.removeprefix("initial.")
    for quadrant in range(t.shape[0]):
        culprit = None
        if not all(np.all(np.isfinite(part[quadrant, 1])) for part in curve_parts):
            culprit = name
        for i, along in enumerate(problem.along):
            if culprit is None and (carrier == "u_curve") == bool(along):
                if not np.isfinite(eps[quadrant, 1, i]) or not np.isfinite(eps_s[quadrant, 1, i]):
                    culprit = f"initial.eps[{i}]"
                elif not np.isfinite(slope[quadrant, 1, i]):
                    culprit = f"initial.slope[{i}]"
        if culprit is not None:
            signs = [int(problem.sign_u[quadrant, 0]), int(problem.sign_v[quadrant, 0])]
            raise FabkitError(
                f"{culprit}: not finite at the first grid step along the {carrier} "
                f"(t = {t[quadrant, 1]:.4g}, quadrant {signs}): that quadrant cannot start; "
                "change the expression or leave the quadrant out (solver.quadrants)"
            )


def origin_state(problem: Problem, specs: Sequence[Spec], u_data: State, v_data: State) -> State:
    """Complete data at (u, v) = (0, 0) for every row, as a diagonal of length 1."""
    along = problem.along
    starts = np.array([[t.start for t in spec.targets] for spec in specs])  # (B, S, 2)
    directors = np.array([[t.director for t in spec.targets] for spec in specs])
    r = starts[problem.candidate][:, None].copy()
    n = directors[problem.candidate][:, None].copy()
    r[:, :, 0], n[:, :, 0] = u_data["r0"][:, :1], u_data["n0"][:, :1]
    first_u = {k: val[:, :1] for k, val in u_data.items()}
    first_v = {k: val[:, :1] for k, val in v_data.items()}
    return {
        "alpha": first_u["alpha"],
        "b": first_u["b"],
        "beta": first_v["beta"],
        "s": first_v["s"],
        "eps": np.where(along, first_u["eps"], first_v["eps"]),
        "p": np.where(along, first_u["p"], first_v["p"]),
        "q": np.where(along, first_u["q"], first_v["q"]),
        "r": r,
        "n": n,
    }


def refuse_bad_start(failed: np.ndarray) -> None:
    """Refuse the problem when the start point itself cannot be solved."""
    code = int(failed[0, 0]) if failed.size else 0
    if code == DET_M:
        raise FabkitError(
            "det M = 0 at the start point: these stimuli cannot shape the targets independently "
            "(see the supplement's word of caution); choose other stimuli"
        )
    if code == ISOTROPIC:
        raise FabkitError("the start point is isotropic (lambda1 = lambda2 at every stimulus)")
    if code:
        raise FabkitError(f"inconsistent initial data at the start point: {REASONS[code]}")
