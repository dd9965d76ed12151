"""The batch the solver marches: its rows, the state on a diagonal, the stop reasons and
the solved points.

One solve is many rows marched together, diagonal d of each at once (:class:`Problem`):
one row per quadrant, per march (at step h and h/2, :data:`COARSE` and :data:`FINE`) and
per candidate (a spec of a batch, :func:`fabkit.design.solver.solve_batch`). A point that
fails a check stops with one of :data:`REASONS` (:class:`Stop`); a march's solved points on
the design grid are :class:`Points`. The stages that use them: :mod:`fabkit.design.initial`
(the data on the initial curves), :mod:`fabkit.design.march` (the march) and
:mod:`fabkit.design.solver` (the solve, its error control and the design).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

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


State = dict[str, np.ndarray]
"""Values on one diagonal of every row: arrays (R, L, ...) by variable name."""

COARSE, FINE = 0, 1
"""The two marches, at step h and h/2, solved together: rows 0..Q-1 and Q..2Q-1."""


@dataclass(frozen=True)
class Problem:
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


def batch_problem(specs: Sequence[Spec]) -> Problem:
    """The problem of a batch of specs (see :class:`Problem` for the rows)."""
    spec = specs[0]
    count = len(spec.solver.quadrants)
    quadrants = np.tile(np.array(spec.solver.quadrants, dtype=float), (2 * len(specs), 1))
    step = spec.solver.step
    march = np.tile(np.repeat([COARSE, FINE], count), len(specs))
    candidate = np.repeat(np.arange(len(specs)), 2 * count)
    group = 2 * candidate + march
    return Problem(
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


def stop_order(stop: Stop) -> tuple[float, float, float]:
    """Sort key of stops: nearest the origin first, then by u and v."""
    return (abs(stop.u) + abs(stop.v), stop.u, stop.v)


DESIGN_KEYS = ("alpha", "beta", "eps", "r", "n")
"""The variables a design keeps (b, s, p and q are only needed while marching)."""


@dataclass(frozen=True)
class Points:
    """Solved points of one march on the design grid: ``index`` (P,) flat indices into
    the (n, n) grid, ascending, and ``values`` by variable: alpha, beta (P,), eps (P, N),
    r and n (P, S, 2)."""

    index: np.ndarray
    values: State

    def take(self, pick: np.ndarray) -> Points:
        """The points ``pick`` (indices or a boolean mask over the P points)."""
        return Points(self.index[pick], {k: v[pick] for k, v in self.values.items()})
