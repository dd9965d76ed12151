"""One toolpath job, as the command line states it: inputs, process, layers, outputs.

:func:`run_job` loads the inputs (design files, director TOML files, or a director
expression on a named shape), takes the process it is given (the command line reads the
machine profile or ``--process`` file once) with the overrides, plans the toolpath, and
writes into the output folder:

* ``toolpath.npz`` (and ``toolpath.json`` on request): the :class:`Toolpath`;
* ``quality.json``: the quality of every layer, the settings and any warnings;
* ``preview.png`` and ``preview.svg`` (unless ``preview`` is off: ``fabkit run`` has
  them drawn in its worker process, :func:`fabkit.toolpath.preview.preview_images`).

:func:`run_channel_job` does the same for baromorph channels: ``channels.json`` (closed
polygons, widths, eps, the checks), ``mould.stl`` and ``channels.png``/``channels.svg``.

Every file is written atomically (no half-written output on failure).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import shapely

from fabkit.design.design import Design
from fabkit.design.layers import SHARED_TURN_DEG
from fabkit.errors import FabkitError
from fabkit.field.design_field import field_from_design
from fabkit.field.director_file import load_director_file
from fabkit.field.flat import FlatField, field_from_expression
from fabkit.field.outlines import parse_shape, read_outline
from fabkit.field.part import MIN_WIDTH_PITCHES, MIN_WIDTH_ROADS, Part, PartOptions, PartRequest
from fabkit.files.atomic import atomic_path, check_folder
from fabkit.limits import TOOLPATH_LAYERS, TOOLPATH_MOVES
from fabkit.process import Process
from fabkit.toolpath.baromorph import (
    BaromorphSettings,
    ChannelLayout,
    ChannelReport,
    check_channels,
    layout_channels,
)
from fabkit.toolpath.lines import LineSettings
from fabkit.toolpath.model import save_toolpath
from fabkit.toolpath.mould import POLARITY, mould_mesh, save_mould
from fabkit.toolpath.plan import Plan, PlanSettings, plan_toolpath
from fabkit.toolpath.process_file import machine_process, resolve_channels


@dataclass(frozen=True)
class ToolpathJob:
    """What to make (see ``fabkit toolpath --help``); lengths in mm.

    A design input is cut to its part (:mod:`fabkit.field.part`) by ``part_request`` (its
    outline also clips a director field; its trim is in bending lengths of a sheet as thick
    as the layers); ``part`` and ``design``: the part made
    and the design loaded already (``fabkit run``) for the one design input, which then
    names them; ``process``: the process to print with (default: the default machine's).
    """

    inputs: tuple[str, ...] = ()
    director: str | None = None
    shape: str | None = None
    eps: str | None = None
    size_mm: float | None = None
    mm_per_unit: float | None = None
    part_request: PartRequest = PartRequest()
    part: Part | None = None
    design: Design | None = None
    process: Process | None = None
    road_width_mm: float | None = None
    layer_height_mm: float | None = None
    layers: int | None = None
    pattern: str = "same"
    encode: bool = True
    ignore_features: tuple[str, ...] = ()
    clip_eps: bool = False
    end_inset: float = LineSettings().end_inset
    phase_rad: float = 0.0
    out: str = "toolpath"
    json: bool = False
    preview: bool = True


@dataclass(frozen=True)
class JobResult:
    """The plan, the files written, the part of every design input and the outline of
    every layer's field (mm)."""

    plan: Plan
    files: tuple[Path, ...]
    parts: tuple[Part, ...] = ()
    outlines: tuple[shapely.Geometry, ...] = ()


def run_job(job: ToolpathJob) -> JobResult:
    """Load, plan and write everything for ``job``."""
    _check_inset(job)
    check_folder(job.out, f"--out {job.out}")
    plan, process, fields = _plan(job)
    out = Path(job.out)
    files = [out / "toolpath.npz", out / "quality.json"]
    save_toolpath(plan.toolpath, files[0])
    _save_quality(plan, process, files[1], fields)
    if job.preview:
        from fabkit.toolpath.preview import save_preview  # matplotlib: only when drawing

        files += [out / "preview.png", out / "preview.svg"]
        save_preview(plan.toolpath, [f.outline for f in fields], files[2:4])
    if job.json:
        files.append(out / "toolpath.json")
        save_toolpath(plan.toolpath, files[-1])
    return _result(plan, tuple(files), fields)


def plan_job(job: ToolpathJob) -> JobResult:
    """Load and plan ``job`` in memory, writing nothing (``files`` is empty; ``out``,
    ``json`` and ``preview`` are not used): :func:`fabkit.api.plan_toolpath`."""
    _check_inset(job)
    plan, _, fields = _plan(job)
    return _result(plan, (), fields)


def _check_inset(job: ToolpathJob) -> None:
    if not 0 <= job.end_inset <= 1:
        raise FabkitError(f"--end-inset {job.end_inset:g}: expected a fraction of w in [0, 1]")


def _plan(job: ToolpathJob) -> tuple[Plan, Process, list[FlatField]]:
    """The plan of ``job``, the process it was planned for and the fields it was planned
    from (bottom layer first)."""
    process = job_process(job)
    designs = [p for p in job.inputs if Path(p).suffix == ".npz"]
    if job.design is None and len(job.inputs) == 1 and designs:
        job = replace(job, design=Design.load(designs[0]))  # loaded once, for every stage
    layers = job.layers if job.layers is not None else _design_layers(job)
    fields = load_fields(job, process.road_width_mm, layers * process.layer_height_mm)
    if job.encode:
        for flat in fields:  # a feature without a channel is refused before planning
            ignore = tuple(name for name in job.ignore_features if name in flat.names)
            resolve_channels(process, flat.names, ignore)
    _check_extent(fields, process.road_width_mm, layers)
    settings = PlanSettings(
        layers=layers,
        pattern=job.pattern,
        encode=job.encode,
        ignore=job.ignore_features,
        lines=LineSettings(end_inset=job.end_inset),
        phase_rad=job.phase_rad,
        shared_lines=_small_turn(job.design),
    )
    return plan_toolpath(fields, process, settings), process, fields


def _small_turn(design: Design | None) -> bool:
    """Whether ``design`` is layered, its bottom and top layers' directors within
    :data:`~fabkit.design.layers.SHARED_TURN_DEG` (lines turned further would drift apart
    along their length, so those layers are planned apart)."""
    if design is None or design.layering is None:
        return False
    layering = design.layering
    spread = float(layering.heights[-1] - layering.heights[0])
    turn = np.nanmax(np.abs(layering.turn), initial=0.0) * spread
    return bool(turn <= np.radians(SHARED_TURN_DEG) * (1 + 1e-9))  # the refinement's cap


def _result(plan: Plan, files: tuple[Path, ...], fields: list[FlatField]) -> JobResult:
    parts = tuple(f.part for f in fields if f.part is not None)
    return JobResult(plan, files, parts, tuple(f.outline for f in fields))


def _design_layers(job: ToolpathJob) -> int:
    """The layers a job prints without ``--layers``: a layered design's, else one per
    input."""
    if job.design is not None:
        return job.design.layers
    return max(1, len(job.inputs) + (job.director is not None))


MAX_ROADS_ACROSS = 5000
"""Road widths across the sheet beyond which planning would take hours and many GB."""


def _check_extent(fields: list[FlatField], road_width_mm: float, layers: int) -> None:
    """Refuse, before planning, a sheet too many road widths across (e.g. a mistyped
    --size), or so many layers of it that the toolpath would hold more moves than a
    toolpath file may (about two moves, a line and a travel, per road width per layer)."""
    x0, y0, x1, y1 = np.array([f.outline.bounds for f in fields]).T
    across = max(x1.max() - x0.min(), y1.max() - y0.min())
    roads = across / road_width_mm
    if roads > MAX_ROADS_ACROSS:
        raise FabkitError(
            f"the sheet is {across:.4g} mm across, {roads:.4g} road widths of "
            f"{road_width_mm:g} mm, more than {MAX_ROADS_ACROSS}: give a smaller --size "
            "(or a wider --road-width)"
        )
    moves = 2 * roads * max(layers, 1)
    if layers > TOOLPATH_LAYERS or moves > TOOLPATH_MOVES:
        raise FabkitError(
            f"--layers {layers} of a sheet {roads:.0f} road widths across make about "
            f"{moves:.3g} moves, more than the limit of {TOOLPATH_MOVES} moves (or "
            f"{TOOLPATH_LAYERS} layers) a toolpath file holds: give fewer --layers"
        )


def load_fields(
    job: ToolpathJob,
    road_width_mm: float | None = None,
    thickness_mm: float | None = None,
    roads: float = MIN_WIDTH_ROADS,
) -> list[FlatField]:
    """The flat-sheet fields of the job's inputs, in order (bottom layer first); a design
    is cut to its part for a process of this road width (mm) making a sheet this thick
    (mm), by default no narrower than ``roads`` road widths."""
    options = job.part_request.for_process(road_width_mm, thickness_mm, roads)
    if (job.part is not None or job.design is not None) and len(job.inputs) != 1:
        raise FabkitError("a part or design made already goes with one design input")
    fields = [f for path in job.inputs for f in _load_input(path, job, job.part or options)]
    if job.director is not None:
        if job.shape is None:
            raise FabkitError("--director needs --shape (e.g. --shape disc:10)")
        fields.append(
            field_from_expression(job.director, parse_shape(job.shape, "--shape"), job.eps)
        )
    elif job.shape is not None or job.eps is not None:
        raise FabkitError("--shape and --eps go with --director")
    if not fields:
        raise FabkitError("give a design.npz or director .toml input, or --director with --shape")
    if job.part_request.outline is not None:
        clip = read_outline(job.part_request.outline)
        fields = [f if f.part is not None else f.clipped(clip) for f in fields]
    return fields


def _load_input(path: str, job: ToolpathJob, part: Part | PartOptions) -> list[FlatField]:
    """The input's field; a layered design's: one per layer, bottom first, on one part."""
    suffix = Path(path).suffix
    if suffix == ".npz":
        design = job.design or Design.load(path)  # the one design input, loaded already (run)
        if isinstance(part, Part):
            whole = field_from_design(design, part=part, name=path)
        else:
            whole = field_from_design(design, job.size_mm, job.mm_per_unit, part, name=path)
        if design.layering is None:
            return [whole]
        return [
            field_from_design(design.layer(k), part=whole.part, name=f"{path} layer {k + 1}")
            for k in range(design.layers)
        ]
    if suffix == ".toml":
        return [load_director_file(path)]
    raise FabkitError(f"input '{path}': expected a design .npz or a director .toml file")


def job_process(job: ToolpathJob) -> Process:
    """The job's process (default: the default machine's), then the overrides."""
    process = job.process or machine_process(None)
    process = process.with_overrides(
        road_width_mm=job.road_width_mm, layer_height_mm=job.layer_height_mm
    )
    return process.with_clip() if job.clip_eps else process


def _save_quality(plan: Plan, process: Process, path: Path, fields: list[FlatField]) -> None:
    report = {
        "parts": [f.part.to_dict() for f in fields if f.part is not None],
        "layers": [q.to_dict() for q in plan.quality],
        "road_width_mm": process.road_width_mm,
        "layer_height_mm": process.layer_height_mm,
        "process": process.source,
        "channels": dict(plan.toolpath.channels),
        "ignored_features": plan.toolpath.meta.get("ignored_features", []),
        "sources": plan.toolpath.meta.get("sources", []),
        "warnings": list(plan.warnings),
    }
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(report, indent=2), encoding="utf-8")


@dataclass(frozen=True)
class ChannelJob:
    """Baromorph channels for one input (the field options as in :class:`ToolpathJob`)."""

    fields: ToolpathJob
    baromorph: BaromorphSettings
    out: str = "channels"


@dataclass(frozen=True)
class ChannelResult:
    """The layout, its checks, the files written, and the design's scale (mm per design
    unit; None for a director field)."""

    layout: ChannelLayout
    report: ChannelReport
    files: tuple[Path, ...]
    mm_per_unit: float | None = None
    part: Part | None = None


def run_channel_job(job: ChannelJob) -> ChannelResult:
    """Lay out, check and write baromorph channels and their mould."""
    check_folder(job.out, f"--out {job.out}")
    settings = job.baromorph
    fields = load_fields(
        job.fields, settings.pitch_mm, settings.part_thickness_mm, MIN_WIDTH_PITCHES
    )
    if len(fields) != 1:
        raise FabkitError("channels: give exactly one input field")
    layout = layout_channels(fields[0], settings)
    report = check_channels(layout, settings)
    out = Path(job.out)
    files = (out / "channels.json", out / "mould.stl", out / "channels.png", out / "channels.svg")
    with atomic_path(files[0]) as tmp:
        tmp.write_text(json.dumps(_channels_json(layout, report)), encoding="utf-8")
    save_mould(mould_mesh(layout, settings), files[1])
    from fabkit.toolpath.preview import save_channel_preview  # matplotlib: only when drawing

    save_channel_preview(layout, list(files[2:]))
    return ChannelResult(layout, report, files, fields[0].mm_per_unit, fields[0].part)


def _channels_json(layout: ChannelLayout, report: ChannelReport) -> dict:
    def rings(geometry) -> list[dict]:
        return [
            {
                "exterior": np.asarray(polygon.exterior.coords).tolist(),
                "holes": [np.asarray(r.coords).tolist() for r in polygon.interiors],
            }
            for polygon in shapely.get_parts(geometry)
        ]

    return {
        "units": "mm",
        "polarity": POLARITY,
        "report": asdict(report),
        "inlet": list(layout.inlet),
        "network": rings(layout.network),
        "manifold": rings(layout.manifold),
        "channels": [
            {
                "polygon": rings(channel),
                "centreline": line.tolist(),
                "width_mm": width.tolist(),
                "eps": eps.tolist(),
            }
            for channel, line, width, eps in zip(
                layout.channels, layout.centrelines, layout.widths, layout.eps, strict=True
            )
        ],
    }
