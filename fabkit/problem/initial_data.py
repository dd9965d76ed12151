"""The ``[initial]`` table of a spec: the Goursat data on the flat sheet, checked.

:func:`read_initial` reads the initial curves, eps and slopes as expressions in t and
refuses values that are not finite at the start; :func:`check_curves` finds the start
point and the flat sheet's director where the curves meet (perpendicular, the v-curve
counter-clockwise from the u-curve). The spec that holds them is in
:mod:`fabkit.problem.spec`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from fabkit.errors import FabkitError
from fabkit.files.tomlfile import Table
from fabkit.problem.expr import Expression, parse, shorten
from fabkit.problem.material import ALONG, MaterialLaw

PERPENDICULAR_TOLERANCE = 1e-6
"""Largest |cos| between the initial curves' tangents at t = 0 accepted as perpendicular."""


@dataclass(frozen=True)
class InitialData:
    """The Goursat data: curves on the flat sheet (parameter t) and eps with its slope.

    ``eps[i]`` and ``slope[i]`` are functions of t along the u-curve for a feature acting
    along the director (slope = q) and along the v-curve for one acting across (slope = p).
    """

    u_curve: tuple[Expression, Expression]
    v_curve: tuple[Expression, Expression]
    eps: tuple[Expression, ...]
    slope: tuple[Expression, ...]


def read_initial(
    t: Table,
    material: MaterialLaw,
    classes: tuple[str, ...],
    parameters: Mapping[str, float],
):
    t.check_keys({"u_curve", "v_curve", "eps", "slope"})
    count = len(material.features)
    curves = []
    for key in ("u_curve", "v_curve"):
        what = 'two expressions in t, like ["t", "0"]'
        value = t.array(key, what)
        if len(value) != 2:
            t.expected(key, what, value)
        curves.append(tuple(parse(v, ("t",), t.at(key), parameters) for v in value))
    series = []
    for key in ("eps", "slope"):
        what = f"{count} expression(s) in t, one per feature {list(material.features)}"
        value = t.array(key, what)
        if len(value) != count:
            t.expected(key, what, value)
        series.append(
            tuple(parse(v, ("t",), t.at(f"{key}[{i}]"), parameters) for i, v in enumerate(value))
        )
    initial = InitialData(curves[0], curves[1], series[0], series[1])
    normalised = {
        "u_curve": [e.text for e in initial.u_curve],
        "v_curve": [e.text for e in initial.v_curve],
        "eps": [e.text for e in initial.eps],
        "slope": [e.text for e in initial.slope],
    }
    _check_finite_initial(initial, classes, t)
    return initial, normalised


def _check_finite_initial(initial: InitialData, classes: tuple[str, ...], t: Table) -> None:
    """eps, its derivative along its curve and the slope must be finite at t = 0."""
    for i, kind in enumerate(classes):
        carrier = "u_curve" if kind == ALONG else "v_curve"
        checks = (("eps", initial.eps[i], 1), ("slope", initial.slope[i], 0))
        for label, expression, order in checks:
            value, grad, _ = expression.jets(0.0, wrt=("t",), order=order)
            if not np.isfinite(value) or (order and not np.isfinite(grad[0])):
                what = "it or its derivative is" if order else "it is"
                t.fail(
                    f"not finite at t = 0 on the {carrier} ({what} not finite: "
                    f"'{shorten(expression.text)}')",
                    f"{label}[{i}]",
                )


def check_curves(initial: InitialData, where: str) -> tuple[np.ndarray, np.ndarray]:
    """The common start point and the flat-sheet director (unit u-curve tangent) at t = 0;
    ``where`` is the ``[initial]`` table (``FILE: initial``)."""
    for key in ("u_curve", "v_curve"):
        for expression in getattr(initial, key):
            if not all(np.all(np.isfinite(p)) for p in expression.jets(0.0, wrt=("t",))):
                raise FabkitError(
                    f"{where}.{key}: not finite at t = 0: '{shorten(expression.text)}' or its "
                    "first or second derivative (the curve, its tangent or its curvature)"
                )
    u_point = np.array([c(0.0) for c in initial.u_curve])
    v_point = np.array([c(0.0) for c in initial.v_curve])
    u_tangent = np.array([c.diff("t")(0.0) for c in initial.u_curve])
    v_tangent = np.array([c.diff("t")(0.0) for c in initial.v_curve])
    if np.linalg.norm(u_point - v_point) > 1e-9 * (1 + np.linalg.norm(u_point)):
        raise FabkitError(
            f"{where}: the u-curve starts at {u_point.tolist()} but the v-curve at "
            f"{v_point.tolist()}; they must meet at t = 0"
        )
    u_speed, v_speed = np.linalg.norm(u_tangent), np.linalg.norm(v_tangent)
    if not (u_speed > 0 and v_speed > 0):
        raise FabkitError(f"{where}: the u- and v-curves need non-zero tangents at t = 0")
    cosine = float(u_tangent @ v_tangent) / (u_speed * v_speed)
    if abs(cosine) > PERPENDICULAR_TOLERANCE:
        raise FabkitError(
            f"{where}: the u- and v-curves must be perpendicular at t = 0 (cos = {cosine:.3g})"
        )
    cross = u_tangent[0] * v_tangent[1] - u_tangent[1] * v_tangent[0]
    if cross < 0:
        raise FabkitError(
            f"{where}: the v-curve must leave the start point 90 degrees counter-clockwise from "
            "the u-curve (reverse the v-curve's parameter)"
        )
    return u_point, u_tangent / u_speed
