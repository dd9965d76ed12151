"""The multi-surface inverse-design solver: a Goursat problem marched along diagonals.

Unknowns on the material grid (u, v) (see ``shared/notes/equations.md``): alpha,
beta, b, s, eps (N), p, q (N), and for every surface j a chart point r_j and a
director n_j. They split by the characteristic direction of their equation:

* u-propagated ("U-set"): beta, s, and eps, p of features acting across n;
* v-propagated ("V-set"): alpha, b, and eps, q of features acting along n;
* both: r_j, n_j (the two estimates are averaged);
* cross-derived: p of along features and q of across features, from eps by a
  difference *along the diagonal* plus the known characteristic derivative,
  so no value beyond the current diagonal is needed.

The highest derivatives (d_v b, d_u s, d_u p_across, d_v q_along) follow from the
target curvatures: w = M^-1 (K_target - Kbar). Each step from diagonal d to d+1 is
Heun's predictor-corrector (trapezoidal rule along the characteristics), second-order
accurate in the step; every diagonal of every quadrant is one vectorised update.

A point that fails a check (alpha <= 0, lambda <= 0, isotropic point, det M ~ 0,
leaving a chart, non-finite, too much strain) stops; only the points depending on
it (its quarter-plane of influence) are removed, and the stop is reported.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from fabkit.design.design import Design
from fabkit.errors import FabkitError
from fabkit.material import ALONG
from fabkit.spec import Spec

REASONS = (
    "",
    "non-finite values",
    "alpha <= 0 (defect of the director texture)",
    "beta <= 0 (defect of the director texture)",
    "lambda <= 0",
    "strain beyond solver.max_strain",
    "isotropic point (lambda1 = lambda2 at every stimulus)",
    "det M near zero",
    "target point left its chart",
    "no neighbours for the cross derivative",
)
NON_FINITE, ALPHA, BETA, LAMBDA, STRAIN, ISOTROPIC, DET_M, CHART, ISOLATED = range(1, 10)
DET_TOLERANCE = 1e-8
"""|det M| below this times the product of M's row norms counts as singular."""
ISOTROPIC_TOLERANCE = 1e-9
"""|lambda1 - lambda2| below this relative tolerance counts as isotropic."""


@dataclass(frozen=True)
class Stop:
    """Where and why the integration stopped at one grid point (u, v in design units)."""

    reason: str
    u: float
    v: float
    surface: str | None


@dataclass(frozen=True)
class Solution:
    """A solved design, its stops, and the wall time of the solve in seconds."""

    design: Design
    stops: tuple[Stop, ...]
    seconds: float


State = dict[str, np.ndarray]
"""Values on one diagonal of every quadrant: arrays (Q, L, ...) by variable name."""


@dataclass(frozen=True)
class _Problem:
    """Constants of one solve, derived once from the spec."""

    spec: Spec
    along: np.ndarray  # (N,) bool: feature acts along the director
    stimuli: np.ndarray  # (S, k)
    sign_u: np.ndarray  # (Q, 1) quadrant sign of u
    sign_v: np.ndarray  # (Q, 1) quadrant sign of v
    step: float
    diagonals: int

    @property
    def surfaces(self):
        return [t.surface for t in self.spec.targets]


def solve(spec: Spec, progress: Callable[[int, int], None] | None = None) -> Solution:
    """Solve the design problem on the spec's grid; ``progress(done, total)`` per diagonal.

    With ``solver.extrapolate`` (the default) the problem is also solved at half the step
    and the two combined by Richardson extrapolation, (4 X_{h/2} - X_h) / 3, which removes
    the leading h^2 error of the second-order march; the stops reported are the fine
    march's, the more precise of the two.
    """
    started = time.perf_counter()
    settings = spec.solver
    total = settings.diagonals * (3 if settings.extrapolate else 1)

    def report(done: int) -> None:
        if progress:
            progress(done, total)

    with np.errstate(all="ignore"):  # overflow and NaN are stops, checked point by point
        coarse, stops = _march(spec, settings.step, settings.diagonals, report, 0)
        if settings.extrapolate:
            fine, stops = _march(
                spec, settings.step / 2, 2 * settings.diagonals, report, settings.diagonals, every=2
            )
            coarse = _extrapolate(spec, coarse, fine)
    return Solution(coarse, stops, time.perf_counter() - started)


def _march(spec: Spec, step: float, diagonals: int, report, offset: int, every: int = 1):
    """March every quadrant out to ``diagonals`` diagonals of width ``step``; the design
    keeps every ``every``-th grid line."""
    problem = _problem(spec, step, diagonals)
    u_data, v_data = _curve_data(problem)
    origin = _origin(problem, u_data, v_data)
    grid = _Grid(problem, origin)
    old = origin
    rates_old, failed = _rates(problem, old)
    _refuse_bad_start(failed)
    for d in range(diagonals):
        old, rates_old = _advance(problem, grid, old, rates_old, d, u_data, v_data)
        report(offset + d + 1)
        if d >= 1 and not grid.valid_diagonal(d + 1)[:, 1:-1].any():
            break  # beyond, only the bare initial curves could go on: no area of design
    return grid.assemble(every), grid.stops()


def _extrapolate(spec: Spec, coarse: Design, fine: Design) -> Design:
    """Richardson combination of a march at step h and one at h/2, on the coarse grid."""
    valid = coarse.valid & fine.valid

    def combine(c: np.ndarray, f: np.ndarray, grid_axes: int) -> np.ndarray:
        mask = valid.reshape((1,) * grid_axes + valid.shape + (1,) * (c.ndim - grid_axes - 2))
        return np.where(mask, (4 * f - c) / 3, np.nan)

    r = combine(coarse.r, fine.r, 1)
    n = combine(coarse.n, fine.n, 1)
    for j, target in enumerate(spec.targets):
        g = target.surface.metric(np.where(valid[..., None], r[j], 0.0))
        n[j] /= np.sqrt(np.einsum("...i,...ij,...j->...", n[j], g, n[j]))[..., None]
    return Design(
        u=coarse.u,
        v=coarse.v,
        valid=valid,
        alpha=combine(coarse.alpha, fine.alpha, 0),
        beta=combine(coarse.beta, fine.beta, 0),
        eps=combine(coarse.eps, fine.eps, 1),
        r=r,
        n=n,
        stimuli=coarse.stimuli,
        spec=coarse.spec,
    )


def _problem(spec: Spec, step: float, diagonals: int) -> _Problem:
    quadrants = np.array(spec.solver.quadrants, dtype=float)
    return _Problem(
        spec=spec,
        along=np.array([c == ALONG for c in spec.classes]),
        stimuli=spec.stimuli,
        sign_u=quadrants[:, :1],
        sign_v=quadrants[:, 1:],
        step=step,
        diagonals=diagonals,
    )


# --- initial data -------------------------------------------------------------------------


def _curve(curve, t: np.ndarray):
    """Point, speed, unit tangent and signed curvature of a plane curve at parameters t."""
    point = np.stack([c(t) for c in curve], -1)
    first = np.stack([c.diff("t")(t) for c in curve], -1)
    second = np.stack([c.diff("t").diff("t")(t) for c in curve], -1)
    speed = np.linalg.norm(first, axis=-1)
    cross = first[..., 0] * second[..., 1] - first[..., 1] * second[..., 0]
    return point, speed, first / speed[..., None], cross / speed**3


_GAUSS_NODES, _GAUSS_WEIGHTS = np.polynomial.legendre.leggauss(6)
PANELS = 4096
"""Panels of the composite Gauss-Legendre rule that measures arc length along initial curves."""


def arc_length_parameters(curve, lengths: np.ndarray, where: str) -> np.ndarray:
    """Curve parameters t at which the arc length from t = 0 equals ``lengths`` (signed).

    The u- and v-coordinates are arc length along the initial curves (alpha = beta = 1
    there), whatever parameter t the spec writes them in. Where the curve's speed is not
    finite (``sqrt(1 - t)`` beyond t = 1), the curve ends: lengths beyond get t = NaN, and
    the solver stops there.
    """

    def speed(t: np.ndarray) -> np.ndarray:
        return np.linalg.norm(np.stack([c.diff("t")(t) for c in curve], -1), axis=-1)

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


def _curve_data(problem: _Problem) -> tuple[State, State]:
    """Exact data along the initial u-curve (index i) and v-curve (index j), (Q, D+1, ...).

    Grid coordinates are arc length along the curves, so alpha = 1 on the u-curve and
    beta = 1 on the v-curve.
    """
    h, initial = problem.step, problem.spec.initial
    index = np.arange(problem.diagonals + 1)
    data = []
    for curve, sign, name in (
        (initial.u_curve, problem.sign_u, "initial.u_curve"),
        (initial.v_curve, problem.sign_v, "initial.v_curve"),
    ):
        t = arc_length_parameters(curve, sign * index * h, name)
        point, speed, tangent, curvature = _curve(curve, t)
        eps = np.stack([e(t) for e in initial.eps], -1)
        eps_s = np.stack([e.diff("t")(t) for e in initial.eps], -1) / speed[..., None]
        slope = np.stack([e(t) for e in initial.slope], -1)
        _refuse_first_step(problem, name, t, (point, curvature), eps, eps_s, slope)
        data.append((point, tangent, curvature, eps, eps_s, slope))
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


def _refuse_first_step(problem: _Problem, name: str, t, curve_parts, eps, eps_s, slope) -> None:
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


def _origin(problem: _Problem, u_data: State, v_data: State) -> State:
    """Complete data at (u, v) = (0, 0) for every quadrant, as a diagonal of length 1."""
    along = problem.along
    quadrants = problem.sign_u.shape[0]
    targets = problem.spec.targets
    r = np.stack([t.start for t in targets])[None, None].repeat(quadrants, 0)
    n = np.stack([t.director for t in targets])[None, None].repeat(quadrants, 0)
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


def _refuse_bad_start(failed: np.ndarray) -> None:
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


# --- the propagation equations ------------------------------------------------------------


def _rates(problem: _Problem, state: State) -> tuple[tuple[State, State], np.ndarray]:
    """Derivatives in u and in v of every variable, and a failure code per point.

    Returns ``((du, dv), failed)`` with ``failed`` (Q, L) int (0 = fine, else an index
    into REASONS) and, as ``du["n_unit"]``, the directors renormalised in their metrics.
    """
    alpha, beta, b, s = state["alpha"], state["beta"], state["b"], state["s"]
    eps, p, q, r, n = state["eps"], state["p"], state["q"], state["r"], state["n"]
    response = problem.spec.material.response(np.moveaxis(eps, -1, 0), problem.stimuli)
    lam1 = np.moveaxis(response.lambda1, 0, -1)  # (Q, L, S)
    lam2 = np.moveaxis(response.lambda2, 0, -1)
    l1e = np.moveaxis(response.l1_e, (0, 1), (-2, -1))  # (Q, L, S, N)
    l2e = np.moveaxis(response.l2_e, (0, 1), (-2, -1))
    l1ee = np.moveaxis(response.l1_ee, (0, 1, 2), (-3, -2, -1))  # (Q, L, S, N, N)
    l2ee = np.moveaxis(response.l2_ee, (0, 1, 2), (-3, -2, -1))

    l1q = np.einsum("...sn,...n->...s", l1e, q)
    l2q = np.einsum("...sn,...n->...s", l2e, q)
    l1p = np.einsum("...sn,...n->...s", l1e, p)
    l2p = np.einsum("...sn,...n->...s", l2e, p)
    ku = (b[..., None] - l1q) / lam2
    kv = (s[..., None] + l2p) / lam1

    g, gamma, curvature, inside = _geometry(problem, r)
    gn = np.einsum("...ij,...j->...i", g, n)
    norm = np.sqrt(np.einsum("...i,...i->...", n, gn))
    n = n / norm[..., None]
    gn = gn / norm[..., None]
    det_g = g[..., 0, 0] * g[..., 1, 1] - g[..., 0, 1] ** 2
    n_perp = np.stack([-gn[..., 1], gn[..., 0]], -1) / np.sqrt(det_g)[..., None]

    stretch_u = alpha[..., None] * lam1  # (Q, L, S): alpha lambda1
    stretch_v = beta[..., None] * lam2
    gamma_nn = np.einsum("...ikl,...k,...l->...i", gamma, n, n)
    gamma_pn = np.einsum("...ikl,...k,...l->...i", gamma, n_perp, n)

    matrix = _curvature_matrix(problem.along, lam1, lam2, l1e, l2e)
    k_bar = (
        -(ku**2)
        - kv**2
        - (
            np.einsum("...ij,...i,...j->...", l1ee, q[..., None, :], q[..., None, :])
            + (b[..., None] - l1q) * l2q
        )
        / lam2**2
        - (
            np.einsum("...ij,...i,...j->...", l2ee, p[..., None, :], p[..., None, :])
            - (s[..., None] + l2p) * l1p
        )
        / lam1**2
    )
    singular = _singular(matrix)
    safe = np.where(singular[..., None, None], np.eye(matrix.shape[-1]), matrix)
    with np.errstate(all="ignore"):
        w = np.linalg.solve(safe, (curvature - k_bar)[..., None])[..., 0]  # (Q, L, S)

    du = {
        "beta": alpha * beta * s,
        "s": alpha * w[..., 1],
        "eps": alpha[..., None] * p,
        "p": alpha[..., None] * w[..., 2:],
        "r": stretch_u[..., None] * n,
        "n": stretch_u[..., None] * (ku[..., None] * n_perp - gamma_nn),
        "n_unit": n,
    }
    dv = {
        "alpha": -alpha * beta * b,
        "b": beta * w[..., 0],
        "eps": beta[..., None] * q,
        "q": beta[..., None] * w[..., 2:],
        "r": stretch_v[..., None] * n_perp,
        "n": stretch_v[..., None] * (kv[..., None] * n_perp - gamma_pn),
    }
    failed = _failures(problem, state, lam1, lam2, inside, singular, du, dv)
    return (du, dv), failed


def _geometry(problem: _Problem, r: np.ndarray):
    """Metric, Christoffel symbols, K and chart membership of every surface at r (Q, L, S, 2)."""
    parts = [surface.geometry(r[..., j, :]) for j, surface in enumerate(problem.surfaces)]
    inside = np.stack(
        [surface.contains(r[..., j, :]) for j, surface in enumerate(problem.surfaces)], -1
    )
    g = np.stack([part[0] for part in parts], -3)
    gamma = np.stack([part[1] for part in parts], -4)
    curvature = np.stack([part[2] for part in parts], -1)
    return g, gamma, curvature, inside


def _curvature_matrix(along, lam1, lam2, l1e, l2e) -> np.ndarray:
    """M (Q, L, S, S): K_j = M_j . w + Kbar_j with w = (d_v b/beta, d_u s/alpha, w_1..w_N)."""
    columns = [1 / lam2**2, -1 / lam1**2]
    for i, is_along in enumerate(along):
        columns.append(-l1e[..., i] / lam2**2 if is_along else -l2e[..., i] / lam1**2)
    return np.stack(columns, -1)


def _singular(matrix: np.ndarray) -> np.ndarray:
    """True where det M is near zero relative to the product of M's row norms."""
    with np.errstate(all="ignore"):
        scale = np.prod(np.linalg.norm(matrix, axis=-1), axis=-1)
        finite = np.all(np.isfinite(matrix), axis=(-2, -1))
        det = np.linalg.det(np.where(finite[..., None, None], matrix, 0.0))
        return ~finite | ~(np.abs(det) > DET_TOLERANCE * scale)


def _failures(problem, state, lam1, lam2, inside, singular, du, dv) -> np.ndarray:
    """First failure reason per point (Q, L); 0 where the point is fine."""
    scalars = [state["alpha"], state["beta"], state["b"], state["s"]]
    arrays = [state["eps"], state["p"], state["q"], state["r"], state["n"]]
    finite = np.all([np.isfinite(x) for x in scalars], axis=0)
    for x in arrays + [du["n"], dv["n"], du["s"], dv["b"], du["p"], dv["q"]]:
        finite &= np.all(np.isfinite(x.reshape(*x.shape[:2], -1)), axis=-1)
    targets = slice(1, None)
    with np.errstate(invalid="ignore"):
        checks = [
            (NON_FINITE, ~finite),
            (ALPHA, ~(state["alpha"] > 0)),
            (BETA, ~(state["beta"] > 0)),
            (LAMBDA, np.any(~(lam1 > 0) | ~(lam2 > 0), axis=-1)),
            (
                STRAIN,
                np.any(
                    np.maximum(abs(lam1 - 1), abs(lam2 - 1)) > problem.spec.solver.max_strain,
                    axis=-1,
                ),
            ),
            (
                ISOTROPIC,
                np.all(
                    abs(lam1 - lam2)[..., targets]
                    <= ISOTROPIC_TOLERANCE * (lam1 + lam2)[..., targets],
                    axis=-1,
                ),
            ),
            (DET_M, singular),
            (CHART, np.any(~inside, axis=-1)),
        ]
    failed = np.zeros(state["alpha"].shape, dtype=int)
    for code, bad in reversed(checks):
        failed = np.where(bad, code, failed)
    return failed


# --- marching -----------------------------------------------------------------------------

U_SET = ("beta", "s")
V_SET = ("alpha", "b")


def _advance(problem, grid, old, rates_old, d, u_data, v_data):
    """One Heun step from diagonal d to d+1 in every quadrant; stores and returns the result."""
    sources = grid.valid_diagonal(d)
    ok_new = np.concatenate([sources[:, :1], sources[:, 1:] & sources[:, :-1], sources[:, -1:]], 1)
    predicted = _propagate(problem, old, rates_old, None, d, u_data, v_data)
    fail_predicted = _cross_derive(problem, predicted, ok_new, d, u_data, v_data)
    rates_predicted, failed = _rates_where(problem, predicted, ok_new & (fail_predicted == 0))
    failed = np.where(fail_predicted, fail_predicted, failed)
    ok_predicted = ok_new & (failed == 0)
    corrected = _propagate(problem, old, rates_old, rates_predicted, d, u_data, v_data)
    fail_corrected = _cross_derive(problem, corrected, ok_predicted, d, u_data, v_data)
    ok_corrected = ok_predicted & (fail_corrected == 0)
    _share_axes(problem, corrected, ok_corrected)
    rates_new, failed_new = _rates_where(problem, corrected, ok_corrected)
    corrected["n"] = rates_new[0]["n_unit"]
    failed = np.where(failed, failed, np.where(fail_corrected, fail_corrected, failed_new))
    failed = np.where(ok_new, failed, 0)
    valid = ok_new & (failed == 0)
    grid.store(d + 1, corrected, valid, failed)
    for key, value in corrected.items():
        mask = valid.reshape(valid.shape + (1,) * (value.ndim - 2))
        corrected[key] = np.where(mask, value, np.nan)
    return corrected, rates_new


def _rates_where(problem: _Problem, state: State, mask: np.ndarray):
    """:func:`_rates` at the points of ``mask`` (Q, L) only; NaN rates elsewhere."""
    if mask.all() or not mask.any():
        return _rates(problem, state)
    picked = {key: value[mask][None] for key, value in state.items()}
    rates, failed = _rates(problem, picked)
    out = np.zeros(mask.shape, dtype=int)
    out[mask] = failed[0]
    return _scatter_rates(mask, rates), out


def _scatter_rates(mask: np.ndarray, rates):
    """Rates on the full diagonal (NaN off the mask) from rates at the masked points."""
    scattered = []
    for part in rates:
        full = {}
        for key, value in part.items():
            out = np.full(mask.shape + value.shape[2:], np.nan)
            out[mask] = value[0]
            full[key] = out
        scattered.append(full)
    return tuple(scattered)


def _share_axes(problem: _Problem, state: State, ok: np.ndarray) -> None:
    """Give quadrants that share an axis point one value there: the mean of their values.

    Each quadrant's one-sided cross derivatives differ at O(h^2) on the axes; without this,
    the assembled design would have a small kink along u = 0 and v = 0.
    """
    for position, signs in ((0, problem.sign_v[:, 0]), (-1, problem.sign_u[:, 0])):
        for sign in (-1.0, 1.0):
            group = (signs == sign) & ok[:, position]
            if group.sum() < 2:
                continue
            for value in state.values():
                value[group, position] = value[group, position].mean(axis=0)


def _propagate(problem, old, rates_old, rates_new, d, u_data, v_data) -> State:
    """Values on diagonal d+1 from diagonal d: Euler (rates_new None) or trapezoidal."""
    h, along = problem.step, problem.along

    def rate(kind: int, key: str) -> np.ndarray:
        """Effective slope for the step: (Q, d+1, ...) along u (kind 0) or v (kind 1)."""
        first = rates_old[kind][key]
        if rates_new is None:
            return first
        second = rates_new[kind][key]
        second = second[:, 1:] if kind == 0 else second[:, :-1]
        return 0.5 * (first + second)

    def from_west(key: str) -> np.ndarray:
        slope = rate(0, key)
        return old[key] + h * _expand(problem.sign_u, slope.ndim) * slope

    def from_south(key: str) -> np.ndarray:
        slope = rate(1, key)
        return old[key] + h * _expand(problem.sign_v, slope.ndim) * slope

    v_end = {k: val[:, d + 1 : d + 2] for k, val in v_data.items()}
    u_end = {k: val[:, d + 1 : d + 2] for k, val in u_data.items()}
    new: State = {}
    for key in U_SET:
        new[key] = np.concatenate([v_end[key], from_west(key)], 1)
    for key in V_SET:
        new[key] = np.concatenate([from_south(key), u_end[key]], 1)
    eps_u = np.concatenate([v_end["eps"], from_west("eps")], 1)
    eps_v = np.concatenate([from_south("eps"), u_end["eps"]], 1)
    new["eps"] = np.where(along, eps_v, eps_u)
    p_u = np.concatenate([v_end["p"], from_west("p")], 1)
    q_v = np.concatenate([from_south("q"), u_end["q"]], 1)
    new["p"], new["q"] = p_u, q_v  # cross-derived components are replaced later
    for key in ("r", "n"):
        west, south = from_west(key), from_south(key)
        middle = 0.5 * (west[:, :-1] + south[:, 1:])
        new[key] = np.concatenate([south[:, :1], middle, west[:, -1:]], 1)
        end = "r0" if key == "r" else "n0"
        new[key][:, 0, 0] = v_end[end][:, 0]
        new[key][:, -1, 0] = u_end[end][:, 0]
    return new


def _expand(sign: np.ndarray, ndim: int) -> np.ndarray:
    """Quadrant signs (Q, 1) shaped to broadcast against an array of ndim dimensions."""
    return sign.reshape(sign.shape + (1,) * (ndim - 2))


def _cross_derive(problem, state, ok, d, u_data, v_data) -> np.ndarray:
    """Fill p of along features and q of across features from eps along the diagonal.

    d eps / (index step) = h (sign_u eps_u - sign_v eps_v); with the characteristic
    derivative known, the other one follows. Returns a failure code per point (Q, L)
    where no valid neighbour exists for the difference.
    """
    h, along = problem.step, problem.along
    su, sv = problem.sign_u[..., None], problem.sign_v[..., None]
    slope, has = _diagonal_difference(state["eps"], ok)
    alpha, beta = state["alpha"][..., None], state["beta"][..., None]
    eps_v_along = beta * state["q"]
    eps_u_across = alpha * state["p"]
    p_along = su * (slope / h + sv * eps_v_along) / alpha
    q_across = sv * (su * eps_u_across - slope / h) / beta
    state["p"] = np.where(along, p_along, state["p"])
    state["q"] = np.where(along, state["q"], q_across)
    state["p"][:, -1] = np.where(along, u_data["p"][:, d + 1], state["p"][:, -1])
    state["q"][:, 0] = np.where(along, state["q"][:, 0], v_data["q"][:, d + 1])
    position = np.arange(ok.shape[1])
    need = (along.any() & (position != ok.shape[1] - 1)) | ((~along).any() & (position != 0))
    return np.where(ok & ~has & need, ISOLATED, 0)


def _diagonal_difference(values: np.ndarray, ok: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """d values / d index along axis 1, second order where possible, over valid points only.

    Centred where both neighbours are valid, else one-sided with three points, else two.
    Returns (derivative per index step, whether one could be formed).
    """
    pad = [(0, 0), (2, 2)] + [(0, 0)] * (values.ndim - 2)
    v = np.pad(values, pad, constant_values=np.nan)
    o = np.pad(ok, [(0, 0), (2, 2)], constant_values=False)
    length = values.shape[1]

    def at(shift: int):
        return v[:, 2 + shift : 2 + shift + length], o[:, 2 + shift : 2 + shift + length]

    (m2, om2), (m1, om1), (c0, _), (p1, op1), (p2, op2) = (at(k) for k in (-2, -1, 0, 1, 2))
    extra = (Ellipsis,) + (None,) * (values.ndim - 2)
    centred = (om1 & op1)[extra]
    forward3 = (op1 & op2)[extra]
    backward3 = (om1 & om2)[extra]
    forward2, backward2 = op1[extra], om1[extra]
    with np.errstate(invalid="ignore"):
        derivative = np.where(
            centred,
            (p1 - m1) / 2,
            np.where(
                forward3,
                (-3 * c0 + 4 * p1 - p2) / 2,
                np.where(
                    backward3,
                    (3 * c0 - 4 * m1 + m2) / 2,
                    np.where(forward2, p1 - c0, np.where(backward2, c0 - m1, np.nan)),
                ),
            ),
        )
    has = op1 | om1
    return derivative, has


class _Grid:
    """The solution, diagonal by diagonal, for every quadrant (local indices i, j >= 0)."""

    def __init__(self, problem: _Problem, origin: State):
        self.problem = problem
        self.diagonals: list[tuple[State, np.ndarray, np.ndarray]] = []
        quadrants = origin["alpha"].shape[0]
        self.store(0, origin, np.ones((quadrants, 1), dtype=bool), np.zeros((quadrants, 1), int))

    def store(self, d: int, state: State, valid: np.ndarray, failed: np.ndarray) -> None:
        """Keep diagonal d (must be the next one) with its valid mask and failure codes."""
        assert d == len(self.diagonals)
        self.diagonals.append(({k: v.copy() for k, v in state.items()}, valid, failed))

    def valid_diagonal(self, d: int) -> np.ndarray:
        return self.diagonals[d][1]

    def _points(self, pick: int):
        """(quadrant, i, j) of stored points whose mask (valid: 1, failed: 2) is set."""
        quadrants, rows, cols, diagonals = [], [], [], []
        for d, (_, valid, failed) in enumerate(self.diagonals):
            mask = valid if pick == 1 else failed > 0
            q, k = np.nonzero(mask)
            quadrants.append(q)
            rows.append(k)
            cols.append(d - k)
            diagonals.append(np.full(len(k), d))
        return tuple(np.concatenate(x) for x in (quadrants, rows, cols, diagonals))

    def stops(self) -> tuple[Stop, ...]:
        names = [t.name for t in self.problem.spec.targets]
        quadrants, rows, cols, diagonals = self._points(2)
        stops = []
        for quadrant, i, j, d in zip(quadrants, rows, cols, diagonals, strict=True):
            state, _, failed = self.diagonals[d]
            code = int(failed[quadrant, i])
            u = float(self.problem.sign_u[quadrant, 0] * i * self.problem.step)
            v = float(self.problem.sign_v[quadrant, 0] * j * self.problem.step)
            surface = None
            if code == CHART:
                r = state["r"][quadrant, i]
                outside = [
                    k for k, t in enumerate(self.problem.surfaces) if not t.contains(r[k][None])[0]
                ]
                surface = names[outside[0]] if outside else None
            stops.append(Stop(REASONS[code], u, v, surface))
        return tuple(sorted(stops, key=lambda s: (abs(s.u) + abs(s.v), s.u, s.v)))

    def assemble(self, every: int = 1) -> Design:
        """All quadrants on one grid of step ``every`` x h; shared axes are averaged.

        ``every = 2`` keeps every other grid line (the fine march of the Richardson step
        is only needed on the coarse grid).
        """
        problem = self.problem
        size = problem.diagonals // every
        full = 2 * size + 1
        axis = every * problem.step * np.arange(-size, size + 1)
        quadrants, rows, cols, _ = self._points(1)
        keep = (rows % every == 0) & (cols % every == 0)
        quadrants, rows, cols = quadrants[keep], rows[keep] // every, cols[keep] // every
        g_rows = size + (problem.sign_u[quadrants, 0] * rows).astype(int)
        g_cols = size + (problem.sign_v[quadrants, 0] * cols).astype(int)
        counts = np.zeros((full, full))
        np.add.at(counts, (g_rows, g_cols), 1.0)
        valid = counts > 0
        mean = {}
        for key in self.diagonals[0][0]:
            values = np.concatenate([state[key][valid_d] for state, valid_d, _ in self.diagonals])
            values = values[keep]
            sums = np.zeros((full, full) + values.shape[1:])
            np.add.at(sums, (g_rows, g_cols), values)
            out = np.full_like(sums, np.nan)
            out[valid] = sums[valid] / counts[valid].reshape((-1,) + (1,) * (values.ndim - 1))
            mean[key] = out
        return Design(
            u=axis,
            v=axis.copy(),
            valid=valid,
            alpha=mean["alpha"],
            beta=mean["beta"],
            eps=np.moveaxis(mean["eps"], -1, 0),
            r=np.moveaxis(mean["r"], -2, 0),
            n=np.moveaxis(mean["n"], -2, 0),
            stimuli=problem.stimuli,
            spec=problem.spec.to_json(),
        )
