"""Material response: stretches lambda1 (along n) and lambda2 (across n) of eps and Lambda.

Each designable feature eps_i acts either **along** the director (it changes
lambda1 at some given stimulus) or **across** it (it changes lambda2); a feature
that does both makes the design equations non-hyperbolic and is refused, as is one
that does neither (:func:`classify`).

A material is given as expressions (:class:`Material`) or as a table fitted to measured
samples (:class:`fabkit.problem.material_table.TableMaterial`, ``fabkit calibrate``);
both are a :class:`MaterialLaw`, all the rest of fabkit asks of a material.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from fabkit.errors import FabkitError
from fabkit.problem.expr import Expression

ALONG = "along"
ACROSS = "across"
CLASSIFY_SAMPLES = 64
"""Random eps points (beside 13 round ones) at which a feature's effect is tested."""


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

    def describe(self) -> str:
        """The law in one line, as ``fabkit spec`` prints it."""
        return f"lambda1 = {self.lambda1.text}, lambda2 = {self.lambda2.text}"

    def check_points(self) -> np.ndarray:
        """(N, M) eps points at which :func:`check_unstretched` evaluates the law: a grid
        of six values from -1 to 2 per feature."""
        return grid_points([np.array([-1.0, -0.3, 0.0, 0.4, 1.0, 2.0])] * len(self.features))

    def check_domain(self, eps: np.ndarray, where: str) -> None:
        """Nothing to refuse: expressions have no range of their own (a value where they
        are not finite is refused or stops the solver where it is met)."""

    def classify(self, stimuli: np.ndarray) -> tuple[str, ...]:
        """``along``/``across`` per feature at the ``stimuli`` (S, k): see :func:`classify`."""
        return classify(self, stimuli)

    def acts(self, stretch: int, index: int, stimuli: np.ndarray) -> bool:
        """Whether feature ``index`` changes lambda1 (``stretch`` 0) or lambda2 (1)."""
        return self._acts((self.lambda1, self.lambda2)[stretch], index, stimuli)

    def _acts(self, stretch: Expression, index: int, stimuli: np.ndarray) -> bool:
        """Whether d stretch / d eps_index is not zero at one of the ``stimuli`` (S, k).

        Exactly zero when eps_index does not occur in the expression; otherwise the
        derivative (exact, by automatic differentiation) is evaluated at
        :data:`CLASSIFY_SAMPLES` eps points for every stimulus and counts as zero where
        ``|d stretch / d eps| <= 1e-9 (1 + |stretch|)`` at every finite sample. No computer
        algebra runs: ``simplify`` on a law like ``(1 + L*eps)**1000`` took minutes.
        """
        if not stretch.depends_on(self.features[index]):
            return False
        eps = _classify_samples(len(self.features))  # (N, M)
        stimuli = np.atleast_2d(np.asarray(stimuli, dtype=float))
        arguments = [e[None, :] for e in eps] + [s[:, None] for s in stimuli.T]
        value, grad, _ = stretch.jets(*arguments, wrt=(self.features[index],), order=1)
        finite = np.isfinite(value) & np.isfinite(grad[0])
        if not finite.any():
            raise FabkitError(
                f"{stretch.where}: not finite at any of {eps.shape[1]} sample values of "
                f"{', '.join(self.features)} in [-2, 2] at the target stimuli"
            )
        return bool(np.any(np.abs(grad[0][finite]) > 1e-9 * (1 + np.abs(value[finite]))))

    def response(self, eps: np.ndarray, stimuli: np.ndarray) -> Response:
        """Evaluate at features ``eps`` (N, *P) for every stimulus row of ``stimuli`` (S, k).

        lambda by evaluation, the log-derivatives from its exact gradient and Hessian:
        (log lambda)' = lambda' / lambda and
        (log lambda)'' = lambda'' / lambda - lambda' lambda'^T / lambda^2.
        """
        eps = np.asarray(eps, dtype=float)
        stimuli = np.atleast_2d(np.asarray(stimuli, dtype=float))
        point_shape = eps.shape[1:]
        expand = (slice(None),) + (None,) * len(point_shape)
        arguments = [e[None] for e in eps] + [
            stimuli[:, c][expand] for c in range(stimuli.shape[1])
        ]
        logs = []
        with np.errstate(all="ignore"):
            for stretch in (self.lambda1, self.lambda2):
                value, grad, hess = stretch.jets(*arguments, wrt=self.features)
                log_grad = grad / value
                log_hess = hess / value - log_grad[:, None] * log_grad[None, :]
                logs.append(
                    (value, np.moveaxis(log_grad, 0, 1), np.moveaxis(log_hess, (0, 1), (1, 2)))
                )
        (lam1, l1_e, l1_ee), (lam2, l2_e, l2_ee) = logs
        return Response(lam1, lam2, l1_e, l2_e, l1_ee, l2_ee)


class MaterialLaw(Protocol):
    """What the rest of fabkit asks of a material: its names, its response, and whether a
    feature acts on a stretch. :class:`Material` (expressions) and
    :class:`fabkit.problem.material_table.TableMaterial` (a fitted table) are both one."""

    features: tuple[str, ...]
    stimuli: tuple[str, ...]

    @property
    def names(self) -> tuple[str, ...]: ...

    def classify(self, stimuli: np.ndarray) -> tuple[str, ...]: ...

    def acts(self, stretch: int, index: int, stimuli: np.ndarray) -> bool: ...

    def response(self, eps: np.ndarray, stimuli: np.ndarray) -> Response: ...

    def describe(self) -> str: ...

    def check_points(self) -> np.ndarray: ...

    def check_domain(self, eps: np.ndarray, where: str) -> None: ...


def classify(material: MaterialLaw, stimuli: np.ndarray) -> tuple[str, ...]:
    """``along``/``across`` per feature of ``material``, from whether it changes lambda1 or
    lambda2 at one of the ``stimuli`` (S, k) at which the sheet is used
    (``material.acts``). Raises :class:`FabkitError` for a feature acting both ways or
    neither: the words every material (expressions, table, ``fabkit calibrate``) refuses it
    with."""
    classes = []
    for index, feature in enumerate(material.features):
        along = material.acts(0, index, stimuli)
        across = material.acts(1, index, stimuli)
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


def grid_points(axes: Sequence[np.ndarray]) -> np.ndarray:
    """(len(axes), M) the points of the grid of the values ``axes`` (one array per axis)."""
    return np.stack([g.ravel() for g in np.meshgrid(*axes, indexing="ij")])


def _classify_samples(count: int) -> np.ndarray:
    """(count, M) eps sample points for :meth:`Material._acts`: round values from -2 to 2
    on every axis, plus seeded random points in [-2, 2]^count."""
    axis = np.array([0.0, 0.01, -0.01, 0.1, -0.1, 0.3, -0.3, 0.5, -0.5, 1.0, -1.0, 2.0, -2.0])
    rounded = np.repeat(axis[None, :], count, axis=0)
    scattered = np.random.default_rng(0).uniform(-2.0, 2.0, (count, CLASSIFY_SAMPLES))
    return np.concatenate([rounded, scattered], axis=1)


def check_unstretched(material: MaterialLaw, stimulus: Sequence[float], where: str) -> None:
    """Refuse unless lambda1 = lambda2 = 1 at the flat sheet's stimulus, for any eps."""
    response = material.response(material.check_points(), np.asarray([stimulus], dtype=float))
    for label, values in (("lambda1", response.lambda1), ("lambda2", response.lambda2)):
        if not np.allclose(values, 1.0, rtol=0, atol=1e-12):
            worst = values.flat[np.argmax(abs(values - 1))]
            raise FabkitError(
                f"{where}: {label} must equal 1 at the flat sheet's stimulus "
                f"{[float(s) for s in stimulus]} "
                f"for every eps (it is {worst:.4g} somewhere): surfaces[0] is the sheet as made"
            )
