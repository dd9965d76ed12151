"""Smooth fits of gridded heights: a spectral smoothing spline with data-chosen smoothing.

Heights ``z`` (ny, nx) sampled at ``x0 + i hx``, ``y0 + j hy`` (NaN = hole) are fitted
by the function ``f`` that minimises

    sum over data (z - f)^2  +  penalty(f),

where the penalty is the Kronecker product of two 1D third-difference penalties
(Whittaker smoothers), one per axis, each with its own smoothing length ``l``
(chart units): detail of wavelength ``2 pi l`` along that axis keeps about half its
amplitude, longer waves pass, shorter ones are removed; quadratics pass untouched,
so smoothing biases curvature only where it varies. The penalty is diagonal in the
eigenvectors of the 1D penalty matrices, so a fit for any smoothing costs four
dense matrix products, and the criteria that choose the smoothing are cheap
sums over the data's spectrum.

The smoothed grid values are then interpolated by a uniform cubic B-spline
(not-a-knot ends), whose coefficients give ``f`` and its first and second
derivatives in closed form anywhere in the grid, vectorised over points.

Choosing the smoothing (unless the user sets it):

1. the noise level of the heights: a robust spread of their third differences
   (:func:`noise_level`);
2. each axis' smoothing length then minimises an unbiased estimate of the mean
   squared error of the fitted Hessian (``f_xx``, ``f_xy``, ``f_yy``), which is what
   the Gaussian curvature and Christoffel symbols are made of, by coordinate
   descent over a logarithmic ladder of lengths. With holes this is done on the
   largest hole-free rectangle of the grid.

Holes are filled by the fit that ignores them (the fixed point of
expectation-maximisation), solved by conjugate gradients from a smooth first guess.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property, lru_cache

import numpy as np
from scipy import linalg, ndimage, sparse
from scipy.sparse import linalg as sparse_linalg

LADDER = 60
"""Number of candidate smoothing lengths per search."""
SWEEPS = 3
"""Coordinate-descent sweeps over the two axes' smoothing lengths."""
MAD_TO_SIGMA = 1.4826
"""Median absolute deviation to standard deviation, for Gaussian noise."""
FILL_ROUNDS = 25
"""Most conjugate-gradient iterations that fill holes."""
FILL_TOLERANCE = 0.05
"""Hole filling stops when the residual's RMS per hole node is below this times the noise."""
NOISE_FLOOR = 1e-6
"""Noise below this fraction of the height range counts as this, for settling holes."""
FILL_BAND = 8
"""Hole nodes within this many nodes of data get a smooth initial fill."""
MIN_CLEAR = 16
"""Smallest hole-free rectangle side (nodes) on which the smoothing is chosen."""
FILL_ANCHOR = 1e-8
"""Weak pull of the smooth fill towards the nearest data value, so it is always determined."""


@dataclass(frozen=True)
class SurfaceFit:
    """A fitted height function f(x, y) on a regular grid, with its derivatives.

    ``coefficients`` (ny + 2, nx + 2) are uniform cubic B-spline coefficients: the
    basis function centred on node (i, j) of the (ny, nx) grid has index (j + 1, i + 1).
    ``origin`` = (x0, y0) and ``spacing`` = (hx, hy) in chart units.
    ``smoothing`` = (lx, ly) smoothing lengths in chart units; ``chosen`` is True when
    they were chosen from the data. ``noise`` is the estimated standard deviation of
    the noise in the data (:func:`noise_level`) and ``residual`` the RMS of
    (fit - data) over valid nodes, both in height units.
    """

    origin: tuple[float, float]
    spacing: tuple[float, float]
    coefficients: np.ndarray
    smoothing: tuple[float, float]
    chosen: bool
    noise: float
    residual: float

    @property
    def shape(self) -> tuple[int, int]:
        """Grid shape (ny, nx)."""
        return self.coefficients.shape[0] - 2, self.coefficients.shape[1] - 2

    def derivatives(self, points: np.ndarray) -> np.ndarray:
        """(f, f_x, f_y, f_xx, f_xy, f_yy) stacked on a new first axis: (6, ...) at points (..., 2).

        Points outside the grid get the polynomial of the nearest edge cell (extrapolation);
        non-finite points give NaN.
        """
        points = np.asarray(points, dtype=float)
        shape = points.shape[:-1]
        flat = points.reshape(-1, 2)
        ny, nx = self.shape
        (hx, hy), (x0, y0) = self.spacing, self.origin
        ix, tx = _cell((flat[:, 0] - x0) / hx, nx)
        iy, ty = _cell((flat[:, 1] - y0) / hy, ny)
        offsets = np.arange(4)
        patch = self.coefficients[
            (iy[:, None] + offsets)[:, :, None], (ix[:, None] + offsets)[:, None, :]
        ]
        bx, by = _basis(tx), _basis(ty)
        along_y = np.einsum("dma,mab->dmb", by, patch)
        values = np.stack(
            [
                np.einsum("mb,mb->m", along_y[0], bx[0]),
                np.einsum("mb,mb->m", along_y[0], bx[1]) / hx,
                np.einsum("mb,mb->m", along_y[1], bx[0]) / hy,
                np.einsum("mb,mb->m", along_y[0], bx[2]) / hx**2,
                np.einsum("mb,mb->m", along_y[1], bx[1]) / (hx * hy),
                np.einsum("mb,mb->m", along_y[2], bx[0]) / hy**2,
            ]
        )
        return values.reshape(6, *shape)


def _cell(position: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Cell index in [0, n - 2] and local coordinate for grid positions (m,) in node units."""
    with np.errstate(invalid="ignore"):
        index = np.clip(np.floor(position), 0, n - 2)
        index = np.where(np.isfinite(index), index, 0).astype(np.intp)
    return index, position - index


def _basis(t: np.ndarray) -> np.ndarray:
    """Uniform cubic B-spline weights of a cell's 4 coefficients and their first and second
    derivatives in t: (3, m, 4) for local coordinates t (m,) in [0, 1]."""
    s = 1.0 - t
    t2, t3 = t * t, t * t * t
    return np.stack(
        [
            np.stack([s**3, 3 * t3 - 6 * t2 + 4, -3 * t3 + 3 * t2 + 3 * t + 1, t3], -1) / 6,
            np.stack([-(s**2), 3 * t2 - 4 * t, -3 * t2 + 2 * t + 1, t2], -1) / 2,
            np.stack([s, 3 * t - 2, 1 - 3 * t, t], -1),
        ]
    )


@dataclass(frozen=True)
class _Axis:
    """One grid axis: n nodes at spacing h (chart units), with the smoother's modes."""

    n: int
    h: float

    @property
    def modes(self) -> np.ndarray:
        """Orthonormal eigenvectors (n, n) of the third-difference penalty, as columns."""
        return _penalty_modes(self.n)[1]

    @property
    def spline_modes(self) -> np.ndarray:
        """(n + 2, n): B-spline coefficients of the interpolant of each mode."""
        return _spline_modes(self.n)

    @cached_property
    def frequency(self) -> np.ndarray:
        """Squared angular frequency (n,) of each mode in 1/length^2 (about omega^2)."""
        return np.clip(_penalty_modes(self.n)[0], 0.0, None) ** (1 / 3) / self.h**2

    def filter(self, lengths: np.ndarray) -> np.ndarray:
        """Smoother gain (..., n) of each mode for smoothing lengths (...,) in chart units."""
        lengths = np.asarray(lengths, dtype=float)[..., None]
        return 1.0 / (1.0 + (lengths**2 * self.frequency) ** 3)

    def smoother(self, length: float) -> np.ndarray:
        """(n, n) symmetric matrix that smooths values along this axis with the given length."""
        return (self.modes * self.filter(length)) @ self.modes.T

    def ladder(self) -> np.ndarray:
        """Candidate smoothing lengths (chart units): 0.3 to 50 spacings, at most a quarter span."""
        longest = max(0.3, min(50.0, (self.n - 1) / 4)) * self.h
        return np.geomspace(0.3 * self.h, longest, LADDER)


@lru_cache(maxsize=4)
def _penalty_modes(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (n,) and orthonormal eigenvectors (n, n) of the n-node third-difference
    penalty D^T D, a symmetric band matrix with 3 off-diagonals (cached: the solver builds
    many surfaces of the same size)."""
    differences = _third_differences(n)
    penalty = (differences.T @ differences).todia()
    return linalg.eig_banded(_band(penalty, 0, 3))


@lru_cache(maxsize=4)
def _spline_modes(n: int) -> np.ndarray:
    """(n + 2, n): uniform cubic B-spline coefficients (not-a-knot ends) interpolating each
    penalty mode at the n nodes."""
    rows = np.arange(1, n + 1)
    system = sparse.lil_matrix((n + 2, n + 2))
    system[rows, rows - 1], system[rows, rows], system[rows, rows + 1] = 1 / 6, 4 / 6, 1 / 6
    system[0, :4] = [1, -3, 3, -1]
    system[n + 1, n - 2 :] = [-1, 3, -3, 1]
    rhs = np.zeros((n + 2, n))
    rhs[1:-1] = _penalty_modes(n)[1]
    return linalg.solve_banded((3, 3), _band(system, 3, 3), rhs)


def _band(matrix: sparse.spmatrix, lower: int, upper: int) -> np.ndarray:
    """LAPACK band storage (upper + lower + 1, n) of a square sparse matrix:
    band[upper + i - j, j] = matrix[i, j]."""
    n = matrix.shape[0]
    band = np.zeros((upper + lower + 1, n))
    for offset in range(-lower, upper + 1):
        diagonal = matrix.diagonal(offset)
        columns = slice(offset, n) if offset >= 0 else slice(0, n + offset)
        band[upper - offset, columns] = diagonal
    return band


def fit_grid(
    z: np.ndarray,
    origin: tuple[float, float],
    spacing: tuple[float, float],
    smoothing: tuple[float, float] | None = None,
) -> SurfaceFit:
    """Fit heights z (ny, nx), NaN = hole, with node (i, j) at origin + (i, j) * spacing.

    ``smoothing`` = (lx, ly) in chart units, or None to choose it from the data.
    The caller guarantees at least 4 x 4 nodes and some finite values.
    """
    valid = np.isfinite(z)
    ny, nx = z.shape
    axes = (_Axis(nx, float(spacing[0])), _Axis(ny, float(spacing[1])))
    noise = noise_level(z)
    lengths = smoothing if smoothing is not None else _choose_lengths(z, valid, spacing, noise)
    filled = z if valid.all() else _fill_holes(z, valid, axes, lengths, noise)
    spectrum = _gained_spectrum(filled, axes, lengths)
    fitted = axes[1].modes @ spectrum @ axes[0].modes.T
    return SurfaceFit(
        origin=(float(origin[0]), float(origin[1])),
        spacing=(axes[0].h, axes[1].h),
        coefficients=axes[1].spline_modes @ spectrum @ axes[0].spline_modes.T,
        smoothing=(float(lengths[0]), float(lengths[1])),
        chosen=smoothing is None,
        noise=noise,
        residual=float(np.sqrt(np.mean((fitted - z)[valid] ** 2))),
    )


def _gained_spectrum(
    values: np.ndarray, axes: tuple[_Axis, _Axis], lengths: tuple[float, float]
) -> np.ndarray:
    """Spectrum (ny, nx) of grid values (ny, nx) times the smoother's gain for lengths (lx, ly)."""
    gain = axes[1].filter(lengths[1])[:, None] * axes[0].filter(lengths[0])[None, :]
    return (axes[1].modes.T @ values @ axes[0].modes) * gain


def _choose_lengths(
    z: np.ndarray, valid: np.ndarray, spacing: tuple[float, float], noise: float
) -> tuple[float, float]:
    """Smoothing lengths (lx, ly) chosen on the largest hole-free rectangle of z (ny, nx),
    or on the whole grid with holes filled by their nearest value if that rectangle is small."""
    rows, columns = _clear_rectangle(valid)
    sample = z[rows, columns]
    if min(sample.shape) < MIN_CLEAR:
        sample = _fill_nearest(z, valid)
    ny, nx = sample.shape
    axes = (_Axis(nx, float(spacing[0])), _Axis(ny, float(spacing[1])))
    spectrum = axes[1].modes.T @ sample @ axes[0].modes
    return _smoothing(spectrum, noise**2, axes)


def _clear_rectangle(valid: np.ndarray) -> tuple[slice, slice]:
    """A large rectangle (rows, columns) of valid nodes: the widest square around the node
    farthest from holes, grown side by side while the added strip has no hole."""
    distance = ndimage.distance_transform_cdt(np.pad(valid, 1), metric="chessboard")[1:-1, 1:-1]
    row, column = np.unravel_index(int(np.argmax(distance)), valid.shape)
    half = int(distance[row, column]) - 1
    bounds = [row - half, row + half + 1, column - half, column + half + 1]
    holes = np.pad(np.cumsum(np.cumsum(~valid, 0), 1), ((1, 0), (1, 0)))

    def clear(r0: int, r1: int, c0: int, c1: int) -> bool:
        inside = r0 >= 0 and r1 <= valid.shape[0] and c0 >= 0 and c1 <= valid.shape[1]
        return inside and holes[r1, c1] - holes[r0, c1] - holes[r1, c0] + holes[r0, c0] == 0

    grown = True
    while grown:
        grown = False
        for side, step in ((0, -1), (1, 1), (2, -1), (3, 1)):
            trial = list(bounds)
            trial[side] += step
            if clear(*trial):
                bounds, grown = trial, True
    return slice(bounds[0], bounds[1]), slice(bounds[2], bounds[3])


def _fill_nearest(z: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """z (ny, nx) with every hole replaced by the nearest valid value."""
    _, (rows, columns) = ndimage.distance_transform_edt(~valid, return_indices=True)
    return z[rows, columns]


def _fill_holes(
    z: np.ndarray,
    valid: np.ndarray,
    axes: tuple[_Axis, _Axis],
    lengths: tuple[float, float],
    noise: float,
) -> np.ndarray:
    """z (ny, nx) with holes filled by the fit that ignores them.

    The hole values h solve (I - S_hh) h = S_hv z_v, S the smoother: the fixed point of
    expectation-maximisation, found by conjugate gradients. The first guess extends
    the smoothed data into the holes by least third differences (no noise amplification).
    The smoother is separable, S = S_y (x) S_x, so S_hh only needs the rows and columns
    of S_y and S_x that the holes span.
    """
    holes = ~valid
    data = np.where(valid, z, 0.0)
    along_y, along_x = axes[1].smoother(lengths[1]), axes[0].smoother(lengths[0])
    rows, columns = (np.flatnonzero(holes.any(axis)) for axis in (1, 0))
    local = holes[np.ix_(rows, columns)]
    box_y, box_x = along_y[np.ix_(rows, rows)], along_x[np.ix_(columns, columns)]

    def smooth_holes(values: np.ndarray) -> np.ndarray:
        block = np.zeros(local.shape)
        block[local] = values
        return (box_y @ block @ box_x)[local]

    smoothed = along_y @ _fill_nearest(z, valid) @ along_x
    guess = _extend(smoothed, valid)[holes]
    rhs = (along_y @ data @ along_x)[holes]
    settled = FILL_TOLERANCE * max(noise, NOISE_FLOOR * float(np.ptp(z[valid])))
    filled = data.copy()
    filled[holes] = _conjugate_gradients(
        lambda h: h - smooth_holes(h), rhs, guess, settled * np.sqrt(holes.sum())
    )
    return filled


def _conjugate_gradients(
    operator: Callable[[np.ndarray], np.ndarray],
    rhs: np.ndarray,
    guess: np.ndarray,
    tolerance: float,
) -> np.ndarray:
    """Solve operator(x) = rhs (symmetric positive definite) from guess until the residual
    norm is below tolerance or FILL_ROUNDS iterations have run."""
    solution = guess.copy()
    residual = rhs - operator(solution)
    direction = residual.copy()
    norm = residual @ residual
    for _ in range(FILL_ROUNDS):
        if np.sqrt(norm) <= tolerance:
            break
        image = operator(direction)
        step = norm / (direction @ image)
        solution += step * direction
        residual -= step * image
        norm, previous = residual @ residual, norm
        direction = residual + (norm / previous) * direction
    return solution


def _extend(values: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """values (ny, nx) with hole nodes within FILL_BAND of data replaced by the values that
    minimise the squared third differences along x and y (valid nodes held fixed).

    Only the bounding box of those nodes, widened by the 3-node reach of a third
    difference, takes part."""
    distance = ndimage.distance_transform_edt(~valid)
    unknown = (distance > 0) & (distance <= FILL_BAND)
    rows, columns = (np.flatnonzero(unknown.any(axis)) for axis in (1, 0))
    box = (
        slice(max(rows[0] - 3, 0), rows[-1] + 4),
        slice(max(columns[0] - 3, 0), columns[-1] + 4),
    )
    extended = values.copy()
    extended[box] = _least_third_differences(values[box], unknown[box])
    return extended


def _least_third_differences(values: np.ndarray, unknown: np.ndarray) -> np.ndarray:
    """values (ny, nx) with the unknown nodes set to minimise the sum of squared third
    differences along both axes, the other nodes held fixed."""
    ny, nx = values.shape
    differences = sparse.vstack(
        [
            sparse.kron(sparse.eye(ny), _third_differences(nx)),
            sparse.kron(_third_differences(ny), sparse.eye(nx)),
        ]
    ).tocsc()
    flat, free_nodes = values.ravel().copy(), unknown.ravel()
    free, fixed = differences[:, free_nodes], differences[:, ~free_nodes]
    system = (free.T @ free + FILL_ANCHOR * sparse.eye(free.shape[1])).tocsc()
    rhs = FILL_ANCHOR * flat[free_nodes] - free.T @ (fixed @ flat[~free_nodes])
    flat[free_nodes] = sparse_linalg.spsolve(system, rhs)
    return flat.reshape(values.shape)


def _third_differences(n: int) -> sparse.csr_matrix:
    """(n - 3, n) third-difference operator."""
    return sparse.diags([-1.0, 3.0, -3.0, 1.0], [0, 1, 2, 3], shape=(n - 3, n), format="csr")


def _smoothing(
    spectrum: np.ndarray, noise_variance: float, axes: tuple[_Axis, _Axis]
) -> tuple[float, float]:
    """Smoothing lengths (lx, ly) minimising the estimated Hessian error for the spectrum
    (ny, nx) of data with noise_variance, by coordinate descent from the smallest lengths."""
    x_axis, y_axis = axes
    ladders = (x_axis.ladder(), y_axis.ladder())
    excess = spectrum**2 - noise_variance
    lengths = [ladders[0][0], ladders[1][0]]
    for _ in range(SWEEPS):
        lengths[0] = _best_length(excess, noise_variance, x_axis, y_axis, lengths[1], ladders[0])
        lengths[1] = _best_length(excess.T, noise_variance, y_axis, x_axis, lengths[0], ladders[1])
    return float(lengths[0]), float(lengths[1])


def noise_level(z: np.ndarray) -> float:
    """Standard deviation of the noise in heights z (ny, nx), NaN = hole.

    Third differences along each axis remove quadratics and leave 20 times the noise
    variance plus a little signal; a robust spread (median absolute deviation) of them
    is taken along each axis and the smaller (less signal) estimate is kept.
    """
    estimates = []
    for axis in (0, 1):
        differences = np.diff(z, 3, axis=axis)
        differences = differences[np.isfinite(differences)]
        if differences.size:
            spread = np.median(np.abs(differences - np.median(differences)))
            estimates.append(MAD_TO_SIGMA * spread / np.sqrt(20.0))
    return float(min(estimates, default=0.0))


def _best_length(
    excess: np.ndarray,
    noise_variance: float,
    axis: _Axis,
    other: _Axis,
    other_length: float,
    ladder: np.ndarray,
) -> float:
    """The smoothing length on ``axis`` (from ``ladder``) minimising the estimated Hessian error.

    ``excess`` (n_other, n_axis) is power minus noise variance, an unbiased estimate of the
    signal power per mode. With gains s = s_other s_axis and Hessian weight
    W = (w_other + w_axis)^2 (w = squared frequency), the risk is
    sum W [excess (1 - s)^2 + noise_variance s^2]; it is expanded into products of
    per-axis sums so each candidate costs O(n_axis).
    """
    w_other, s_other = other.frequency, other.filter(other_length)
    w, gains = axis.frequency, axis.filter(ladder)
    binomial, signs = (1.0, 2.0, 1.0), (1.0, -2.0, 1.0)
    risk = np.zeros(len(ladder))
    for p in range(3):
        for q in range(3):
            reduced = (w_other**p * s_other**q) @ excess
            risk += binomial[p] * signs[q] * (gains**q * w ** (2 - p)) @ reduced
        variance = np.sum(w_other**p * s_other**2) * (gains**2 @ w ** (2 - p))
        risk += binomial[p] * noise_variance * variance
    return float(ladder[int(np.argmin(risk))])
