"""A material given as a table (``[material] table = "material.toml"``): log(lambda1) and
log(lambda2) as tensor-product cubic B-splines over every feature and stimulus.

``fabkit calibrate`` writes such a table from measured samples (docs/calibrate.md); a
spec uses it in place of the expressions, and the rest of fabkit sees the same
:class:`fabkit.problem.material.MaterialLaw`. A table file holds::

    features = ["eps"]                    # the axes, features first, then stimuli
    stimuli  = ["L"]
    flat     = [0.0]                      # the stimulus at which the sheet is made
    [knots]                               # clamped cubic knot vector per axis
    eps = [0.0, 0.0, 0.0, 0.0, 0.5, 1.0, 1.0, 1.0, 1.0]
    L   = [...]
    [lambda1]
    log = [...]                           # coefficients of log(lambda1), C order
    [lambda2]
    log = [...]

and, written by ``fabkit calibrate`` for the reader and ignored here, a ``[fit]`` table.
The coefficients array has shape (len(knots[a]) - 4 for every axis a), features first.

The table is C2 in every axis, so the solver's second derivatives by eps exist. Outside
the box its knots span (the samples' range) it is not defined: the stretches and their
derivatives are NaN there, which the solver treats as the end of the material, as it
treats a non-finite geometry as the edge of a surface. A stimulus outside the box is
refused when the spec is read.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from fabkit.errors import FabkitError
from fabkit.files.tomlfile import Table
from fabkit.problem.material import Response, classify, grid_points

DEGREE = 3
"""Cubic B-splines: the table and its first two derivatives are continuous."""
KNOT_LIMIT = 64
"""At most this many knots per axis, and 4096 coefficients per stretch: a table is small."""
GRID = 9
"""Points per feature axis at which :meth:`TableMaterial.acts` looks for an effect."""
TABLE_KEYS = ("features", "stimuli", "flat", "knots", "lambda1", "lambda2")


@dataclass(frozen=True, eq=False)
class TableMaterial:
    """log(lambda1), log(lambda2) as cubic B-splines (see the module docstring).

    ``knots`` holds one clamped knot vector per axis (features, then stimuli); ``log1``
    and ``log2`` are the coefficient arrays, shape (len(knots[a]) - 4 for every axis a).
    ``flat`` (k,) is the stimulus at which the sheet is made (lambda = 1 there).
    """

    features: tuple[str, ...]
    stimuli: tuple[str, ...]
    flat: tuple[float, ...]
    knots: tuple[np.ndarray, ...]
    log1: np.ndarray
    log2: np.ndarray

    @property
    def names(self) -> tuple[str, ...]:
        return self.features + self.stimuli

    @property
    def box(self) -> np.ndarray:
        """(d, 2) the range [low, high] of every axis, features first: where the table is
        defined (the samples' range)."""
        return np.array([[t[0], t[-1]] for t in self.knots])

    def describe(self) -> str:
        """The table in one line, as ``fabkit spec`` prints it."""
        ranges = ", ".join(
            f"{name} in [{low:.4g}, {high:.4g}]"
            for name, (low, high) in zip(self.names, self.box, strict=True)
        )
        shape = " x ".join(str(n) for n in self.log1.shape)
        return f"table of log(lambda1), log(lambda2), cubic B-splines ({shape}) over {ranges}"

    def classify(self, stimuli: np.ndarray) -> tuple[str, ...]:
        """``along``/``across`` per feature at the ``stimuli`` (S, k), in the words of
        :func:`fabkit.problem.material.classify`."""
        self.check_stimuli(stimuli, "material.table")
        return classify(self, stimuli)

    def acts(self, stretch: int, index: int, stimuli: np.ndarray) -> bool:
        """Whether feature ``index`` changes lambda1 (``stretch`` 0) or lambda2 (1) at one
        of the ``stimuli`` (S, k): as for expressions, ``|d lambda / d eps| > 1e-9 (1 +
        |lambda|)`` somewhere on a grid of :data:`GRID` points per feature over the box
        (exactly zero along an axis whose coefficients are constant)."""
        response = self.response(self._grid(GRID), stimuli)
        value = (response.lambda1, response.lambda2)[stretch]
        slope = (response.l1_e, response.l2_e)[stretch][:, index] * value
        return bool(np.any(np.abs(slope) > 1e-9 * (1 + np.abs(value))))

    def check_points(self) -> np.ndarray:
        """(N, M) eps points at which the flat sheet is checked unstretched: a grid of six
        values per feature over the box."""
        return self._grid(6)

    def _grid(self, count: int) -> np.ndarray:
        """(N, count**N) the grid of ``count`` values per feature over the box."""
        return grid_points([np.linspace(a, b, count) for a, b in self.box[: len(self.features)]])

    def check_domain(self, eps: np.ndarray, where: str) -> None:
        """Refuse features ``eps`` (N,) (the design's start) outside the table's box."""
        for name, value, (low, high) in zip(self.features, eps, self.box[: len(eps)], strict=True):
            if not low <= value <= high:
                raise FabkitError(
                    f"{where}: {name} = {value:.6g} at the start point is outside the material "
                    f"table's range [{low:.6g}, {high:.6g}] (the samples'): measure samples there"
                )

    def check_stimuli(self, stimuli: np.ndarray, where: str) -> None:
        """Refuse a stimulus (rows of ``stimuli`` (S, k)) outside the table's box."""
        box = self.box[len(self.features) :]
        for row in np.atleast_2d(np.asarray(stimuli, dtype=float)):
            for name, value, (low, high) in zip(self.stimuli, row, box, strict=True):
                if not low <= value <= high:
                    raise FabkitError(
                        f"{where}: stimulus {name} = {value:.6g} is outside the table's range "
                        f"[{low:.6g}, {high:.6g}] (the samples'): measure samples there"
                    )

    def response(self, eps: np.ndarray, stimuli: np.ndarray) -> Response:
        """Evaluate at features ``eps`` (N, *P) for every stimulus row of ``stimuli`` (S, k)
        (see :class:`fabkit.problem.material.Response`); NaN outside the box."""
        eps = np.asarray(eps, dtype=float)
        stimuli = np.atleast_2d(np.asarray(stimuli, dtype=float))
        count, point_shape = eps.shape[0], eps.shape[1:]
        points = np.empty((stimuli.shape[0], *point_shape, len(self.names)))
        points[..., :count] = np.moveaxis(eps, 0, -1)[None]
        points[..., count:] = stimuli.reshape(stimuli.shape[0], *(1,) * len(point_shape), -1)
        parts = [_jets(spline, points, count) for spline in self._splines]
        (g1, l1_e, l1_ee), (g2, l2_e, l2_ee) = parts
        return Response(np.exp(g1), np.exp(g2), l1_e, l2_e, l1_ee, l2_ee)

    @functools.cached_property
    def _splines(self) -> tuple[Any, Any]:
        from scipy.interpolate import NdBSpline  # here: reading a spec needs no scipy

        return tuple(
            NdBSpline(self.knots, coefficients, DEGREE, extrapolate=False)
            for coefficients in (self.log1, self.log2)
        )

    def to_table(self) -> dict[str, Any]:
        """The table as plain TOML/JSON values (:func:`read_table` reads it back)."""
        return {
            "features": list(self.features),
            "stimuli": list(self.stimuli),
            "flat": [float(v) for v in self.flat],
            "knots": {n: t.tolist() for n, t in zip(self.names, self.knots, strict=True)},
            "lambda1": {"log": self.log1.ravel().tolist()},
            "lambda2": {"log": self.log2.ravel().tolist()},
        }


def _jets(spline: Any, points: np.ndarray, count: int):
    """Value (S, *P), gradient (S, N, *P) and Hessian (S, N, N, *P) by the first ``count``
    axes of a spline at ``points`` (S, *P, d)."""
    flat = points.reshape(-1, points.shape[-1])
    shape = points.shape[:-1]
    dims = points.shape[-1]

    def at(*axes: int) -> np.ndarray:
        nu = np.zeros(dims, dtype=int)
        for axis in axes:
            nu[axis] += 1
        return spline(flat, nu=nu).reshape(shape)

    value = at()
    grad = np.stack([at(i) for i in range(count)], axis=1)
    hess = np.empty((shape[0], count, count, *shape[1:]))
    for i in range(count):
        for j in range(i, count):
            hess[:, i, j] = hess[:, j, i] = at(i, j)
    return value, grad, hess


def read_table(t: Table) -> TableMaterial:
    """A :class:`TableMaterial` from its table ``t`` (the file's top level, or the inline
    table of a normalised spec); one-line errors naming the key."""
    t.check_keys({*TABLE_KEYS, "fit"})
    t.require(TABLE_KEYS, "see docs/calibrate.md for a material table")
    features, stimuli = _axis_names(t, "features"), _axis_names(t, "stimuli")
    if not features:
        t.expected("features", "at least one designable feature", [])
    names = features + stimuli
    if len(set(names)) != len(names):
        t.expected("stimuli", "names that are not features", list(stimuli))
    knots_table = t.table("knots")
    knots_table.check_keys(set(names))
    knots = tuple(_knots(knots_table, name) for name in names)
    shape = tuple(len(k) - DEGREE - 1 for k in knots)
    if math.prod(shape) > KNOT_LIMIT**2:
        t.expected("knots", f"at most {KNOT_LIMIT**2} coefficients per stretch", math.prod(shape))
    logs = []
    for key in ("lambda1", "lambda2"):
        table = t.table(key)
        table.check_keys({"log"})
        values = table.numbers("log", length=math.prod(shape), bound=50.0)
        logs.append(np.array(values).reshape(shape))
    flat = t.numbers("flat", length=len(stimuli))
    material = TableMaterial(features, stimuli, flat, knots, *logs)
    material.check_stimuli(np.array([flat]), t.at("flat"))
    return material


def _axis_names(t: Table, key: str) -> tuple[str, ...]:
    what = 'a list of distinct names, like ["eps"]'
    value = t.array(key, what)
    if not all(isinstance(v, str) and v.isidentifier() for v in value):
        t.expected(key, what, value)
    if len(set(value)) != len(value):
        t.expected(key, what, value)
    return tuple(value)


def _knots(t: Table, name: str) -> np.ndarray:
    """A clamped cubic knot vector: non-decreasing, its first and last 4 knots equal, at
    least 8 and at most :data:`KNOT_LIMIT` knots, the ends apart."""
    what = (
        f"a clamped cubic knot vector: {2 * DEGREE + 2} to {KNOT_LIMIT} non-decreasing "
        f"numbers, the first {DEGREE + 1} equal, the last {DEGREE + 1} equal"
    )
    values = t.array(name, what)
    knots = np.array(t.numbers(name, bound=1e6))
    ends = knots[: DEGREE + 1], knots[-DEGREE - 1 :]
    if (
        not 2 * DEGREE + 2 <= len(values) <= KNOT_LIMIT
        or np.any(np.diff(knots) < 0)
        or np.ptp(ends[0]) != 0
        or np.ptp(ends[1]) != 0
        or not knots[0] < knots[-1]
        or np.any(knots[DEGREE + 1 : -DEGREE - 1] >= knots[-1])
        or np.any(knots[DEGREE + 1 : -DEGREE - 1] <= knots[0])
    ):
        t.expected(name, what, values)
    return knots
