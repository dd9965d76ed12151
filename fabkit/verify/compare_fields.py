"""The machine file's grid against the design: coverage, director and features, per layer.

:class:`ComparedSheet` lays a read-back grid (:class:`fabkit.verify.raster.Readback`) on
the design's flat sheet: the cells inside its outline, those a road or exposure covers
(``empty``, ``overlap``), and the angle between the read-back director and the design's.
:func:`decode_features` reads every encoded feature back by inverting its channel's
calibration (:meth:`fabkit.process.Encode.decode`), and :func:`feature_errors` measures
|read back - designed| as a percentage of the feature's designed range;
:func:`layer_fields` and :func:`layer_readings` do it for every printed layer of a
layered design. Called by :func:`fabkit.verify.machine_file.verify`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely

from fabkit.design.design import Design
from fabkit.errors import FabkitError
from fabkit.field.design_field import field_from_design
from fabkit.field.flat import FlatField, director_angle
from fabkit.process import Resolution
from fabkit.verify.raster import Readback


@dataclass(frozen=True)
class FeatureError:
    """One feature read back: its channel, RMS and 95th-percentile error as % of its
    designed range, the range, and the cells compared."""

    feature: str
    channel: str
    rms_pct: float
    p95_pct: float
    design_range: float
    cells: int


@dataclass(frozen=True)
class LayerReading:
    """One printed layer (1 = bottom) read back against the design's layer it makes:
    coverage, director error (degrees) and every feature's error."""

    layer: int
    designed_layer: int
    empty_fraction: float
    mean_overlap: float
    director_mean_deg: float
    director_p95_deg: float
    features: tuple[FeatureError, ...]


def layer_fields(design: Design, flat: FlatField, name: str, layers: int) -> list[FlatField]:
    """The designed field of every printed layer (bottom first): a layered design's own
    layers (the file must print as many), else the design's field on every layer."""
    if design.layering is None:
        return [flat] * layers
    if layers != design.layers:
        raise FabkitError(
            f"{name}: a design of {design.layers} layers, but the machine file prints "
            f"{layers}: it was not made from this design"
        )
    return [
        field_from_design(design.layer(k), part=flat.part, name=f"{name} layer {k + 1}")
        for k in range(layers)
    ]


def layer_readings(
    sheets: list[ComparedSheet], readings: list[list[FeatureError]], designed: int
) -> tuple[LayerReading, ...]:
    """Every printed layer's coverage, director and features against its designed layer."""
    return tuple(
        LayerReading(
            layer=k + 1,
            designed_layer=k + 1 if designed > 1 else 1,
            empty_fraction=sheet.empty,
            mean_overlap=sheet.overlap,
            director_mean_deg=sheet.director_mean,
            director_p95_deg=sheet.director_p95,
            features=tuple(reading),
        )
        for k, (sheet, reading) in enumerate(zip(sheets, readings, strict=True))
    )


@dataclass(frozen=True, eq=False)
class ComparedSheet:
    """The read-back grid against the design: cells inside the outline, covered (their
    centres ``points``, mm, and the designed features there), and the coverage and
    director figures."""

    inside: np.ndarray
    covered: np.ndarray
    points: np.ndarray
    designed: dict[str, np.ndarray]
    empty: float
    overlap: float
    director_mean: float
    director_p95: float

    @classmethod
    def of(cls, readback: Readback, flat: FlatField) -> ComparedSheet:
        x, y = readback.centres()
        inside = shapely.contains_xy(flat.outline, x, y)
        if readback.region is not None:
            inside &= readback.region
        if not inside.any():
            raise FabkitError(
                "no cell of the machine file lies on the design's flat sheet: wrong "
                "--offset or --size?"
            )
        covered = inside & (readback.hits > 0)
        points = np.column_stack([x[covered], y[covered]])
        designed, features = flat.sample(points)
        error = np.abs(director_angle(readback.theta[covered] - designed))
        degrees = np.degrees(error) if len(error) else np.array([np.nan])
        hits = readback.hits[covered]
        return cls(
            inside=inside,
            covered=covered,
            points=points,
            designed=features,
            empty=float(1.0 - covered.sum() / inside.sum()),
            overlap=float(np.mean(hits - 1)) if len(hits) else 0.0,
            director_mean=float(np.mean(degrees)),
            director_p95=float(np.percentile(degrees, 95)),
        )


def decode_features(readback: Readback, resolution: Resolution) -> dict[str, np.ndarray]:
    """Every encoded feature read back on the grid (NaN where its values are unknown)."""
    out = {}
    for channel in resolution.channels:
        shape = readback.shape
        values = {p: readback.values.get(p, np.full(shape, np.nan)) for p in channel.parameters}
        out.update(channel.decode(values))
    return out


def feature_errors(
    readback: Readback,
    resolution: Resolution,
    sheet: ComparedSheet,
    design: Design,
    names: tuple[str, ...],
) -> list[FeatureError]:
    """Each encoded feature's error over the covered cells inside the outline."""
    decoded = decode_features(readback, resolution)
    out = []
    for channel in resolution.channels:
        for name in channel.features:
            span = float(np.ptp(design.eps[names.index(name)][design.valid])) or 1.0
            read = decoded[name][sheet.covered]
            known = np.isfinite(read)
            designed = sheet.designed[name][known]
            error = np.abs(read[known] - designed) / span * 100.0
            out.append(
                FeatureError(
                    feature=name,
                    channel=", ".join(channel.parameters),
                    rms_pct=float(np.sqrt(np.mean(error**2))) if len(error) else math.nan,
                    p95_pct=float(np.percentile(error, 95)) if len(error) else math.nan,
                    design_range=span,
                    cells=int(known.sum()),
                )
            )
    return out
