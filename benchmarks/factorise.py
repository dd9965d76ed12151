"""Factorising a sheet's Newton matrix: banded Cholesky against SuperLU.

For the Fig. 3 sheet (examples/three_shapes.toml) at the default and a coarse design
grid, and the Fig. 1 sheet, it builds two Newton matrices of a target's simulation at
its seeded start: the projected one (positive definite: banded Cholesky) and the damped
exact one (indefinite there, the sheet not yet buckled: the Cholesky fails and SuperLU
factorises it, so the row shows what the failed attempt costs). For each it prints the
unknowns, the reverse Cuthill-McKee band width (-1: not positive definite), the time of
:func:`fabkit.mechanics.factor.factorise` (one BLAS thread, as in a simulation) and of
SuperLU's LU as the simulator called it before, their ratio, and how far the two
solutions of one system are apart (relative).

    python benchmarks/factorise.py
"""

from __future__ import annotations

import itertools
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sparse
import scipy.sparse.linalg as splinalg
from threadpoolctl import threadpool_limits

from fabkit.design.solver import solve
from fabkit.mechanics.factor import BandedCholesky, factorise
from fabkit.mechanics.mesh import design_mesh
from fabkit.mechanics.shell import Sheet, build_shell
from fabkit.mechanics.simulate import (
    Settings,
    default_thickness,
    design_metrics,
    seeded,
)
from fabkit.problem.spec import load_spec

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
REPEAT = 5


def newton_matrix(spec: str, grid: dict, surface: int, projected: bool) -> sparse.csr_matrix:
    """The Newton matrix (3V, 3V) of ``spec``'s design at the seeded start, damped by 1e-4
    of its mean diagonal: the ``projected`` Hessian or the exact one."""
    loaded = load_spec(EXAMPLES / spec)
    if grid:
        loaded = loaded.with_solver(**grid)
    design = solve(loaded).design
    mesh = design_mesh(design)
    sheet = Sheet.build(mesh.points, mesh.triangles)
    metrics = design_metrics(design, mesh, surface)
    shell = build_shell(sheet, metrics, default_thickness(design))
    hessian = shell.hessian(seeded(sheet.points, Settings()), projected=projected)
    mean = float(np.mean(np.abs(hessian.diagonal())))
    return (hessian + sparse.identity(hessian.shape[0]) * 1e-4 * mean).tocsr()


def seconds(call) -> float:
    """Mean wall time (s) of ``call()`` over :data:`REPEAT` calls, after one warm-up."""
    call()
    started = time.perf_counter()
    for _ in range(REPEAT):
        call()
    return (time.perf_counter() - started) / REPEAT


def superlu(matrix: sparse.csr_matrix) -> splinalg.SuperLU:
    """The LU the simulator used before banded Cholesky."""
    return splinalg.splu(
        matrix.tocsc(),
        permc_spec="MMD_AT_PLUS_A",
        diag_pivot_thresh=0.0,
        options={"SymmetricMode": True},
    )


def main() -> None:
    coarse = {"step": 0.1, "diagonals": 30}
    cases = [
        ("Fig. 3 wavy, default grid", "three_shapes.toml", {}, 2),
        ("Fig. 3 wavy, step 0.1, 30 diagonals", "three_shapes.toml", coarse, 2),
        ("Fig. 1 bump, default grid", "two_shapes.toml", {}, 1),
    ]
    columns = ("unknowns", "band", "banded ms", "SuperLU ms", "ratio", "apart")
    print(f"{'case':50s} " + " ".join(f"{c:>10s}" for c in columns))
    with threadpool_limits(limits=1, user_api="blas"):
        for (name, spec, grid, surface), projected in itertools.product(cases, (True, False)):
            matrix = newton_matrix(spec, grid, surface, projected)
            name = f"{name}, {'projected' if projected else 'exact'}"
            factor = factorise(matrix)
            band = factor.band.shape[0] - 1 if isinstance(factor, BandedCholesky) else -1
            right = np.random.default_rng(0).normal(size=matrix.shape[0])
            lu = superlu(matrix)
            apart = np.linalg.norm(factor.solve(right) - lu.solve(right)) / np.linalg.norm(
                lu.solve(right)
            )
            banded = seconds(lambda m=matrix: factorise(m))
            sparse_lu = seconds(lambda m=matrix: superlu(m))
            print(
                f"{name:50s} {matrix.shape[0]:10d} {band:10d} {banded * 1e3:10.1f} "
                f"{sparse_lu * 1e3:10.1f} {sparse_lu / banded:10.2f} {apart:10.1e}"
            )


if __name__ == "__main__":
    main()
