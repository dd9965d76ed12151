"""Least-squares fit of log(lambda) as a tensor-product cubic B-spline, monotone per axis.

For one stretch, with samples at points X (n, d) (features first, then stimuli) and
values y = log(lambda) (n,), weights w (n,) (1 / spread of log lambda, or 1):

1. the *free* fit: penalised least squares (a light second-difference penalty along
   every axis) with log lambda = 0 at the flat stimulus for every feature value;
2. an axis has an *effect* when dropping it (the spline constant along it) worsens the
   fit by an F-test at level :data:`LEVEL`; an axis without one is constant;
3. an axis with an effect is *monotone* in the direction its free fit goes unless
   constraining it so worsens the fit beyond chance (a chi-square test at :data:`LEVEL`
   on the constraints that bind, with the free fit's residual variance);
4. the final fit imposes every monotone direction: its coefficients' first differences
   along the axis have one sign, which makes the spline monotone along it.

The constrained problem, min ||A c - y|| with G c >= 0, is solved exactly as a least
distance problem by non-negative least squares (Lawson and Hanson, *Solving Least
Squares Problems*, ch. 23).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import reduce

import numpy as np
from scipy import linalg, optimize, stats
from scipy.interpolate import BSpline

from fabkit.problem.material_table import DEGREE

LEVEL = 1e-3
"""Significance level of the effect and monotonicity tests."""
MAX_COEFFICIENTS = 7
"""Coefficients per axis at most (fewer for axes with few distinct values)."""
SMOOTHING = 1e-4
"""Weight of the second-difference penalty relative to the data (scale free)."""
RIDGE = 1e-10
"""Relative ridge that keeps the penalised system full rank."""


@dataclass(frozen=True)
class Basis:
    """The spline space over the samples: ``knots`` per axis, the design matrix ``A`` (n,
    p) at the sample points, ``flat`` (q, p) the rows whose zero makes log lambda = 0 at
    the flat stimulus for every feature value (q = 0 rows without stimuli)."""

    knots: tuple[np.ndarray, ...]
    A: np.ndarray
    flat: np.ndarray

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(len(t) - DEGREE - 1 for t in self.knots)


@dataclass(frozen=True)
class StretchFit:
    """The fit of one stretch: coefficients (``Basis.shape``), per axis its ``direction``
    (+1 increasing, -1 decreasing, 0 no effect, None an effect in both directions),
    ``fitted`` log lambda at the samples (n,)."""

    coefficients: np.ndarray
    directions: tuple[int | None, ...]
    fitted: np.ndarray


def knots_for(values: np.ndarray, count: int) -> np.ndarray:
    """A clamped cubic knot vector over [min, max] of ``values`` (n,) with ``count``
    coefficients, its interior knots at quantiles of the distinct values."""
    low, high = values.min(), values.max()
    interior = np.quantile(np.unique(values), np.linspace(0, 1, count - DEGREE + 1)[1:-1])
    spacing = (high - low) / (count - DEGREE)
    if np.any(np.diff(np.r_[low, interior, high]) < 0.25 * spacing):  # clustered data
        interior = np.linspace(low, high, count - DEGREE + 1)[1:-1]
    return np.r_[[low] * (DEGREE + 1), interior, [high] * (DEGREE + 1)]


def coefficient_counts(
    points: np.ndarray, logs: np.ndarray, weights: np.ndarray, flat: np.ndarray, budget: int
) -> list[int]:
    """Coefficients per axis of ``points`` (n, d): from 4 each, the axis whose one more
    coefficient lowers the generalised cross-validation score of the free fits of both
    stretches (``logs``, ``weights`` (2, n)) the most, while one does and their product
    stays within ``budget``; at most :data:`MAX_COEFFICIENTS` per axis, and at most the
    axis's distinct values."""
    limits = [min(MAX_COEFFICIENTS, max(DEGREE + 1, len(np.unique(c)))) for c in points.T]
    counts = [DEGREE + 1] * points.shape[1]

    def score(candidate: list[int]) -> float:
        space = basis(points, candidate, flat)
        T = _parametrisation(space, (False,) * len(candidate))
        dof = len(points) - T.shape[1]
        if dof <= 0:
            return np.inf
        rss = sum(
            _rss(space, y, w, _solve(space, y, w, T, ()))
            for y, w in zip(logs, weights, strict=True)
        )
        return len(points) * rss / dof**2

    best = score(counts)
    while True:
        trials = []
        for axis, limit in enumerate(limits):
            candidate = counts.copy()
            candidate[axis] += 1
            if candidate[axis] <= limit and np.prod(candidate) <= budget:
                trials.append((score(candidate), candidate))
        if not trials or min(trials)[0] >= best:
            return counts
        best, counts = min(trials)


def basis(points: np.ndarray, counts: list[int], flat: np.ndarray) -> Basis:
    """The :class:`Basis` at ``points`` (n, d), ``counts`` coefficients per axis; the
    last ``len(flat)`` axes are stimuli, ``flat`` (k,) the flat sheet's stimulus."""
    knots = tuple(knots_for(column, count) for column, count in zip(points.T, counts, strict=True))
    columns = [
        BSpline.design_matrix(column, t, DEGREE).toarray()
        for column, t in zip(points.T, knots, strict=True)
    ]
    A = reduce(lambda a, b: np.einsum("ni,nj->nij", a, b).reshape(len(points), -1), columns)
    features = len(knots) - len(flat)
    factors = [np.eye(count) for count in counts[:features]]
    for t, value in zip(knots[features:], flat, strict=True):
        factors.append(BSpline.design_matrix(np.array([value]), t, DEGREE).toarray())
    rows = reduce(np.kron, factors) if flat.size else np.zeros((0, A.shape[1]))
    return Basis(knots, A, rows)


def _along(shape: tuple[int, ...], axis: int, matrix: np.ndarray) -> np.ndarray:
    """``matrix`` (r, shape[axis]) applied along ``axis`` of the flattened coefficients."""
    factors = [np.eye(n) for n in shape]
    factors[axis] = matrix
    return reduce(np.kron, factors)


def _differences(count: int, order: int) -> np.ndarray:
    return np.diff(np.eye(count), n=order, axis=0)


def _parametrisation(space: Basis, constant: tuple[bool, ...]) -> np.ndarray:
    """T (p, q): the coefficients c = T z of splines constant along the ``constant`` axes
    and zero at the flat stimulus."""
    factors = [
        np.ones((n, 1)) if fixed else np.eye(n)
        for n, fixed in zip(space.shape, constant, strict=True)
    ]
    T = reduce(np.kron, factors)
    if space.flat.size:
        T = T @ linalg.null_space(space.flat @ T, rcond=1e-10)
    return T


def fit_stretch(space: Basis, y: np.ndarray, weights: np.ndarray) -> StretchFit:
    """Steps 1 to 4 of the module docstring for one stretch: values ``y`` (n,) = log
    lambda at the samples, ``weights`` (n,)."""
    dims = len(space.shape)
    free_T = _parametrisation(space, (False,) * dims)
    free = _solve(space, y, weights, free_T, ())
    rss_free, q_free = _rss(space, y, weights, free), free_T.shape[1]
    dof = len(y) - q_free
    effect = []
    for axis in range(dims):
        T = _parametrisation(space, tuple(a == axis for a in range(dims)))
        rss = _rss(space, y, weights, _solve(space, y, weights, T, ()))
        extra = q_free - T.shape[1]
        f = ((rss - rss_free) / max(extra, 1)) / max(rss_free / dof, 1e-300)
        effect.append(extra > 0 and stats.f.sf(f, extra, dof) < LEVEL)
    T = _parametrisation(space, tuple(not e for e in effect))
    model = _solve(space, y, weights, T, ())
    rss_model = _rss(space, y, weights, model)
    variance = max(rss_model / (len(y) - T.shape[1]), 1e-300)
    directions: list[int | None] = []
    for axis in range(dims):
        if not effect[axis]:
            directions.append(0)
            continue
        G = _along(space.shape, axis, _differences(space.shape[axis], 1))
        G = G[np.abs(G @ T).sum(axis=1) > 1e-12]  # not the differences the model fixes
        sign = 1 if np.sum(G @ model) >= 0 else -1
        constrained = _solve(space, y, weights, T, ((axis, sign),))
        tolerance = 1e-9 * (1 + np.abs(constrained).max())
        binding = int(np.sum(np.abs(G @ constrained) < tolerance))
        excess = (_rss(space, y, weights, constrained) - rss_model) / variance
        monotone = excess <= stats.chi2.isf(LEVEL, max(binding, 1))
        directions.append(sign if monotone else None)
    monotone_axes = tuple((a, d) for a, d in enumerate(directions) if d)
    final = _solve(space, y, weights, T, monotone_axes)
    return StretchFit(final.reshape(space.shape), tuple(directions), space.A @ final)


def _rss(space: Basis, y: np.ndarray, weights: np.ndarray, c: np.ndarray) -> float:
    return float(np.sum((weights * (space.A @ c - y)) ** 2))


def _solve(
    space: Basis,
    y: np.ndarray,
    weights: np.ndarray,
    T: np.ndarray,
    monotone: tuple[tuple[int, int], ...],
) -> np.ndarray:
    """Coefficients c = T z (p,) minimising the weighted, penalised residual, with c's
    first differences along each ``(axis, sign)`` of ``monotone`` of that sign."""
    A = (weights[:, None] * space.A) @ T
    shape = space.shape
    penalty = np.vstack(
        [_along(shape, a, _differences(n, 2)) for a, n in enumerate(shape) if n > 2]
    )
    penalty = penalty @ T
    scale = np.trace(A.T @ A) / max(np.trace(penalty.T @ penalty), 1e-300)
    system = np.vstack(
        [A, np.sqrt(SMOOTHING * scale) * penalty, np.sqrt(RIDGE * scale) * np.eye(T.shape[1])]
    )
    target = np.r_[weights * y, np.zeros(len(system) - len(y))]
    R, f = _triangular(system, target)
    if not monotone:
        return T @ linalg.solve_triangular(R, f)
    G = np.vstack([sign * _along(shape, a, _differences(shape[a], 1)) for a, sign in monotone])
    G = G @ T
    G = G[np.abs(G).sum(axis=1) > 1e-12]
    return T @ _least_squares_above(R, f, G)


def _triangular(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R (q, q) upper triangular and f (q,) with ||A x - b||^2 = ||R x - f||^2 + const, for
    A (m, q) of full column rank: R from the Cholesky factor of A^T A (the R of A's QR
    decomposition, faster for m >> q), f = R^-T A^T b."""
    R = linalg.cholesky(A.T @ A)
    return R, linalg.solve_triangular(R, A.T @ b, trans="T")


def _least_squares_above(R: np.ndarray, f: np.ndarray, G: np.ndarray) -> np.ndarray:
    """argmin ||R x - f|| subject to G x >= 0, R (q, q) upper triangular, invertible.

    With z = R x - f this is the least distance problem min ||z|| with E z >= h,
    E = G R^-1, h = -E f, solved by non-negative least squares on
    [E^T; h^T] u ~ (0, ..., 0, 1) (Lawson and Hanson, ch. 23)."""
    E = linalg.solve_triangular(R, G.T, trans="T").T  # G R^-1
    h = -E @ f
    if np.all(h <= 0):  # the unconstrained minimum is feasible
        return linalg.solve_triangular(R, f)
    M = np.vstack([E.T, h[None, :]])
    d = np.zeros(len(M))
    d[-1] = 1.0
    u, _ = optimize.nnls(M, d, maxiter=50 * M.shape[1])
    r = M @ u - d
    z = -r[:-1] / r[-1]
    return linalg.solve_triangular(R, z + f)
