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

Error control: every point is solved twice, at step h and h/2; their relative difference
(of the designed lengths alpha lambda1 and beta lambda2 on every surface) is the point's
error estimate, kept in the design. A point whose estimate exceeds
``solver.tolerance`` is dropped with its quarter-plane of influence, and reported.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from fabkit.design import kernels
from fabkit.design.design import Design
from fabkit.errors import FabkitError
from fabkit.problem.expr import Expression
from fabkit.problem.material import ALONG
from fabkit.problem.spec import Spec

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
    "error estimate beyond solver.tolerance",
)
NON_FINITE, ALPHA, BETA, LAMBDA, STRAIN, ISOTROPIC, DET_M, CHART, ISOLATED, ERROR = range(1, 11)
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
"""Values on one diagonal of every row: arrays (R, L, ...) by variable name."""

COARSE, FINE = 0, 1
"""The two marches, at step h and h/2, solved together: rows 0..Q-1 and Q..2Q-1."""


@dataclass(frozen=True)
class _Problem:
    """Constants of one solve, derived once from the specs of a batch.

    Row k of every array is one quadrant of one march of one candidate (a spec of the
    batch): candidate ``k // 2Q``, march ``(k // Q) % 2`` (COARSE, FINE), quadrant ``k % Q``.
    Every row advances together, diagonal d of each at once. The candidates share the
    material, the surfaces and the solver settings (``spec`` is the first one's); they
    differ only in their initial data and their targets' start points and directors.
    """

    spec: Spec
    along: np.ndarray  # (N,) bool: feature acts along the director
    stimuli: np.ndarray  # (S, k)
    sign_u: np.ndarray  # (R, 1) quadrant sign of u
    sign_v: np.ndarray  # (R, 1) quadrant sign of v
    step: np.ndarray  # (R, 1) grid step of the row's march (design units)
    march: np.ndarray  # (R,) COARSE or FINE
    candidate: np.ndarray  # (R,) index of the row's spec in the batch
    diagonals: tuple[int, int]  # diagonals of the coarse and the fine march
    axis_pairs: tuple[tuple[np.ndarray, np.ndarray], ...]  # rows sharing u = 0, v = 0

    @property
    def surfaces(self):
        return [t.surface for t in self.spec.targets]


def solve(spec: Spec, progress: Callable[[int, int], None] | None = None) -> Solution:
    """Solve the design problem on the spec's grid; ``progress(done, total)`` per diagonal.

    The problem is solved at step h and at h/2. With ``solver.extrapolate`` (the default)
    the two are combined by Richardson extrapolation, (4 X_{h/2} - X_h) / 3, which removes
    the leading h^2 error of the second-order march; without it the design is the march at
    step h. Either way their difference is every point's error estimate, and points over
    ``solver.tolerance`` are dropped (:func:`_error_control`). The stops reported are the
    fine march's, the more precise of the two, and the error control's.
    """
    (result,) = solve_batch([spec], progress)
    if isinstance(result, FabkitError):
        raise result
    return result


def solve_batch(
    specs: Sequence[Spec],
    progress: Callable[[int, int], None] | None = None,
    crop: bool = False,
) -> list[Solution | FabkitError]:
    """Solve several specs that differ only in their initial data, marching them together.

    The specs must share the material, the surfaces (geometry and stimulus) and the solver
    settings: what a search over initial data varies is the curves, eps and slopes on
    them, and the targets' start points and directors. Each candidate's rows are more rows
    of the same arrays, so the per-diagonal cost of numpy calls is paid once for the batch.
    Every candidate's design is the one :func:`solve` gives it alone (its rows are computed
    by the same elementwise operations). A candidate the solver refuses (initial data not
    finite at the first step, a bad start point) gives its :class:`FabkitError` in place of
    a solution. ``Solution.seconds`` is the wall time of the whole batch. With ``crop``,
    each design's grid spans only its solved points and :data:`CROP_MARGIN` more lines (a
    search needs no more; the design file of a solve spans the full grid of the spec's
    diagonals).
    """
    started = time.perf_counter()
    specs = list(specs)
    _check_batch(specs)
    settings = specs[0].solver
    total = settings.diagonals * 3

    def report(done: int) -> None:
        if progress:
            progress(done, total)

    results: list[Solution | FabkitError | None] = [None] * len(specs)
    with np.errstate(all="ignore"):  # overflow and NaN are stops, checked point by point
        problem, u_data, v_data, origin, rates, kept = _start(specs, results)
        if kept:
            grid = _march(problem, u_data, v_data, origin, rates, report)
        for slot, index in enumerate(kept):
            results[index] = _finish(problem, specs[index], grid, slot, crop)
    seconds = time.perf_counter() - started
    return [
        replace(result, seconds=seconds) if isinstance(result, Solution) else result
        for result in results
    ]


def _check_batch(specs: Sequence[Spec]) -> None:
    """Refuse (ValueError: a caller's mistake) a batch whose specs differ in anything but
    their initial data and their targets' start points and directors."""
    if not specs:
        raise ValueError("solve_batch needs at least one spec")
    shared = {_shared(spec) for spec in specs}
    if len(shared) != 1:
        raise ValueError("the specs of a batch must share material, surfaces and solver")


def _shared(spec: Spec) -> str:
    """What the specs of a batch must have in common, as text."""
    table = spec.normalised
    surfaces = [
        {k: v for k, v in s.items() if k not in ("start", "director")} for s in table["surfaces"]
    ]
    return json.dumps([table["material"], surfaces, table["solver"]], sort_keys=True)


def _start(specs: Sequence[Spec], results: list):
    """The batch's problem and its data at the start, for the candidates the solver does
    not refuse; ``results`` gets the refusals. Returns (problem, u_data, v_data, origin,
    rates at the origin, indices of the kept specs)."""
    kept, data = [], []
    for index, spec in enumerate(specs):
        try:
            data.append(_curve_data(_problem([spec]), spec))
            kept.append(index)
        except FabkitError as exc:
            results[index] = exc
    while True:
        batch = [specs[i] for i in kept]
        problem = _problem(batch or specs[:1])
        u_data = _concatenate([d[0] for d in data])
        v_data = _concatenate([d[1] for d in data])
        if not kept:
            return problem, u_data, v_data, {}, None, kept
        origin = _origin(problem, batch, u_data, v_data)
        rates, failed = _rates(problem, origin)
        first_rows = np.searchsorted(problem.candidate, np.arange(len(kept)))
        refused = set()
        for slot, row in enumerate(first_rows):
            try:
                _refuse_bad_start(failed[row : row + 1])
            except FabkitError as exc:
                results[kept[slot]] = exc
                refused.add(slot)
        if not refused:
            return problem, u_data, v_data, origin, rates, kept
        data = [d for slot, d in enumerate(data) if slot not in refused]
        kept = [index for slot, index in enumerate(kept) if slot not in refused]


def _concatenate(parts: Sequence[State]) -> State:
    """Curve data of several candidates, row after row."""
    if not parts:
        return {}
    return {key: np.concatenate([part[key] for part in parts]) for key in parts[0]}


def _finish(problem: _Problem, spec: Spec, grid: _Grid, slot: int, crop: bool) -> Solution:
    """One candidate's solution from the marched batch: extrapolation, error estimate,
    error control, its design and its stops."""
    settings = spec.solver
    coarse, fine = grid.assemble(COARSE, slot), grid.assemble(FINE, slot)
    common, in_coarse, in_fine = np.intersect1d(coarse.index, fine.index, return_indices=True)
    coarse, fine = coarse.take(in_coarse), fine.take(in_fine)
    points = _extrapolate(spec, coarse, fine) if settings.extrapolate else coarse
    error = error_estimate(spec, coarse, fine)
    keep, dropped = _error_control(problem, common, error)
    design = _design(problem, spec, points.take(keep), error[keep], crop)
    stops = tuple(sorted(grid.stops(slot) + dropped, key=_stop_order))
    return Solution(design, stops, 0.0)


def _stop_order(stop: Stop) -> tuple[float, float, float]:
    return (abs(stop.u) + abs(stop.v), stop.u, stop.v)


DESIGN_KEYS = ("alpha", "beta", "eps", "r", "n")
"""The variables a design keeps (b, s, p and q are only needed while marching)."""


@dataclass(frozen=True)
class _Points:
    """Solved points of one march on the design grid: ``index`` (P,) flat indices into
    the (n, n) grid, ascending, and ``values`` by variable: alpha, beta (P,), eps (P, N),
    r and n (P, S, 2)."""

    index: np.ndarray
    values: State

    def take(self, pick: np.ndarray) -> _Points:
        """The points ``pick`` (indices or a boolean mask over the P points)."""
        return _Points(self.index[pick], {k: v[pick] for k, v in self.values.items()})


def _extrapolate(spec: Spec, coarse: _Points, fine: _Points) -> _Points:
    """Richardson combination of a march at step h and one at h/2, at common points."""
    values = {k: (4 * fine.values[k] - coarse.values[k]) / 3 for k in DESIGN_KEYS}
    r, n = values["r"], values["n"]
    for j, target in enumerate(spec.targets):
        g = target.surface.metric(r[:, j])
        n[:, j] /= np.sqrt(np.einsum("...i,...ij,...j->...", n[:, j], g, n[:, j]))[..., None]
    return _Points(coarse.index, values)


def error_estimate(spec: Spec, coarse: _Points, fine: _Points) -> np.ndarray:
    """Error estimate (P,) of every point solved at step h (coarse) and h/2 (fine).

    The largest, over the surfaces j, of the relative differences of the designed lengths
    alpha lambda1_j and beta lambda2_j (what ``fabkit check`` compares with the solved
    chart map) between the two marches. It is 3/4 of the step-h march's leading error and
    larger than the extrapolated design's. Non-finite differences count as infinite.
    """
    c, f = coarse.values, fine.values
    responses = [spec.material.response(x["eps"].T, spec.stimuli) for x in (c, f)]
    parts = []
    for scale, stretch in (("alpha", "lambda1"), ("beta", "lambda2")):
        lengths = [
            x[scale] * getattr(response, stretch)
            for x, response in zip((c, f), responses, strict=True)
        ]
        parts.append(np.abs(lengths[0] - lengths[1]) / np.abs(lengths[1]))
    with np.errstate(invalid="ignore"):
        return np.max([np.where(np.isfinite(p), p, np.inf) for p in parts], axis=(0, 1))


def _error_control(problem: _Problem, index: np.ndarray, error: np.ndarray):
    """Which points (P,) to keep: those whose error estimate is at most solver.tolerance.

    A point over it is dropped with its quarter-plane of influence (every point further
    from both axes in its quadrant: the points it is a source of). Returns the mask and
    one stop per point over tolerance that no other such point influences. Influence
    runs away from the axes, so the square around the origin that holds the points is
    all the grid it needs.
    """
    size = problem.diagonals[COARSE]
    rows, cols = np.divmod(index, 2 * size + 1)
    half = int(np.max(np.abs(np.concatenate([rows, cols]) - size), initial=0))
    box = (rows - size + half) * (2 * half + 1) + (cols - size + half)
    with np.errstate(invalid="ignore"):
        over = np.zeros((2 * half + 1, 2 * half + 1), dtype=bool)
        over.flat[box] = ~(error <= problem.spec.solver.tolerance)
    dropped, inherited = _influence(over)
    step = problem.spec.solver.step
    stops = tuple(
        Stop(REASONS[ERROR], float((i - half) * step), float((j - half) * step), None)
        for i, j in zip(*np.nonzero(over & ~inherited), strict=True)
    )
    return ~dropped.flat[box], stops


def _influence(sources: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Quarter-planes of influence of ``sources`` on a square grid centred on the origin.

    Returns (every point influenced by a source or being one, every point influenced by a
    source other than itself). Influence runs away from the axes in every quadrant; a
    source on an axis influences the quadrants on both sides of it.
    """
    centre = sources.shape[0] // 2
    reached = np.zeros_like(sources)
    inherited = np.zeros_like(sources)
    for flip_u in (False, True):
        for flip_v in (False, True):
            pick = (
                slice(centre, None) if not flip_u else slice(centre, None, -1),
                slice(centre, None) if not flip_v else slice(centre, None, -1),
            )
            quarter = sources[pick]
            spread = np.logical_or.accumulate(np.logical_or.accumulate(quarter, 0), 1)
            reached[pick] |= spread
            below = np.zeros_like(spread)
            below[1:] |= spread[:-1]
            below[:, 1:] |= spread[:, :-1]
            inherited[pick] |= below
    return reached, inherited


CROP_MARGIN = 3
"""Unsolved grid lines a cropped design keeps around its points: the reach of the check's
widest stencil, so that the check sees the same neighbourhood as on the full grid."""


def _design(
    problem: _Problem, spec: Spec, points: _Points, error: np.ndarray, crop: bool = False
) -> Design:
    """The design file's arrays: the points on the full grid (with ``crop``, on the part of
    it that spans the points), NaN elsewhere."""
    size = problem.diagonals[COARSE]
    full = 2 * size + 1
    rows, cols = np.divmod(points.index, full)
    margin = CROP_MARGIN if crop else full
    low = (max(rows.min() - margin, 0), max(cols.min() - margin, 0))
    high = (min(rows.max() + 1 + margin, full), min(cols.max() + 1 + margin, full))
    shape = (high[0] - low[0], high[1] - low[1])
    flat = (rows - low[0]) * shape[1] + (cols - low[1])
    axis = spec.solver.step * np.arange(-size, size + 1)
    valid = np.zeros(shape[0] * shape[1], dtype=bool)
    valid[flat] = True

    def spread(values: np.ndarray) -> np.ndarray:
        """(P, *rest) at the points -> (*rest[:1], nu, nv, *rest[1:])."""
        out = np.full((valid.size,) + values.shape[1:], np.nan)
        out[flat] = values
        out = out.reshape(shape + values.shape[1:])
        return np.moveaxis(out, 2, 0) if values.ndim > 1 else out

    v = points.values
    return Design(
        u=axis[low[0] : high[0]],
        v=axis[low[1] : high[1]].copy(),
        valid=valid.reshape(shape),
        alpha=spread(v["alpha"]),
        beta=spread(v["beta"]),
        eps=spread(v["eps"]),
        r=spread(v["r"]),
        n=spread(v["n"]),
        error=spread(error),
        stimuli=problem.stimuli,
        spec=spec.to_json(),
    )


def _march(problem: _Problem, u_data: State, v_data: State, origin: State, rates, report):
    """March every row out to its march's diagonals; returns the grid of solved points.

    A candidate's march ends early once a diagonal has no solved interior point in any of
    its quadrants: beyond, only the bare initial curves could go on, no area of design.
    """
    grid = _Grid(problem, origin)
    old, rates_old = origin, rates
    rows = len(problem.march)
    window = _Window(np.zeros(rows, dtype=int), np.ones((rows, 1), dtype=bool))
    groups = 2 * problem.candidate + problem.march  # rows of one march of one candidate
    live = np.ones(rows, dtype=bool)
    for d in range(max(problem.diagonals)):
        old, rates_old, window = _advance(
            problem, grid, old, rates_old, window, d, u_data, v_data, live
        )
        report(min(d + 1, problem.diagonals[COARSE]) + d + 1)
        position = window.position()
        interior = (window.valid & (position > 0) & (position < d + 1)).any(1)
        solved = np.zeros(groups.max() + 1, dtype=bool)
        np.logical_or.at(solved, groups, interior)
        ended = np.array(problem.diagonals)[problem.march] == d + 1
        live &= ~ended & (solved[groups] | (d < 1))
        if not live.any():
            break
    return grid


def _problem(specs: Sequence[Spec]) -> _Problem:
    """The problem of a batch of specs (see :class:`_Problem` for the rows)."""
    spec = specs[0]
    count = len(spec.solver.quadrants)
    quadrants = np.tile(np.array(spec.solver.quadrants, dtype=float), (2 * len(specs), 1))
    step = spec.solver.step
    march = np.tile(np.repeat([COARSE, FINE], count), len(specs))
    candidate = np.repeat(np.arange(len(specs)), 2 * count)
    group = 2 * candidate + march
    return _Problem(
        spec=spec,
        along=np.array([c == ALONG for c in spec.classes]),
        stimuli=spec.stimuli,
        sign_u=quadrants[:, :1],
        sign_v=quadrants[:, 1:],
        step=np.where(march == COARSE, step, step / 2)[:, None],
        march=march,
        candidate=candidate,
        diagonals=(spec.solver.diagonals, 2 * spec.solver.diagonals),
        axis_pairs=(_pairs(quadrants[:, 1], group), _pairs(quadrants[:, 0], group)),
    )


def _pairs(signs: np.ndarray, group: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows (first, second) of one march of one candidate with the same sign: the two
    quadrants that share the half-axis on which the other coordinate has that sign."""
    first, second = np.triu_indices(len(signs), 1)
    same = (signs[first] == signs[second]) & (group[first] == group[second])
    return first[same], second[same]


# --- initial data -------------------------------------------------------------------------


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


def _curve_data(problem: _Problem, spec: Spec) -> tuple[State, State]:
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


def _origin(problem: _Problem, specs: Sequence[Spec], u_data: State, v_data: State) -> State:
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


def _rates(problem: _Problem, state: State, mask: np.ndarray | None = None):
    """Derivatives in u and in v of every variable, and a failure code per point, at the
    points of ``mask`` (Q, L) (default: every point).

    Returns ``((du, dv, at), failed)``: du and dv by variable at the P points of the mask
    (P, ...) in row-major order, ``at`` (Q, L) each point's index among them (-1: off the
    mask), ``failed`` (Q, L) int (0 = fine or off the mask, else an index into REASONS);
    ``du["n_unit"]`` holds the directors renormalised in their metrics. The material's
    response and the targets' geometry are evaluated here (numpy, on every point at once);
    the rest is :func:`fabkit.design.kernels.rates`, point by point.
    """
    shape = state["alpha"].shape
    flat = {
        key: np.ascontiguousarray(value).reshape((-1,) + value.shape[2:])
        for key, value in state.items()
    }
    size = flat["alpha"].shape[0]
    index = np.arange(size) if mask is None else np.flatnonzero(mask)
    at = np.full(size, -1)
    at[index] = np.arange(len(index))
    response = problem.spec.material.response(flat["eps"][index].T, problem.stimuli)
    lam1, lam2 = (np.ascontiguousarray(x.T) for x in (response.lambda1, response.lambda2))
    l1e, l2e, l1ee, l2ee = (
        np.ascontiguousarray(np.moveaxis(x, -1, 0))
        for x in (response.l1_e, response.l2_e, response.l1_ee, response.l2_ee)
    )
    g, gamma, curvature, inside = _geometry(problem, flat["r"][index])
    du, dv, failed = kernels.rates(
        index, flat["alpha"], flat["beta"], flat["b"], flat["s"], flat["eps"], flat["p"],
        flat["q"], flat["r"], flat["n"], lam1, lam2, l1e, l2e, l1ee, l2ee,
        g, gamma, curvature, inside,
        problem.along, problem.spec.solver.max_strain, DET_TOLERANCE, ISOTROPIC_TOLERANCE,
    )  # fmt: skip
    du = dict(zip(("beta", "s", "eps", "p", "r", "n", "n_unit"), du, strict=True))
    dv = dict(zip(("alpha", "b", "eps", "q", "r", "n"), dv, strict=True))
    return (du, dv, at.reshape(shape)), failed.reshape(shape)


def _geometry(problem: _Problem, r: np.ndarray):
    """Metric, Christoffel symbols, K and chart membership of every surface at r (..., S, 2)."""
    parts = [surface.geometry(r[..., j, :]) for j, surface in enumerate(problem.surfaces)]
    inside = np.stack(
        [surface.contains(r[..., j, :]) for j, surface in enumerate(problem.surfaces)], -1
    )
    g = np.stack([part[0] for part in parts], -3)
    gamma = np.stack([part[1] for part in parts], -4)
    curvature = np.stack([part[2] for part in parts], -1)
    return g, gamma, curvature, inside


# --- marching -----------------------------------------------------------------------------

U_SET = ("beta", "s")
V_SET = ("alpha", "b")


@dataclass(frozen=True)
class _Window:
    """The part of a diagonal the march keeps: per row, ``width`` points from global
    index ``offset`` (R,) on (index i along u; j = d - i), holding every solved point."""

    offset: np.ndarray
    valid: np.ndarray  # (R, width) bool

    def position(self) -> np.ndarray:
        """Global index of every point of the window (R, width)."""
        return self.offset[:, None] + np.arange(self.valid.shape[1])


def _advance(problem, grid, old, rates_old, window: _Window, d, u_data, v_data, live):
    """One Heun step from diagonal d to d+1 in every live row; stores the new diagonal and
    returns it trimmed to the window of its solved points, with its rates.

    The new points of a row are those of the old window and one more (its west and south
    sources lie in the old window); the ends of the diagonal, on the initial curves, need
    only one source, and only a window that reaches them holds them.
    """
    sources = window.valid & live[:, None]
    at_start = (window.offset == 0)[:, None]
    at_end = (window.offset + sources.shape[1] == d + 1)[:, None]
    ok_new = np.concatenate(
        [sources[:, :1] & at_start, sources[:, 1:] & sources[:, :-1], sources[:, -1:] & at_end], 1
    )
    predicted = _propagate(problem, old, rates_old, None, d, u_data, v_data)
    fail_predicted = _cross_derive(problem, predicted, ok_new, d, u_data, v_data)
    rates_predicted, failed = _rates(problem, predicted, ok_new & (fail_predicted == 0))
    failed = np.where(fail_predicted, fail_predicted, failed)
    ok_predicted = ok_new & (failed == 0)
    corrected = _propagate(problem, old, rates_old, rates_predicted, d, u_data, v_data)
    fail_corrected = _cross_derive(problem, corrected, ok_predicted, d, u_data, v_data)
    ok_corrected = ok_predicted & (fail_corrected == 0)
    _share_axes(problem, corrected, ok_corrected)
    rates_new, failed_new = _rates(problem, corrected, ok_corrected)
    corrected["n"] = np.full_like(corrected["n"], np.nan)
    corrected["n"][rates_new[2] >= 0] = rates_new[0]["n_unit"]
    failed = np.where(failed, failed, np.where(fail_corrected, fail_corrected, failed_new))
    failed = np.where(ok_new, failed, 0)
    valid = ok_new & (failed == 0)
    grid.store(d + 1, corrected, _Window(window.offset, valid), failed)
    for key, value in corrected.items():
        mask = valid.reshape(valid.shape + (1,) * (value.ndim - 2))
        corrected[key] = np.where(mask, value, np.nan)
    return _trim(corrected, rates_new, _Window(window.offset, valid))


def _trim(state: State, rates, window: _Window):
    """The state, its rates and the window cut to the span of every row's solved points
    (the next diagonal's points all have their sources there)."""
    valid = window.valid
    length = valid.shape[1]
    has = valid.any(1)
    first = np.where(has, valid.argmax(1), 0)
    last = np.where(has, length - 1 - valid[:, ::-1].argmax(1), 0)
    width = max(int((last - first).max(initial=0)) + 1, 1)
    if width == length:
        return state, rates, window
    # every row's window is a stretch of its own diagonal: a row whose span is narrower
    # than the widest starts earlier rather than running past the diagonal's end (the
    # march reads the window's last point as the diagonal's end when the two meet)
    first = np.minimum(first, length - width)
    index = first[:, None] + np.arange(width)
    rows = np.arange(len(first))[:, None]

    def cut(value: np.ndarray) -> np.ndarray:
        return value[rows, index]

    state = {key: cut(value) for key, value in state.items()}
    du, dv, at = rates
    return state, (du, dv, cut(at)), _Window(window.offset + first, cut(valid))


def _share_axes(problem: _Problem, state: State, ok: np.ndarray) -> None:
    """Give quadrants that share an axis point one value there: the mean of their values.

    Each quadrant's one-sided cross derivatives differ at O(h^2) on the axes; without this,
    the assembled design would have a small kink along u = 0 and v = 0.
    """
    for position, (first, second) in zip((0, -1), problem.axis_pairs, strict=True):
        both = ok[first, position] & ok[second, position]
        if not both.any():
            continue
        first, second = first[both], second[both]
        for value in state.values():
            mean = (value[first, position] + value[second, position]) / 2
            value[first, position] = value[second, position] = mean


def _propagate(problem, old, rates_old, rates_new, d, u_data, v_data) -> State:
    """Values on diagonal d+1 from diagonal d: Euler (rates_new None) or trapezoidal.

    u-propagated variables (:data:`U_SET`, p) come from their west source, v-propagated
    ones (:data:`V_SET`, q) from their south source, eps feature by feature as it acts,
    r and n from both (the mean). p and q are taken as propagated here; their
    cross-derived components are replaced later (:func:`_cross_derive`).
    """
    rows, length = old["alpha"].shape
    steps = ((problem.step * problem.sign_u)[:, 0], (problem.step * problem.sign_v)[:, 0])
    heun = rates_new is not None
    du_old, dv_old, at_old = rates_old
    du_new, dv_new, at_new = rates_new if heun else rates_old
    ends = tuple({k: val[:, d + 1] for k, val in data.items()} for data in (u_data, v_data))
    new: State = {}
    for key, value in old.items():
        shape = value.shape[2:]
        if key in U_SET + ("p",):
            modes, u_end, v_end = np.full(shape, kernels.WEST), ends[1][key], ends[1][key]
        elif key in V_SET + ("q",):
            modes, u_end, v_end = np.full(shape, kernels.SOUTH), ends[0][key], ends[0][key]
        elif key == "eps":
            modes = np.where(problem.along, kernels.SOUTH, kernels.WEST)
            u_end, v_end = ends[0][key], ends[1][key]
        else:  # r, n
            modes = np.full(shape, kernels.MEAN)
            modes[0] = kernels.MEAN_ENDS
            u_end, v_end = _curve_ends(ends[0][key + "0"], ends[1][key + "0"], shape)
        # a variable without a rate in one direction passes the other (never read)
        size = int(np.prod(shape, dtype=int))
        sources = []
        for du, dv in ((du_old, dv_old), (du_new, dv_new)):
            for x in (du.get(key, dv.get(key)), dv.get(key, du.get(key))):
                sources.append(x.reshape(len(x), size))
        new[key] = kernels.propagate(
            np.ascontiguousarray(value).reshape(rows, length, size),
            *sources[:2],
            at_old,
            *sources[2:],
            at_new,
            heun,
            *steps,
            np.ascontiguousarray(u_end).reshape(rows, size),
            np.ascontiguousarray(v_end).reshape(rows, size),
            modes.ravel(),
        ).reshape((rows, length + 1) + shape)
    return new


def _curve_ends(u_end: np.ndarray, v_end: np.ndarray, shape: tuple[int, ...]):
    """The curves' chart point or tangent (R, 2) at the ends of a diagonal as the first
    surface's entries of arrays (R, S, 2) (the flat sheet is the one the curves lie on)."""
    arrays = []
    for end in (u_end, v_end):
        full = np.full((end.shape[0],) + shape, np.nan)
        full[:, 0] = end
        arrays.append(full)
    return arrays


def _cross_derive(problem, state, ok, d, u_data, v_data) -> np.ndarray:
    """Fill p of along features and q of across features from eps along the diagonal
    (:func:`fabkit.design.kernels.cross_derive`). Returns a failure code per point (Q, L)
    where no valid neighbour exists for the difference."""
    contiguous = {k: np.ascontiguousarray(state[k]) for k in ("eps", "alpha", "beta", "p", "q")}
    state["p"], state["q"], failed = kernels.cross_derive(
        *contiguous.values(),
        np.ascontiguousarray(ok),
        problem.along,
        problem.step[:, 0],
        problem.sign_u[:, 0],
        problem.sign_v[:, 0],
        np.ascontiguousarray(u_data["p"][:, d + 1]),
        np.ascontiguousarray(v_data["q"][:, d + 1]),
        ISOLATED,
    )
    return failed


class _Grid:
    """The solution, diagonal by diagonal, for every row (local indices i, j >= 0).

    A diagonal keeps its valid mask and failure codes (R, L), the design's variables at its
    valid points and the chart points r at its failed ones (those name the surface a
    point left); :meth:`points` gathers one candidate's.
    """

    def __init__(self, problem: _Problem, origin: State):
        self.problem = problem
        self.points: list[tuple[np.ndarray, np.ndarray]] = []  # valid, failed (row, i)
        self.codes: list[np.ndarray] = []
        self.values: list[State] = []
        self.failed_r: list[np.ndarray] = []
        rows = origin["alpha"].shape[0]
        window = _Window(np.zeros(rows, dtype=int), np.ones((rows, 1), dtype=bool))
        self.store(0, origin, window, np.zeros((rows, 1), int))
        self._gathered: tuple | None = None

    def store(self, d: int, state: State, window: _Window, failed: np.ndarray) -> None:
        """Keep diagonal d (must be the next one): its valid points and their values, its
        failed points, their codes and chart points."""
        assert d == len(self.points)
        valid = window.valid
        found = []
        for mask in (valid, failed > 0):
            row, k = np.nonzero(mask)
            found.append((row, window.offset[row] + k))
        self.points.append(tuple(found))
        self.codes.append(failed[failed > 0])
        self.values.append({key: state[key][valid] for key in DESIGN_KEYS})
        self.failed_r.append(state["r"][failed > 0])

    def _gather(self):
        """Every stored point of the batch, sorted by candidate: (slices per candidate,
        valid points (row, i, j), their values), (failed points (row, i, j, code), r)."""
        if self._gathered is None:
            valid_parts, failed_parts = [], []
            for d, (valid, failed) in enumerate(self.points):
                valid_parts.append((valid[0], valid[1], d - valid[1]))
                failed_parts.append((failed[0], failed[1], d - failed[1], self.codes[d]))
            valid = [np.concatenate(x) for x in zip(*valid_parts, strict=True)]
            failed = [np.concatenate(x) for x in zip(*failed_parts, strict=True)]
            values = {}
            for key in DESIGN_KEYS:
                values[key] = np.concatenate([v.pop(key) for v in self.values])
            failed_r = np.concatenate(self.failed_r)
            self.values, self.failed_r = [], []
            candidate = self.problem.candidate
            count = int(candidate.max()) + 1
            gathered = []
            for arrays, extra in ((valid, values), (failed, {"r": failed_r})):
                if count > 1:
                    order = np.argsort(candidate[arrays[0]], kind="stable")
                    arrays = [x[order] for x in arrays]
                    extra = {k: v[order] for k, v in extra.items()}
                edges = np.searchsorted(candidate[arrays[0]], np.arange(count + 1))
                gathered.append((edges, arrays, extra))
            self._gathered = tuple(gathered)
        return self._gathered

    def _candidate(self, which: int, slot: int):
        """(row, i, j, ...) and the kept values of one candidate's valid (which = 0) or
        failed (1) points."""
        edges, arrays, extra = self._gather()[which]
        pick = slice(edges[slot], edges[slot + 1])
        return [x[pick] for x in arrays], {k: v[pick] for k, v in extra.items()}

    def stops(self, slot: int) -> tuple[Stop, ...]:
        """Every failed point of the candidate's fine march, nearest the origin first."""
        problem = self.problem
        names = [t.name for t in problem.spec.targets]
        (rows, i, j, codes), extra = self._candidate(1, slot)
        stops = []
        for row, ii, jj, code, r in zip(rows, i, j, codes, extra["r"], strict=True):
            if problem.march[row] != FINE:
                continue
            u = float(problem.sign_u[row, 0] * ii * problem.step[row, 0])
            v = float(problem.sign_v[row, 0] * jj * problem.step[row, 0])
            surface = None
            if code == CHART:
                outside = [
                    k for k, t in enumerate(problem.surfaces) if not t.contains(r[k][None])[0]
                ]
                surface = names[outside[0]] if outside else None
            stops.append(Stop(REASONS[code], u, v, surface))
        return tuple(sorted(stops, key=_stop_order))

    def assemble(self, march: int, slot: int) -> _Points:
        """The candidate's march on the design grid of step h (the fine march keeps every
        other grid line: it is only needed there); quadrants sharing an axis point give it
        the mean of their values."""
        problem = self.problem
        every = 1 if march == COARSE else 2
        size = problem.diagonals[COARSE]
        (rows, i, j), values = self._candidate(0, slot)
        keep = (problem.march[rows] == march) & (i % every == 0) & (j % every == 0)
        rows, i, j = rows[keep], i[keep] // every, j[keep] // every
        g_rows = size + (problem.sign_u[rows, 0] * i).astype(int)
        g_cols = size + (problem.sign_v[rows, 0] * j).astype(int)
        index, where = np.unique(g_rows * (2 * size + 1) + g_cols, return_inverse=True)
        counts = np.zeros(len(index))
        np.add.at(counts, where, 1.0)
        mean = {}
        for key in DESIGN_KEYS:
            kept = values[key][keep]
            sums = np.zeros((len(index),) + kept.shape[1:])
            np.add.at(sums, where, kept)
            mean[key] = sums / counts.reshape((-1,) + (1,) * (kept.ndim - 1))
        return _Points(index, mean)
