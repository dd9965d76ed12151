"""Calibration tables: how a process parameter's value makes eps, and back.

The parameters a table may set (:data:`PARAMETERS`, with their units and labels), and
the two kinds of table: a :class:`Calibration` (measured eps against one parameter's
value) and a :class:`JointCalibration` (a measured grid of two parameters and the eps
pair each gave, for two parameters that each move both features). The channels of a
process that use them are in :mod:`fabkit.process`.

Encoding (eps -> value) interpolates a calibration table by monotone piecewise-cubic
(PCHIP) interpolation: it never overshoots between measured points and keeps the table's
direction. Decoding (value -> eps: reading a machine file back) inverts that curve
numerically. A joint table is interpolated bilinearly in the parameter pair; its map to
the eps pair is refused unless it is one-to-one (the Jacobian keeps one sign and the
boundary does not fold over), and it is inverted cell by cell with Newton's method.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from fabkit.errors import FabkitError

PRINT_PARAMETERS = (
    "print_speed_mm_s",
    "extrusion_multiplier",
    "pressure_kpa",
    "line_spacing_mm",
    "temperature_c",
    "ink_fraction",
)
"""Print-road parameters a channel may encode (the toolpath's and the G-code writer's)."""
CLIP_HINT = (
    "clip eps to it: clip = true in the process file, which fabkit run --process reads, or "
    "fabkit toolpath --clip-eps"
)
"""What an eps outside a table may do instead, with the options of the commands that have
them (the end of both tables' range errors)."""
LIGHT_PARAMETERS = ("dose_mj_cm2", "cure_dose_mj_cm2")
"""Exposure parameters of a light writer: the polarised alignment exposure's dose, and a
second, unpolarised exposure set (a curing or cross-linking dose)."""
CHANNEL_WIDTH = "channel_width_mm"
"""The baromorph channel width (``[baromorph.calibration]``)."""
PARAMETERS = (*PRINT_PARAMETERS, *LIGHT_PARAMETERS, CHANNEL_WIDTH)

UNITS = {
    "print_speed_mm_s": "mm/s",
    "extrusion_multiplier": "",
    "pressure_kpa": "kPa",
    "line_spacing_mm": "mm",
    "temperature_c": "C",
    "ink_fraction": "",
    "dose_mj_cm2": "mJ/cm^2",
    "cure_dose_mj_cm2": "mJ/cm^2",
    CHANNEL_WIDTH: "mm",
}
LABELS = {
    "print_speed_mm_s": "print speed (mm/s)",
    "extrusion_multiplier": "extrusion multiplier",
    "pressure_kpa": "dispense pressure (kPa)",
    "line_spacing_mm": "line spacing (mm)",
    "temperature_c": "nozzle temperature (°C)",
    "ink_fraction": "second-ink fraction",
    "dose_mj_cm2": "alignment dose (mJ/cm²)",
    "cure_dose_mj_cm2": "cure dose (mJ/cm²)",
    CHANNEL_WIDTH: "channel width (mm)",
}
"""Human names with units (pictures, reports)."""
FRACTIONS = ("ink_fraction",)
"""Parameters whose values lie in [0, 1]; every other parameter's values are > 0."""
CALIBRATION_PARAMETERS = PRINT_PARAMETERS + LIGHT_PARAMETERS
"""Parameters a channel of a process may encode (light ones on laser writers only)."""
DECODE_SAMPLES = 4097
"""Points of the encoding curve sampled to invert it (relative error ~1e-7 of the range)."""


@dataclass(frozen=True)
class Coded:
    """Values of the encoded parameters (name -> array) and the fraction of points clipped."""

    values: dict[str, np.ndarray]
    clipped_fraction: float


@dataclass(frozen=True)
class Calibration:
    """Measured eps (strictly increasing) against one parameter's value (strictly monotone).

    ``clip``: eps outside the table is clipped to it (the fraction is reported) instead of
    being an error. Values are > 0, or in [0, 1] for a fraction (:data:`FRACTIONS`).
    """

    parameter: str
    eps: tuple[float, ...]
    value: tuple[float, ...]
    clip: bool = False

    def __post_init__(self) -> None:
        where = f"calibration of {self.parameter}"
        if self.parameter not in PARAMETERS:
            raise FabkitError(f"parameter '{self.parameter}' is not one of {', '.join(PARAMETERS)}")
        eps, value = np.asarray(self.eps, float), np.asarray(self.value, float)
        if eps.ndim != 1 or len(eps) < 2 or eps.shape != value.shape:
            raise FabkitError(f"{where}: eps and value need the same length, at least 2")
        if not (np.isfinite(eps).all() and np.isfinite(value).all()):
            raise FabkitError(f"{where}: eps and value must be finite numbers")
        if np.any(np.diff(eps) <= 0):
            raise FabkitError(f"{where}: eps must be strictly increasing")
        steps = np.diff(value)
        if not (np.all(steps > 0) or np.all(steps < 0)):
            raise FabkitError(f"{where}: value must be strictly increasing or decreasing in eps")
        _check_domain(self.parameter, value, where)

    @property
    def eps_range(self) -> tuple[float, float]:
        return self.eps[0], self.eps[-1]

    @property
    def value_range(self) -> tuple[float, float]:
        return min(self.value), max(self.value)

    @cached_property
    def _curve(self):
        """The PCHIP interpolant of the table (scipy imported here: machine profiles are
        read by every command, most of which never encode)."""
        from scipy.interpolate import PchipInterpolator

        return PchipInterpolator(np.asarray(self.eps), np.asarray(self.value))

    @cached_property
    def _inverse(self) -> tuple[np.ndarray, np.ndarray]:
        """(values increasing, eps) sampled densely along the encoding curve."""
        eps = np.linspace(*self.eps_range, DECODE_SAMPLES)
        value = self._curve(eps)
        order = np.argsort(value)
        return value[order], eps[order]

    def encode(self, eps: np.ndarray, where: str = "") -> tuple[np.ndarray, float]:
        """The value for each eps, and the fraction clipped; eps outside the table is an
        error naming both ranges unless ``clip``."""
        eps = np.asarray(eps, dtype=float)
        if not np.isfinite(eps).all():
            raise FabkitError(f"{where or self.parameter}: eps is not finite everywhere")
        low, high = self.eps_range
        outside = (eps < low) | (eps > high)
        if outside.any() and not self.clip:
            raise FabkitError(
                f"{where + ': ' if where else ''}eps spans [{eps.min():.4g}, {eps.max():.4g}], "
                f"outside the calibrated range [{low:g}, {high:g}] of {self.parameter} "
                f"(extend the table, or {CLIP_HINT})"
            )
        fraction = float(outside.mean()) if eps.size else 0.0
        return self._curve(np.clip(eps, low, high)), fraction

    def decode(self, value: np.ndarray) -> np.ndarray:
        """eps for each value (NaN stays NaN); values outside the table take its end."""
        values, eps = self._inverse
        value = np.asarray(value, dtype=float)
        return np.where(np.isfinite(value), np.interp(value, values, eps), np.nan)


@dataclass(frozen=True)
class JointCalibration:
    """Two parameters that each move two features: a measured grid, inverted numerically.

    ``first`` (n1,) and ``second`` (n2,) are the grids of the two parameters (strictly
    increasing); ``measured`` (2, n1, n2) holds the eps of each feature measured at
    ``(first[i], second[j])``. The map from a parameter pair to the eps pair is bilinear
    in each grid cell; it must be one-to-one (checked on construction).
    """

    parameters: tuple[str, str]
    first: tuple[float, ...]
    second: tuple[float, ...]
    measured: tuple[tuple[tuple[float, ...], ...], tuple[tuple[float, ...], ...]]
    clip: bool = False

    def __post_init__(self) -> None:
        where = f"joint calibration of {' and '.join(self.parameters)}"
        if len(self.parameters) != 2 or self.parameters[0] == self.parameters[1]:
            raise FabkitError(f"{where}: needs two different parameters")
        for name in self.parameters:
            if name not in PARAMETERS:
                raise FabkitError(f"parameter '{name}' is not one of {', '.join(PARAMETERS)}")
        grids = [np.asarray(self.first, float), np.asarray(self.second, float)]
        for name, grid in zip(self.parameters, grids, strict=True):
            if grid.ndim != 1 or len(grid) < 2 or not np.isfinite(grid).all():
                raise FabkitError(f"{where}: the grid of {name} needs at least 2 finite values")
            if np.any(np.diff(grid) <= 0):
                raise FabkitError(f"{where}: the grid of {name} must be strictly increasing")
            _check_domain(name, grid, where)
        measured = np.asarray(self.measured, dtype=float)
        if measured.shape != (2, len(grids[0]), len(grids[1])):
            raise FabkitError(
                f"{where}: each measured eps table needs {len(grids[0])} rows of "
                f"{len(grids[1])} numbers (rows: {self.parameters[0]}, columns: "
                f"{self.parameters[1]})"
            )
        if not np.isfinite(measured).all():
            raise FabkitError(f"{where}: the measured eps must be finite numbers")
        self._check_invertible(where)

    @cached_property
    def _grid(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """first (n1,), second (n2,), eps pairs (n1, n2, 2)."""
        measured = np.moveaxis(np.asarray(self.measured, dtype=float), 0, -1)
        return np.asarray(self.first, float), np.asarray(self.second, float), measured

    def _check_invertible(self, where: str) -> None:
        """Refuse a table whose eps map folds: the Jacobian of a bilinear cell is affine
        in the cell, so its sign at the corners of every cell decides it; then the image
        of the grid's boundary must not cross itself."""
        first, second, eps = self._grid
        d1 = np.diff(eps, axis=0) / np.diff(first)[:, None, None]  # (n1-1, n2, 2)
        d2 = np.diff(eps, axis=1) / np.diff(second)[None, :, None]  # (n1, n2-1, 2)
        corners = []
        for di in (0, 1):
            for dj in (0, 1):
                a = d1[:, dj : dj + d2.shape[1]]  # d/dfirst along the cell's row dj
                b = d2[di : di + d1.shape[0]]  # d/dsecond along the cell's column di
                corners.append(a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0])
        det = np.stack(corners)  # (4, n1-1, n2-1)
        scale = np.abs(det).max()
        sign = np.sign(det.sum()) or 1.0
        folded = np.argwhere((sign * det).min(axis=0) <= 1e-9 * scale)
        if len(folded) or not scale > 0:
            i, j = folded[0] if len(folded) else (0, 0)
            raise FabkitError(
                f"{where} cannot be inverted: two parameter pairs give the same eps pair "
                f"near {self.parameters[0]} = {first[i]:g}, {self.parameters[1]} = "
                f"{second[j]:g} (the map folds there); measure a grid on which every "
                "parameter pair gives its own eps pair"
            )
        import shapely

        ring = np.concatenate([eps[:, 0], eps[-1, 1:], eps[-2::-1, -1], eps[0, -2:0:-1]])
        if not shapely.LinearRing(ring).is_simple:
            raise FabkitError(
                f"{where} cannot be inverted: the eps pairs of the grid's edge cross each "
                "other (the map folds over); measure a grid on which every parameter pair "
                "gives its own eps pair"
            )

    def forward(self, p1: np.ndarray, p2: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """The eps pair (each like ``p1``) at parameter pairs, bilinear; pairs outside the
        grid take its edge; also the fraction outside."""
        first, second, eps = self._grid
        p1, p2 = np.broadcast_arrays(np.asarray(p1, float), np.asarray(p2, float))
        known = np.isfinite(p1) & np.isfinite(p2)
        q1 = np.clip(np.where(known, p1, first[0]), first[0], first[-1])
        q2 = np.clip(np.where(known, p2, second[0]), second[0], second[-1])
        outside = known & ((q1 != p1) | (q2 != p2))
        i = np.clip(np.searchsorted(first, q1, side="right") - 1, 0, len(first) - 2)
        j = np.clip(np.searchsorted(second, q2, side="right") - 1, 0, len(second) - 2)
        s = (q1 - first[i]) / (first[i + 1] - first[i])
        t = (q2 - second[j]) / (second[j + 1] - second[j])
        value = _bilinear(eps, i, j, s, t)
        value = np.where(known[..., None], value, np.nan)
        fraction = float(outside.mean()) if p1.size else 0.0
        return value[..., 0], value[..., 1], fraction

    def invert(self, e1: np.ndarray, e2: np.ndarray, where: str = "") -> Coded:
        """The parameter pair for each eps pair (cell by cell, Newton in the cell).

        An eps pair outside the grid's image is an error naming the first such point,
        unless ``clip``: then it takes the parameters of the nearest measured edge point.
        """
        first, second, eps = self._grid
        e1, e2 = (np.asarray(e, dtype=float).ravel() for e in (e1, e2))
        if not (np.isfinite(e1).all() and np.isfinite(e2).all()):
            raise FabkitError(f"{where or 'joint calibration'}: eps is not finite everywhere")
        target = np.column_stack([e1, e2])
        found = np.zeros(len(target), dtype=bool)
        st = np.zeros((len(target), 2))
        cell = np.zeros((len(target), 2), dtype=int)
        for i in range(len(first) - 1):
            for j in range(len(second) - 1):
                todo = np.flatnonzero(~found)
                if not len(todo):
                    break
                quad = eps[i : i + 2, j : j + 2]
                low, high = quad.reshape(-1, 2).min(0), quad.reshape(-1, 2).max(0)
                box = (target[todo] >= low - 1e-12) & (target[todo] <= high + 1e-12)
                near = todo[box.all(axis=1)]
                if not len(near):
                    continue
                solution, inside = _invert_cell(quad, target[near])
                hit = near[inside]
                st[hit], cell[hit], found[hit] = solution[inside], (i, j), True
        missing = np.flatnonzero(~found)
        clipped = len(missing) / max(len(target), 1)
        if len(missing):
            if not self.clip:
                k = missing[0]
                raise FabkitError(
                    f"{where + ': ' if where else ''}the eps pair ({e1[k]:.4g}, {e2[k]:.4g}) is "
                    f"outside what the joint table of {' and '.join(self.parameters)} can make "
                    f"({len(missing)} of {len(target)} points); extend the table, or " + CLIP_HINT
                )
            st[missing], cell[missing] = self._nearest_edge(target[missing])
        i, j = cell[:, 0], cell[:, 1]
        p1 = first[i] + st[:, 0] * (first[i + 1] - first[i])
        p2 = second[j] + st[:, 1] * (second[j + 1] - second[j])
        return Coded({self.parameters[0]: p1, self.parameters[1]: p2}, clipped)

    def _nearest_edge(self, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For eps pairs outside the image: (s, t) and the cell of the nearest point of the
        image's boundary (sampled finely along the grid's edge)."""
        first, second, eps = self._grid
        samples = np.linspace(0.0, 1.0, 65)
        n1, n2 = len(first) - 1, len(second) - 1
        edges = [(i, 0, s, 0.0) for i in range(n1) for s in samples]
        edges += [(i, n2 - 1, s, 1.0) for i in range(n1) for s in samples]
        edges += [(0, j, 0.0, t) for j in range(n2) for t in samples]
        edges += [(n1 - 1, j, 1.0, t) for j in range(n2) for t in samples]
        table = np.array(edges)
        cells = table[:, :2].astype(int)
        points = _bilinear(eps, cells[:, 0], cells[:, 1], table[:, 2], table[:, 3])
        from scipy.spatial import cKDTree

        _, nearest = cKDTree(points).query(target)
        return table[nearest, 2:], cells[nearest]


def _bilinear(eps: np.ndarray, i, j, s, t) -> np.ndarray:
    """Bilinear interpolation of eps pairs (n1, n2, 2) in cells (i, j) at (s, t) in [0, 1]."""
    s, t = np.asarray(s)[..., None], np.asarray(t)[..., None]
    return (
        (1 - s) * (1 - t) * eps[i, j]
        + s * (1 - t) * eps[i + 1, j]
        + (1 - s) * t * eps[i, j + 1]
        + s * t * eps[i + 1, j + 1]
    )


def _invert_cell(quad: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(s, t) with bilinear(quad; s, t) = target, for (m, 2) targets (Newton from the
    middle; the Jacobian keeps its sign in the cell); and whether each lies in [0, 1]^2."""
    p00, p10, p01, p11 = quad[0, 0], quad[1, 0], quad[0, 1], quad[1, 1]
    st = np.full((len(target), 2), 0.5)
    for _ in range(30):
        s, t = st[:, :1], st[:, 1:]
        value = (1 - s) * (1 - t) * p00 + s * (1 - t) * p10 + (1 - s) * t * p01 + s * t * p11
        ds = (1 - t) * (p10 - p00) + t * (p11 - p01)
        dt = (1 - s) * (p01 - p00) + s * (p11 - p10)
        det = ds[:, 0] * dt[:, 1] - ds[:, 1] * dt[:, 0]
        r = target - value
        step_s = (r[:, 0] * dt[:, 1] - r[:, 1] * dt[:, 0]) / det
        step_t = (ds[:, 0] * r[:, 1] - ds[:, 1] * r[:, 0]) / det
        step = np.column_stack([step_s, step_t])
        st = np.clip(st + step, -0.5, 1.5)
        if np.max(np.abs(step)) < 1e-13:
            break
    inside = np.all((st >= -1e-9) & (st <= 1 + 1e-9), axis=1)
    return np.clip(st, 0.0, 1.0), inside


def _check_domain(parameter: str, values: np.ndarray, where: str) -> None:
    if parameter in FRACTIONS:
        if np.any((values < 0) | (values > 1)):
            raise FabkitError(f"{where}: {parameter} values must lie in [0, 1]")
    elif np.any(values <= 0):
        raise FabkitError(f"{where}: value must hold positive numbers only")
