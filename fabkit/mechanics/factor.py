"""Factorising a sheet's Newton matrix: banded Cholesky where it is positive definite.

A sheet's Hessian couples a vertex with its neighbours' neighbours (the hinges), so in
reverse Cuthill-McKee order it is a band about as wide as the mesh is across (236 of
7,449 unknowns on the Fig. 3 sheet at the default grid). LAPACK's banded Cholesky
(``pbtrf`` through :func:`scipy.linalg.cholesky_banded`, on the machine's BLAS) factorises
that band 3-5 times faster than SuperLU factorises the sparse matrix (SuperLU in SciPy
runs on its own reference BLAS); measured in ``benchmarks/factorise.py``. A matrix that
is not positive definite (a damped Newton matrix near a buckling point) is factorised by
SuperLU's LU as before, so every system is solved either way.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as linalg
import scipy.sparse as sparse
import scipy.sparse.linalg as splinalg
from scipy.sparse.csgraph import reverse_cuthill_mckee


@dataclass(frozen=True)
class BandedCholesky:
    """L L^T of P A P^T, A symmetric positive definite (n, n), P the reverse
    Cuthill-McKee order ``order`` (n,); ``band`` (w + 1, n) the lower band of L."""

    band: np.ndarray
    order: np.ndarray

    def solve(self, right: np.ndarray) -> np.ndarray:
        """x (n,) with A x = ``right`` (n,)."""
        permuted = linalg.cho_solve_banded((self.band, True), right[self.order], check_finite=False)
        solution = np.empty_like(permuted)
        solution[self.order] = permuted
        return solution


def factorise(matrix: sparse.spmatrix) -> BandedCholesky | splinalg.SuperLU:
    """A factorisation of the symmetric ``matrix`` (n, n) with ``solve(right)``: banded
    Cholesky when the matrix is positive definite, else SuperLU's LU (minimum degree on
    A + A^T, symmetric mode). Raises RuntimeError when the matrix is exactly singular."""
    csr = sparse.csr_matrix(matrix)
    csr.sum_duplicates()
    layout = _layout(csr)
    band = np.zeros(layout.shape)
    band[layout.rows, layout.columns] = csr.data[layout.lower]
    try:
        return BandedCholesky(
            linalg.cholesky_banded(band, lower=True, check_finite=False), layout.order
        )
    except linalg.LinAlgError:  # not positive definite
        return splinalg.splu(
            csr.tocsc(),
            permc_spec="MMD_AT_PLUS_A",
            diag_pivot_thresh=0.0,
            options={"SymmetricMode": True},
        )


@dataclass(frozen=True)
class _Layout:
    """Where a sparsity pattern's lower triangle goes in the band of its reverse
    Cuthill-McKee order ``order``: the stored entries ``lower`` (a mask) to band
    ``rows`` (offsets below the diagonal) and ``columns``; ``shape`` of the band."""

    indptr: np.ndarray
    indices: np.ndarray
    order: np.ndarray
    lower: np.ndarray
    rows: np.ndarray
    columns: np.ndarray
    shape: tuple[int, int]


_last: list[_Layout] = []
"""The layout of the last pattern factorised: a simulation factorises matrices of one
pattern hundreds of times."""


def _layout(csr: sparse.csr_matrix) -> _Layout:
    """The band layout of ``csr``'s pattern (the last one again when the pattern is)."""
    if _last and _same_pattern(_last[0], csr):
        return _last[0]
    size = csr.shape[0]
    order = reverse_cuthill_mckee(csr, symmetric_mode=True).astype(np.int64)
    rank = np.empty_like(order)
    rank[order] = np.arange(size)
    rows = rank[np.repeat(np.arange(size), np.diff(csr.indptr))]
    columns = rank[csr.indices]
    lower = rows >= columns
    offsets = rows[lower] - columns[lower]
    shape = (int(offsets.max(initial=0)) + 1, size)
    layout = _Layout(
        csr.indptr.copy(), csr.indices.copy(), order, lower, offsets, columns[lower], shape
    )
    _last[:] = [layout]
    return layout


def _same_pattern(layout: _Layout, csr: sparse.csr_matrix) -> bool:
    return (
        len(layout.indices) == len(csr.indices)
        and np.array_equal(layout.indptr, csr.indptr)
        and np.array_equal(layout.indices, csr.indices)
    )
