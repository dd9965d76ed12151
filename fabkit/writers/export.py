"""``fabkit export``: one input file, one machine, one format, one output.

:func:`write_machine_file` writes from a value (a toolpath, a design or a director field)
and returns an :class:`Exported`; :func:`export` reads the input file first. Inputs,
recognised by content: a toolpath (``.npz``/``.json`` written by
:func:`fabkit.toolpath.save_toolpath`), a design (``design.npz`` from ``fabkit solve``) or a
director file (``.toml``, see :func:`fabkit.field.director_file.load_director_file`).

======== ============================================ ===================================
format   from a toolpath                              from a design / director file
======== ============================================ ===================================
gcode    the toolpath                                 refused: make a toolpath first
dxf      PATHS, TRAVEL (+ ``geometry`` layers)        OUTLINE of the flat sheet (+ geometry)
laser    refused: needs a director field              angle/dose maps, masks, manifest, scan
======== ============================================ ===================================

``geometry`` is an optional GeoJSON file (a FeatureCollection, sheet frame, mm) whose
features carry ``"layer": "outline" | "channels" | "inlet"`` in their properties.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import shapely
import shapely.geometry
from shapely.errors import ShapelyError

from fabkit.design.design import Design
from fabkit.errors import FabkitError
from fabkit.field.design_field import field_from_design
from fabkit.field.director_file import load_director_file
from fabkit.field.flat import FlatField
from fabkit.field.outlines import read_outline
from fabkit.field.part import Part, PartRequest
from fabkit.files.npzfile import npz_keys
from fabkit.files.readfile import read_json
from fabkit.machines import MachineProfile, load_machine
from fabkit.process import Process
from fabkit.progress import clock
from fabkit.toolpath.exposure import LaserSettings, sample_field
from fabkit.toolpath.model import Toolpath, load_toolpath
from fabkit.writers.common import FORMATS
from fabkit.writers.dxf import DEFAULT_INLET_RADIUS_MM, DxfSummary, write_dxf
from fabkit.writers.gcode import GcodeOptions, GcodeSummary, write_gcode
from fabkit.writers.laser import write_laser

GEOMETRY_LAYERS = ("outline", "channels", "inlet")


@dataclass(frozen=True)
class ExportOptions:
    """Everything ``fabkit export`` may be told; None = the writer's default.

    ``size_mm`` / ``mm_per_unit`` scale a design (give one); ``pixel_mm`` is the laser
    pixel pitch (default: the profile's ``laser.pixel_pitch_mm``, else its road width);
    ``process`` replaces the profile's process for laser patterns (its dose channels);
    ``ignore_features`` are features left out of the laser patterns on purpose.
    A design is cut to its part (:mod:`fabkit.field.part`): ``part`` made already (``fabkit
    run``), else made by ``part_request`` for the process's road width and layer height;
    its ``outline`` also clips a director file's field.
    """

    offset_mm: tuple[float, ...] | None = None
    size_mm: float | None = None
    mm_per_unit: float | None = None
    process: Process | None = None
    ignore_features: tuple[str, ...] = ()
    gcode: GcodeOptions = field(default_factory=GcodeOptions)
    geometry: Path | None = None
    inlet_radius_mm: float = DEFAULT_INLET_RADIUS_MM
    pixel_mm: float | None = None
    laser: dict[str, Any] = field(default_factory=dict)
    part: Part | None = None
    part_request: PartRequest = PartRequest()


@dataclass(frozen=True)
class Exported:
    """What one writer wrote: ``path`` (a file, or the laser writer's folder) in ``format``
    for ``machine``, ``summary``, its one-paragraph description (``fabkit export`` prints
    it; ``report.json`` keeps it), and ``figures``, its key figures as numbers named with
    their units (G-code: lines, lengths, material volume, estimated time; DXF: entities
    per layer; laser patterns: exposures and pixels)."""

    path: Path
    format: str
    machine: str
    summary: str
    figures: dict[str, Any] = field(default_factory=dict)

    def __str__(self) -> str:
        return self.summary


Source = Toolpath | Design | FlatField
"""What a machine file is written from: a toolpath (G-code, DXF), a solved design or a
director field (laser patterns, the DXF outline)."""


def export(
    source: str | Path,
    machine_name: str,
    fmt: str,
    out: str | Path,
    options: ExportOptions | None = None,
) -> Exported:
    """Read the input file ``source`` (see :func:`read_input`) and write ``out`` in format
    ``fmt`` for the named machine (:func:`write_machine_file`)."""
    options = options or ExportOptions()
    if fmt not in FORMATS:
        raise FabkitError(f"format '{fmt}' is not one of {', '.join(FORMATS)}")
    machine = load_machine(machine_name)
    return write_machine_file(read_input(Path(source), options), machine, fmt, out, options)


def write_machine_file(
    source: Source,
    machine: MachineProfile,
    fmt: str,
    out: str | Path,
    options: ExportOptions | None = None,
) -> Exported:
    """Write ``out`` in format ``fmt`` (gcode, dxf, laser) for ``machine`` from a value."""
    options = options or ExportOptions()
    writers = {"gcode": _gcode, "dxf": _dxf, "laser": _laser}
    if fmt not in writers:
        raise FabkitError(f"format '{fmt}' is not one of {', '.join(FORMATS)}")
    summary, figures = writers[fmt](source, machine, Path(out), options)
    return Exported(Path(out), fmt, machine.name, summary, figures)


def read_input(path: Path, options: ExportOptions | None = None) -> Source:
    """The toolpath, design or director field (clipped to ``options.outline``) in ``path``."""
    if not path.is_file():
        raise FabkitError(f"input file '{path}' does not exist")
    if path.suffix == ".toml":
        flat = load_director_file(path)
        outline = options.part_request.outline if options else None
        return flat if outline is None else flat.clipped(read_outline(outline))
    if path.suffix == ".json":
        return load_toolpath(path)
    if path.suffix != ".npz":
        raise FabkitError(f"input '{path}': expected a toolpath or design .npz, or a .toml")
    names = npz_keys(path, f"{path}: cannot read")
    if {"valid", "r", "n", "eps"} <= names:
        return Design.load(path)
    if "format" in names:
        return load_toolpath(path)
    raise FabkitError(f"{path}: neither a fabkit toolpath nor a design file")


def _field(source: Design | FlatField, options: ExportOptions, process: Process) -> FlatField:
    """The source's field; a design's cut to its part for ``process``'s road width and
    layer height."""
    if isinstance(source, FlatField):
        return source
    if options.part is not None:
        return field_from_design(source, part=options.part)
    if options.size_mm is None and options.mm_per_unit is None:
        raise FabkitError(
            "a design is in design units: give its size (--size MM, longest side) "
            "or --scale MM_PER_UNIT"
        )
    part = options.part_request.for_process(process.road_width_mm, process.layer_height_mm)
    return field_from_design(source, options.size_mm, options.mm_per_unit, part)


Written = tuple[str, dict[str, Any]]
"""A writer's summary and figures (:class:`Exported`)."""


def _gcode(source: Source, machine: MachineProfile, out: Path, options: ExportOptions) -> Written:
    if not isinstance(source, Toolpath):
        raise FabkitError(
            "G-code is written from a toolpath: make one from the design first "
            "(fabkit toolpath), then export the toolpath"
        )
    gcode = replace(options.gcode, offset_mm=options.offset_mm)
    s = write_gcode(source, machine, out, gcode)
    figures = {
        "lines": s.lines,
        "moves": s.motion_lines,
        "print_length_mm": s.print_length_mm,
        "non_printing_mm": s.travel_length_mm,
        "volume_mm3": s.volume_mm3,
        "estimated_seconds": s.duration_s,
    }
    return describe_gcode(out, s, machine.name), figures


def describe_gcode(out: Path, s: GcodeSummary, machine: str) -> str:
    """The one-line summary of a written G-code file (``fabkit export``, ``report.json``)."""
    if s.e_mode == "none":
        extrusion = "no E axis: flow switched by the machine's flow on/off G-code"
    elif s.nominal_e:
        extrusion = (
            "no E axis: flow switched by the machine's flow on/off G-code; nominal E "
            f"{s.e_mode}, in {s.e_units} units, for G-code viewers (the firmware ignores it)"
        )
    else:
        extrusion = f"E {s.e_mode}, in {s.e_units} units"
    return (
        f"wrote {out}: {s.lines} lines ({s.motion_lines} moves), printing {s.print_length_mm:.1f}"
        f" mm, non-printing moves {s.travel_length_mm:.1f} mm (travels between lines, lifts, "
        f"to and from the sheet), volume {s.volume_mm3:.2f} mm^3, estimated duration "
        f"{clock(s.duration_s)}; {extrusion}; offset {_xyz(s.offset_mm)} mm on {machine}"
    )


def _dxf(source: Source, machine: MachineProfile, out: Path, options: ExportOptions) -> Written:
    layers = load_geometry(options.geometry) if options.geometry else {}
    toolpath: Toolpath | None = None
    if isinstance(source, Toolpath):
        toolpath = source
    elif "outline" not in layers:
        process = options.process or machine.process
        layers["outline"] = _field(source, options, process).outline
    s = write_dxf(
        out,
        toolpath,
        machine=machine,
        offset_mm=options.offset_mm,
        inlet_radius_mm=options.inlet_radius_mm,
        **layers,
    )
    return describe_dxf(out, s, machine.name), {"entities": dict(s.entities)}


def describe_dxf(out: Path, s: DxfSummary, machine: str) -> str:
    """The one-line summary of a written DXF file (``fabkit export``, ``report.json``)."""
    counts = ", ".join(f"{name} {n}" for name, n in s.entities.items() if n)
    return f"wrote {out}: entities per layer {counts}; offset {_xyz(s.offset_mm)} mm on {machine}"


def _laser(source: Source, machine: MachineProfile, out: Path, options: ExportOptions) -> Written:
    if isinstance(source, Toolpath):
        raise FabkitError(
            "laser patterns are written from a director field: export the design.npz "
            "(or a director .toml), not a toolpath"
        )
    optics = machine.laser
    pixel = (
        options.pixel_mm
        or (optics.pixel_pitch_mm if optics is not None else None)
        or machine.process.road_width_mm
    )
    laser = dict(options.laser)
    image_format = laser.pop("image_format", None) or "png"
    settings = LaserSettings.for_machine(
        machine, **laser, process=options.process, ignore=options.ignore_features
    )
    # the part of a pattern: the writer's own pixel and film, whatever --process encodes
    grid = sample_field(_field(source, options, machine.process), pixel)
    s = write_laser(grid, out, machine, settings, options.offset_mm, image_format)
    scan = f", {s.scan_lines} scan lines" if s.scan_lines else ""
    cures = len(s.manifest["cure_exposures"])
    cure = f" and {cures} cure masks" if cures else ""
    notes = "".join(f"; warning: {w}" for w in s.warnings)
    summary = (
        f"wrote {out}/: {s.domain_pixels} domain pixels at {pixel:g} mm in {s.exposures} "
        f"exposure masks{cure}{scan}; binning error max {s.max_binning_error_deg:.2f} deg, rms "
        f"{s.rms_binning_error_deg:.2f} deg; origin {_xyz(s.origin_mm)} mm on {machine.name}"
        f"{notes}"
    )
    figures = {"exposures": s.exposures, "domain_pixels": s.domain_pixels, "pixel_mm": pixel}
    return summary, figures


def load_geometry(path: Path) -> dict[str, shapely.Geometry]:
    """The outline/channels/inlet layers of a GeoJSON FeatureCollection (mm)."""
    data = read_json(path, "geometry file")
    try:
        features = data["features"] if data.get("type") == "FeatureCollection" else None
    except (AttributeError, KeyError, TypeError) as exc:
        raise FabkitError(f"geometry file '{path}': not GeoJSON ({exc})") from None
    if not isinstance(features, list):
        raise FabkitError(f"geometry file '{path}': expected a GeoJSON FeatureCollection")
    parts: dict[str, list[shapely.Geometry]] = {}
    for k, feature in enumerate(features):
        layer = (feature.get("properties") or {}).get("layer")
        if layer not in GEOMETRY_LAYERS:
            raise FabkitError(
                f"geometry file '{path}': feature {k} has layer {layer!r}, "
                f"expected one of {', '.join(GEOMETRY_LAYERS)}"
            )
        try:
            parts.setdefault(layer, []).append(shapely.geometry.shape(feature["geometry"]))
        except (KeyError, TypeError, ValueError, AttributeError, ShapelyError) as exc:
            raise FabkitError(f"geometry file '{path}': feature {k}: {exc}") from None
    return {layer: shapely.GeometryCollection(items) for layer, items in parts.items()}


def _xyz(values: tuple[float, ...]) -> str:
    return ",".join(f"{v:.2f}" for v in values)
