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

The stages, one module each: :mod:`fabkit.design.batch` (the rows of a batch, the stop
reasons, the solved points), :mod:`fabkit.design.initial` (the data on the initial curves
and at the origin), :mod:`fabkit.design.march` (the propagation equations and the march);
this module solves (:func:`solve`, :func:`solve_batch`), extrapolates, estimates and
controls the error and makes the design.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from fabkit.design.batch import (
    COARSE,
    DESIGN_KEYS,
    ERROR,
    FINE,
    REASONS,
    Points,
    Problem,
    State,
    Stop,
    batch_problem,
    stop_order,
)
from fabkit.design.design import Design
from fabkit.design.initial import curve_data, origin_state, refuse_bad_start
from fabkit.design.march import Grid, march_rows, point_rates
from fabkit.errors import FabkitError
from fabkit.problem.spec import Spec


@dataclass(frozen=True)
class Solution:
    """A solved design, its stops, and the wall time of the solve in seconds."""

    design: Design
    stops: tuple[Stop, ...]
    seconds: float


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
            grid = march_rows(problem, u_data, v_data, origin, rates, report)
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
            data.append(curve_data(batch_problem([spec]), spec))
            kept.append(index)
        except FabkitError as exc:
            results[index] = exc
    while True:
        batch = [specs[i] for i in kept]
        problem = batch_problem(batch or specs[:1])
        u_data = _concatenate([d[0] for d in data])
        v_data = _concatenate([d[1] for d in data])
        if not kept:
            return problem, u_data, v_data, {}, None, kept
        origin = origin_state(problem, batch, u_data, v_data)
        rates, failed = point_rates(problem, origin)
        first_rows = np.searchsorted(problem.candidate, np.arange(len(kept)))
        refused = set()
        for slot, row in enumerate(first_rows):
            try:
                refuse_bad_start(failed[row : row + 1])
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


def _finish(problem: Problem, spec: Spec, grid: Grid, slot: int, crop: bool) -> Solution:
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
    stops = tuple(sorted(grid.stops(slot) + dropped, key=stop_order))
    return Solution(design, stops, 0.0)


def _extrapolate(spec: Spec, coarse: Points, fine: Points) -> Points:
    """Richardson combination of a march at step h and one at h/2, at common points."""
    values = {k: (4 * fine.values[k] - coarse.values[k]) / 3 for k in DESIGN_KEYS}
    r, n = values["r"], values["n"]
    for j, target in enumerate(spec.targets):
        g = target.surface.metric(r[:, j])
        n[:, j] /= np.sqrt(np.einsum("...i,...ij,...j->...", n[:, j], g, n[:, j]))[..., None]
    return Points(coarse.index, values)


def error_estimate(spec: Spec, coarse: Points, fine: Points) -> np.ndarray:
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


def _error_control(problem: Problem, index: np.ndarray, error: np.ndarray):
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
    problem: Problem, spec: Spec, points: Points, error: np.ndarray, crop: bool = False
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
