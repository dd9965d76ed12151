"""Compiled (numba) kernels of the solver's march: the per-point arithmetic of one diagonal.

The march spends its time in the arithmetic of every point of a diagonal: the rates of
the propagation equations, the curvature system M w = K - Kbar, the failure checks.
Written as numpy calls on small arrays, each diagonal pays hundreds of calls and their
temporaries; here one compiled loop over the points does it (``cache=True``: compiled
once per machine, then loaded from ``__pycache__``).

The operations are those of the numpy formulation, in the same order (numba does not
reorder or fuse floating-point operations without ``fastmath``), except the S x S solve
and determinant: an LU factorisation with partial pivoting here, LAPACK's in numpy; they
agree to rounding (about 1e-16 relative per step).

Point-first layouts: a point's values are ``x[k]``, ``x[k, j]`` (surface j) or
``x[k, j, i]`` (feature i).
"""

from __future__ import annotations

import numba
import numpy as np

NON_FINITE, ALPHA, BETA, LAMBDA, STRAIN, ISOTROPIC, DET_M, CHART = range(1, 9)
"""Failure codes, as the solver's REASONS number them."""


@numba.njit(cache=True, error_model="numpy", inline="always")
def _lu_solve(a: np.ndarray, x: np.ndarray, out: np.ndarray) -> float:
    """Solve a out = x (S x S, S) by LU with partial pivoting, overwriting ``a`` and ``x``;
    returns det(a)."""
    size = x.shape[0]
    det = 1.0
    for col in range(size):
        pivot = col
        for row in range(col + 1, size):
            if abs(a[row, col]) > abs(a[pivot, col]):
                pivot = row
        if pivot != col:
            det = -det
            for k in range(size):
                a[col, k], a[pivot, k] = a[pivot, k], a[col, k]
            x[col], x[pivot] = x[pivot], x[col]
        det *= a[col, col]
        if a[col, col] == 0.0:
            continue
        for row in range(col + 1, size):
            factor = a[row, col] / a[col, col]
            for k in range(col + 1, size):
                a[row, k] -= factor * a[col, k]
            x[row] -= factor * x[col]
    for row in range(size - 1, -1, -1):
        total = x[row]
        for k in range(row + 1, size):
            total -= a[row, k] * out[k]
        out[row] = total / a[row, row]
    return det


@numba.njit(cache=True, error_model="numpy")
def rates(
    index, alpha, beta, b, s, eps, p, q, r, n,
    lam1, lam2, l1e, l2e, l1ee, l2ee,
    g, gamma, curvature, inside,
    along, max_strain, det_tolerance, isotropic_tolerance,
):  # fmt: skip
    """Rates in u and v of every variable, the unit directors and failure codes at the P
    points ``index`` (P,) of M points.

    In: the state at the M points: alpha, beta, b, s (M,), eps, p, q (M, N), r, n (M, S, 2);
    at the P points: lam1, lam2 (P, S), l1e, l2e (P, S, N) and l1ee, l2ee (P, S, N, N), the
    log-derivatives of the stretches in eps; g (P, S, 2, 2), gamma (P, S, 2, 2, 2),
    curvature (P, S), inside (P, S) bool, the targets' metric, Christoffel symbols, Gaussian
    curvature and chart membership at r; along (N,) bool. Out, at the P points: du (beta, s,
    eps, p, r, n), n_unit, dv (alpha, b, eps, q, r, n); and failed (M,) int at the M points
    (0 = fine or not computed, else the first failing check's code).
    """
    count, surfaces = index.shape[0], lam1.shape[1]
    total, features = eps.shape
    du_beta, du_s = np.empty(count), np.empty(count)
    dv_alpha, dv_b = np.empty(count), np.empty(count)
    du_eps, du_p = np.empty((count, features)), np.empty((count, features))
    dv_eps, dv_q = np.empty((count, features)), np.empty((count, features))
    du_r, du_n = np.empty((count, surfaces, 2)), np.empty((count, surfaces, 2))
    dv_r, dv_n = np.empty((count, surfaces, 2)), np.empty((count, surfaces, 2))
    n_unit = np.empty((count, surfaces, 2))
    failed = np.zeros(total, dtype=np.int64)
    matrix = np.empty((surfaces, surfaces))
    rhs = np.empty(surfaces)
    w = np.empty(surfaces)
    ku, kv = np.empty(surfaces), np.empty(surfaces)
    l1p, l2p = np.empty(surfaces), np.empty(surfaces)
    for k in range(count):
        m = index[k]
        for j in range(surfaces):
            l1q, l2q = l1e[k, j, 0] * q[m, 0], l2e[k, j, 0] * q[m, 0]
            l1p[j], l2p[j] = l1e[k, j, 0] * p[m, 0], l2e[k, j, 0] * p[m, 0]
            for i in range(1, features):
                l1q = l1q + l1e[k, j, i] * q[m, i]
                l2q = l2q + l2e[k, j, i] * q[m, i]
                l1p[j] = l1p[j] + l1e[k, j, i] * p[m, i]
                l2p[j] = l2p[j] + l2e[k, j, i] * p[m, i]
            ku[j] = (b[m] - l1q) / lam2[k, j]
            kv[j] = (s[m] + l2p[j]) / lam1[k, j]
            quad1 = l1ee[k, j, 0, 0] * (q[m, 0] * q[m, 0])
            quad2 = l2ee[k, j, 0, 0] * (p[m, 0] * p[m, 0])
            for a in range(features):
                for c in range(features):
                    if a == 0 and c == 0:
                        continue
                    quad1 = quad1 + l1ee[k, j, a, c] * (q[m, a] * q[m, c])
                    quad2 = quad2 + l2ee[k, j, a, c] * (p[m, a] * p[m, c])
            lam1_2, lam2_2 = lam1[k, j] ** 2, lam2[k, j] ** 2
            k_bar = (
                -(ku[j] ** 2)
                - kv[j] ** 2
                - (quad1 + (b[m] - l1q) * l2q) / lam2_2
                - (quad2 - (s[m] + l2p[j]) * l1p[j]) / lam1_2
            )
            rhs[j] = curvature[k, j] - k_bar
            matrix[j, 0] = 1 / lam2_2
            matrix[j, 1] = -1 / lam1_2
            for i in range(features):
                if along[i]:
                    matrix[j, 2 + i] = -l1e[k, j, i] / lam2_2
                else:
                    matrix[j, 2 + i] = -l2e[k, j, i] / lam1_2
        # det M near zero relative to the product of its row norms: singular
        scale = 1.0
        for j in range(surfaces):
            squares = 0.0
            for c in range(surfaces):
                squares += matrix[j, c] * matrix[j, c]
            scale *= np.sqrt(squares)
        singular = False
        for j in range(surfaces):
            for c in range(surfaces):
                singular = singular or not np.isfinite(matrix[j, c])
        if singular:
            for j in range(surfaces):
                w[j] = rhs[j]
        else:
            det = _lu_solve(matrix, rhs, w)
            if not abs(det) > det_tolerance * scale:
                singular = True
                for j in range(surfaces):
                    w[j] = rhs[j]
        # rates
        du_beta[k] = alpha[m] * beta[m] * s[m]
        du_s[k] = alpha[m] * w[1]
        dv_alpha[k] = -alpha[m] * beta[m] * b[m]
        dv_b[k] = beta[m] * w[0]
        for i in range(features):
            du_eps[k, i] = alpha[m] * p[m, i]
            du_p[k, i] = alpha[m] * w[2 + i]
            dv_eps[k, i] = beta[m] * q[m, i]
            dv_q[k, i] = beta[m] * w[2 + i]
        for j in range(surfaces):
            g00, g01 = g[k, j, 0, 0], g[k, j, 0, 1]
            g10, g11 = g[k, j, 1, 0], g[k, j, 1, 1]
            n0, n1 = n[m, j, 0], n[m, j, 1]
            gn0, gn1 = g00 * n0 + g01 * n1, g10 * n0 + g11 * n1
            norm = np.sqrt(n0 * gn0 + n1 * gn1)
            n0, n1, gn0, gn1 = n0 / norm, n1 / norm, gn0 / norm, gn1 / norm
            root_det = np.sqrt(g00 * g11 - g01**2)
            m0, m1 = -gn1 / root_det, gn0 / root_det
            stretch_u = alpha[m] * lam1[k, j]
            stretch_v = beta[m] * lam2[k, j]
            n_unit[k, j, 0], n_unit[k, j, 1] = n0, n1
            for i in range(2):
                gnn = (
                    gamma[k, j, i, 0, 0] * n0 * n0
                    + gamma[k, j, i, 0, 1] * n0 * n1
                    + gamma[k, j, i, 1, 0] * n1 * n0
                    + gamma[k, j, i, 1, 1] * n1 * n1
                )
                gpn = (
                    gamma[k, j, i, 0, 0] * m0 * n0
                    + gamma[k, j, i, 0, 1] * m0 * n1
                    + gamma[k, j, i, 1, 0] * m1 * n0
                    + gamma[k, j, i, 1, 1] * m1 * n1
                )
                unit = n0 if i == 0 else n1
                perp = m0 if i == 0 else m1
                du_r[k, j, i] = stretch_u * unit
                du_n[k, j, i] = stretch_u * (ku[j] * perp - gnn)
                dv_r[k, j, i] = stretch_v * perp
                dv_n[k, j, i] = stretch_v * (kv[j] * perp - gpn)
        failed[m] = _failure(
            k, m, alpha, beta, b, s, eps, p, q, r, n, du_n, dv_n, du_s, dv_b, du_p, dv_q,
            lam1, lam2, inside, singular, max_strain, isotropic_tolerance,
        )  # fmt: skip
    du = (du_beta, du_s, du_eps, du_p, du_r, du_n, n_unit)
    return du, (dv_alpha, dv_b, dv_eps, dv_q, dv_r, dv_n), failed


@numba.njit(cache=True, error_model="numpy", inline="always")
def _failure(
    k, m, alpha, beta, b, s, eps, p, q, r, n, du_n, dv_n, du_s, dv_b, du_p, dv_q,
    lam1, lam2, inside, singular, max_strain, isotropic_tolerance,
) -> int:  # fmt: skip
    """The first failing check of point m of the state (k of the P points and the rates),
    in the solver's order; 0 if none fails."""
    finite = (
        np.isfinite(alpha[m])
        and np.isfinite(beta[m])
        and np.isfinite(b[m])
        and np.isfinite(s[m])
        and np.isfinite(du_s[k])
        and np.isfinite(dv_b[k])
    )
    for i in range(eps.shape[1]):
        finite = finite and np.isfinite(eps[m, i]) and np.isfinite(p[m, i])
        finite = finite and np.isfinite(q[m, i]) and np.isfinite(du_p[k, i])
        finite = finite and np.isfinite(dv_q[k, i])
    for j in range(r.shape[1]):
        for i in range(2):
            finite = finite and np.isfinite(r[m, j, i]) and np.isfinite(n[m, j, i])
            finite = finite and np.isfinite(du_n[k, j, i]) and np.isfinite(dv_n[k, j, i])
    if not finite:
        return NON_FINITE
    if not alpha[m] > 0:
        return ALPHA
    if not beta[m] > 0:
        return BETA
    surfaces = lam1.shape[1]
    for j in range(surfaces):
        if not (lam1[k, j] > 0) or not (lam2[k, j] > 0):
            return LAMBDA
    for j in range(surfaces):
        d1, d2 = abs(lam1[k, j] - 1), abs(lam2[k, j] - 1)
        if d1 == d1 and d2 == d2 and max(d1, d2) > max_strain:
            return STRAIN
    isotropic = True
    for j in range(1, surfaces):
        d = abs(lam1[k, j] - lam2[k, j])
        isotropic = isotropic and d <= isotropic_tolerance * (lam1[k, j] + lam2[k, j])
    if isotropic:
        return ISOTROPIC
    if singular:
        return DET_M
    for j in range(surfaces):
        if not inside[k, j]:
            return CHART
    return 0


WEST, SOUTH, MEAN, MEAN_ENDS = range(4)
"""How :func:`propagate` gets a component on the next diagonal: from its west source
(u-propagated; the v-curve's data at the diagonal's start), from its south source
(v-propagated; the u-curve's data at its end), or the mean of the two (at the ends: the
one source there, or with MEAN_ENDS the curves' data)."""


@numba.njit(cache=True, error_model="numpy")
def propagate(old, du_old, dv_old, at_old, du_new, dv_new, at_new, heun, step_u, step_v, u_end,
              v_end, mode):  # fmt: skip
    """One variable on diagonal d+1 (R, L+1, F) from diagonal d (R, L, F): Euler with the
    rates at d, or with ``heun`` the trapezoidal rule with the rates at d+1 too.

    du_old, dv_old (P, F): the variable's rates in u and v at the points of diagonal d that
    have rates, ``at_old`` (R, L) the index of each point's there (-1: none, a NaN rate);
    du_new, dv_new and at_new (R, L+1) the same on diagonal d+1 (a rate the component's
    ``mode`` (F,) does not use is never read); step_u, step_v (R,): signed grid steps;
    u_end, v_end (R, F): the initial curves' data at the ends of diagonal d+1 (the
    u-curve's at its last point, the v-curve's at its first).
    """
    rows, length, size = old.shape
    new = np.empty((rows, length + 1, size))
    for row in range(rows):
        for f in range(size):
            kind = mode[f]
            for k in range(length + 1):
                west, south = np.nan, np.nan
                if kind != SOUTH and k >= 1:
                    slope = _rate(du_old, at_old[row, k - 1], f)
                    if heun:
                        slope = 0.5 * (slope + _rate(du_new, at_new[row, k], f))
                    west = old[row, k - 1, f] + step_u[row] * slope
                if kind != WEST and k < length:
                    slope = _rate(dv_old, at_old[row, k], f)
                    if heun:
                        slope = 0.5 * (slope + _rate(dv_new, at_new[row, k], f))
                    south = old[row, k, f] + step_v[row] * slope
                if kind == WEST:
                    value = v_end[row, f] if k == 0 else west
                elif kind == SOUTH:
                    value = u_end[row, f] if k == length else south
                elif k == 0:
                    value = v_end[row, f] if kind == MEAN_ENDS else south
                elif k == length:
                    value = u_end[row, f] if kind == MEAN_ENDS else west
                else:
                    value = 0.5 * (west + south)
                new[row, k, f] = value
    return new


@numba.njit(cache=True, error_model="numpy")
def _rate(rates, at, f):
    """Component f of the rate at compact index ``at`` (-1: none, NaN)."""
    return rates[at, f] if at >= 0 else np.nan


@numba.njit(cache=True, error_model="numpy")
def cross_derive(eps, alpha, beta, p, q, ok, along, step, sign_u, sign_v, p_end, q_end, code):
    """p of along features and q of across features from eps along the diagonal.

    eps, p, q (R, L, N); alpha, beta, ok (R, L); along (N,); step, sign_u, sign_v (R,);
    p_end, q_end (R, N): the initial curves' p at the diagonal's last point and q at its
    first. d eps / (index step) = h (sign_u eps_u - sign_v eps_v), from valid points only
    (centred where both neighbours are valid, else one-sided with three points, else two);
    with the characteristic derivative known, the other one follows. Returns the new p, q
    and ``code`` (R, L) where a valid point has no valid neighbour for the difference
    and needs one, else 0.
    """
    rows, length, features = eps.shape
    new_p, new_q = p.copy(), q.copy()
    failed = np.zeros((rows, length), dtype=np.int64)
    any_along, any_across = False, False
    for i in range(features):
        any_along = any_along or along[i]
        any_across = any_across or not along[i]
    for row in range(rows):
        h, su, sv = step[row], sign_u[row], sign_v[row]
        for k in range(length):
            om1 = k >= 1 and ok[row, k - 1]
            om2 = k >= 2 and ok[row, k - 2]
            op1 = k + 1 < length and ok[row, k + 1]
            op2 = k + 2 < length and ok[row, k + 2]
            need = (any_along and k != length - 1) or (any_across and k != 0)
            if ok[row, k] and not (op1 or om1) and need:
                failed[row, k] = code
            for i in range(features):
                c0 = eps[row, k, i]
                if om1 and op1:
                    slope = (eps[row, k + 1, i] - eps[row, k - 1, i]) / 2
                elif op1 and op2:
                    slope = (-3 * c0 + 4 * eps[row, k + 1, i] - eps[row, k + 2, i]) / 2
                elif om1 and om2:
                    slope = (3 * c0 - 4 * eps[row, k - 1, i] + eps[row, k - 2, i]) / 2
                elif op1:
                    slope = eps[row, k + 1, i] - c0
                elif om1:
                    slope = c0 - eps[row, k - 1, i]
                else:
                    slope = np.nan
                if along[i]:
                    if k == length - 1:
                        new_p[row, k, i] = p_end[row, i]
                    else:
                        eps_v = beta[row, k] * q[row, k, i]
                        new_p[row, k, i] = su * (slope / h + sv * eps_v) / alpha[row, k]
                elif k == 0:
                    new_q[row, k, i] = q_end[row, i]
                else:
                    eps_u = alpha[row, k] * p[row, k, i]
                    new_q[row, k, i] = sv * (su * eps_u - slope / h) / beta[row, k]
    return new_p, new_q, failed
