"""The process: road and layer settings, and one channel per designable feature.

A :class:`Process` holds the settings every print needs (road width, layer height,
print and travel speed; mm and mm/s) and a tuple of :class:`Encode` s, the channels:
each maps one feature of the design to one process parameter through a measured
:class:`Calibration` (eps against the parameter's value), or two features to two
parameters through a :class:`JointCalibration` (a measured grid of parameter pairs and
the eps pair each gave), for two parameters that each move both features.

A channel names its features by name (``"eps1"``, as in the spec) or by position (an
integer, 0 = the design's first feature: a machine profile meant for any design). It is
*resolved* against a design's feature names (:meth:`Process.channels`); a feature of the
design that no channel encodes is an error naming it, unless it is ignored on purpose.

Encoding (eps -> value) interpolates a calibration table by monotone piecewise-cubic
(PCHIP) interpolation: it never overshoots between measured points and keeps the table's
direction. Decoding (value -> eps: reading a machine file back) inverts that curve
numerically. A joint table is interpolated bilinearly in the parameter pair; its map to
the eps pair is refused unless it is one-to-one (the Jacobian keeps one sign and the
boundary does not fold over), and it is inverted cell by cell with Newton's method.

This module is plain data and numbers, and :func:`parse_process`, which reads the
``[process]`` table of a machine profile (for :mod:`fabkit.machines`) or of a
``--process`` file (for :mod:`fabkit.toolpath.process_file`) into it; the toolpath stage
encodes with it, the writers emit the channels, and ``fabkit verify`` decodes with it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from fabkit.errors import FabkitError
from fabkit.limits import MAGNITUDE
from fabkit.tomlfile import Table

PRINT_PARAMETERS = (
    "print_speed_mm_s",
    "extrusion_multiplier",
    "pressure_kpa",
    "line_spacing_mm",
    "temperature_c",
    "ink_fraction",
)
"""Print-road parameters a channel may encode (the toolpath's and the G-code writer's)."""
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
SETTING_KEYS = ("road_width_mm", "layer_height_mm", "print_speed_mm_s", "travel_speed_mm_s")
DECODE_SAMPLES = 4097
"""Points of the encoding curve sampled to invert it (relative error ~1e-7 of the range)."""

FeatureRef = str | int
"""A feature by name, or by position (0 = the design's first feature)."""


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
                "(extend the table, or set clip = true / --clip-eps)"
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
                    f"({len(missing)} of {len(target)} points); extend the table, or set "
                    "clip = true / --clip-eps"
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


@dataclass(frozen=True)
class Encode:
    """One channel: ``features`` (one, or two for a joint table) to the table's parameters.

    ``features`` are names or positions (see :data:`FeatureRef`) until resolved against a
    design (:meth:`resolve`), names after.
    """

    features: tuple[FeatureRef, ...]
    table: Calibration | JointCalibration

    def __post_init__(self) -> None:
        wanted = 2 if isinstance(self.table, JointCalibration) else 1
        if len(self.features) != wanted:
            raise FabkitError(f"a {self.kind} channel encodes {wanted} feature(s)")
        if len(set(self.features)) != len(self.features):
            raise FabkitError(f"a joint channel needs two different features, got {self.features}")

    @property
    def kind(self) -> str:
        return "joint" if isinstance(self.table, JointCalibration) else "single"

    @property
    def parameters(self) -> tuple[str, ...]:
        if isinstance(self.table, JointCalibration):
            return self.table.parameters
        return (self.table.parameter,)

    @property
    def label(self) -> str:
        """``eps1 -> print_speed_mm_s`` or ``eps1, eps2 -> print_speed_mm_s, pressure_kpa``."""
        names = ", ".join(_ref_text(f) for f in self.features)
        return f"{names} -> {', '.join(self.parameters)}"

    def resolve(self, names: Sequence[str]) -> Encode | None:
        """The channel with feature names of a design with features ``names``; None when
        a feature it refers to is not there."""
        resolved = []
        for ref in self.features:
            if isinstance(ref, int):
                if not 0 <= ref < len(names):
                    return None
                resolved.append(names[ref])
            elif ref in names:
                resolved.append(ref)
            else:
                return None
        return replace(self, features=tuple(resolved))

    def with_clip(self) -> Encode:
        return replace(self, table=replace(self.table, clip=True))

    def encode(self, eps: Mapping[str, np.ndarray], where: str = "") -> Coded:
        """Parameter values from the features' eps (arrays of one shape)."""
        if isinstance(self.table, JointCalibration):
            first, second = (np.asarray(eps[name], dtype=float) for name in self.features)
            coded = self.table.invert(first, second, where)
            return Coded(
                {k: v.reshape(first.shape) for k, v in coded.values.items()},
                coded.clipped_fraction,
            )
        value, fraction = self.table.encode(eps[self.features[0]], where)
        return Coded({self.table.parameter: value}, fraction)

    def decode(self, values: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """eps of each feature from the parameters' values (reading a machine file back)."""
        if isinstance(self.table, JointCalibration):
            first, second, _ = self.table.forward(*(values[p] for p in self.parameters))
            return {self.features[0]: first, self.features[1]: second}
        return {self.features[0]: self.table.decode(values[self.table.parameter])}


def _ref_text(ref: FeatureRef) -> str:
    return f"feature {ref}" if isinstance(ref, int) else str(ref)


@dataclass(frozen=True)
class Resolution:
    """A process's channels resolved against a design's features.

    ``channels`` encode every feature not ignored; ``unused`` are the process's channels
    that refer to no feature of this design; ``ignored`` the features left out on purpose.
    """

    channels: tuple[Encode, ...]
    unused: tuple[Encode, ...]
    ignored: tuple[str, ...]

    @property
    def parameters(self) -> tuple[str, ...]:
        return tuple(p for channel in self.channels for p in channel.parameters)

    def channel_of(self, parameter: str) -> Encode | None:
        for channel in self.channels:
            if parameter in channel.parameters:
                return channel
        return None

    def bounds(self, names: Sequence[str]) -> np.ndarray:
        """(N, 2) the eps range each of the features ``names`` can be encoded in: its
        table's range (a joint table's: the range measured for that feature, a box around
        the measured region), (-inf, inf) for a feature no channel encodes."""
        out = np.tile([-np.inf, np.inf], (len(names), 1))
        for channel in self.channels:
            table = channel.table
            for k, name in enumerate(channel.features):
                if isinstance(table, JointCalibration):
                    measured = np.asarray(table.measured[k], dtype=float)
                    out[names.index(name)] = (np.nanmin(measured), np.nanmax(measured))
                else:
                    out[names.index(name)] = table.eps_range
        return out


@dataclass(frozen=True)
class Process:
    """Road width and layer height (mm), print and travel speed (mm/s), and the channels.

    ``source`` says where it was read (``machine marlin_diw_pneumatic``, a file path).
    """

    road_width_mm: float
    layer_height_mm: float
    print_speed_mm_s: float
    travel_speed_mm_s: float
    encodes: tuple[Encode, ...] = ()
    source: str = ""

    def __post_init__(self) -> None:
        for key in SETTING_KEYS:
            value = getattr(self, key)
            ok = isinstance(value, int | float) and not isinstance(value, bool)
            if not (ok and math.isfinite(value) and value > 0):
                raise FabkitError(f"[process] {key} must be a positive number, got {value!r}")

    def with_overrides(self, **values: float | None) -> Process:
        """A copy with the given (non-None) settings replaced."""
        return replace(self, **{k: v for k, v in values.items() if v is not None})

    def with_clip(self) -> Process:
        """A copy whose every table clips eps to its range instead of refusing."""
        return replace(self, encodes=tuple(e.with_clip() for e in self.encodes))

    def resolve(
        self, features: Sequence[str], ignore: Sequence[str] = (), hint: str = ""
    ) -> Resolution:
        """The channels for a design with ``features``, leaving ``ignore`` out.

        Raises a one-line error for an ignored name that is not a feature, a feature or a
        parameter encoded twice, and a feature no channel encodes (naming every one, and
        ending with ``hint``, e.g. the machines that could).
        """
        features = tuple(features)
        for name in ignore:
            if name not in features:
                known = ", ".join(features) or "none"
                raise FabkitError(
                    f"--ignore-feature {name}: not a feature of the design (features: {known})"
                )
        channels, unused = [], []
        for encode in self.encodes:
            resolved = encode.resolve(features)
            if resolved is None:
                unused.append(encode)
            elif not set(resolved.features) & set(ignore):
                channels.append(resolved)
            elif set(resolved.features) - set(ignore):
                kept = ", ".join(sorted(set(resolved.features) - set(ignore)))
                raise FabkitError(
                    f"{self.source}: the joint channel {resolved.label} cannot encode {kept} "
                    "alone; ignore both features or neither"
                )
        _refuse_twice(channels, self.source)
        encoded = {name for channel in channels for name in channel.features}
        missing = [name for name in features if name not in encoded and name not in ignore]
        if missing:
            raise FabkitError(missing_message(self, missing, channels) + hint)
        return Resolution(tuple(channels), tuple(unused), tuple(ignore))


def missing_message(process: Process, missing: Sequence[str], channels: Sequence[Encode]) -> str:
    """The one-line refusal of a design whose features ``missing`` have no channel."""
    have = "; ".join(c.label for c in channels) or "nothing"
    plural = "s" if len(missing) > 1 else ""
    return (
        f"{process.source or 'the process'} encodes no channel for feature{plural} "
        f"{', '.join(missing)} of the design (it encodes: {have}); add a [[process.encode]] "
        f"table for {'each' if plural else 'it'} (docs/toolpath.md), or pass "
        + " ".join(f"--ignore-feature {name}" for name in missing)
        + " to leave it out"
    )


def _refuse_twice(channels: Sequence[Encode], source: str) -> None:
    """Refuse a feature that two channels encode, or a parameter that two channels set
    (the message names both channels), in the order the channels come."""
    features: dict[str, str] = {}  # name -> label of the channel that has it
    parameters: dict[str, str] = {}
    for channel in channels:
        for names, seen, twice in (
            (channel.features, features, "feature {} is encoded twice"),
            (channel.parameters, parameters, "parameter {} encodes two channels"),
        ):
            for name in names:
                if name in seen:
                    raise FabkitError(
                        f"{source}: {twice.format(name)} ({seen[name]}; {channel.label})"
                    )
                seen[name] = channel.label


# --------------------------------------------------------------------------- reading


def parse_process(t: Table, *, light: bool = True, source: str | None = None) -> Process:
    """The ``[process]`` table ``t`` (settings and channels) of a machine profile or a
    ``--process`` file.

    ``light``: light parameters (LIGHT_PARAMETERS) are allowed (a laser writer's profile,
    or a ``--process`` file); ``source`` names it in messages (default: the file).
    Errors are one line naming the file and the key path (:mod:`fabkit.tomlfile`).
    """
    values = {key: t.number(key, positive=True, bound=MAGNITUDE) for key in SETTING_KEYS}
    parameters = CALIBRATION_PARAMETERS if light else PRINT_PARAMETERS
    encodes = [_encode(t.item("encode", k), parameters) for k in range(t.count("encode"))]
    encodes += [_joint(t.item("joint", k), parameters) for k in range(t.count("joint"))]
    if t.has("calibration"):
        if encodes:
            t.expected(
                "calibration",
                "[[process.encode]] tables only ([process.calibration], one table for the "
                "first feature, cannot be mixed with [[process.encode]] / [[process.joint]])",
                t.get("calibration"),
            )
        encodes.append(_legacy(t.table("calibration"), parameters))
    t.finish()
    return Process(**values, encodes=tuple(encodes), source=source or t.shown)


def _encode(t: Table, parameters: tuple[str, ...]) -> Encode:
    feature = _feature(t, "feature", t.raw("feature", _FEATURE))
    table = _calibration(t, parameters)
    t.finish()
    return Encode((feature,), table)


def _legacy(t: Table, parameters: tuple[str, ...]) -> Encode:
    """``[process.calibration]`` of the one-feature format: the design's first feature."""
    table = _calibration(t, parameters)
    t.finish()
    return Encode((0,), table)


def _calibration(t: Table, parameters: tuple[str, ...]) -> Calibration:
    parameter = t.text("parameter", parameters)
    eps, value = t.numbers("eps", bound=MAGNITUDE), t.numbers("value", bound=MAGNITUDE)
    clip = t.flag("clip", default=False)
    try:
        return Calibration(parameter, eps, value, clip)
    except FabkitError as exc:
        t.fail(str(exc))


_FEATURE = "a feature name or its position (0 = the first)"


def _feature(t: Table, key: str, value: object) -> str | int:
    """A feature by name (a string) or position (an integer >= 0, 0 = the first)."""
    if isinstance(value, str) and value.strip():
        return value
    if isinstance(value, int) and not isinstance(value, bool) and value >= 0:
        return value
    t.expected(key, _FEATURE, value)


def _pair(t: Table, key: str, what: str) -> list:
    value = t.raw(key, f"an array of two {what}")
    if not isinstance(value, list) or len(value) != 2:
        t.expected(key, f"an array of two {what}", value)
    return value


def _joint(t: Table, parameters: tuple[str, ...]) -> Encode:
    features = tuple(
        _feature(t, f"features[{i}]", v) for i, v in enumerate(_pair(t, "features", "features"))
    )
    names = _pair(t, "parameters", "parameters")
    for i, name in enumerate(names):
        if not isinstance(name, str) or name not in parameters:
            t.expected(f"parameters[{i}]", f"one of {', '.join(parameters)}", name)
    table_values = (t.numbers("grid1", bound=MAGNITUDE), t.numbers("grid2", bound=MAGNITUDE))
    measured = (t.matrix("measured1", bound=MAGNITUDE), t.matrix("measured2", bound=MAGNITUDE))
    clip = t.flag("clip", default=False)
    t.finish()
    try:
        return Encode(features, JointCalibration(tuple(names), *table_values, measured, clip))
    except FabkitError as exc:
        t.fail(str(exc))
