"""``fabkit run``'s options, and the inputs it checks and reads before any work.

:class:`RunOptions` is what the run is asked to do; :func:`with_defaults` fills in the
machine and the formats that suit the route (print lines, laser patterns or baromorph
channels); :func:`check_inputs` refuses bad input before anything is written (formats,
sizes, the output folder, the send, the spec, the process and its channels) and reads
what every stage takes once (:class:`RunInputs`). Called by
:func:`fabkit.run.pipeline.run_pipeline`; ``fabkit run``'s command line builds the options.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

from fabkit.design.design import MAX_LAYERS
from fabkit.design.patches import MESH_TYPES, patch_paths
from fabkit.errors import FabkitError
from fabkit.field.part import (
    DEFAULT_SIZE_MM,
    PartRequest,
)
from fabkit.files.atomic import check_folder
from fabkit.machines import DEFAULT_MACHINE, MachineProfile
from fabkit.mechanics.verdict import FORM_TOLERANCE
from fabkit.problem.spec import Spec, load_spec
from fabkit.process import Process
from fabkit.toolpath.baromorph import BaromorphSettings, load_baromorph
from fabkit.toolpath.process_file import load_process, resolve_channels

FORMAT_FILES = {"gcode": "sheet.gcode", "dxf": "sheet.dxf", "laser": "laser"}
BAROMORPH_MACHINE = "laser_cutter"
LASER_WRITER = "laser_writer"
MAX_PRINTS = 8
"""Most prints ``--prints`` judges (each costs a planning, a read-back and a verdict)."""


@dataclass(frozen=True)
class RunOptions:
    """What ``fabkit run`` is asked to do; ``size_mm`` is the longest side of the part
    that is printed, in mm.

    ``step`` and ``diagonals`` replace the spec's solver settings when given;
    ``mesh_format`` is the patch meshes' file type (ply, stl, glb or obj).

    ``formats`` None: DXF for baromorph channels, laser patterns on a laser writer, else
    G-code. ``machine`` None: laser_cutter for baromorph channels, else a pneumatic DIW.
    ``ignore_features`` are left out of the machine file on purpose; ``verify`` reads the
    machine file back and checks it (:mod:`fabkit.verify`); ``pictures`` False draws
    none (the design's, the toolpath preview, the shapes'). ``overwrite`` replaces the
    files an earlier run wrote into ``out`` (else such a folder is refused).
    ``part_request`` cuts the part (:class:`fabkit.field.part.PartRequest`). ``layers``
    (>= 2) prints the sheet in that many layers programmed with each target's curvature
    (:mod:`fabkit.design.layers`); None lets the run choose (:func:`with_defaults`:
    :data:`AUTO_LAYERS` on a printer, which the solve stage may raise to one of
    :func:`layer_choices`, one where the route makes one; ``layers_chosen`` then True);
    ``refine`` refines those layers against the simulation
    (:mod:`fabkit.mechanics.refine`). Every target is simulated, as designed and as
    fabricated, and held to ``form_tolerance`` (RMS, a share of the patch diameter);
    ``strict`` makes a target not formed an error (the run's exit code). ``simulate``
    False skips those simulations: no verdict on the shapes (refused with ``strict``,
    which needs one). ``prints`` > 1 judges that many prints of the design as fabricated
    (the machine file's and ``prints`` - 1 made in memory with the stripes shifted), the
    verdict each target's worst.
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
    pictures: bool = True
    overwrite: bool = False
    part_request: PartRequest = PartRequest()
    layers: int | None = None
    layers_chosen: bool = False
    refine: bool = False
    strict: bool = False
    form_tolerance: float = FORM_TOLERANCE
    simulate: bool = True
    prints: int = 1


@dataclass(frozen=True)
class RunInputs:
    """What the checks read once and every stage takes: the spec (the solver options
    applied), the machine profile, the process (None on a baromorph run) and the
    baromorph's channel settings (None on a print run)."""

    spec: Spec
    machine: MachineProfile
    process: Process | None
    baromorph: BaromorphSettings | None


def _check_send(options: RunOptions) -> None:
    """Refuse a bad printer host URL or API key, a bad port URL and a device that does not
    exist or may not be opened, before any work. The port is not opened until the send:
    opening resets many boards, and held open while the design solves it would be busy
    for everyone else."""
    from fabkit.link.host.ports import check_port
    from fabkit.link.host.web import is_host_url, parse_host_url, resolve_api_key

    if options.send and is_host_url(options.send):
        parse_host_url(options.send)
        resolve_api_key(options.api_key, options.api_key_file)
        return
    if options.api_key is not None or options.api_key_file is not None:
        raise FabkitError("--api-key and --api-key-file are for --send to a printer host")
    if options.send:
        check_port(options.send)


def check_inputs(options: RunOptions, machine: MachineProfile) -> RunInputs:
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
    if not options.simulate and options.strict:
        raise FabkitError(
            "--no-simulate with --strict: it judges the shapes the sheet takes in the "
            "simulations; leave one of the two out"
        )
    if options.refine and not options.simulate:
        raise FabkitError(
            "--refine with --no-simulate: the layers are refined against the simulations; "
            "leave one of the two out"
        )
    if options.refine and options.layers < 2:
        raise FabkitError(
            f"--refine with --layers {options.layers}: it refines the differences between "
            "layers; print two or more (--layers 2, a printer's default)"
        )
    if not 1 <= options.prints <= MAX_PRINTS:
        raise FabkitError(f"--prints {options.prints}: expected 1 to {MAX_PRINTS} prints")
    if options.prints > 1 and not (options.verify and options.simulate):
        raise FabkitError(
            f"--prints {options.prints} with --no-verify or --no-simulate: it judges every "
            "print as the machine file is judged, read back and simulated; leave one out"
        )
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
    if options.prints > 1 and (options.baromorph or machine.kind == LASER_WRITER):
        raise FabkitError(
            f"--prints {options.prints}: only print lines have a phase to shift; a "
            f"{'baromorph' if options.baromorph else 'laser writer'} run makes one pattern"
        )
    what = one_layer_route(options, machine)
    if options.layers > 1 and what:
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
    return RunInputs(spec, machine, process, baromorph)


def ignored_notice(options: RunOptions) -> str:
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


def machine_name(options: RunOptions) -> str:
    """The machine of a run: --machine, else the laser cutter for baromorph channels, else
    the default printer."""
    return options.machine or (BAROMORPH_MACHINE if options.baromorph else DEFAULT_MACHINE)


AUTO_LAYERS = 2
"""The fewest layers that program a natural curvature, and so each target's side: a
sheet of one layer has none, whatever its metric a target and its mirror image are
equally its shapes, and it takes the one its start favours (docs/layers.md). A printed
run with no ``--layers`` judges this many and more (:func:`layer_choices`), or prints
this many where it judges nothing (``--no-simulate``)."""
LAYER_CHOICES = (AUTO_LAYERS, 3, 4, 5)
"""The layer counts a printed run with no ``--layers`` judges as designed
(:func:`fabkit.run.solve.choose_layers`): a thicker sheet averages more of the print's
error over its thickness and is trimmed nearer its targets' bending lengths, but bends
less far (docs/layers.md, "How many layers")."""
MIN_SIZE_PER_THICKNESS = 30.0
"""The thickest sheet a run chooses for its size: the part's longest side at least this
many times the sheet's thickness (Fig. 1 at 40 mm in 5 layers of 0.3 mm, 27 times: its
sphere 14.5 % RMS from its target as designed)."""


def layer_choices(size_mm: float, layer_height_mm: float) -> tuple[int, ...]:
    """The layer counts of :data:`LAYER_CHOICES` a run of a part ``size_mm`` long (its
    longest side) judges (:data:`MIN_SIZE_PER_THICKNESS`); at least the fewest."""
    thin = [k for k in LAYER_CHOICES if size_mm >= MIN_SIZE_PER_THICKNESS * k * layer_height_mm]
    return tuple(thin) or LAYER_CHOICES[:1]


def one_layer_route(options: RunOptions, machine: MachineProfile) -> str:
    """What makes a run's sheet one layer whatever is asked ("" when it can be layered)."""
    if options.baromorph:
        return "a baromorph's channels"
    if machine.kind == LASER_WRITER:
        return f"laser writers such as {machine.name}"
    return ""


def layers_notice(options: RunOptions, inputs: RunInputs) -> str:
    """The run's first line on the layers it chose itself ("" when --layers was given)."""
    if not options.layers_chosen:
        return ""
    route = one_layer_route(options, inputs.machine)
    if route:
        return (
            f"ONE LAYER: {route} make one layer, so no target's side is programmed: the "
            "sheet takes each target or its mirror image, as it happens to start"
        )
    height = inputs.process.layer_height_mm
    choices = layer_choices(options.size_mm, height) if options.simulate else (options.layers,)
    counts = f"{choices[0]} to {choices[-1]}" if len(choices) > 1 else f"{choices[0]}"
    judged = (
        ", judged as designed: the run prints the thickest sheet that forms every target "
        "with room for the print's error, the next while a print misses one, then refines "
        "the nearest as printed (minutes; --layers K decides)"
        if len(choices) > 1
        else ""
    )
    return (
        f"LAYERS CHOSEN: {counts} layers of {height:g} mm (no --layers){judged}, each "
        "programmed with every target's side, which one layer cannot program (--layers 1 "
        "prints one)"
    )


def with_defaults(options: RunOptions, machine: MachineProfile) -> RunOptions:
    """Fill in the machine, the formats that suit the route and the layers (see
    :class:`RunOptions`)."""
    formats = options.formats
    if not formats:
        if options.baromorph:
            formats = ("dxf",)
        elif machine.kind == LASER_WRITER:
            formats = ("laser",)
        else:
            formats = ("gcode",)
    layers = options.layers
    if layers is None:
        layers = 1 if one_layer_route(options, machine) else AUTO_LAYERS
    return replace(
        options,
        machine=machine_name(options),
        formats=tuple(formats),
        layers=layers,
        layers_chosen=options.layers is None,
    )
