"""The solver's march: the propagation equations and Heun's step from one diagonal to the
next, for every row of the batch at once (:mod:`fabkit.design.batch`).

:func:`point_rates` gives the derivatives in u and v of every variable at the points of a
diagonal (the material's response and the targets' geometry in numpy, the rest in the
compiled :mod:`fabkit.design.kernels`); :func:`march_rows` advances every row from the
origin (:mod:`fabkit.design.initial`) to its march's last diagonal, predictor then
corrector, cross-deriving p and q along the diagonal, and keeps every diagonal in a
:class:`Grid`, from which :mod:`fabkit.design.solver` assembles each candidate's points and
stops.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fabkit.design import kernels
from fabkit.design.batch import (
    CHART,
    COARSE,
    DESIGN_KEYS,
    DET_TOLERANCE,
    FINE,
    ISOLATED,
    ISOTROPIC_TOLERANCE,
    REASONS,
    Points,
    Problem,
    State,
    Stop,
    stop_order,
)

# --- the propagation equations ------------------------------------------------------------


def point_rates(problem: Problem, state: State, mask: np.ndarray | None = None):
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


def _geometry(problem: Problem, r: np.ndarray):
    """Metric, Christoffel symbols, K and chart membership of every surface at r (..., S, 2)."""
    parts = [surface.geometry(r[..., j, :]) for j, surface in enumerate(problem.surfaces)]
    inside = np.stack(
        [surface.contains(r[..., j, :]) for j, surface in enumerate(problem.surfaces)], -1
    )
    g = np.stack([part[0] for part in parts], -3)
    gamma = np.stack([part[1] for part in parts], -4)
    curvature = np.stack([part[2] for part in parts], -1)
    return g, gamma, curvature, inside


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
    rates_predicted, failed = point_rates(problem, predicted, ok_new & (fail_predicted == 0))
    failed = np.where(fail_predicted, fail_predicted, failed)
    ok_predicted = ok_new & (failed == 0)
    corrected = _propagate(problem, old, rates_old, rates_predicted, d, u_data, v_data)
    fail_corrected = _cross_derive(problem, corrected, ok_predicted, d, u_data, v_data)
    ok_corrected = ok_predicted & (fail_corrected == 0)
    _share_axes(problem, corrected, ok_corrected)
    rates_new, failed_new = point_rates(problem, corrected, ok_corrected)
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


def _share_axes(problem: Problem, state: State, ok: np.ndarray) -> None:
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


class Grid:
    """The solution, diagonal by diagonal, for every row (local indices i, j >= 0).

    A diagonal keeps its valid mask and failure codes (R, L), the design's variables at its
    valid points and the chart points r at its failed ones (those name the surface a
    point left); :meth:`points` gathers one candidate's.
    """

    def __init__(self, problem: Problem, origin: State):
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
        return tuple(sorted(stops, key=stop_order))

    def assemble(self, march: int, slot: int) -> Points:
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
        return Points(index, mean)


def march_rows(problem: Problem, u_data: State, v_data: State, origin: State, rates, report):
    """March every row out to its march's diagonals; returns the grid of solved points.

    A candidate's march ends early once a diagonal has no solved interior point in any of
    its quadrants: beyond, only the bare initial curves could go on, no area of design.
    """
    grid = Grid(problem, origin)
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
