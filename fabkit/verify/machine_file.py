"""``fabkit verify``: a machine file read back, compared with its design, and simulated.

:func:`verify` reads the file (G-code, a DXF's roads, or a laser pattern folder), lays
what it makes on a grid of the flat sheet (:mod:`fabkit.verify.raster`), reads every
feature back by inverting its channel's calibration (:meth:`fabkit.process.Encode.decode`),
and compares, over the cells inside the design's outline:

* coverage: ``empty`` (cells no road or exposure covers) and ``overlap`` (mean number
  of further roads over the covered cells);
* the director: the angle between the road direction (the exposure's director) and the
  design's, mean and 95th percentile, degrees;
* each feature: |read back - designed| as a percentage of the feature's designed range
  (max - min over the design), RMS and 95th percentile, over the covered cells.

Then the sheet *as fabricated* (the read-back director and features, on the printed
outline) is simulated under the stimulus of every target and its distance to the
target reported as ``fabkit simulate`` does (RMS and max after rigid alignment, % of the
patch diameter); ``reference`` adds the sheet as designed on the same mesh.

This module holds the options, the result (:class:`Verification` and its table),
:func:`verify` and the reading of the file onto grids of the sheet, one per printed
layer; the comparison with the design is :mod:`fabkit.verify.compare_fields`, the
simulation of the sheet as fabricated and its verdict :mod:`fabkit.verify.as_fabricated`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from fabkit.design.design import Design
from fabkit.errors import FabkitError
from fabkit.field.design_field import feature_names, field_from_design
from fabkit.field.flat import FlatField
from fabkit.field.part import MIN_WIDTH_PITCHES, MIN_WIDTH_ROADS, Part, PartOptions, PartRequest
from fabkit.files.tomlfile import real
from fabkit.machines import DEFAULT_MACHINE, MachineProfile
from fabkit.mechanics.fabricated import SheetFields
from fabkit.mechanics.simulate import Settings
from fabkit.mechanics.verdict import FORM_TOLERANCE, Shape, Verdict
from fabkit.process import Encode, Process, Resolution
from fabkit.toolpath.baromorph import BaromorphSettings
from fabkit.verify.as_fabricated import (
    TargetDistance,
    fabricated_verdict,
    sheet_fields,
    simulate_targets,
    simulation_figures,
    simulation_note,
)
from fabkit.verify.compare_fields import (
    ComparedSheet,
    FeatureError,
    LayerReading,
    feature_errors,
    layer_fields,
    layer_readings,
)
from fabkit.verify.raster import Readback, Roads, rasterise
from fabkit.verify.read_dxf import read_channels, read_dxf
from fabkit.verify.read_gcode import Placement, Printed, read_gcode
from fabkit.verify.read_laser import read_laser
from fabkit.writers.which_machine import MachineChoice, choose_machine

CELL_PER_WIDTH = 4
"""Grid cells per road width (roads are read on cells of w / 4)."""


@dataclass(frozen=True)
class VerifyOptions:
    """What ``fabkit verify`` is told; None = from the file or the default.

    ``machine`` the profile (or its name; default: the one the file names, else
    marlin_diw_pneumatic, the laser cutter for baromorph channels:
    :mod:`fabkit.writers.which_machine`); ``process`` replaces its process; ``size_mm`` /
    ``mm_per_unit`` the sheet's scale and ``offset_mm`` its placement (default: the file's records);
    ``cell_mm`` the grid (default w / 4, or the laser pixel); ``simulate`` runs the
    forward simulations, ``reference`` adds the sheet as designed; ``stride`` coarsens
    the design's grid for them (default: about
    :data:`fabkit.verify.as_fabricated.TARGET_TRIANGLES` triangles);
    ``smoothing_mm`` the Gaussian the read-back fields are averaged over before them
    (default: the larger of the road width and the simulated thickness; 0: none);
    ``baromorph`` the channel settings of a baromorph drawing (its channels are read
    instead of roads); ``form_tolerance`` the RMS distance (share of the patch diameter)
    within which the sheet forms a target (:mod:`fabkit.mechanics.verdict`). The design's
    part (:mod:`fabkit.field.part`) is ``part`` when made
    already (``fabkit run``), else made as the file's maker made it: by ``part_request``
    for the process's road width and a sheet as thick as
    the layers the file prints (a baromorph drawing: its part thickness). Coverage is
    measured on the part, and the simulations mesh its cells.
    """

    machine: MachineProfile | str | None = None
    process: Process | None = None
    size_mm: float | None = None
    mm_per_unit: float | None = None
    offset_mm: tuple[float, ...] | None = None
    cell_mm: float | None = None
    ignore_features: tuple[str, ...] = ()
    simulate: bool = True
    reference: bool = False
    stride: int | None = None
    max_iterations: int = Settings.max_iterations
    smoothing_mm: float | None = None
    baromorph: BaromorphSettings | None = None
    part: Part | None = None
    part_request: PartRequest = PartRequest()
    form_tolerance: float = FORM_TOLERANCE


@dataclass(frozen=True)
class Verification:
    """Everything ``fabkit verify`` measured (see the module docstring); the top-level
    coverage, director and feature figures are the bottom layer's, ``layers`` has every
    layer's when the file prints more than one."""

    file: str
    kind: str
    machine: str
    process: str
    placement: str
    cell_mm: float
    empty_fraction: float
    mean_overlap: float
    director_mean_deg: float
    director_p95_deg: float
    features: tuple[FeatureError, ...]
    targets: tuple[TargetDistance, ...]
    ignored: tuple[str, ...]
    notes: tuple[str, ...]
    seconds: float = 0.0
    extra: dict[str, Any] = field(default_factory=dict)
    simulation: dict[str, Any] = field(default_factory=dict)
    layers: tuple[LayerReading, ...] = ()
    verdict: Verdict | None = None
    thickness_notice: str = ""

    def to_dict(self) -> dict[str, Any]:
        data = asdict(replace(self, verdict=None))  # the verdict's meshes stay out
        data["verdict"] = self.verdict.to_dict() if self.verdict is not None else None
        if self.notice():
            return {"notice": self.notice(), **data}
        return data

    def notice(self) -> str:
        """The first line of the report when features were left out, or the process's
        layer height is not the file's ("" if neither)."""
        notices = [self.thickness_notice] if self.thickness_notice else []
        if self.ignored:
            notices.insert(
                0,
                f"NOT ENCODED: feature{'s' if len(self.ignored) > 1 else ''} "
                f"{', '.join(self.ignored)} left out on purpose (--ignore-feature): the "
                "machine file does not carry it and the sheet as fabricated was not simulated",
            )
        return "; ".join(notices)

    def table(self) -> str:
        """The report as text (the first line says when features were left out, or the
        sheet's thickness is not the process's)."""
        lines = [self.notice()] if self.notice() else []
        own = self.process == f"machine {self.machine}"
        process = "its own process" if own else f"process {self.process}"
        bottom = f" (layer 1 of {len(self.layers)}, the bottom one)" if self.layers else ""
        lines += [
            f"verify {self.file} ({self.kind}, machine {self.machine}, {process}; "
            f"placement from {self.placement}; cells {self.cell_mm:.3g} mm)",
            *([f"  {self.extra['part']['summary']}"] if "part" in self.extra else []),
            f"  coverage{bottom}: empty {100 * self.empty_fraction:.2f} %, overlap "
            f"{100 * self.mean_overlap:.2f} %",
            f"  director error: mean {self.director_mean_deg:.2f} deg, p95 "
            f"{self.director_p95_deg:.2f} deg",
        ]
        for f in self.features:
            lines.append(
                f"  {f.feature} ({f.channel}): error RMS {f.rms_pct:.2f} %, p95 {f.p95_pct:.2f} "
                f"% of its range {f.design_range:.4g} ({f.cells} cells)"
            )
        for layer in self.layers[1:]:
            errors = ", ".join(f"{f.feature} RMS {f.rms_pct:.2f} %" for f in layer.features)
            lines.append(
                f"  layer {layer.layer}: empty {100 * layer.empty_fraction:.2f} %, director "
                f"mean {layer.director_mean_deg:.2f} deg, p95 {layer.director_p95_deg:.2f} deg"
                + (f"; {errors}" if errors else "")
            )
        shapes = {s.target: s for s in self.verdict.shapes} if self.verdict else {}
        for t in self.targets:
            mirror = " (mirror image)" if t.mirrored else ""
            moving = "" if t.converged else " (not converged)"
            shape = shapes.get(t.target)
            formed = "" if shape is None else ("formed, " if shape.formed else "NOT formed, ")
            line = (
                f"  as fabricated vs {t.target}: {formed}RMS {t.rms_pct:.2f} %, max "
                f"{t.max_pct:.2f} % of the patch diameter{mirror}{moving}"
            )
            if t.designed_rms_pct is not None:
                moving = "" if t.designed_converged else " (not converged)"
                line += (
                    f"; as designed RMS {t.designed_rms_pct:.2f} %, max "
                    f"{t.designed_max_pct:.2f} %{moving}"
                )
            lines.append(line)
        lines += [f"  note: {note}" for note in self.notes]
        lines.append(f"  verified in {self.seconds:.1f} s")
        return "\n".join(lines)

    def text(self) -> str:
        """What ``fabkit verify`` prints: :meth:`table`, then, when the sheet was
        simulated, the verdict's line per target and its headline last."""
        if self.verdict is None:
            return self.table()
        shapes = [f"    {line}" for line in self.verdict.lines()]
        block = [f"  the sheet {self.verdict.what}:", *shapes, self.verdict.headline()]
        return "\n".join([self.table(), *block])


@dataclass(frozen=True)
class Reading:
    """A machine file read back against its design, before any simulation: the file's
    ``kind``, the machine ``choice``, the ``process`` and how it encodes each feature
    (``resolution``), every printed layer's ``readbacks`` and the heights they lie at
    (mm), its ``placement``, the printed ``thickness_mm``, the design's ``flat`` field
    on the part, every layer compared with its own designed layer (``sheets``,
    ``readings``) and the design's feature ``names``."""

    design: Design
    kind: str
    choice: MachineChoice
    process: Process
    resolution: Resolution
    readbacks: list[Readback]
    placement: Placement
    heights: list[float]
    thickness_mm: float
    flat: FlatField
    sheets: list[ComparedSheet]
    readings: list[Any]
    names: tuple[str, ...]

    def fields(self, options: VerifyOptions) -> list[SheetFields]:
        """Every printed layer's director and features as functions of flat-sheet points
        (design units), averaged as the simulations take them (:func:`sheet_fields`)."""
        smoothing = _smoothing_mm(options, self.readbacks[0], self.thickness_mm)
        scale = float(self.flat.mm_per_unit)
        return [
            sheet_fields(r, self.resolution, sheet, scale, self.names, smoothing)
            for r, sheet in zip(self.readbacks, self.sheets, strict=True)
        ]


def read_back(
    design_path: str | Path,
    machine_file: str | Path,
    options: VerifyOptions,
    design: Design | None = None,
) -> Reading:
    """Read ``machine_file`` back and compare every printed layer with its designed one
    (:func:`verify`'s reading, without its simulations); ``design``: the design in
    ``design_path``, loaded already."""
    _check_options(options)
    design = Design.load(design_path) if design is None else design
    names = feature_names(design, str(design_path))
    machine_file = Path(machine_file)
    if not machine_file.exists():
        raise FabkitError(f"machine file '{machine_file}' does not exist")
    kind = "channels" if options.baromorph else _kind(machine_file)
    choice = _machine(options, machine_file, kind)
    process = _process(options, choice.profile)
    resolution = process.resolve(names, options.ignore_features)
    readbacks, placement, heights = _read(
        machine_file, kind, choice.profile, process, resolution, options
    )
    thickness_mm = _printed_thickness(options, process, kind, len(readbacks), heights)
    cut = _part_options(options, process, thickness_mm)
    flat = _flat_field(design, str(design_path), options, placement, cut)
    designed = layer_fields(design, flat, str(design_path), len(readbacks))
    sheets = [ComparedSheet.of(r, f) for r, f in zip(readbacks, designed, strict=True)]
    readings = [
        feature_errors(r, resolution, sheet, design, names)
        for r, sheet in zip(readbacks, sheets, strict=True)
    ]
    return Reading(
        design, kind, choice, process, resolution, readbacks, placement, heights,
        thickness_mm, flat, sheets, readings, names,
    )  # fmt: skip


def simulate_reading(
    reading: Reading,
    options: VerifyOptions,
    progress: Callable[[int, int], None] | None = None,
) -> tuple[tuple[TargetDistance, ...], tuple[Shape, ...]]:
    """The sheet ``reading`` read back simulated under every target's stimulus from every
    start (:func:`~fabkit.verify.as_fabricated.simulate_targets`, as :func:`verify` does):
    its distances and shapes."""
    return simulate_targets(
        reading.design,
        reading.fields(options),
        reading.flat.part,
        reading.thickness_mm,
        float(reading.flat.mm_per_unit),
        stride=options.stride,
        max_iterations=options.max_iterations,
        with_reference=options.reference,
        tolerance=options.form_tolerance,
        progress=progress,
    )


def verify(
    design_path: str | Path,
    machine_file: str | Path,
    options: VerifyOptions,
    progress: Callable[[int, int], None] | None = None,
    design: Design | None = None,
) -> Verification:
    """Read ``machine_file`` back and check it against the design (module docstring).

    ``progress(done, total)`` follows the simulations: ramp steps over every target;
    ``design``: the design in ``design_path``, loaded already (``fabkit run``)."""
    started = time.perf_counter()
    reading = read_back(design_path, machine_file, options, design)
    design, machine, process = reading.design, reading.choice.profile, reading.process
    readbacks, sheets, readings = reading.readbacks, reading.sheets, reading.readings
    layers, thickness_mm, flat = len(readbacks), reading.thickness_mm, reading.flat
    features, sheet = readings[0], sheets[0]
    notes = list(dict.fromkeys(note for r in readbacks for note in r.notes))
    missing = sorted({f.feature for reading in readings for f in reading if f.cells == 0})
    if missing:
        notes.append(f"not read back (the file carries no value for it): {', '.join(missing)}")
    if reading.choice.against_the_file:
        named = reading.choice.named
        notes.append(f"read as machine {machine.name} reads it, but the file names {named}")
    targets: tuple[TargetDistance, ...] = ()
    shapes: tuple[Shape, ...] = ()
    simulation: dict[str, Any] = {}
    if not options.simulate:
        notes.append("not simulated (--no-simulate)")
    elif reading.resolution.ignored or missing:
        notes.append("not simulated: a feature of the design is not in the machine file")
    else:
        targets, shapes = simulate_reading(reading, options, progress)
        smoothing = _smoothing_mm(options, readbacks[0], thickness_mm)
        simulation = simulation_figures(smoothing, readbacks[0], thickness_mm, layers)
        notes.append(simulation_note(simulation))
    return Verification(
        file=str(machine_file),
        kind=reading.kind,
        machine=machine.name,
        process=process.source,
        placement=reading.placement.source,
        cell_mm=readbacks[0].cell_mm,
        empty_fraction=sheet.empty,
        mean_overlap=sheet.overlap,
        director_mean_deg=sheet.director_mean,
        director_p95_deg=sheet.director_p95,
        features=tuple(features),
        targets=targets,
        ignored=reading.resolution.ignored,
        notes=tuple(notes),
        seconds=time.perf_counter() - started,
        extra={"part": _part_figures(flat.part)} if flat.part is not None else {},
        simulation=simulation,
        layers=layer_readings(sheets, readings, design.layers) if layers > 1 else (),
        verdict=fabricated_verdict(shapes, layers, thickness_mm),
        thickness_notice=""
        if reading.kind == "channels"
        else thickness_notice(process, reading.heights),
    )


def _printed_thickness(
    options: VerifyOptions, process: Process, kind: str, layers: int, heights: Sequence[float]
) -> float:
    """The sheet the file makes, mm: the height of its top layer, as the file prints it
    (a baromorph drawing: the part's thickness; a laser pattern, or a file printed at
    the bed's height: its layers times the process's layer height)."""
    if kind == "channels":
        return options.baromorph.part_thickness_mm
    if heights and max(heights) > 0:
        return float(max(heights))
    return layers * process.layer_height_mm


def thickness_notice(process: Process, heights: Sequence[float]) -> str:
    """The first line of the report when the process's layer height is not the one the
    file prints at ("" when they agree within 1 %, or the file has no heights)."""
    if not heights or max(heights) <= 0:
        return ""
    printed, said = max(heights), len(heights) * process.layer_height_mm
    if abs(printed - said) <= 0.01 * printed:
        return ""
    layers = f"{len(heights)} layer{'s' if len(heights) > 1 else ''}"
    return (
        f"THICKNESS FROM THE FILE: it prints {layers}, {printed:.3g} mm in all, where "
        f"the process ({process.source}) says {said:.3g} mm "
        f"({process.layer_height_mm:g} mm per layer): read back and simulated at the file's"
    )


def _part_figures(part: Part) -> dict[str, Any]:
    return {"summary": part.summary(), **part.to_dict()}


def _part_options(options: VerifyOptions, process: Process, thickness_mm: float) -> PartOptions:
    """How the file's maker cut the part: the options, the process's road width (a
    baromorph drawing's: its channel pitch) and the sheet's thickness (mm)."""
    if options.baromorph:
        road, roads = options.baromorph.pitch_mm, MIN_WIDTH_PITCHES
    else:
        road, roads = process.road_width_mm, MIN_WIDTH_ROADS
    return options.part_request.for_process(road, thickness_mm, roads)


def _check_options(options: VerifyOptions) -> None:
    """Refuse options out of range before reading anything."""
    for name, value in (
        ("--cell", options.cell_mm),
        ("--size", options.size_mm),
        ("--scale", options.mm_per_unit),
    ):
        if value is not None:
            real(value, name, positive=True)
    if options.smoothing_mm is not None:
        real(options.smoothing_mm, "--smoothing", nonnegative=True)
    for name, value, least in (
        ("--stride", options.stride, 1),
        ("--max-iterations", options.max_iterations, 1),
    ):
        if value is not None and value < least:
            raise FabkitError(f"{name} {value}: expected an integer >= {least}")


def _kind(path: Path) -> str:
    if path.is_dir():
        return "laser"
    return "dxf" if path.suffix.lower() == ".dxf" else "gcode"


def _machine(options: VerifyOptions, path: Path, kind: str) -> MachineChoice:
    """The profile asked for, else the one the file names, else the default (the laser
    cutter for baromorph channels; a laser pattern folder must name its own)."""
    defaults = {"channels": "laser_cutter", "laser": None}
    default = defaults.get(kind, DEFAULT_MACHINE)
    return choose_machine(path, options.machine, default, force=True)


def _process(options: VerifyOptions, machine: MachineProfile) -> Process:
    """The process the file was made with: the one given, the baromorph channel settings
    (a channel-width channel for the first feature), else the machine's."""
    if options.baromorph:
        settings = options.baromorph
        channel = Encode((0,), settings.calibration)
        return Process(
            settings.pitch_mm,
            settings.channel_depth_mm,
            1.0,
            1.0,
            (channel,),
            "baromorph channel settings",
        )
    return options.process or machine.process


def _read(
    path: Path,
    kind: str,
    machine: MachineProfile,
    process: Process,
    resolution: Resolution,
    options: VerifyOptions,
) -> tuple[list[Readback], Placement, tuple[float, ...]]:
    """The file on grids of the sheet's frame, one per layer it prints (bottom first; a
    laser pattern or baromorph channels: one), where the placement came from, and the
    height each layer is printed at (mm above the bed, bottom first; () for a laser
    pattern or channels, whose file has no heights)."""
    if kind in ("laser", "channels"):
        if kind == "laser":
            readback, found, _ = read_laser(path)
        else:
            readback, found = _read_channels(path, options.baromorph)
        placement = _placement(options, found)
        shift = np.asarray(placement.offset_mm)
        moved = (readback.origin[0] - shift[0], readback.origin[1] - shift[1])
        return [_replace_origin(readback, moved)], placement, ()
    cell = options.cell_mm or process.road_width_mm / CELL_PER_WIDTH
    if kind == "dxf":
        start, end, width, road, values, height, found = read_dxf(path, process.road_width_mm)
        values = {p: values.get(p, np.full(len(start), np.nan)) for p in resolution.parameters}
        heights = np.unique(np.round(height, 6))  # a layer at each height drawn at
        layers = []
        for z in heights:
            at = np.isclose(height, z, atol=1e-6)
            own = {p: v[at] for p, v in values.items()}
            layers.append(Roads(start[at], end[at], width[at], road[at], own, None))
    else:
        printed = read_gcode(path, machine)
        found = printed.placement
        heights = np.unique(np.round(printed.start[:, 2], 6)) if len(printed.start) else [0.0]
        own = layer_thicknesses(heights, process.layer_height_mm)
        layers = [
            _gcode_roads(printed, machine, process, resolution, z, h)
            for z, h in zip(heights, own, strict=True)
        ]
    placement = _placement(options, found)
    offset = np.asarray(placement.offset_mm)
    grids = [rasterise(roads.shifted(offset), cell) for roads in layers]
    return grids, placement, tuple(float(z) for z in heights)


def layer_thicknesses(heights_mm: Sequence[float], layer_height_mm: float) -> list[float]:
    """Each layer's thickness, mm: the step from the height below it (the bed, at 0, below
    the first), the process's ``layer_height_mm`` where the heights say nothing (a file
    printed at the bed's height, or a drawing without heights)."""
    below = np.concatenate([[0.0], np.asarray(heights_mm, dtype=float)[:-1]])
    steps = np.asarray(heights_mm, dtype=float) - below
    return [float(step) if step > 0 else layer_height_mm for step in steps]


def _read_channels(path: Path, settings: BaromorphSettings) -> tuple[Readback, Placement]:
    """A baromorph drawing's channels with the ``settings`` it was laid out with: the band
    along the outline holding the manifold ring is left out."""
    widest = max(settings.calibration.value)
    band = settings.min_wall_mm + settings.manifold_width_mm + settings.pitch_mm / 2
    return read_channels(path, settings.pitch_mm, widest, band)


def _replace_origin(readback: Readback, origin: tuple[float, float]) -> Readback:
    return replace(readback, origin=origin)


def _placement(options: VerifyOptions, found: Placement) -> Placement:
    """--offset, else the file's record; a one-line error when neither is there."""
    if options.offset_mm is not None:
        if len(options.offset_mm) not in (2, 3) or not np.isfinite(options.offset_mm).all():
            raise FabkitError(f"--offset {options.offset_mm}: expected X,Y in mm")
        return Placement(tuple(options.offset_mm[:2]), found.mm_per_unit, "--offset")
    if found.offset_mm is None:
        raise FabkitError(
            f"{found.source.split(' ')[0]}: the file does not record where the sheet was "
            "placed on the machine; give --offset X,Y (mm)"
        )
    return found


def _flat_field(
    design: Design, name: str, options: VerifyOptions, placement: Placement, part: PartOptions
) -> FlatField:
    """The design's flat sheet in mm on its part: the part made already, else at --scale,
    at --size, or at the file's scale (``name``: the design file, in messages)."""
    if options.part is not None:
        return field_from_design(design, part=options.part, name=name)
    if options.mm_per_unit is not None:
        return field_from_design(design, None, options.mm_per_unit, part, name=name)
    if options.size_mm is not None:
        return field_from_design(design, options.size_mm, None, part, name=name)
    if placement.mm_per_unit is None:
        raise FabkitError(
            f"{placement.source.split(' ')[0]}: the file does not record the sheet's scale; "
            "give --size MM (its longest side, as fabkit run --size) or --scale MM_PER_UNIT"
        )
    return field_from_design(design, None, placement.mm_per_unit, part, name=name)


def _gcode_roads(
    printed: Printed,
    machine: MachineProfile,
    process: Process,
    resolution: Resolution,
    height: float,
    thickness: float,
) -> Roads:
    """The segments printed at ``height`` (mm) with each channel's parameter per segment;
    ``thickness`` (mm) is the layer's, which the extruded volume fills."""
    first = np.isclose(printed.start[:, 2], height, atol=1e-6)
    start, end = printed.start[first, :2], printed.end[first, :2]
    length = np.linalg.norm(end - start, axis=1)
    feed, volume = printed.feed[first], printed.volume[first]
    w, h = process.road_width_mm, thickness
    has_e = machine.gcode is not None and not machine.gcode.flow_on_gcode.strip()
    with np.errstate(invalid="ignore", divide="ignore"):
        flow = volume / (length * w * h) if has_e else process.print_speed_mm_s / feed
        width = w * flow if has_e else np.full(len(start), w)
    raw = {
        "print_speed_mm_s": feed,
        "extrusion_multiplier": flow,
        "pressure_kpa": printed.pressure[first],
        "temperature_c": printed.temperature[first],
        "ink_fraction": printed.mix[first],
        "line_spacing_mm": np.full(len(start), np.nan),
    }
    values = {p: raw.get(p, np.full(len(start), np.nan)) for p in resolution.parameters}
    alternate = machine.inks is not None and machine.inks.method == "alternate"
    ink = None
    if "ink_fraction" in values and alternate:
        ink = printed.ink[first]
        del values["ink_fraction"]
    return Roads(start, end, width, printed.road[first], values, ink)


def _smoothing_mm(options: VerifyOptions, readback: Readback, thickness_mm: float) -> float:
    """The length (mm) the read-back fields are averaged over: ``options.smoothing_mm``,
    else the larger of the road width (or pixel) and the simulated sheet's thickness."""
    if options.smoothing_mm is not None:
        return options.smoothing_mm
    return max(readback.width_mm, thickness_mm)
