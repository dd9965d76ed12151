"""``fabkit run``'s stages after the solve: the machine files, verify, the shapes, send.

:func:`fabricate` writes the machine files of the run's route (print lines and their
G-code or DXF, laser patterns on a laser writer, or baromorph channels and their DXF),
reads the first back and checks it (:mod:`fabkit.verify`, unless ``--no-verify``),
with ``--prints K`` judges K - 1 more prints of the design made in memory (the stripes
shifted k / K of their spacing: :func:`print_in_memory`), writes the shape the sheet
takes under every target's stimulus (``as_fabricated/``, else ``as_designed/``) and
sends the G-code (``--send``). The pictures are handed to the run's worker
(:class:`Drawings`) and written at the report. Called by
:func:`fabkit.run.pipeline.run_pipeline`.
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from functools import partial
from multiprocessing.pool import AsyncResult
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fabkit.background import Worker
from fabkit.design.design import Design
from fabkit.files.atomic import atomic_path, inside, record
from fabkit.machines import MachineProfile
from fabkit.mechanics.mesh import save_mesh
from fabkit.mechanics.verdict import Verdict, worst_of
from fabkit.run.inputs import FORMAT_FILES, LASER_WRITER, RunInputs, RunOptions
from fabkit.run.solve import Solved
from fabkit.toolpath.job import ChannelJob, JobResult, ToolpathJob, run_channel_job, run_job
from fabkit.writers.dxf import layout_layers, write_dxf
from fabkit.writers.export import ExportOptions, describe_dxf, write_machine_file

if TYPE_CHECKING:
    from fabkit.link.host.hosts import HostReport
    from fabkit.link.host.session import SendReport
    from fabkit.verify.machine_file import Verification


class Drawings:
    """Pictures the worker draws while the run goes on, and how each is written: all are
    written together, when the run reaches its report or when a later stage fails."""

    def __init__(self, background: Worker | None) -> None:
        self._background = background
        self._pending: list[tuple[AsyncResult, Callable[[Any], Any]]] = []

    @property
    def on(self) -> bool:
        """Whether pictures are drawn (no worker: ``fabkit run --no-pictures``)."""
        return self._background is not None

    def draw(self, function: str, args: tuple[Any, ...], write: Callable[[Any], Any]) -> None:
        """Have ``function`` (``"module:name"``) draw from ``args``; ``write`` its result
        (nothing when the pictures are off)."""
        if self._background is not None:
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
class Run:
    """What every stage after the solve takes: the run's ``options``, the ``inputs`` read
    once, the ``solved`` design, the worker's ``drawings`` and ``say`` for its lines."""

    options: RunOptions
    inputs: RunInputs
    solved: Solved
    drawings: Drawings
    say: Callable[[str], None]

    @property
    def out(self) -> Path:
        """The output folder."""
        return Path(self.options.out)


@dataclass(frozen=True)
class Made:
    """What the stages after the solve made: the ``fabricated`` figures and preview, the
    first ``machine_file``'s figures, its ``verification`` (None with --no-verify), the
    ``final`` verdict (as fabricated when the machine file was simulated, else as
    designed; None when nothing was simulated) and the ``shapes`` it found (report.json's
    ``shapes``, None when nothing was simulated)."""

    fabricated: _Fabricated
    machine_file: dict[str, Any]
    verification: Verification | None
    final: Verdict | None
    shapes: dict[str, Any] | None
    prints: list[dict[str, Any]] | None = None


def fabricate(run: Run) -> Made:
    """The machine files, their verification and the shapes the sheet takes (not sent:
    :func:`send_stage`)."""
    options = run.options
    if options.baromorph:
        fabricated = _channels(run)
    elif run.inputs.machine.kind == LASER_WRITER:
        fabricated = _laser_patterns(run)
    else:
        fabricated = _print_lines(run)

    verification = _verify(run)
    final, prints = run.solved.verdict, None
    if verification is not None and verification.verdict is not None:
        final = verification.verdict
        if options.prints > 1:
            final, prints = _other_prints(run, final)
    shapes = _shapes(run, final) if final is not None else None
    return Made(fabricated, fabricated.machine_file, verification, final, shapes, prints)


def send_stage(run: Run) -> dict[str, Any] | None:
    """The machine file sent to ``--send`` (report.json's ``sent``; None without it)."""
    options = run.options
    if not options.send:
        run.say("[6/7] not sending (no --send)")
        return None
    run.say(f"[6/7] sending sheet.gcode to {options.send}")
    return _send(run.out / "sheet.gcode", options, run.inputs.machine).figures()


def _shapes(run: Run, verdict: Verdict) -> dict[str, Any]:
    """The shape the sheet takes under every target's stimulus (``verdict``'s meshes): a
    mesh per target written now (PLY, mm, with each vertex's distance to the target) and
    the target's own (its ``_target.ply``, where the sheet is placed on it: open both in
    a mesh viewer), a picture per target drawn by the worker; all in ``as_fabricated/``
    (``as_designed/`` when the machine file was not simulated). Returns report.json's
    ``shapes``."""
    folder = verdict.what.replace(" ", "_")
    shown = tuple(shape for shape in verdict.shapes if shape.mesh is not None)
    targets = []
    for shape in shown:
        mesh = shape.mesh
        path = inside(run.out / folder, f"{shape.target}.ply")
        save_mesh(path, mesh.vertices_mm, mesh.triangles, {"distance_mm": mesh.distance_mm})
        save_mesh(
            inside(run.out / folder, f"{shape.target}_target.ply"), mesh.target_mm, mesh.triangles
        )
        targets.append(
            {
                "target": shape.target,
                "mesh": f"{folder}/{shape.target}.ply",
                "target_mesh": f"{folder}/{shape.target}_target.ply",
            }
        )
    if run.drawings.on:  # a picture per target, named where it will be written
        for target in targets:
            target["picture"] = f"{folder}/{target['target']}.png"
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


def _verify(run: Run) -> Verification | None:
    """Read the first machine file back and check it (None with --no-verify)."""
    options, out, say = run.options, run.out, run.say
    if not options.verify:
        say("[5/7] not verifying (--no-verify)")
        return None
    from fabkit.verify.machine_file import VerifyOptions, verify

    target = out / ("channels.dxf" if options.baromorph else FORMAT_FILES[options.formats[0]])
    simulating = ", simulating the sheet as fabricated" if options.simulate else ""
    say(f"[5/7] verifying {target.name}: reading it back{simulating}")
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
            simulate=options.simulate,
        ),
        design=run.solved.design,
    )
    for line in result.table().splitlines()[1:-1]:
        say(f"      {line.strip()}")
    return result


def _other_prints(run: Run, verdict: Verdict) -> tuple[Verdict, list[dict[str, Any]]]:
    """``--prints K``: the design printed K - 1 more times in memory, the stripes of print k
    shifted k / K of their spacing (an equally good print, its roads elsewhere), each
    judged from every start as the machine file was (``verdict``); returns the worst of
    them all, target by target (:func:`~fabkit.mechanics.verdict.worst_of`), and
    report.json's ``prints``."""
    count, say = run.options.prints, run.say
    judged = [(0.0, "the machine file", verdict)]
    for k in range(1, count):
        phase = 2 * math.pi * k / count
        shift = f"its lines shifted {k}/{count} of their spacing"
        say(f"      print {k + 1} of {count}, in memory, {shift}:")
        other, _ = print_in_memory(run, run.solved.design, phase)
        say(f"        {other.headline()}")
        judged.append((phase, "in memory", other))
    worst = worst_of([v for _, _, v in judged])
    say(f"      over the {count} prints (each target as its worst print makes it):")
    say(f"        {worst.headline()}")
    prints = [
        {
            "phase_rad": phase,
            "file": where,
            "headline": v.headline(),
            "formed": v.formed,
            "targets_formed": [shape.formed for shape in v.shapes],
            "rms_pct": [100 * shape.rms for shape in v.shapes],
        }
        for phase, where, v in judged
    ]
    return worst, prints


def print_in_memory(run: Run, design: Design, phase_rad: float = 0.0) -> tuple[Verdict, list]:
    """``design`` printed into a temporary folder by the run's planner (the stripes at
    ``phase_rad``) and writer, read back and judged as ``fabkit verify`` judges it: the
    verdict as fabricated and the layers read back (:class:`~fabkit.mechanics.fabricated.
    SheetFields`, bottom first)."""
    from fabkit.verify.as_fabricated import fabricated_verdict
    from fabkit.verify.machine_file import VerifyOptions, read_back, simulate_reading

    options, inputs, solved = run.options, run.inputs, run.solved
    with tempfile.TemporaryDirectory(prefix="fabkit-printed-") as folder:
        out = Path(folder)
        quiet = replace(
            run,
            options=replace(options, out=folder),
            solved=replace(solved, design=design),
            drawings=Drawings(None),
        )
        job = plan_print(quiet, out, phase_rad)
        write_machine_file(job.plan.toolpath, inputs.machine, "gcode", out / "sheet.gcode")
        check = VerifyOptions(
            machine=inputs.machine,
            process=inputs.process,
            part=solved.part,
            form_tolerance=options.form_tolerance,
        )
        reading = read_back(out / "design.npz", out / "sheet.gcode", check, design)
    _, shapes = simulate_reading(reading, check)
    verdict = fabricated_verdict(shapes, len(reading.readbacks), reading.thickness_mm)
    return verdict, reading.fields(check)


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


@dataclass(frozen=True)
class _Fabricated:
    """Key figures of the fabrication stages, their preview (caption, PNG; None when the
    pictures are off) and the first machine file's figures (``file`` in the output folder,
    ``format``, and the writer's :attr:`~fabkit.writers.export.Exported.figures`)."""

    figures: dict[str, Any]
    picture: tuple[str, Path] | None
    machine_file: dict[str, Any]


def plan_print(run: Run, out: Path, phase_rad: float = 0.0) -> JobResult:
    """The run's print lines planned from its solved design (the stripes at ``phase_rad``:
    :class:`~fabkit.toolpath.plan.PlanSettings`), toolpath.npz written into
    ``out``/toolpath (no preview)."""
    options, solved = run.options, run.solved
    return run_job(
        ToolpathJob(
            inputs=(str(out / "design.npz"),),
            process=run.inputs.process,
            size_mm=options.size_mm,
            ignore_features=options.ignore_features,
            phase_rad=phase_rad,
            out=str(out / "toolpath"),
            part=solved.part,
            design=solved.design,
            preview=False,
        )
    )


def _print_lines(run: Run) -> _Fabricated:
    """Print lines along the director, then the machine files (from the toolpath in
    memory; toolpath.npz is a side output, its preview drawn by the worker)."""
    options, out, say = run.options, run.out, run.say
    say(f"[3/7] planning print lines for {options.machine} at {options.size_mm:g} mm")
    job = plan_print(run, out)
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
    preview = (caption, out / "toolpath" / "preview.png") if run.drawings.on else None
    return _Fabricated(figures, preview, machine_file)


def _laser_patterns(run: Run) -> _Fabricated:
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


def _channels(run: Run) -> _Fabricated:
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
