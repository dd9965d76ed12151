"""The solver's compiled kernels (fabkit/design/kernels.py) against their definitions."""

from __future__ import annotations

import numpy as np
import pytest

from fabkit.design import batch, kernels, march, solver
from fabkit.problem.spec import build_spec
from tests.conftest import EXAMPLES, example_table


@pytest.mark.parametrize("size", [2, 3, 4, 5])
def test_the_lu_solve_agrees_with_lapack(size):
    rng = np.random.default_rng(size)
    for _ in range(20):
        matrix = rng.normal(size=(size, size)) + size * np.eye(size)
        rhs = rng.normal(size=size)
        out = np.empty(size)
        det = kernels._lu_solve(matrix.copy(), rhs.copy(), out)
        np.testing.assert_allclose(out, np.linalg.solve(matrix, rhs), rtol=1e-12, atol=1e-13)
        np.testing.assert_allclose(det, np.linalg.det(matrix), rtol=1e-12)
    # a permutation needs pivoting: a zero on the diagonal
    matrix = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 2.0], [3.0, 0.0, 0.0]])
    out = np.empty(3)
    det = kernels._lu_solve(matrix.copy(), np.array([1.0, 2.0, 3.0]), out)
    np.testing.assert_allclose(out, [1.0, 1.0, 1.0])
    assert det == pytest.approx(np.linalg.det(matrix))


def diagonal_state():
    """The problem of Fig. 1 (step 0.1) and a made-up diagonal (R, 6) around its origin."""
    table = example_table("two_shapes.toml")
    table["solver"].update(step=0.1, diagonals=4)
    spec = build_spec(table, EXAMPLES)
    results = [None]
    problem, _, _, origin, _, kept = solver._start([spec], results)
    assert kept == [0]
    rng = np.random.default_rng(0)
    state = {}
    for key, value in origin.items():
        tiled = np.repeat(value, 6, axis=1)
        state[key] = tiled * (1 + 0.05 * rng.uniform(-1, 1, tiled.shape))
    state["alpha"][0, 2] = -1.0  # one point fails (a defect)
    return problem, state


def test_rates_at_the_masked_points_do_not_depend_on_the_others():
    """A point's rates and failure are its own: computed alone, with others, or for every
    point, they are the same; off the mask there are none (index -1, code 0)."""
    problem, state = diagonal_state()
    (du_all, dv_all, at_all), failed_all = march.point_rates(problem, state)
    assert np.array_equal(at_all.ravel(), np.arange(at_all.size))
    assert failed_all[0, 2] == batch.ALPHA
    assert (failed_all[:, [0, 1, 3]] == 0).all()
    mask = np.zeros(failed_all.shape, dtype=bool)
    mask[0, 2] = mask[1, 1:4] = mask[-1, -1] = True
    (du, dv, at), failed = march.point_rates(problem, state, mask)
    assert np.array_equal(failed, np.where(mask, failed_all, 0))
    assert np.array_equal(at[mask], np.arange(mask.sum())) and (at[~mask] == -1).all()
    for every, some in ((du_all, du), (dv_all, dv)):
        assert every.keys() == some.keys()
        for key, value in some.items():
            assert np.array_equal(value, every[key][at_all[mask]]), key
    (du_none, _, at_none), failed_none = march.point_rates(problem, state, np.zeros_like(mask))
    assert not failed_none.any() and len(du_none["beta"]) == 0 and (at_none == -1).all()


def numpy_step(old, du_old, dv_old, du_new, dv_new, heun, step_u, step_v):
    """The west and south estimates of a step (the numpy formulation)."""
    slope_u, slope_v = du_old, dv_old
    if heun:
        slope_u, slope_v = 0.5 * (du_old + du_new[:, 1:]), 0.5 * (dv_old + dv_new[:, :-1])
    west = old + step_u[:, None, None] * slope_u
    south = old + step_v[:, None, None] * slope_v
    return west, south


@pytest.mark.parametrize("heun", [False, True])
def test_propagate_takes_each_component_from_its_sources(heun):
    """Every mode against the numpy formulation, with the rates given at some points only
    (compact, by index): a point without a rate gets none (NaN) from it."""
    rng = np.random.default_rng(1)
    rows, length = 3, 5
    modes = np.array([kernels.WEST, kernels.SOUTH, kernels.MEAN, kernels.MEAN_ENDS])
    size = len(modes)
    old, du_old, dv_old = (rng.normal(size=(rows, length, size)) for _ in range(3))
    du_new, dv_new = (rng.normal(size=(rows, length + 1, size)) for _ in range(2))
    du_old[1, 2] = dv_old[1, 2] = du_new[2, 3] = dv_new[2, 3] = np.nan  # no rate there
    step_u, step_v = rng.normal(size=rows), rng.normal(size=rows)
    u_end, v_end = rng.normal(size=(rows, size)), rng.normal(size=(rows, size))
    compact = []
    for full in ((du_old, dv_old), (du_new, dv_new)):
        has = ~np.isnan(full[0][..., 0])
        at = np.where(has, np.cumsum(has).reshape(has.shape) - 1, -1)
        compact += [full[0][has], full[1][has], at]
    new = kernels.propagate(old, *compact, heun, step_u, step_v, u_end, v_end, modes)
    west, south = numpy_step(old, du_old, dv_old, du_new, dv_new, heun, step_u, step_v)
    assert new.shape == (rows, length + 1, size)

    def same(a, b):
        return np.array_equal(a, b, equal_nan=True)

    assert same(new[:, 1:, 0], west[..., 0]) and same(new[:, 0, 0], v_end[:, 0])
    assert same(new[:, :-1, 1], south[..., 1]) and same(new[:, -1, 1], u_end[:, 1])
    for f in (2, 3):
        assert same(new[:, 1:-1, f], 0.5 * (west[:, :-1, f] + south[:, 1:, f]))
    assert same(new[:, 0, 2], south[:, 0, 2]) and same(new[:, -1, 2], west[:, -1, 2])
    assert same(new[:, 0, 3], v_end[:, 3]) and same(new[:, -1, 3], u_end[:, 3])
    assert np.isnan(new[1, 3, 0]) and np.isnan(new[1, 2, 1])  # from the point without rates


def test_cross_derivatives_from_eps_along_the_diagonal():
    """eps quadratic along the diagonal: the centred and the three-point differences are
    exact, the two-point ones are not; a valid point with no valid neighbour fails; the
    ends take the curves' data; the characteristic components stay as they are."""
    rows, length, h = 2, 8, 0.1
    k = np.arange(length, dtype=float)
    values = 0.5 + 0.2 * k + 0.01 * k**2
    eps = np.repeat(np.stack([values, values], -1)[None], rows, axis=0)  # (R, L, 2)
    ok = np.ones((rows, length), dtype=bool)
    ok[1] = [True, True, False, True, False, True, True, True]
    slope = np.repeat((0.2 + 0.02 * k)[None], rows, axis=0)  # d eps / d index, exact
    slope[1, [0, 1]] = values[1] - values[0]  # two-point differences on row 1
    slope[1, 3] = np.nan  # no valid neighbour
    alpha, beta = np.full((rows, length), 2.0), np.full((rows, length), 4.0)
    p, q = np.full((rows, length, 2), 0.3), np.full((rows, length, 2), -0.1)
    along = np.array([True, False])
    sign_u, sign_v = np.array([1.0, -1.0]), np.array([1.0, 1.0])
    p_end, q_end = np.full((rows, 2), 7.0), np.full((rows, 2), 9.0)
    new_p, new_q, failed = kernels.cross_derive(
        eps, alpha, beta, p, q, ok, along, np.full(rows, h), sign_u, sign_v, p_end, q_end, 99
    )
    su, sv = sign_u[:, None], sign_v[:, None]
    p_along = su * (slope / h + sv * beta * q[..., 0]) / alpha
    q_across = sv * (su * alpha * p[..., 1] - slope / h) / beta
    p_along[:, -1], q_across[:, 0] = 7.0, 9.0
    valid = ok & ~np.isnan(slope)
    np.testing.assert_allclose(new_p[..., 0][valid], p_along[valid], rtol=1e-12)
    np.testing.assert_allclose(new_q[..., 1][valid], q_across[valid], rtol=1e-12)
    assert np.array_equal(new_p[..., 1], p[..., 1]) and np.array_equal(new_q[..., 0], q[..., 0])
    assert failed[1, 3] == 99 and failed.sum() == 99


def test_the_kernels_failure_codes_are_the_solvers():
    for name in ("NON_FINITE", "ALPHA", "BETA", "LAMBDA", "STRAIN", "ISOTROPIC", "DET_M", "CHART"):
        assert getattr(kernels, name) == getattr(batch, name), name
