"""``fabkit calibrate``: a material table fitted to measured samples (docs/calibrate.md).

Reads the samples CSV (:mod:`fabkit.calibrate.samples`), fits log(lambda1) and
log(lambda2) as monotone cubic B-spline tables (:mod:`fabkit.calibrate.fit`), refuses a
feature acting both ways or neither in the spec check's words, and reports the fit's
residuals and the box the samples cover; with a spec, the spec is validated with the
table in place of its material and the report says where its stimuli and initial eps
lie against the box. The table file is written only when all of that passed.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from fabkit.calibrate.fit import LEVEL, StretchFit, basis, coefficient_counts, fit_stretch
from fabkit.calibrate.samples import STRETCHES, Samples, read_samples
from fabkit.errors import FabkitError
from fabkit.files.atomic import atomic_path
from fabkit.files.tomlfile import Table, read_toml
from fabkit.problem.expr import parse
from fabkit.problem.material_table import DEGREE, TableMaterial
from fabkit.problem.spec import Spec, build_spec

SAMPLES_PER_COEFFICIENT = 2
"""A table needs at least this many samples per coefficient it fits."""
SCATTER = 0.25
"""Without spreads, a stretch whose residual (RMS, log) exceeds this fraction of its
fitted range over the samples is too noisy to fit."""
DIRECTION_WORDS = {1: "increases", -1: "decreases", 0: "constant", None: "both ways"}


@dataclass(frozen=True)
class Residuals:
    """Residuals of one stretch at the samples, measured minus fitted (stretch units):
    ``rms``, ``max`` (absolute), ``spread_rms`` the RMS of residual / given spread (None
    without spreads)."""

    rms: float
    max: float
    spread_rms: float | None


@dataclass(frozen=True)
class Calibration:
    """The fitted table, its fits and residuals per stretch, the report's coverage lines
    and the fit's wall time (s)."""

    material: TableMaterial
    fits: tuple[StretchFit, StretchFit]
    residuals: tuple[Residuals, Residuals]
    samples: int
    coverage: tuple[str, ...]
    seconds: float


def calibrate(
    samples_path: str | Path,
    out: str | Path | None,
    *,
    features: Sequence[str] | None = None,
    stimuli: Sequence[str] | None = None,
    spec_path: str | Path | None = None,
    flat: Sequence[float] | None = None,
) -> Calibration:
    """Fit a table to the samples CSV and write it to ``out`` (None: write nothing).

    The columns' roles come from ``features`` and ``stimuli`` (names), else from the
    ``[material]`` of the spec at ``spec_path``; the flat stimulus (lambda = 1 there) is
    ``flat``, else the spec's surfaces[0] stimulus, else 0 for every stimulus."""
    start = time.perf_counter()
    raw = read_toml(spec_path, "spec") if spec_path is not None else None
    features, stimuli = _roles(features, stimuli, raw, spec_path)
    samples = read_samples(samples_path, features, stimuli)
    flat_stimulus = _flat(flat, raw, spec_path, samples, str(samples_path))
    material, fits, residuals = fit_table(samples, flat_stimulus, str(samples_path))
    coverage = _coverage(material, raw, Path(spec_path)) if raw is not None else ()
    if out is not None:
        write_table(material, fits, residuals, len(samples.points), out)
    elapsed = time.perf_counter() - start
    return Calibration(material, fits, residuals, len(samples.points), coverage, elapsed)


def _roles(
    features: Sequence[str] | None,
    stimuli: Sequence[str] | None,
    raw: dict[str, Any] | None,
    spec_path: str | Path | None,
) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Feature and stimulus names from the options, else the spec's ``[material]``."""
    given = {"features": features, "stimuli": stimuli}
    if raw is not None:
        material = Table(raw, str(spec_path)).table("material")
        for key, names in given.items():
            if key in material:
                from_spec = tuple(material.array(key, 'a list of names, like ["eps"]'))
                if names is not None and tuple(names) != from_spec:
                    raise FabkitError(
                        f"--{key} {','.join(names)} differs from the spec's "
                        f"material.{key} {list(from_spec)}"
                    )
                given[key] = from_spec
    for key, names in given.items():
        if names is None:
            raise FabkitError(
                f"calibrate: which columns are {key}? give --{key} NAMES (comma-separated) "
                "or --spec with a [material] that lists them"
            )
        if len(set(names)) != len(names) or not all(n.isidentifier() for n in names):
            raise FabkitError(f"--{key}: expected distinct names like eps, got {list(names)}")
    if not given["features"]:
        raise FabkitError("--features: at least one designable feature")
    if set(given["features"]) & set(given["stimuli"]):
        raise FabkitError("--stimuli: names that are not features")
    return tuple(given["features"]), tuple(given["stimuli"])


def _flat(
    flat: Sequence[float] | None,
    raw: dict[str, Any] | None,
    spec_path: str | Path | None,
    samples: Samples,
    shown: str,
) -> np.ndarray:
    """The flat sheet's stimulus (k,), inside the samples' stimulus range."""
    count = len(samples.stimuli)
    where = "--flat"
    if flat is None and raw is not None:
        surface = Table(raw, str(spec_path)).item("surfaces", 0)
        values = surface.array("stimulus", f"{count} numbers, one per stimulus")
        where = surface.at("stimulus")
        flat = [parse(v, (), surface.at("stimulus"))() if isinstance(v, str) else v for v in values]
    try:
        value = np.zeros(count) if flat is None else np.asarray(flat, dtype=float)
    except (TypeError, ValueError):
        value = np.array([])
    if value.shape != (count,) or not np.isfinite(value).all():
        raise FabkitError(
            f"{where}: expected {count} value(s), one per stimulus {list(samples.stimuli)}"
        )
    columns = samples.points[:, len(samples.features) :]
    for name, v, column in zip(samples.stimuli, value, columns.T, strict=True):
        if not column.min() <= v <= column.max():
            raise FabkitError(
                f"{shown}: the flat sheet's stimulus {name} = {v:g} is outside the samples' "
                f"range [{column.min():g}, {column.max():g}]: measure samples there (where "
                "lambda1 = lambda2 = 1)"
            )
    return value


def fit_table(
    samples: Samples, flat: np.ndarray, shown: str
) -> tuple[TableMaterial, tuple[StretchFit, StretchFit], tuple[Residuals, Residuals]]:
    """The table fitted to ``samples`` with lambda = 1 at the ``flat`` stimulus (k,),
    classified at the samples' stimuli; refusals name the file as ``shown``."""
    names = samples.features + samples.stimuli
    for name, column in zip(names, samples.points.T, strict=True):
        if np.ptp(column) == 0:
            raise FabkitError(
                f"{shown}: column {name} takes the one value {column[0]:g}: a table needs "
                "samples at 2 values at least"
            )
    n = len(samples.points)
    minimum = SAMPLES_PER_COEFFICIENT * (DEGREE + 1) ** len(names)
    if n < minimum:
        raise FabkitError(
            f"{shown}: too few samples to fit: {n} for a table over {', '.join(names)} "
            f"(at least {minimum}: {SAMPLES_PER_COEFFICIENT} per coefficient of the coarsest)"
        )
    logs = np.log(samples.stretches.T)
    given = np.isfinite(samples.spreads).all(axis=0)
    weights = np.where(given[:, None], samples.stretches.T / samples.spreads.T, 1.0)
    counts = coefficient_counts(samples.points, logs, weights, flat, n // SAMPLES_PER_COEFFICIENT)
    space = basis(samples.points, counts, flat)
    fits, residuals = [], []
    for index, stretch in enumerate(STRETCHES):
        measured, spread = samples.stretches[:, index], samples.spreads[:, index]
        fit = fit_stretch(space, logs[index], weights[index])
        _refuse_unfit(fit, stretch, names, len(samples.features), shown)
        residual = measured - np.exp(fit.fitted)
        spread_rms = _rms(residual / spread) if given[index] else None
        _refuse_noise(fit, logs[index], weights[index], given[index], stretch, shown)
        fits.append(fit)
        residuals.append(Residuals(_rms(residual), float(np.abs(residual).max()), spread_rms))
    material = TableMaterial(
        samples.features, samples.stimuli, tuple(flat), space.knots, *(f.coefficients for f in fits)
    )
    material.classify(_used_stimuli(samples, flat))
    return material, (fits[0], fits[1]), (residuals[0], residuals[1])


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(values**2)))


def _refuse_unfit(
    fit: StretchFit, stretch: str, names: tuple[str, ...], features: int, shown: str
) -> None:
    """Refuse a stretch that rises and falls along a feature beyond the noise."""
    for axis, direction in enumerate(fit.directions[:features]):
        if direction is None:
            raise FabkitError(
                f"{shown}: {stretch} is not monotone in {names[axis]}: it rises and falls "
                "beyond the noise (a monotone table misfits it at the "
                f"{LEVEL:g} level), so no feature value is defined by its stretch"
            )


def _refuse_noise(
    fit: StretchFit, y: np.ndarray, weights: np.ndarray, given: bool, stretch: str, shown: str
) -> None:
    """Refuse a stretch noisier than its stated spread, or (without one) than its effect."""
    residual = y - fit.fitted
    if given:
        chi2 = float(np.sum((weights * residual) ** 2))
        if stats.chi2.sf(chi2, len(y)) < LEVEL**2:
            raise FabkitError(
                f"{shown}: {stretch} scatters about the fit "
                f"{np.sqrt(chi2 / len(y)):.3g} times its stated spread {stretch}_sd (RMS): "
                "noisier than measured, or a law faster than the table's knots follow"
            )
    elif any(fit.directions) and _rms(residual) > SCATTER * np.ptp(fit.fitted):
        raise FabkitError(
            f"{shown}: {stretch} scatters about the fit by {_rms(residual):.3g} (RMS of log "
            f"{stretch}), over {SCATTER:g} of its range {np.ptp(fit.fitted):.3g} over the "
            f"samples: too noisy to fit; give {stretch}_sd if the spread is known"
        )


def _used_stimuli(samples: Samples, flat: np.ndarray) -> np.ndarray:
    """(S, k) the samples' distinct stimuli other than the flat one (at most 64, spread
    over them), at which the table is classified."""
    rows = np.unique(samples.points[:, len(samples.features) :], axis=0)
    rows = rows[np.any(rows != flat, axis=1)]
    return rows[np.linspace(0, len(rows) - 1, min(len(rows), 64)).astype(int)]


def _coverage(material: TableMaterial, raw: dict[str, Any], spec_path: Path) -> tuple[str, ...]:
    """Validate the spec with the table as its material; lines saying where its stimuli
    and its initial eps (along the initial curves, over the grid's reach) lie against the
    table's box."""
    table = dict(raw)
    table["material"] = {
        "features": list(material.features),
        "stimuli": list(material.stimuli),
        "table": material.to_table(),
    }
    spec = build_spec(table, spec_path.resolve().parent, str(spec_path))
    return tuple(_stimulus_lines(spec, material) + _eps_lines(spec, material))


def _stimulus_lines(spec: Spec, material: TableMaterial) -> list[str]:
    box = material.box[len(material.features) :]
    lines = []
    for name, column, (low, high) in zip(material.stimuli, spec.stimuli.T, box, strict=True):
        lines.append(
            f"{name}: the spec's stimuli {column.min():.4g} to {column.max():.4g}, inside the "
            f"samples' [{low:.4g}, {high:.4g}]"
        )
    return lines


def _eps_lines(spec: Spec, material: TableMaterial) -> list[str]:
    reach = spec.solver.step * spec.solver.diagonals
    t = np.linspace(-reach, reach, 401)
    lines = []
    box = material.box[: len(material.features)]
    for name, eps, (low, high) in zip(material.features, spec.initial.eps, box, strict=True):
        values = np.broadcast_to(np.asarray(eps(t), dtype=float), t.shape)
        values = values[np.isfinite(values)]
        outside = np.mean((values < low) | (values > high))
        where = (
            "inside"
            if outside == 0
            else f"{100 * outside:.0f} % of it OUTSIDE (the solver stops where eps leaves it)"
        )
        lines.append(
            f"{name}: the spec's initial {name} {values.min():.4g} to {values.max():.4g} over "
            f"t in [-{reach:g}, {reach:g}], {where} the samples' [{low:.4g}, {high:.4g}]"
        )
    return lines


def write_table(
    material: TableMaterial,
    fits: tuple[StretchFit, StretchFit],
    residuals: tuple[Residuals, Residuals],
    samples: int,
    out: str | Path,
) -> None:
    """Write the table and a ``[fit]`` record to ``out`` (TOML, atomically)."""
    table = material.to_table()
    record: dict[str, Any] = {"samples": samples}
    for stretch, fit, residual in zip(STRETCHES, fits, residuals, strict=True):
        record[stretch] = {
            "rms": residual.rms,
            "max": residual.max,
            **({"rms_over_sd": residual.spread_rms} if residual.spread_rms is not None else {}),
            **{
                name: DIRECTION_WORDS[d]
                for name, d in zip(material.names, fit.directions, strict=True)
            },
        }
    lines = [
        "# A material table written by fabkit calibrate: log(lambda1), log(lambda2) as cubic",
        "# B-splines over the features and stimuli (docs/calibrate.md). Use it in a spec as",
        '# [material] table = "<this file>".',
        *(f"{key} = {_toml(table[key])}" for key in ("features", "stimuli", "flat")),
        "",
        "[knots]",
        *(f"{name} = {_toml(knots)}" for name, knots in table["knots"].items()),
    ]
    for stretch in STRETCHES:
        lines += ["", f"[{stretch}]", f"log = {_toml(table[stretch]['log'])}"]
    lines += ["", "[fit]", f"samples = {samples}"]
    for stretch in STRETCHES:
        items = ", ".join(f"{k} = {_toml(v)}" for k, v in record[stretch].items())
        lines.append(f"{stretch} = {{ {items} }}")
    with atomic_path(out) as path:
        path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def _toml(value: Any) -> str:
    """A TOML value: a string (JSON-quoted), a number (repr), a list of either."""
    if isinstance(value, list):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, str):
        return json.dumps(value)
    return repr(float(value)) if isinstance(value, float) else str(value)


def report_lines(calibration: Calibration) -> list[str]:
    """The report ``fabkit calibrate`` prints: per stretch its direction along every axis
    and its residuals, then the samples' box and (with a spec) the coverage lines."""
    material = calibration.material
    lines = [f"fitted {calibration.samples} samples in {calibration.seconds:.2f} s"]
    for stretch, fit, residual in zip(
        STRETCHES, calibration.fits, calibration.residuals, strict=True
    ):
        trend = ", ".join(
            f"{DIRECTION_WORDS[d]} in {name}" if d != 0 else f"constant in {name}"
            for name, d in zip(material.names, fit.directions, strict=True)
        )
        spread = (
            f", {residual.spread_rms:.3g} x the given spread (RMS)"
            if residual.spread_rms is not None
            else ""
        )
        lines.append(f"{stretch}: {trend}")
        lines.append(
            f"  residuals (measured - table): RMS {residual.rms:.3g}, max {residual.max:.3g}"
            f"{spread}"
        )
    ranges = ", ".join(
        f"{name} [{low:.4g}, {high:.4g}]"
        for name, (low, high) in zip(material.names, material.box, strict=True)
    )
    lines.append(f"the samples cover {ranges}; the table is not defined outside")
    lines += list(calibration.coverage)
    return lines
