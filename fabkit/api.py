"""The public API's own functions: the few stages whose existing call needs values a script
should not build (a machine given by name, a toolpath job, a design file's path).

``import fabkit`` resolves every public name lazily (:mod:`fabkit`'s ``__getattr__``); the
names that are plain re-exports (``load_spec``, ``check``, ``send``, ``load_machine``, the
value types) live in their stage modules, these four wrap one stage function each and
hold no stage logic. Every stage module is imported when a function is first called, so
that importing this module stays cheap. Lengths are in mm unless a name says otherwise;
a design's lengths are in design units. docs/api.md has a script that uses them.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from fabkit.design.design import Design
    from fabkit.machines import MachineProfile
    from fabkit.problem.spec import Spec
    from fabkit.toolpath.plan import Plan
    from fabkit.verify.machine_file import Verification
    from fabkit.writers.export import Exported, ExportOptions, Source

PLAN_SETTINGS = (
    "mm_per_unit",
    "part_request",
    "process",
    "road_width_mm",
    "layer_height_mm",
    "layers",
    "pattern",
    "encode",
    "ignore_features",
    "clip_eps",
    "end_inset",
)
"""The fields of :class:`fabkit.toolpath.job.ToolpathJob` that :func:`plan_toolpath` takes
as keywords (the others name input and output files)."""


def solve(spec: Spec, progress: Callable[[int, int], None] | None = None) -> Design:
    """Solve the design problem ``spec`` on its grid (:func:`fabkit.design.solver.solve`);
    returns the :class:`~fabkit.design.design.Design`, which knows its spec.

    The grid is the spec's ``[solver]`` table: ``spec.with_solver(step=0.1,
    diagonals=20)`` makes it coarser (step in design units; the design grid is
    2 diagonals + 1 nodes each way). The design's arrays are on that (nu, nv) grid
    (:mod:`fabkit.design.design` lists them): ``u``, ``v`` (nu,), (nv,) in design units;
    ``valid``, ``alpha``, ``beta`` (nu, nv); ``eps`` (N, nu, nv), one per feature; ``r``
    and ``n`` (S, nu, nv, 2): every target's chart point and director. A grid larger than
    a design file may hold is refused before solving (a
    :class:`~fabkit.errors.FabkitError`); ``progress(done, total)`` is called per
    diagonal. Save the design with ``design.save(path)`` (.npz).
    """
    from fabkit.design.solver import solve as solve_spec
    from fabkit.design.summary import check_grid_size

    check_grid_size(spec)
    return solve_spec(spec, progress).design.knowing(spec)


def plan_toolpath(
    design: Design,
    machine: str | MachineProfile | None = None,
    size_mm: float | None = None,
    **settings: Any,
) -> Plan:
    """Print lines along the director of ``design`` for ``machine``'s process, the part
    ``size_mm`` long on its longest side (default ``fabkit run``'s, 60 mm;
    :func:`fabkit.toolpath.job.plan_job`, as ``fabkit toolpath design.npz --size``,
    writing nothing).

    ``machine``: a profile name (``fabkit machines`` lists them), a .toml path or a
    :class:`~fabkit.machines.MachineProfile` (default marlin_diw_pneumatic). The design
    is cut to the part that is made (:mod:`fabkit.field.part`), every feature encoded by
    the process's channel for it. ``settings``: any of :data:`PLAN_SETTINGS`, as the
    options of ``fabkit toolpath`` (e.g. ``layers=2``, ``pattern="alternate"``,
    ``ignore_features=("eps",)``, ``road_width_mm=0.4``; ``process``: a
    :class:`~fabkit.process.Process` in place of the machine's). Returns the
    :class:`~fabkit.toolpath.plan.Plan`: ``plan.toolpath`` (a
    :class:`~fabkit.toolpath.model.Toolpath`: moves of x, y, z in mm in the sheet's own
    frame, placed on the bed by the writer), ``plan.quality`` (one per layer) and
    ``plan.warnings`` (one line each).
    """
    from fabkit.field.part import DEFAULT_SIZE_MM
    from fabkit.toolpath.job import ToolpathJob, plan_job

    unknown = sorted(set(settings) - set(PLAN_SETTINGS))
    if unknown:
        raise TypeError(f"plan_toolpath() got unexpected keyword arguments: {', '.join(unknown)}")
    job = ToolpathJob(
        inputs=("design.npz",),  # the field's name only: the design is given as a value
        design=design,
        size_mm=DEFAULT_SIZE_MM if size_mm is None else size_mm,
        **({"process": _profile(machine).process} if machine is not None else {}) | settings,
    )
    return plan_job(job).plan


def write_machine_file(
    source: Source,
    machine: str | MachineProfile,
    fmt: str,
    out: str | Path,
    options: ExportOptions | None = None,
) -> Exported:
    """Write ``out`` in format ``fmt`` ("gcode", "dxf" or "laser") for ``machine`` from
    ``source`` (:func:`fabkit.writers.export.write_machine_file`, atomically).

    ``source``: a :class:`~fabkit.toolpath.model.Toolpath` (G-code, DXF; mm), or a
    :class:`~fabkit.design.design.Design` (laser patterns); ``machine``: a profile name,
    a .toml path or a :class:`~fabkit.machines.MachineProfile`; ``out``: the file (laser:
    a folder) whose parent folder exists. ``options``: an
    :class:`~fabkit.writers.export.ExportOptions` (sheet offset on the bed in mm,
    G-code extrusion settings, ...; default: the sheet centred on the bed). Returns the
    :class:`~fabkit.writers.export.Exported`: ``path``, ``summary`` (one paragraph) and
    ``figures`` (lines, lengths in mm, material volume in mm^3, estimated time in s).
    """
    from fabkit.writers.export import write_machine_file as write

    return write(source, _profile(machine), fmt, out, options)


def verify(
    design: Design | str | Path,
    machine_file: str | Path,
    machine: str | MachineProfile | None = None,
    progress: Callable[[int, int], None] | None = None,
    **options: Any,
) -> Verification:
    """Read ``machine_file`` back as the machine reads it and compare it with ``design``
    (:func:`fabkit.verify.machine_file.verify`, as ``fabkit verify``).

    ``design``: the :class:`~fabkit.design.design.Design` (or its .npz file);
    ``machine``: the profile the file was written for (name, .toml path or
    :class:`~fabkit.machines.MachineProfile`; default marlin_diw_pneumatic, a laser
    folder's own); ``options``: fields of :class:`~fabkit.verify.machine_file.VerifyOptions`
    (e.g. ``simulate=False`` to compare the fields only, ``cell_mm=0.2``);
    ``progress(done, total)`` follows the simulations. The sheet's size and placement
    are read from the file's own record. Returns the
    :class:`~fabkit.verify.machine_file.Verification`: coverage (``empty_fraction``,
    ``mean_overlap``), the director's error ``director_mean_deg`` and
    ``director_p95_deg`` (degrees), each feature's error, and, when simulated, the sheet
    as fabricated against every target (``targets``, ``verdict``); ``table()`` as text.
    """
    from fabkit.verify.machine_file import VerifyOptions
    from fabkit.verify.machine_file import verify as verify_file

    profile = None if machine is None else _profile(machine)
    verify_options = VerifyOptions(machine=profile, **options)
    if isinstance(design, str | Path):
        return verify_file(design, machine_file, verify_options, progress)
    return verify_file("design", machine_file, verify_options, progress, design=design)


def _profile(machine: str | Path | MachineProfile) -> MachineProfile:
    """The profile ``machine`` stands for: itself, or the one its name or .toml path loads."""
    from fabkit.machines import load_machine

    return load_machine(machine) if isinstance(machine, str | Path) else machine
