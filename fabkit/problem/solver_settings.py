"""The ``[solver]`` table of a spec: the grid's step, diagonals and quadrants, checked.

:func:`read_solver` reads the settings and refuses a grid the solver cannot march (too
fine a step, too long a reach, or more memory than :data:`MAX_SOLVER_BYTES` by
:func:`solver_memory`, estimated before anything is allocated). The spec that holds
them is in :mod:`fabkit.problem.spec`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from types import MappingProxyType
from typing import Any

from fabkit.errors import FabkitError
from fabkit.files.tomlfile import Table

ALL_QUADRANTS = ((1, 1), (-1, 1), (-1, -1), (1, -1))
MAX_SOLVER_BYTES = 4 * 2**30
"""Largest memory the solver's grid may need (bytes, see :func:`solver_memory`)."""
MIN_STEP = 1e-6
"""Smallest grid step (design units): below, rounding dominates the cross derivatives."""
MAX_REACH = 1e6
"""Largest step x diagonals (design units): the grid's reach |u| + |v|."""


@dataclass(frozen=True)
class SolverSettings:
    """Grid step (design units), diagonals per quadrant, quadrants (sign of u, sign of v).

    ``tolerance``: largest accepted error estimate of a solved point (dimensionless, the
    relative Richardson difference of its designed lengths; see docs/solver.md).
    """

    step: float = 0.05
    diagonals: int = 200
    quadrants: tuple[tuple[int, int], ...] = ALL_QUADRANTS
    max_strain: float = 3.0
    extrapolate: bool = True
    tolerance: float = 1e-2


def read_solver(
    t: Table, features: int, labels: Mapping[str, str] = MappingProxyType({})
) -> tuple[SolverSettings, dict[str, Any]]:
    """Solver settings for ``features`` designable features; ``labels`` name the
    command-line options that gave some keys (``{"step": "--step"}``) in the grid's
    bounds (:func:`_check_grid`)."""
    t.check_keys({"step", "diagonals", "quadrants", "max_strain", "extrapolate", "tolerance"})
    defaults = SolverSettings()
    step = t.number("step", positive=True, default=defaults.step)
    diagonals = t.integer("diagonals", default=defaults.diagonals)
    quadrants = _quadrants(t)
    max_strain = t.number("max_strain", positive=True, default=defaults.max_strain)
    extrapolate = t.flag("extrapolate", default=defaults.extrapolate)
    tolerance = t.number("tolerance", positive=True, default=defaults.tolerance)
    settings = SolverSettings(step, diagonals, quadrants, max_strain, extrapolate, tolerance)
    _check_grid(settings, features, {"step": t.at("step"), "diagonals": t.at("diagonals")} | labels)
    normalised = {
        "step": step,
        "diagonals": diagonals,
        "quadrants": [list(q) for q in quadrants],
        "max_strain": max_strain,
        "extrapolate": extrapolate,
        "tolerance": tolerance,
    }
    return settings, normalised


def solver_memory(settings: SolverSettings, features: int) -> int:
    """Bytes the solver needs at most for ``settings`` and N = ``features`` (S = N + 2
    surfaces), estimated before anything is allocated.

    Every point of every diagonal marched is kept until the design is assembled: alpha,
    beta, b, s, eps, p, q (N each), r and n (2 per surface), 12 + 7N floats, with its
    valid flag and failure code (9 bytes). A march of M diagonals holds Q (M + 1)(M + 2) / 2
    points over Q quadrants; the march at h (M = D) and the one at h/2 (M = 2D) always run
    together (their difference is the error estimate). Three designs of (2D + 1)^2 nodes
    (2 + N + 4S floats and a flag each) are budgeted at the end, and assembling a design
    needs the stored r (2S floats per point) twice more. The total, plus 20 % for
    temporaries, was 1.07 to 1.35 times the peak traced by tracemalloc for Fig. 1 and
    Fig. 3 grids of 40 to 160 diagonals whose points are all solved (the worst case; the
    march keeps only the design's variables at solved points, so this errs on the safe
    side).
    """
    n, surfaces, d = features, features + 2, settings.diagonals
    points = len(settings.quadrants) * sum((m + 1) * (m + 2) // 2 for m in (d, 2 * d))
    nodes = (2 * d + 1) ** 2
    stored = points * (8 * (12 + 7 * n) + 9)
    designs = 3 * nodes * (8 * (2 + n + 4 * surfaces) + 1)
    assembling = 8 * 2 * surfaces * (points + 2 * nodes)
    return int(1.2 * (stored + designs + assembling))


def _check_grid(settings: SolverSettings, features: int, labels: Mapping[str, str]) -> None:
    """Refuse a grid the solver cannot march: too fine a step, too long a reach, or more
    memory than :data:`MAX_SOLVER_BYTES` (estimated before anything is allocated)."""
    if settings.step < MIN_STEP:
        raise FabkitError(
            f"{labels['step']} {settings.step:g}: below {MIN_STEP:g}, rounding error swamps "
            "the cross derivatives; give a larger step (design units)"
        )
    if settings.step * settings.diagonals > MAX_REACH:
        raise FabkitError(
            f"{labels['step']} {settings.step:g} x {labels['diagonals']} {settings.diagonals}: "
            f"the grid would reach {settings.step * settings.diagonals:.3g} design units, more "
            f"than {MAX_REACH:g}; give a smaller step or fewer diagonals"
        )
    needed = solver_memory(settings, features)
    if needed > MAX_SOLVER_BYTES:
        most = settings.diagonals
        while most > 1 and solver_memory(replace(settings, diagonals=most), features) > (
            MAX_SOLVER_BYTES
        ):
            most = int(most * 0.95)
        raise FabkitError(
            f"{labels['diagonals']} {settings.diagonals}: the solver would need about "
            f"{needed / 2**30:,.0f} GiB ({len(settings.quadrants)} quadrants, {features} "
            f"feature(s), a second march at half the step), more than the "
            f"{MAX_SOLVER_BYTES / 2**30:g} GiB limit; use at most about {most} diagonals "
            "(and a larger step for the same reach)"
        )


def _quadrants(t: Table) -> tuple[tuple[int, int], ...]:
    value = t.get("quadrants", "all")
    if value == "all":
        return ALL_QUADRANTS
    what = '"all" or a list of distinct quadrants like [[1, 1], [-1, 1]]'
    if not isinstance(value, list) or not value:
        t.expected("quadrants", what, value)
    quadrants = []
    for item in value:
        if (
            not isinstance(item, list)
            or len(item) != 2
            or any(isinstance(s, bool) or s not in (1, -1) for s in item)
        ):
            t.expected("quadrants", what, value)
        quadrants.append((int(item[0]), int(item[1])))
    if len(set(quadrants)) != len(quadrants):
        t.expected("quadrants", what, value)
    return tuple(quadrants)
