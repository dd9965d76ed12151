"""``fabkit run``: spec to machine files in one go, by calling each stage in turn.

spec -> solve -> check -> part -> pictures -> toolpath -> export -> verify (-> send). The
part of the flat sheet that is made (:mod:`fabkit.field.part`: a smooth outline inside the
solved cells, trimmed of regions too narrow to take their shape, no narrower than the
minimum width, within ``--outline``) is cut once, right after the solve, and every later
stage takes it: the pictures, the print lines, channels or laser patterns, and the
verification. Every
feature of the design goes to the machine through its own channel of the process (a
feature the process does not encode is refused before any work, unless it is named with
``--ignore-feature``, which the report then says on its first line); the machine file is
then read back and checked (``fabkit verify``, skipped with ``--no-verify``). Every stage
writes
through :func:`fabkit.atomic.atomic_path`, so an interrupted run leaves no half-written
file under a final name. The output folder is claimed first
(:func:`fabkit.atomic.output_folder`): a folder holding an earlier run's files is refused
unless ``--overwrite``, which removes exactly the files that run wrote (listed in the
folder's ``.fabkit-files``); a folder holding files fabkit did not write is refused.

Files in the output folder:

================== ==============================================================
design.npz/.json   the design and its solve summary (``fabkit solve``)
pictures/          flat sheet, eps, actuated surfaces, residual maps (PNG)
patches/           each actuated patch as a mesh (PLY, or ``--mesh-format``)
toolpath/          toolpath.npz, quality.json, preview.png/svg (``fabkit toolpath``)
sheet.gcode        machine file(s), one per ``--format`` (``fabkit export``)
sheet.dxf          (with ``--format dxf``)
laser/             (with ``--format laser`` on a laser-writer profile)
as_fabricated/     per target, the sheet as fabricated beside it (PNG) and as a mesh (PLY, mm);
                   ``as_designed/`` when the machine file is not simulated
report.html        the verdict first, then every picture and figure in words (one page)
report.json        the key figures as data (``docs/report.schema.json``)
================== ==============================================================
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from contextlib import suppress
from dataclasses import asdict, dataclass, field, replace
from functools import partial
from multiprocessing.pool import AsyncResult
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from fabkit.atomic import atomic_path, check_folder, inside, output_folder, record
from fabkit.background import Worker, worker
from fabkit.design.check import CheckReport, ResidualMaps
from fabkit.design.design import MAX_LAYERS, Design
from fabkit.design.layers import layered
from fabkit.design.patches import MESH_TYPES, patch_paths, write_patch_meshes
from fabkit.design.summary import checked_points, solve_to_file
from fabkit.errors import FabkitError
from fabkit.field.design_field import feature_names as design_features
from fabkit.field.part import (
    MIN_WIDTH_PITCHES,
    MIN_WIDTH_ROADS,
    Part,
    PartRequest,
    print_part,
    scale_for_size,
    solved_region,
)
from fabkit.figures import AREA_UNIT
from fabkit.machines import DEFAULT_MACHINE, MachineProfile, load_machine
from fabkit.mechanics.mesh import save_mesh
from fabkit.mechanics.verdict import FORM_TOLERANCE, Verdict, design_verdict
from fabkit.plot import DESIGN_PICTURES, write_pictures
from fabkit.plot.html import html_report
from fabkit.plot.page_sections import run_page
from fabkit.plot.scene import scene
from fabkit.problem.spec import Spec, load_spec
from fabkit.process import Process
from fabkit.toolpath.baromorph import BaromorphSettings, load_baromorph
from fabkit.toolpath.job import ChannelJob, ToolpathJob, run_channel_job, run_job
from fabkit.toolpath.process_file import load_process, resolve_channels
from fabkit.writers.dxf import layout_layers, write_dxf
from fabkit.writers.export import ExportOptions, describe_dxf, write_machine_file

if TYPE_CHECKING:
    from fabkit.link.host.hosts import HostReport
    from fabkit.link.host.session import SendReport
    from fabkit.verify.machine_file import Verification

FORMAT_FILES = {"gcode": "sheet.gcode", "dxf": "sheet.dxf", "laser": "laser"}
BAROMORPH_MACHINE = "laser_cutter"
LASER_WRITER = "laser_writer"
DEFAULT_SIZE_MM = 60.0


@dataclass(frozen=True)
class RunOptions:
    """What ``fabkit run`` is asked to do; ``size_mm`` is the sheet's longest side in mm.

    ``step`` and ``diagonals`` replace the spec's solver settings when given;
    ``mesh_format`` is the patch meshes' file type (ply, stl, glb or obj).

    ``formats`` None: DXF for baromorph channels, laser patterns on a laser writer, else
    G-code. ``machine`` None: laser_cutter for baromorph channels, else a pneumatic DIW.
    ``ignore_features`` are left out of the machine file on purpose; ``verify`` reads the
    machine file back and checks it (:mod:`fabkit.verify`). ``overwrite`` replaces the
    files an earlier run wrote into ``out`` (else such a folder is refused).
    ``part_request`` cuts the part (:class:`fabkit.field.part.PartRequest`). ``layers``
    (>= 2) prints the sheet in that many layers programmed with each target's curvature
    (:mod:`fabkit.design.layers`); every target is then simulated from flat, as designed
    and as fabricated, and held to ``form_tolerance`` (RMS, a share of the patch
    diameter); ``strict`` makes a target not formed an error (the run's exit code).
    ``send`` is a port, a pyserial URL or a printer host's URL
    (:mod:`fabkit.link.host.web`), whose API key is ``api_key``, else the first line of
    ``api_key_file``, else the environment's FABKIT_API_KEY; the key is never shown nor
    written.
    """

    spec: str
    out: str
    machine: str | None = None
    formats: tuple[str, ...] | None = None
    size_mm: float = DEFAULT_SIZE_MM
    send: str | None = None
    api_key: str | None = field(default=None, repr=False)
    api_key_file: str | None = None
    process_file: str | None = None
    baromorph: str | None = None
    step: float | None = None
    diagonals: int | None = None
    mesh_format: str = "ply"
    ignore_features: tuple[str, ...] = ()
    verify: bool = True
    overwrite: bool = False
    part_request: PartRequest = PartRequest()
    layers: int = 1
    strict: bool = False
    form_tolerance: float = FORM_TOLERANCE


def run_pipeline(options: RunOptions, say: Callable[[str], None] = print) -> dict[str, Any]:
    """Run every stage; returns the key figures (also written to report.json).

    Every input (spec, options, machine, process and channel files, the output folder) is
    checked before any work, so bad input is refused without writing anything. The
    pictures are drawn in a spawned worker process (:mod:`fabkit.background`), which
    imports the calling script again: a script that calls this keeps its top level under
    ``if __name__ == "__main__":``, as for any spawned process.
    """
    machine = load_machine(_machine_name(options))
    options = _with_defaults(options, machine)
    inputs = _check_inputs(options, machine)
    with output_folder(options.out, f"--out {options.out}", options.overwrite):
        return _stages(options, inputs, say)


@dataclass(frozen=True)
class _Inputs:
    """What the checks read once and every stage takes: the spec (the solver options
    applied), the machine profile, the process (None on a baromorph run) and the
    baromorph's channel settings (None on a print run)."""

    spec: Spec
    machine: MachineProfile
    process: Process | None
    baromorph: BaromorphSettings | None


def _stages(options: RunOptions, inputs: _Inputs, say: Callable[[str], None]) -> dict[str, Any]:
    """Every stage in turn, into the claimed output folder; returns the key figures.

    The design pictures, the toolpath preview and the pictures of the shapes the sheet
    takes are drawn in a second process (:mod:`fabkit.background`) while the later stages
    run, and written at the report (also when a later stage fails).
    """
    out = Path(options.out)
    notice = _notice(options)
    if notice:
        say(f"      {notice}")
    with worker(warm=WORKER_MODULES) as background:
        drawings = _Drawings(background)
        solved = _solve(options, inputs, say)
        say("[2/7] drawing pictures and patch meshes")
        design = solved.design
        drawings.draw(
            "fabkit.plot:draw_design",
            (scene(design, solved.part, solved.maps),),
            partial(write_pictures, folder=out / "pictures"),
        )
        meshes = [
            str(path) for path in write_patch_meshes(design, out / "patches", options.mesh_format)
        ]
        try:
            made = _fabricate(_Run(options, inputs, solved, drawings, say))
        except FabkitError:
            with suppress(Exception):  # the run fails with its own error; keep what it drew
                drawings.write()
            raise
        drawings.write()
    pictures = [(caption, out / "pictures" / name) for name, caption in DESIGN_PICTURES]

    say("[7/7] writing report.html and report.json")
    verification = made.verification.to_dict() if made.verification is not None else None
    figures = {
        **({"notice": notice} if notice else {}),
        "spec": str(options.spec),
        "machine": options.machine,
        "size_mm": options.size_mm,
        "solve": {
            k: solved.summary[k]
            for k in ("solve_seconds", "valid_points", "area_design_units2", "stop_counts")
        },
        "check": solved.check.to_dict(),
        "part": solved.part.to_dict(),
        **({"layers": solved.layering} if solved.layering else {}),
        "as designed": solved.verdict.to_dict(),
        **made.fabricated.figures,
        "machine file": made.machine_file,
        "verify": verification,
        "sent": made.sent,
        "meshes": meshes,
        "shapes": made.shapes,
    }
    verdicts = [solved.verdict.to_dict()]
    if made.final is not solved.verdict:
        verdicts.append(made.final.to_dict())
    figures["verdicts"] = verdicts
    figures["verdict"] = {
        "what": made.final.what,
        "headline": made.final.headline(),
        "formed": all(v["formed"] for v in verdicts),
        "lines": made.final.lines(),
    }
    page = run_page(figures, pictures, made.fabricated.picture, out)
    html_report(page, out / "report.html")
    with atomic_path(out / "report.json") as tmp:
        tmp.write_text(json.dumps(figures, indent=2) + "\n", encoding="utf-8")
    return figures


@dataclass(frozen=True)
class _Solved:
    """The solve stage's results: the ``design`` (layered when asked), its check
    (``check``, the residual ``maps``), the solver's ``summary``, the ``part`` that is
    made, how well the layers program the curvature (``layering``, None for one layer)
    and the ``verdict`` on the sheet as designed."""

    design: Design
    check: CheckReport
    maps: tuple[ResidualMaps, ...]
    summary: dict[str, Any]
    part: Part
    layering: dict[str, Any] | None
    verdict: Verdict


def _solve(options: RunOptions, inputs: _Inputs, say: Callable[[str], None]) -> _Solved:
    """Solve and check the spec into design.npz; cut the part that is made."""
    say(f"[1/7] solving {options.spec}")
    result = solve_to_file(inputs.spec, Path(options.out) / "design.npz", "      solving")
    check, solved = result.check, result.summary
    say(
        f"      {solved['valid_points']} valid points in {solved['solve_seconds']:.2f} s; "
        f"check {'passed' if check.passed else 'FAILED'}"
    )
    say(f"      {checked_points(solved['check'])}")
    say(
        f"      area over the solved cells ({AREA_UNIT}): "
        + ", ".join(f"{k} {v:.4g}" for k, v in solved["area_design_units2"].items())
    )
    design = result.solution.design
    part = _part(options, inputs, design)
    say(f"      {part.summary()}")
    thickness_mm = options.layers * inputs.process.layer_height_mm if inputs.process else None
    layering = None
    if options.layers > 1:
        request = LayerRequest(
            options.layers, inputs.process, part, options.ignore_features, options.form_tolerance
        )
        design, layering = layer_design(design, request, say)
        design.save(Path(options.out) / "design.npz")
    verdict = design_verdict(
        design,
        None if thickness_mm is None else thickness_mm / part.mm_per_unit,
        tolerance=options.form_tolerance,
        part=part,
        mm_per_unit=part.mm_per_unit,
    )
    say(f"      {verdict.headline()}:")
    for line in verdict.lines():
        say(f"        {line}")
    return _Solved(design, check, result.maps, solved, part, layering, verdict)


@dataclass(frozen=True)
class LayerRequest:
    """A layered sheet asked for: ``layers`` of the ``process``'s layer height on the
    ``part`` (its scale sets the thickness in design units), features within the ranges
    their channels encode (``ignore_features`` left out), targets held to ``tolerance``."""

    layers: int
    process: Process
    part: Part
    ignore_features: tuple[str, ...] = ()
    tolerance: float = FORM_TOLERANCE


def layer_design(
    design: Design, request: LayerRequest, say: Callable[[str], None] = print
) -> tuple[Design, dict[str, Any]]:
    """The design made of ``request.layers`` layers, programmed with the curvature of the
    targets the sheet misses when programmed by its metric alone (simulated at the
    layers' thickness: a target it forms asks for nothing, and is bent to no other
    side), and the figures of how well (``fabkit run --layers``, ``fabkit solve
    --layers``)."""
    process, part = request.process, request.part
    thickness = request.layers * process.layer_height_mm / part.mm_per_unit
    names = design_features(design)
    bounds = process.resolve(names, request.ignore_features).bounds(names)
    alone = design_verdict(
        design, thickness, tolerance=request.tolerance, part=part, mm_per_unit=part.mm_per_unit
    )
    say(f"      {alone.headline().replace('as designed', 'programmed by its metric alone')}")
    needed = {shape.target: not shape.formed for shape in alone.shapes}
    weights = np.array([float(needed.get(t.name, False)) for t in design.problem.targets])
    design, report = layered(design, request.layers, thickness, bounds, weights)
    say(
        f"      {request.layers} layers of {process.layer_height_mm:g} mm, programmed with "
        "the curvature of the targets the metric misses:"
    )
    for line in report.lines():
        say(f"        {line}")
    return design, {"metric alone": alone.to_dict(), **report.to_dict()}


def design_part(
    design: Design,
    size_mm: float,
    process: Process,
    layers: int = 1,
    request: PartRequest | None = None,
) -> Part:
    """The part of a printed sheet (``fabkit run``): at ``size_mm`` (its longest side), for
    the process's road width and a sheet of ``layers`` of its layer height."""
    solved = solved_region(design)
    options = (request or PartRequest()).for_process(
        process.road_width_mm, layers * process.layer_height_mm, MIN_WIDTH_ROADS
    )
    return print_part(design, scale_for_size(solved, size_mm), options, solved)


WORKER_MODULES = ("fabkit.plot.design", "fabkit.toolpath.preview", "fabkit.plot.shapes")
"""What the worker imports while the run solves: the drawings it will be given."""


class _Drawings:
    """Pictures the worker draws while the run goes on, and how each is written: all are
    written together, when the run reaches its report or when a later stage fails."""

    def __init__(self, background: Worker) -> None:
        self._background = background
        self._pending: list[tuple[AsyncResult, Callable[[Any], Any]]] = []

    def draw(self, function: str, args: tuple[Any, ...], write: Callable[[Any], Any]) -> None:
        """Have ``function`` (``"module:name"``) draw from ``args``; ``write`` its result."""
        self._pending.append((self._background.start(function, *args), write))

    def write(self) -> None:
        """Wait for every drawing and write it."""
        while self._pending:
            result, write = self._pending.pop(0)
            write(result.get())


def _write_images(stem: Path, images: dict[str, bytes]) -> None:
    """Write each image (format -> bytes) as ``stem`` with the format's suffix."""
    for fmt, data in images.items():
        with atomic_path(stem.with_suffix(f".{fmt}")) as tmp:
            tmp.write_bytes(data)


@dataclass(frozen=True)
class _Run:
    """What every stage after the solve takes: the run's ``options``, the ``inputs`` read
    once, the ``solved`` design, the worker's ``drawings`` and ``say`` for its lines."""

    options: RunOptions
    inputs: _Inputs
    solved: _Solved
    drawings: _Drawings
    say: Callable[[str], None]

    @property
    def out(self) -> Path:
        """The output folder."""
        return Path(self.options.out)


@dataclass(frozen=True)
class _Made:
    """What the stages after the solve made: the ``fabricated`` figures and preview, the
    first ``machine_file``'s figures, its ``verification`` (None with --no-verify), the
    ``final`` verdict (as fabricated when the machine file was simulated, else as
    designed), the ``shapes`` it found (report.json's ``shapes``) and the ``sent``
    figures (None without --send)."""

    fabricated: _Fabricated
    machine_file: dict[str, Any]
    verification: Verification | None
    final: Verdict
    shapes: dict[str, Any]
    sent: dict[str, Any] | None


def _fabricate(run: _Run) -> _Made:
    """The machine files, their verification, the shapes the sheet takes and the send."""
    options = run.options
    if options.baromorph:
        fabricated = _channels(run)
    elif run.inputs.machine.kind == LASER_WRITER:
        fabricated = _laser_patterns(run)
    else:
        fabricated = _print_lines(run)

    verification = _verify(run)
    final = run.solved.verdict
    if verification is not None and verification.verdict is not None:
        final = verification.verdict
    shapes = _shapes(run, final)

    sent = None
    if options.send:
        run.say(f"[6/7] sending sheet.gcode to {options.send}")
        sent = _send(run.out / "sheet.gcode", options, run.inputs.machine).figures()
    else:
        run.say("[6/7] not sending (no --send)")
    return _Made(fabricated, fabricated.machine_file, verification, final, shapes, sent)


def _shapes(run: _Run, verdict: Verdict) -> dict[str, Any]:
    """The shape the sheet takes under every target's stimulus (``verdict``'s meshes): a
    mesh per target written now (PLY, mm, with each vertex's distance to the target), a
    picture per target drawn by the worker; both in ``as_fabricated/`` (``as_designed/``
    when the machine file was not simulated). Returns report.json's ``shapes``."""
    folder = verdict.what.replace(" ", "_")
    shown = tuple(shape for shape in verdict.shapes if shape.mesh is not None)
    targets = []
    for shape in shown:
        mesh = shape.mesh
        path = inside(run.out / folder, f"{shape.target}.ply")
        save_mesh(path, mesh.vertices_mm, mesh.triangles, {"distance_mm": mesh.distance_mm})
        targets.append(
            {
                "target": shape.target,
                "mesh": f"{folder}/{shape.target}.ply",
                "picture": f"{folder}/{shape.target}.png",
            }
        )
    run.drawings.draw(
        "fabkit.plot.shapes:shape_pictures",
        (verdict.what, shown),
        partial(_write_files, [run.out / t["picture"] for t in targets]),
    )
    return {"what": verdict.what, "folder": folder, "targets": targets}


def _write_files(paths: list[Path], contents: tuple[bytes, ...]) -> None:
    """Write each of ``contents`` at its path (atomically)."""
    for path, data in zip(paths, contents, strict=True):
        with atomic_path(path) as tmp:
            tmp.write_bytes(data)


def _check_send(options: RunOptions) -> None:
    """Refuse a bad printer host URL or API key before any work (a port is opened only at
    the send: it may be plugged in meanwhile)."""
    from fabkit.link.host.web import is_host_url, parse_host_url, resolve_api_key

    if options.send and is_host_url(options.send):
        parse_host_url(options.send)
        resolve_api_key(options.api_key, options.api_key_file)
    elif options.api_key is not None or options.api_key_file is not None:
        raise FabkitError("--api-key and --api-key-file are for --send to a printer host")


def _check_inputs(options: RunOptions, machine: MachineProfile) -> _Inputs:
    """Refuse bad input before any work; returns the spec (the solver options applied),
    ``machine`` and the process."""
    for fmt in options.formats:
        if fmt not in FORMAT_FILES:
            raise FabkitError(f"--format {fmt}: expected one of {', '.join(FORMAT_FILES)}")
    if options.mesh_format not in MESH_TYPES:
        raise FabkitError(
            f"--mesh-format {options.mesh_format}: expected one of " + ", ".join(MESH_TYPES)
        )
    if options.send and "gcode" not in options.formats:
        raise FabkitError("--send needs --format gcode")
    _check_send(options)
    if not (math.isfinite(options.size_mm) and options.size_mm > 0):
        raise FabkitError(f"--size {options.size_mm:g}: expected a positive finite number")
    if not 1 <= options.layers <= MAX_LAYERS:
        raise FabkitError(f"--layers {options.layers}: expected 1 to {MAX_LAYERS} layers")
    if not (math.isfinite(options.form_tolerance) and 0 < options.form_tolerance < 1):
        raise FabkitError(
            f"--form-tolerance {100 * options.form_tolerance:g}: expected a percentage "
            "between 0 and 100"
        )
    check_folder(options.out, f"--out {options.out}")
    options.part_request.check()
    spec = load_spec(options.spec)
    patch_paths(spec.targets, Path(options.out) / "patches", options.mesh_format)
    if options.step is not None or options.diagonals is not None:
        spec = spec.with_solver(step=options.step, diagonals=options.diagonals)
    baromorph = None
    if options.baromorph:
        if options.formats != ("dxf",):
            raise FabkitError("a baromorph run writes DXF only: use --format dxf (or no --format)")
        baromorph = load_baromorph(options.baromorph)
    elif machine.kind == LASER_WRITER and options.formats != ("laser",):
        raise FabkitError(
            f"{options.machine} is a laser writer: use --format laser (or no --format)"
        )
    if options.layers > 1 and (options.baromorph or machine.kind == LASER_WRITER):
        what = "a baromorph's channels" if options.baromorph else f"laser writer {machine.name}"
        raise FabkitError(
            f"--layers {options.layers}: {what} make one layer; print a layered sheet on a "
            "printer (fabkit machines lists them)"
        )

    process = None
    if not options.baromorph:
        process = load_process(options.process_file) if options.process_file else machine.process
        resolve_channels(process, spec.material.features, options.ignore_features)
    elif options.ignore_features:
        raise FabkitError("--ignore-feature: a baromorph run encodes one feature as the width")
    spans = [hi - lo for lo, hi in (machine.envelope.x_mm, machine.envelope.y_mm)]
    if options.size_mm > max(spans):
        raise FabkitError(
            f"--size {options.size_mm:g}: the sheet does not fit the envelope of "
            f"{options.machine} ({spans[0]:g} x {spans[1]:g} mm); give a smaller --size"
        )
    return _Inputs(spec, machine, process, baromorph)


def _notice(options: RunOptions) -> str:
    """The report's first line when features are left out on purpose ("" if none)."""
    if not options.ignore_features:
        return ""
    names = ", ".join(options.ignore_features)
    plural = "s" if len(options.ignore_features) > 1 else ""
    return (
        f"NOT ENCODED: feature{plural} {names} left out on purpose (--ignore-feature): the "
        "machine file does not carry "
        + ("them" if plural else "it")
        + ", so the sheet it makes cannot take every designed shape"
    )


def _part(options: RunOptions, inputs: _Inputs, design: Design) -> Part:
    """The part of the flat sheet that is made, at the run's size, for its process: the
    road width (a baromorph's: two channel pitches) and the sheet's thickness (its layers'
    heights; a baromorph's part thickness) set the default minimum width and the trim."""
    if not options.baromorph:
        return design_part(
            design, options.size_mm, inputs.process, options.layers, options.part_request
        )
    settings = inputs.baromorph
    solved = solved_region(design)
    return print_part(
        design,
        scale_for_size(solved, options.size_mm),
        options.part_request.for_process(
            settings.pitch_mm, settings.part_thickness_mm, MIN_WIDTH_PITCHES
        ),
        solved,
    )


def _verify(run: _Run) -> Verification | None:
    """Read the first machine file back and check it (None with --no-verify)."""
    options, out, say = run.options, run.out, run.say
    if not options.verify:
        say("[5/7] not verifying (--no-verify)")
        return None
    from fabkit.verify.machine_file import VerifyOptions, verify

    target = out / ("channels.dxf" if options.baromorph else FORMAT_FILES[options.formats[0]])
    say(f"[5/7] verifying {target.name}: reading it back, simulating the sheet as fabricated")
    result = verify(
        out / "design.npz",
        target,
        VerifyOptions(
            machine=run.inputs.machine,
            process=run.inputs.process,
            ignore_features=options.ignore_features,
            baromorph=run.inputs.baromorph,
            part=run.solved.part,
            form_tolerance=options.form_tolerance,
        ),
        design=run.solved.design,
    )
    for line in result.table().splitlines()[1:-1]:
        say(f"      {line.strip()}")
    return result


def _send(path: Path, options: RunOptions, machine: MachineProfile) -> SendReport | HostReport:
    """Send the machine file to ``options.send``, a port or a printer host, for ``machine``."""
    from fabkit.link.host.send import send_file
    from fabkit.link.host.web import is_host_url

    host = options.send if is_host_url(options.send) else None
    return send_file(
        path,
        None if host else options.send,
        host=host,
        machine=machine,
        api_key=options.api_key,
        api_key_file=options.api_key_file,
    )


def _machine_name(options: RunOptions) -> str:
    """The machine of a run: --machine, else the laser cutter for baromorph channels, else
    the default printer."""
    return options.machine or (BAROMORPH_MACHINE if options.baromorph else DEFAULT_MACHINE)


def _with_defaults(options: RunOptions, machine: MachineProfile) -> RunOptions:
    """Fill in the machine and the formats that suit the route (see :class:`RunOptions`)."""
    formats = options.formats
    if not formats:
        if options.baromorph:
            formats = ("dxf",)
        elif machine.kind == LASER_WRITER:
            formats = ("laser",)
        else:
            formats = ("gcode",)
    return replace(options, machine=_machine_name(options), formats=tuple(formats))


@dataclass(frozen=True)
class _Fabricated:
    """Key figures of the fabrication stages, their preview (caption, PNG) and the first
    machine file's figures (``file`` in the output folder, ``format``, and the writer's
    :attr:`~fabkit.writers.export.Exported.figures`)."""

    figures: dict[str, Any]
    picture: tuple[str, Path]
    machine_file: dict[str, Any]


def _print_lines(run: _Run) -> _Fabricated:
    """Print lines along the director, then the machine files (from the toolpath in
    memory; toolpath.npz is a side output, its preview drawn by the worker)."""
    options, out, say, solved = run.options, run.out, run.say, run.solved
    say(f"[3/7] planning print lines for {options.machine} at {options.size_mm:g} mm")
    job = run_job(
        ToolpathJob(
            inputs=(str(out / "design.npz"),),
            process=run.inputs.process,
            size_mm=options.size_mm,
            ignore_features=options.ignore_features,
            out=str(out / "toolpath"),
            part=solved.part,
            design=solved.design,
            preview=False,
        )
    )
    run.drawings.draw(
        "fabkit.toolpath.preview:preview_images",
        (job.plan.toolpath, list(job.outlines)),
        partial(_write_images, out / "toolpath" / "preview"),
    )
    say(f"[4/7] writing {', '.join(options.formats)}")
    machine = run.inputs.machine
    written = {
        fmt: write_machine_file(job.plan.toolpath, machine, fmt, out / FORMAT_FILES[fmt])
        for fmt in options.formats
    }
    figures = {
        "channels": dict(job.plan.toolpath.channels),
        "toolpath quality": [q.to_dict() for q in job.plan.quality],
        "toolpath warnings": list(job.plan.warnings),
        "exports": {fmt: exported.summary for fmt, exported in written.items()},
    }
    first = options.formats[0]
    machine_file = {"file": FORMAT_FILES[first], "format": first, **written[first].figures}
    caption = "Print lines coloured by the encoded parameter (travels thin)"
    return _Fabricated(figures, (caption, out / "toolpath" / "preview.png"), machine_file)


def _laser_patterns(run: _Run) -> _Fabricated:
    """Photoalignment patterns straight from the design (no print lines)."""
    options, inputs, out, say = run.options, run.inputs, run.out, run.say
    say("[3/7] no print lines: a laser writer exposes the director field directly")
    say("[4/7] writing laser/")
    written = write_machine_file(
        run.solved.design,
        inputs.machine,
        "laser",
        out / "laser",
        ExportOptions(
            process=inputs.process, ignore_features=options.ignore_features, part=run.solved.part
        ),
    )
    record(out / "laser")  # the laser writer renames a whole folder into place
    caption = "Photoalignment pattern: binned director angle and the dose of each exposure (mm)"
    return _Fabricated(
        {"exports": {"laser": written.summary}},
        (caption, out / "laser" / "preview.png"),
        {"file": f"{FORMAT_FILES['laser']}/", "format": "laser", **written.figures},
    )


def _channels(run: _Run) -> _Fabricated:
    """Baromorph channels whose width encodes eps, their mould, and a DXF for a cutter."""
    options, out, say = run.options, run.out, run.say
    say(f"[3/7] laying out baromorph channels at {options.size_mm:g} mm")
    fields = ToolpathJob(
        inputs=(str(out / "design.npz"),), part=run.solved.part, design=run.solved.design
    )
    result = run_channel_job(
        ChannelJob(fields=fields, baromorph=run.inputs.baromorph, out=str(out / "channels"))
    )
    say("[4/7] writing channels.dxf")
    drawing = write_dxf(
        out / "channels.dxf",
        machine=run.inputs.machine,
        mm_per_unit=result.mm_per_unit,
        **layout_layers(result.layout),
    )
    figures = {
        "channels": asdict(result.report),
        "mould": str(out / "channels" / "mould.stl"),
        "exports": {"dxf": describe_dxf(out / "channels.dxf", drawing, options.machine)},
    }
    caption = (
        "Baromorph channels coloured by their local width (mm), manifold dark grey, sheet "
        "(walls) light grey, inlet red"
    )
    machine_file = {"file": "channels.dxf", "format": "dxf", "entities": dict(drawing.entities)}
    return _Fabricated(figures, (caption, out / "channels" / "channels.png"), machine_file)
