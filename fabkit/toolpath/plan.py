"""From flat-sheet fields and process settings to a layered :class:`Toolpath`.

Layers are split into equal consecutive blocks, one per field (a bilayer of two fields:
the swimmer's radial bottom and azimuthal top). Within a block every layer repeats the
field's lines (``pattern = "same"``) or alternates them with the staggered set halfway
between (``"alternate"``: stripe phase pi, and the print order reversed). Layer k is
printed at z = (k + 1) * layer height.

If the process has a calibration and the field has eps, eps is encoded on every vertex:
``print_speed_mm_s`` sets the speed, ``extrusion_multiplier`` the flow,
``temperature_c`` only the value (the writer sets the heater), and ``line_spacing_mm``
the spacing of the lines themselves (through the stripe wavenumber).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from fabkit.errors import FabkitError
from fabkit.fields import FlatField
from fabkit.toolpath.lines import LineSettings, print_lines
from fabkit.toolpath.model import PRINT, TRAVEL, Layer, Move, Toolpath
from fabkit.toolpath.order import order_lines, travel_length
from fabkit.toolpath.process import Calibration, Process, encode_eps
from fabkit.toolpath.quality import Quality, measure_quality

PATTERNS = ("same", "alternate")


@dataclass(frozen=True)
class PlanSettings:
    """Number of layers, layer pattern, whether to encode eps, and the line settings."""

    layers: int = 1
    pattern: str = "same"
    encode: bool = True
    lines: LineSettings = field(default_factory=LineSettings)


@dataclass(frozen=True)
class Plan:
    """The toolpath, the quality of each layer, and warnings for the user (one line each)."""

    toolpath: Toolpath
    quality: tuple[Quality, ...]
    warnings: tuple[str, ...]


def plan_toolpath(
    fields: list[FlatField], process: Process, settings: PlanSettings = PlanSettings()
) -> Plan:
    """Print lines, order, layers, encoding and quality for ``fields`` (bottom first)."""
    _check(fields, settings)
    w = process.road_width_mm
    per_field = settings.layers // len(fields)
    phases = (0.0, np.pi) if settings.pattern == "alternate" and per_field > 1 else (0.0,)
    layers, qualities, warnings = [], [], []
    position = np.zeros(2)
    for flat in fields:
        encoding = _encoding(flat, process, settings)
        spacing = _spacing(flat, encoding)
        line_sets = print_lines(flat, w, spacing, settings.lines, phases)
        for repeat in range(per_field):
            variant = repeat % len(phases)
            lines = order_lines(line_sets[variant], position)
            if variant:
                lines = [line[::-1] for line in lines[::-1]]
            if not lines:
                raise FabkitError(f"{flat.source}: no print line fits (domain narrower than w?)")
            z = (len(layers) + 1) * process.layer_height_mm
            moves, clipped = _moves(lines, flat, process, encoding, z)
            if clipped:
                warnings.append(f"{flat.source}: eps clipped to the calibration on {clipped:.1%}")
            layers.append(Layer(z, process.layer_height_mm, tuple(moves)))
            position = lines[-1][-1]
            travel = travel_length(lines)
            if repeat < len(phases):
                widths = [m.width for m in moves if m.kind == PRINT]
                qualities.append(measure_quality(lines, widths, flat, w, travel))
            else:  # the same lines as len(phases) layers below: only the travels differ
                qualities.append(replace(qualities[-len(phases)], travel_length_mm=travel))
    parameter = process.calibration.parameter if _encodes(fields, process, settings) else ""
    meta = {
        "units": "mm, s, mm/s",
        "sources": [flat.source for flat in fields],
        "process": process.source,
        "road_width_mm": w,
        "layer_height_mm": process.layer_height_mm,
        "pattern": settings.pattern,
    }
    return Plan(Toolpath(tuple(layers), parameter, meta), tuple(qualities), tuple(warnings))


def _check(fields: list[FlatField], settings: PlanSettings) -> None:
    if not fields:
        raise FabkitError("toolpath: no input field")
    if settings.pattern not in PATTERNS:
        raise FabkitError(f"--pattern must be one of {', '.join(PATTERNS)}")
    if settings.layers < len(fields) or settings.layers % len(fields):
        raise FabkitError(
            f"--layers {settings.layers} cannot be split evenly over {len(fields)} inputs"
        )


def _encodes(fields: list[FlatField], process: Process, settings: PlanSettings) -> bool:
    return bool(settings.encode and process.calibration and any(flat.has_eps for flat in fields))


def _encoding(flat: FlatField, process: Process, settings: PlanSettings) -> Calibration | None:
    if settings.encode and process.calibration is not None and flat.has_eps:
        return process.calibration
    return None


def _spacing(flat: FlatField, calibration: Calibration | None):
    """Line spacing (mm): the calibrated one when eps encodes the line spacing."""
    if calibration is None or calibration.parameter != "line_spacing_mm":
        return None

    def spacing(points: np.ndarray) -> np.ndarray:
        eps = np.clip(flat.eps(points), *calibration.eps_range)
        return encode_eps(eps, calibration).value

    return spacing


def _moves(
    lines: list[np.ndarray],
    flat: FlatField,
    process: Process,
    calibration: Calibration | None,
    z: float,
) -> tuple[list[Move], float]:
    """Print moves (encoded) with travels between them; the fraction of eps clipped."""
    w, speed = process.road_width_mm, process.print_speed_mm_s
    values: list[np.ndarray | float] = [np.nan] * len(lines)
    clipped = 0.0
    if calibration is not None:
        points = np.concatenate(lines)
        encoding = encode_eps(flat.eps(points), calibration)
        values = np.split(encoding.value, np.cumsum([len(x) for x in lines])[:-1])
        clipped = encoding.clipped_fraction
    moves = []
    for k, (line, value) in enumerate(zip(lines, values, strict=True)):
        if k:
            hop = np.vstack([lines[k - 1][-1], line[0]])
            moves.append(Move.make(TRAVEL, hop, z, 0.0, process.travel_speed_mm_s, 0.0))
        parameter = calibration.parameter if calibration else ""
        moves.append(
            Move.make(
                PRINT,
                line,
                z,
                w,
                value if parameter == "print_speed_mm_s" else speed,
                value if parameter == "extrusion_multiplier" else 1.0,
                value,
            )
        )
    return moves, clipped
