"""Material response: stretches lambda1 (along n) and lambda2 (across n) of eps and Lambda.

Each designable feature eps_i acts either **along** the director (it changes
lambda1 at some given stimulus) or **across** it (it changes lambda2); a feature
that does both makes the design equations non-hyperbolic and is refused, as is one
that does neither.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import sympy as sp

from fabkit.errors import FabkitError
from fabkit.expr import Expression

ALONG = "along"
ACROSS = "across"


@dataclass(frozen=True)
class Response:
    """Material response at a batch of points, for S stimuli.

    Shapes, with ``P`` the point shape: ``lambda1``, ``lambda2`` (S, *P);
    log-gradients ``l1_e``, ``l2_e`` (S, N, *P); log-Hessians ``l1_ee``, ``l2_ee``
    (S, N, N, *P). ``l = log(lambda)``, derivatives with respect to eps.
    """

    lambda1: np.ndarray
    lambda2: np.ndarray
    l1_e: np.ndarray
    l2_e: np.ndarray
    l1_ee: np.ndarray
    l2_ee: np.ndarray


@dataclass(frozen=True)
class Material:
    """lambda1(eps, Lambda) and lambda2(eps, Lambda) as expressions in features + stimuli."""

    features: tuple[str, ...]
    stimuli: tuple[str, ...]
    lambda1: Expression
    lambda2: Expression

    @property
    def names(self) -> tuple[str, ...]:
        return self.features + self.stimuli

    def classify(self, stimuli: np.ndarray) -> tuple[str, ...]:
        """``along``/``across`` per feature, exactly from the symbolic derivatives.

        ``stimuli`` (S, k) are the stimuli at which the sheet is used; a feature acts
        along the director if d lambda1/d eps_i is not identically zero at one of them.
        Raises :class:`FabkitError` for a feature acting both ways or neither.
        """
        classes = []
        for index, feature in enumerate(self.features):
            along = self._acts(self.lambda1, index, stimuli)
            across = self._acts(self.lambda2, index, stimuli)
            if along and across:
                raise FabkitError(
                    f"material: feature '{feature}' changes both lambda1 and lambda2: the design "
                    "equations are not hyperbolic; let each feature act only along (lambda1) "
                    "or only across (lambda2) the director"
                )
            if not (along or across):
                raise FabkitError(
                    f"material: feature '{feature}' changes neither lambda1 nor lambda2 at the "
                    "given stimuli, so it designs nothing"
                )
            classes.append(ALONG if along else ACROSS)
        return tuple(classes)

    def _acts(self, stretch: Expression, index: int, stimuli: np.ndarray) -> bool:
        symbols = stretch.symbols
        derivative = sp.diff(stretch.sympy, symbols[index])
        stimulus_symbols = symbols[len(self.features) :]
        for row in np.atleast_2d(stimuli):
            values = dict(zip(stimulus_symbols, (sp.nsimplify(v) for v in row), strict=True))
            if sp.simplify(derivative.subs(values)) != 0:
                return True
        return False

    @cached_property
    def _compiled(self):
        """numpy function of (eps..., Lambda...) -> lambda1, lambda2 and their log-derivatives."""
        symbols = self.lambda1.symbols
        eps = symbols[: len(self.features)]
        outputs = []
        for stretch in (self.lambda1, self.lambda2):
            log = sp.log(stretch.sympy)
            gradient = [sp.diff(log, e) for e in eps]
            hessian = [sp.diff(d, e) for d in gradient for e in eps]
            outputs.append([stretch.sympy, *gradient, *hessian])
        return sp.lambdify(symbols, outputs, modules="numpy", cse=True)

    def response(self, eps: np.ndarray, stimuli: np.ndarray) -> Response:
        """Evaluate at features ``eps`` (N, *P) for every stimulus row of ``stimuli`` (S, k)."""
        eps = np.asarray(eps, dtype=float)
        stimuli = np.atleast_2d(np.asarray(stimuli, dtype=float))
        count, point_shape = len(self.features), eps.shape[1:]
        expand = (slice(None),) + (None,) * len(point_shape)
        arguments = [e[None] for e in eps] + [
            stimuli[:, c][expand] for c in range(stimuli.shape[1])
        ]
        shape = (stimuli.shape[0], *point_shape)
        with np.errstate(all="ignore"):
            blocks = self._compiled(*arguments)
        stacked = []
        for block in blocks:
            values = np.stack([np.broadcast_to(v, shape) for v in block])
            stacked.append(
                (
                    values[0],
                    np.moveaxis(values[1 : 1 + count], 0, 1),
                    np.moveaxis(values[1 + count :].reshape(count, count, *shape), (0, 1), (1, 2)),
                )
            )
        (lam1, l1_e, l1_ee), (lam2, l2_e, l2_ee) = stacked
        return Response(lam1, lam2, l1_e, l2_e, l1_ee, l2_ee)


def check_unstretched(material: Material, stimulus: Sequence[float], where: str) -> None:
    """Refuse unless lambda1 = lambda2 = 1 at the flat sheet's stimulus, for any eps."""
    samples = np.array([-1.0, -0.3, 0.0, 0.4, 1.0, 2.0])
    grids = np.meshgrid(*([samples] * len(material.features)), indexing="ij")
    eps = np.stack([g.ravel() for g in grids])
    response = material.response(eps, np.asarray([stimulus], dtype=float))
    for label, values in (("lambda1", response.lambda1), ("lambda2", response.lambda2)):
        if not np.allclose(values, 1.0, rtol=0, atol=1e-12):
            worst = values.flat[np.argmax(abs(values - 1))]
            raise FabkitError(
                f"{where}: {label} must equal 1 at the flat sheet's stimulus {list(stimulus)} "
                f"for every eps (it is {worst:.4g} somewhere): surfaces[0] is the sheet as made"
            )
