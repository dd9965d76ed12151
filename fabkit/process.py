"""The process: road and layer settings, and one channel per designable feature.

A :class:`Process` holds the settings every print needs (road width, layer height,
print and travel speed; mm and mm/s) and a tuple of :class:`Encode` s, the channels:
each maps one feature of the design to one process parameter through a measured
:class:`~fabkit.calibration.Calibration` (eps against the parameter's value), or two
features to two parameters through a :class:`~fabkit.calibration.JointCalibration` (a
measured grid of parameter pairs and the eps pair each gave), for two parameters that
each move both features. The tables, and the parameters they may set, are in
:mod:`fabkit.calibration`.

A channel names its features by name (``"eps1"``, as in the spec) or by position (an
integer, 0 = the design's first feature: a machine profile meant for any design). It is
*resolved* against a design's feature names (:meth:`Process.channels`); a feature of the
design that no channel encodes is an error naming it, unless it is ignored on purpose.

This module is plain data and numbers, and :func:`parse_process`, which reads the
``[process]`` table of a machine profile (for :mod:`fabkit.machines`) or of a
``--process`` file (for :mod:`fabkit.toolpath.process_file`) into it; the toolpath stage
encodes with it, the writers emit the channels, and ``fabkit verify`` decodes with it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from fabkit.calibration import (
    CALIBRATION_PARAMETERS,
    PRINT_PARAMETERS,
    Calibration,
    Coded,
    JointCalibration,
)
from fabkit.errors import FabkitError
from fabkit.files.tomlfile import Table
from fabkit.limits import MAGNITUDE

SETTING_KEYS = ("road_width_mm", "layer_height_mm", "print_speed_mm_s", "travel_speed_mm_s")

FeatureRef = str | int
"""A feature by name, or by position (0 = the design's first feature)."""


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
    Errors are one line naming the file and the key path (:mod:`fabkit.files.tomlfile`).
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
