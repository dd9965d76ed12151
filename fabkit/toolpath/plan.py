"""From flat-sheet fields and process settings to a layered :class:`Toolpath`.

Layers are split into equal consecutive blocks, one per field (a bilayer of two fields:
the swimmer's radial bottom and azimuthal top). Within a block every layer repeats the
field's lines (``pattern = "same"``) or alternates them with the staggered set halfway
between (``"alternate"``: stripe phase pi, and the print order reversed). Layer k is
printed at z = (k + 1) * layer height. Fields that share their lines (``shared_lines``:
the layers of one layered design, whose directors differ by a fraction of a degree) are
printed along the lines planned for the first, each field's turned to its own director
(:func:`~fabkit.toolpath.lines.turned_lines`) and encoding its own features: a print's
roads wander from the director (about a degree on average), and two layers planned apart
wander apart, a twist between them far larger than the one designed (docs/layers.md,
"One set of lines for every layer", has the figures).

Every feature of a field is encoded on every vertex by the process's channel for it
(:meth:`fabkit.process.Process.resolve`: a feature without a channel is an error unless
it is ignored on purpose). Each move carries one array per encoded parameter;
``print_speed_mm_s`` also sets the speed, ``extrusion_multiplier`` the flow, and
``line_spacing_mm`` the spacing of the lines themselves (through the stripe
wavenumber); the writers emit the others (pressure, temperature, ink fraction).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from fabkit.errors import FabkitError
from fabkit.field.flat import FlatField
from fabkit.process import Encode, Process, Resolution
from fabkit.toolpath.lines import LineSettings, print_lines, turned_lines
from fabkit.toolpath.model import PRINT, TRAVEL, Layer, Move, Toolpath
from fabkit.toolpath.order import order_lines, travel_length
from fabkit.toolpath.quality import Quality, measure_quality

PATTERNS = ("same", "alternate")


@dataclass(frozen=True)
class PlanSettings:
    """Number of layers, layer pattern, whether to encode the features, the features left
    out on purpose (``--ignore-feature``), the line settings, and the stripes' phase
    (radians: every line shifted by ``phase_rad`` / 2 pi of its spacing; 0, the default,
    and any other phase give equally good prints of the same fields, their roads
    elsewhere: ``fabkit run --prints``); ``shared_lines``: every field printed along the
    lines planned for the first, turned to its own director (module docstring)."""

    layers: int = 1
    pattern: str = "same"
    encode: bool = True
    ignore: tuple[str, ...] = ()
    lines: LineSettings = field(default_factory=LineSettings)
    phase_rad: float = 0.0
    shared_lines: bool = False


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
    staggered = (0.0, np.pi) if settings.pattern == "alternate" and per_field > 1 else (0.0,)
    phases = tuple(settings.phase_rad + phase for phase in staggered)
    resolutions = [_resolve(flat, process, settings) for flat in fields]
    names = {p: "+".join(c.features) for r in resolutions for c in r.channels for p in c.parameters}
    layers, qualities, warnings = [], [], []
    position = np.zeros(2)
    planned: tuple[FlatField, list] | None = None
    for flat, resolution in zip(fields, resolutions, strict=True):
        if planned is None or not settings.shared_lines:
            spacing = _spacing(flat, resolution.channel_of("line_spacing_mm"))
            line_sets = print_lines(flat, w, spacing, settings.lines, phases)
            planned = (flat, line_sets)
        else:
            base, shared = planned
            line_sets = [turned_lines(lines, base, flat, settings.lines, w) for lines in shared]
        for repeat in range(per_field):
            variant = repeat % len(phases)
            lines = order_lines(line_sets[variant], position)
            if variant:
                lines = [line[::-1] for line in lines[::-1]]
            if not lines:
                raise FabkitError(f"{flat.source}: no print line fits (domain narrower than w?)")
            z = (len(layers) + 1) * process.layer_height_mm
            moves, clipped = _moves(lines, flat, process, resolution, tuple(names), z)
            warnings += [f"{flat.source}: eps clipped to {text}" for text in clipped]
            layers.append(Layer(z, process.layer_height_mm, tuple(moves)))
            position = lines[-1][-1]
            travel = travel_length(lines)
            if repeat < len(phases):
                widths = [m.width for m in moves if m.kind == PRINT]
                qualities.append(measure_quality(lines, widths, flat, w, travel))
            else:  # the same lines as len(phases) layers below: only the travels differ
                qualities.append(replace(qualities[-len(phases)], travel_length_mm=travel))
    ignored = sorted({name for r in resolutions for name in r.ignored})
    if ignored:
        warnings.insert(0, _ignored_text(ignored, settings))
    meta = {
        "units": "mm, s, mm/s",
        "sources": [flat.source for flat in fields],
        "process": process.source,
        "road_width_mm": w,
        "layer_height_mm": process.layer_height_mm,
        "pattern": settings.pattern,
        "mm_per_unit": fields[0].mm_per_unit,
        "features": list(dict.fromkeys(name for flat in fields for name in flat.names)),
        "ignored_features": ignored,
        "unused_channels": sorted({c.label for r in resolutions for c in r.unused}),
    }
    return Plan(Toolpath(tuple(layers), names, meta), tuple(qualities), tuple(warnings))


def _ignored_text(ignored: list[str], settings: PlanSettings) -> str:
    why = "--ignore-feature" if settings.encode else "--no-encode"
    return (
        f"feature{'s' if len(ignored) > 1 else ''} {', '.join(ignored)} left out ({why}): "
        "the machine file does not encode " + ("them" if len(ignored) > 1 else "it")
    )


def _check(fields: list[FlatField], settings: PlanSettings) -> None:
    if not fields:
        raise FabkitError("toolpath: no input field")
    if settings.pattern not in PATTERNS:
        raise FabkitError(f"--pattern must be one of {', '.join(PATTERNS)}")
    if settings.layers < len(fields) or settings.layers % len(fields):
        raise FabkitError(
            f"--layers {settings.layers} cannot be split evenly over {len(fields)} inputs"
        )
    names = list(dict.fromkeys(name for flat in fields for name in flat.names))
    for name in settings.ignore:
        if name not in names:
            raise FabkitError(
                f"--ignore-feature {name}: not a feature of the input "
                f"(features: {', '.join(names) or 'none'})"
            )


def _resolve(flat: FlatField, process: Process, settings: PlanSettings) -> Resolution:
    """The channels of ``flat``'s features (every feature left out with --no-encode)."""
    if not settings.encode:
        return Resolution((), (), flat.names)
    return process.resolve(flat.names, tuple(n for n in settings.ignore if n in flat.names))


def _spacing(flat: FlatField, channel: Encode | None):
    """Line spacing (mm): the encoded one when a feature is encoded as the line spacing."""
    if channel is None:
        return None

    def spacing(points: np.ndarray) -> np.ndarray:
        eps = {name: flat.feature(name, points) for name in channel.features}
        clipped = Encode(channel.features, replace(channel.table, clip=True))
        return clipped.encode(eps).values["line_spacing_mm"]

    return spacing


def _moves(
    lines: list[np.ndarray],
    flat: FlatField,
    process: Process,
    resolution: Resolution,
    parameters: tuple[str, ...],
    z: float,
) -> tuple[list[Move], list[str]]:
    """Print moves (encoded) with travels between them; a note per clipped channel."""
    w, speed = process.road_width_mm, process.print_speed_mm_s
    points = np.concatenate(lines)
    values: dict[str, np.ndarray] = {p: np.full(len(points), np.nan) for p in parameters}
    clipped = []
    sampled = flat.sample(points)[1] if resolution.channels else {}
    for channel in resolution.channels:
        eps = {name: sampled[name] for name in channel.features}
        coded = channel.encode(eps, f"{flat.source}: {channel.label}")
        values.update(coded.values)
        if coded.clipped_fraction:
            clipped.append(f"the table of {channel.label} on {coded.clipped_fraction:.1%}")
    cuts = np.cumsum([len(x) for x in lines])[:-1]
    per_line = {p: np.split(v, cuts) for p, v in values.items()}
    nothing = {p: np.nan for p in parameters}
    moves = []
    for k, line in enumerate(lines):
        if k:
            hop = np.vstack([lines[k - 1][-1], line[0]])
            moves.append(Move.make(TRAVEL, hop, z, 0.0, process.travel_speed_mm_s, 0.0, nothing))
        channels = {p: per_line[p][k] for p in parameters}
        own = {p: channels[p] for p in resolution.parameters}  # this field's channels
        moves.append(
            Move.make(
                PRINT,
                line,
                z,
                w,
                own.get("print_speed_mm_s", speed),
                own.get("extrusion_multiplier", 1.0),
                channels,
            )
        )
    return moves, clipped
