"""Independent verification of a design: isometry and curvature residuals per surface.

Reads only the design file's arrays and rebuilds the surfaces and the material from
its embedded spec; it never calls the solver. For every surface j, with r_u, r_v
finite differences of the solved chart map r_j(u, v): centred five-point stencils, an
off-centre five-point window next to the border of the solved region, centred three points
where nothing else fits:

* length residuals: |sqrt(r_u . g r_u) - alpha lambda1| / (alpha lambda1), and the
  same for r_v against beta lambda2;
* angle residual: |cos| of the angle between r_u and r_v in the metric g;
* curvature residual: |K_designed - K_target(r_j)| / K_scale, where K_designed is the
  Gaussian curvature of the designed metric (alpha lambda1)^2 du^2 + (beta lambda2)^2 dv^2
  (second central differences) and K_scale the problem's curvature scale: the largest
  95th percentile of |K_target| over the target surfaces.

Statistics are over interior points, those whose five-point stencils in u and in v are
all solved (so every derivative is fourth-order accurate there), with alpha, beta >= 0.2.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from fabkit.design.design import Design
from fabkit.problem.spec import Spec

MIN_SCALE = 0.2
"""Points with alpha or beta below this are left out of the statistics."""


@dataclass(frozen=True)
class Tolerances:
    """Pass limits: medians and 95th percentiles of the residuals (dimensionless)."""

    isometry_median: float = 1e-3
    isometry_p95: float = 1e-2
    curvature_median: float = 1e-2


@dataclass(frozen=True)
class Residual:
    """Median and 95th percentile of one residual over the checked points."""

    median: float
    p95: float

    @classmethod
    def of(cls, values: np.ndarray) -> Residual:
        """The statistics of the finite ``values`` (any shape); NaN if there are none."""
        values = values[np.isfinite(values)]
        if values.size == 0:
            return cls(float("nan"), float("nan"))
        return cls(float(np.median(values)), float(np.percentile(values, 95)))


@dataclass(frozen=True)
class SurfaceCheck:
    """Residuals of one surface; ``points`` is the number of points checked."""

    name: str
    points: int
    length_u: Residual
    length_v: Residual
    angle: Residual
    curvature: Residual

    @property
    def isometry(self) -> Residual:
        """The worst of the three isometry residuals, by median and by p95."""
        parts = (self.length_u, self.length_v, self.angle)
        return Residual(max(p.median for p in parts), max(p.p95 for p in parts))

    def passes(self, tolerances: Tolerances) -> bool:
        return (
            self.points > 0
            and self.isometry.median <= tolerances.isometry_median
            and self.isometry.p95 <= tolerances.isometry_p95
            and self.curvature.median <= tolerances.curvature_median
        )


@dataclass(frozen=True)
class CheckReport:
    """The check of a design: one :class:`SurfaceCheck` per target, in the spec's order
    (dimensionless residuals: median and 95th percentile), and the ``tolerances`` they are
    held to; ``passed`` when every target passes, ``table()`` as text."""

    surfaces: tuple[SurfaceCheck, ...]
    tolerances: Tolerances

    @property
    def passed(self) -> bool:
        return all(s.passes(self.tolerances) for s in self.surfaces)

    def to_dict(self) -> dict:
        return {
            "passed": self.passed,
            "tolerances": asdict(self.tolerances),
            "surfaces": [
                {"name": s.name, "checked_points": s.points}
                | {k: v for k, v in asdict(s).items() if k not in ("name", "points")}
                | {"passed": s.passes(self.tolerances)}
                for s in self.surfaces
            ],
        }

    def table(self) -> str:
        """A plain-text table, one line per surface."""
        lines = [
            f"{'surface':<12}{'checked':>8}  {'length_u':>18}{'length_v':>18}{'angle':>18}"
            f"{'curvature':>18}  result",
            f"{'':<12}{'':>8}  {'(median / p95)':>18}",
        ]
        for s in self.surfaces:
            cells = "".join(
                f"{r.median:>9.2e}/{r.p95:<8.1e}"
                for r in (s.length_u, s.length_v, s.angle, s.curvature)
            )
            verdict = "ok" if s.passes(self.tolerances) else "FAIL"
            lines.append(f"{s.name:<12}{s.points:>8}  {cells}  {verdict}")
        return "\n".join(lines)


RESIDUALS = ("length_u", "length_v", "angle", "curvature")
RESIDUAL_TITLES = {
    "length_u": "length along u",
    "length_v": "length along v",
    "angle": "angle (|cos| in the metric)",
    "curvature": "curvature (|K - K target| / K scale)",
}
"""Each residual in words (the pictures' titles, the report's columns)."""


@dataclass(frozen=True)
class ResidualMaps:
    """Per-point residuals of one surface on the design grid, NaN off the checked points.

    Each array has the grid's shape (nu, nv); keys as in :data:`RESIDUALS`.
    """

    name: str
    maps: dict[str, np.ndarray]


def residual_maps(
    design: Design, region: float | None = None, spec: Spec | None = None
) -> tuple[ResidualMaps, ...]:
    """Residual maps of every surface of ``design``.

    ``region``: only points with |u|, |v| <= region are checked (None: all interior points).
    ``spec``: the design's spec when the caller has it (else the design's own,
    :attr:`Design.problem`).
    """
    spec = design.problem if spec is None else spec
    interior = _interior(design, region)
    eps = np.where(design.valid, design.eps, 0.0)
    response = spec.material.response(eps, design.stimuli)
    scale = _curvature_scale(spec, design, interior)
    out = []
    for j, target in enumerate(spec.targets):
        stretch_u = design.alpha * response.lambda1[j]
        stretch_v = design.beta * response.lambda2[j]
        values = _surface_residuals(
            target.surface, design.r[j], stretch_u, stretch_v, design.step, interior, scale
        )
        maps = {}
        for key, value in zip(RESIDUALS, values, strict=True):
            full = np.full(interior.shape, np.nan)
            full[interior] = value
            maps[key] = full
        out.append(ResidualMaps(target.name, maps))
    return tuple(out)


def check_design(
    design: Design,
    tolerances: Tolerances = Tolerances(),
    region: float | None = None,
    spec: Spec | None = None,
) -> CheckReport:
    """Median and 95th percentile of every residual of every surface of ``design``
    (``spec``: the design's spec when the caller has it, else the design's own).

    The residuals are dimensionless (module docstring): relative length errors along u
    and v, the |cos| of the angle between them, the curvature error relative to the
    targets' curvature scale; ``region`` (design units) keeps the points with |u|, |v| <=
    region. Returns a :class:`CheckReport`, one :class:`SurfaceCheck` per target."""
    return check_maps(residual_maps(design, region, spec), tolerances)


def check_maps(
    maps: tuple[ResidualMaps, ...], tolerances: Tolerances = Tolerances()
) -> CheckReport:
    """The check of residual maps computed already (:func:`residual_maps`): their medians
    and 95th percentiles against ``tolerances``."""
    surfaces = []
    for surface in maps:
        points = int(np.isfinite(surface.maps["length_u"]).sum())
        stats = (Residual.of(surface.maps[key]) for key in RESIDUALS)
        surfaces.append(SurfaceCheck(surface.name, points, *stats))
    return CheckReport(tuple(surfaces), tolerances)


def _interior(design: Design, region: float | None) -> np.ndarray:
    """Points whose five-point stencils in u and in v are all solved, alpha, beta >= 0.2."""
    valid = design.valid
    inner = valid.copy()
    for axis in (0, 1):
        for shift in (-2, -1, 1, 2):
            inner &= np.isfinite(_shifted(np.where(valid, 1.0, np.nan), axis, shift))
    with np.errstate(invalid="ignore"):
        inner &= (design.alpha >= MIN_SCALE) & (design.beta >= MIN_SCALE)
    if region is not None:
        u, v = np.meshgrid(design.u, design.v, indexing="ij")
        inner &= (np.abs(u) <= region + 1e-12) & (np.abs(v) <= region + 1e-12)
    return inner


def _curvature_scale(spec: Spec, design: Design, interior: np.ndarray) -> float:
    scales = [
        np.percentile(np.abs(t.surface.curvature(design.r[j][interior])), 95)
        for j, t in enumerate(spec.targets)
        if interior.any()
    ]
    return float(max(scales, default=1.0)) or 1.0


def _shifted(field: np.ndarray, axis: int, shift: int) -> np.ndarray:
    """field[i + shift] along axis, NaN where that index falls off the grid."""
    out = np.full_like(field, np.nan)
    count = field.shape[axis]
    source = [slice(None)] * field.ndim
    target = [slice(None)] * field.ndim
    source[axis] = slice(max(shift, 0), count + min(shift, 0))
    target[axis] = slice(max(-shift, 0), count + min(-shift, 0))
    out[tuple(target)] = field[tuple(source)]
    return out


WINDOWS = ((-2, -1, 0, 1, 2), (-1, 0, 1, 2, 3), (-3, -2, -1, 0, 1), (-1, 0, 1))
"""Stencils tried in turn: centred five points, the two nearest off-centre five-point
windows (next to the border of the solved region), then centred three points."""


def _weights(offsets: tuple[int, ...], order: int) -> np.ndarray:
    """Finite-difference weights for the ``order``-th derivative on integer ``offsets``."""
    powers = np.vander(np.array(offsets, dtype=float), increasing=True).T
    target = np.zeros(len(offsets))
    target[order] = float(np.prod(np.arange(1, order + 1)))
    return np.linalg.solve(powers, target)


def _derivative(field: np.ndarray, axis: int, step: float, order: int) -> np.ndarray:
    """``order``-th derivative along ``axis`` from the best stencil whose points are solved.

    Fourth-order accurate (third for second derivatives off-centre) where five points
    are available, second order with three; NaN where not even three are.
    """
    out = np.full(field.shape, np.nan)
    for offsets in WINDOWS:
        weights = _weights(offsets, order)
        total = sum(w * _shifted(field, axis, k) for w, k in zip(weights, offsets, strict=True))
        out = np.where(np.isnan(out) & np.isfinite(total), total / step**order, out)
    return out


def _central(field: np.ndarray, axis: int, step: float) -> np.ndarray:
    return _derivative(field, axis, step, 1)


def _second(field: np.ndarray, axis: int, step: float) -> np.ndarray:
    return _derivative(field, axis, step, 2)


def designed_curvature(stretch_u: np.ndarray, stretch_v: np.ndarray, step: float) -> np.ndarray:
    """K of the metric A^2 du^2 + B^2 dv^2 on the grid: -(1/AB)[(B_u/A)_u + (A_v/B)_v]."""
    a, b = stretch_u, stretch_v
    a_v, a_vv = _central(a, 1, step), _second(a, 1, step)
    b_u, b_uu = _central(b, 0, step), _second(b, 0, step)
    a_u, b_v = _central(a, 0, step), _central(b, 1, step)
    return -((b_uu * a - b_u * a_u) / a**2 + (a_vv * b - a_v * b_v) / b**2) / (a * b)


def _surface_residuals(surface, r, stretch_u, stretch_v, step, interior, scale):
    """The four residuals at the interior points, as 1D arrays in RESIDUALS order."""
    with np.errstate(all="ignore"):
        r_u, r_v = _central(r, 0, step), _central(r, 1, step)
        points = r[interior]
        g = surface.metric(points)
        ru, rv = r_u[interior], r_v[interior]
        length_u = np.sqrt(np.einsum("...i,...ij,...j->...", ru, g, ru))
        length_v = np.sqrt(np.einsum("...i,...ij,...j->...", rv, g, rv))
        cross = np.einsum("...i,...ij,...j->...", ru, g, rv)
        su, sv = stretch_u[interior], stretch_v[interior]
        k_designed = designed_curvature(stretch_u, stretch_v, step)[interior]
        k_target = surface.curvature(points)
        return (
            np.abs(length_u - su) / su,
            np.abs(length_v - sv) / sv,
            np.abs(cross) / (length_u * length_v),
            np.abs(k_designed - k_target) / scale,
        )
