"""Sub-commands of the ``fabkit`` CLI, one module each, registered by :mod:`fabkit.cli`.

A module here defines ``register(subparsers)`` and nothing with logic of its own. It
imports only argparse-level things at its top (and the constants its options list); the
stage a handler runs is imported inside the handler, so that ``fabkit --help`` and the
quick commands start in a fraction of a second.

:data:`COMMANDS` is the one list of sub-commands, with their help and description: the
CLI shows it in ``fabkit --help`` without importing any of the modules, and imports only
the module of the command it runs.

The options several commands take are added by the ``add_*`` functions here, with the
destination the stages' options name them by (``--process``: ``process_file``, a length
``--road-width``: ``road_width_mm``), so that a handler passes them on with
:func:`call_with` and says only what it makes from them.
"""

from __future__ import annotations

import argparse
import functools
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, NamedTuple, TypeVar

if TYPE_CHECKING:
    from fabkit.process import Process
    from fabkit.toolpath.baromorph import BaromorphSettings

T = TypeVar("T")


class Command(NamedTuple):
    """A sub-command: the module (in this package) that registers it, its one-line help
    (``fabkit --help``) and the paragraph that opens its own ``--help`` (None: none)."""

    module: str
    help: str
    description: str | None = None


COMMANDS: dict[str, Command] = {
    "calibrate": Command(
        "calibrate",
        "fit a material table to measured samples, for a spec's [material] table",
        "Fit lambda1 and lambda2 of the features and stimuli to the samples of a CSV as a "
        "monotone cubic B-spline table, report its residuals and the range the samples "
        "cover, and write it (TOML) for a spec's [material] table = FILE "
        "(docs/calibrate.md).",
    ),
    "check": Command(
        "check", "measure how well a design realises each target (exit 1 if over tolerance)"
    ),
    "compare": Command(
        "compare",
        "compare a scan of the printed sheet with its target, as run's verdict (docs/compare.md)",
        "Read a scan (mesh or point cloud, in --units), fit it to the target at the part's "
        "printed size (a global search, then ICP; its mirror image tried too) and give the "
        "verdict in run's words and limit: formed or not, RMS and max distance, the mirror "
        "image, the share of the target the scan covers; and, where the run simulated the "
        "sheet, the scan against that sheet. Writes compare.png, scan_aligned.ply (with each "
        "vertex's distance_mm) and compare.json into --out.",
    ),
    "energy": Command("energy", "work bounds: frustrated stretching energy of a design held flat"),
    "export": Command(
        "export",
        "write G-code, DXF or laser-writer patterns for a machine",
        "Write a toolpath or design as a machine file; everything is checked against the "
        "machine profile before anything is written (see docs/export.md).",
    ),
    "machines": Command(
        "machines",
        "list the machine profiles",
        "List the machine profiles in machines/ (see docs/machines.md).",
    ),
    "optimise": Command(
        "optimise",
        "vary a spec's initial data to cover the most area (docs/optimise.md)",
        "Differential evolution over the initial data (curve parameters, eps and slopes on "
        "the curves, the targets' start points and directors) maximising the area covered "
        "by the cells of a design that passes the check; writes the best spec, its figures "
        "and pictures beside --out, and a checkpoint a stopped search resumes from.",
    ),
    "plot": Command("plot", "draw a design: pictures, actuated patches as meshes, HTML report"),
    "run": Command(
        "run", "spec to machine files in one go: solve, check, pictures, toolpath, export, send"
    ),
    "send": Command(
        "send",
        "check a G-code file and stream it to a machine",
        "Check FILE against the machine profile (envelope, speeds, temperatures, commands), "
        "estimate its duration, then stream it to PORT with the machine's protocol. The "
        "machine is --machine, else the one the file's header names (fabkit writes it), "
        "else the port's default; each send says which. PORT is a device (/dev/ttyUSB0, "
        "COM3) or a pyserial URL; sim://marlin and sim://grbl are built-in emulators "
        "(docs/link.md). Ctrl-C stops with the profile's safe-stop snippet, prints the "
        "--resume-from line and exits with 130; Ctrl-Z pauses and resumes. With --host the "
        "file goes to a printer host instead (OctoPrint, Moonraker: docs/link.md), checked "
        "first the same way, then uploaded, started and followed to its end; Ctrl-C cancels "
        "the job there.",
    ),
    "simulate": Command(
        "simulate", "simulate the designed sheet at a stimulus and compare with its target"
    ),
    "solve": Command("solve", "solve a design spec into design.npz"),
    "spec": Command("spec", "validate a design spec and print a summary"),
    "swimmer": Command(
        "swimmer",
        "simulate the bilayer swimmer's cycle, its motion per cycle, and make it",
        "Equilibrium shapes along the stimulus path, the force- and torque-free motion in "
        "Stokes flow (regularised Stokeslets), plots, the work bound per stage, and both "
        "layers' toolpath and G-code (docs/swimmer.md).",
    ),
    "toolpath": Command(
        "toolpath",
        "print lines along the director of a design or director field (docs/toolpath.md)",
        "Evenly spaced print lines along the director, ordered, layered and encoded; "
        "writes toolpath.npz, quality.json and preview.png/svg into --out.",
    ),
    "channels": Command(
        "toolpath",
        "baromorph channels along the director, and their casting mould (STL)",
        "Channels along the director with widths from eps, a manifold to one inlet, walls "
        "of at least min_wall_mm; writes channels.json, mould.stl and channels.png/svg "
        "into --out.",
    ),
    "verify": Command(
        "verify",
        "read a machine file back (G-code, DXF, laser pattern) and check it against its "
        "design, then simulate the sheet as fabricated",
        "Read the machine file as the machine would, independent of toolpath.npz: "
        "director, every feature (its calibration inverted) and coverage on the flat "
        "sheet, compared with the design; then the sheet as fabricated under every "
        "stimulus against each target (docs/verify.md).",
    ),
}
"""Every sub-command by name, in the order ``fabkit --help`` lists them."""


def add_command(subparsers: argparse._SubParsersAction, name: str) -> argparse.ArgumentParser:
    """Sub-command ``name``'s parser, with its help and description from :data:`COMMANDS`."""
    command = COMMANDS[name]
    return subparsers.add_parser(name, help=command.help, description=command.description)


def add_overwrite(parser: argparse.ArgumentParser, option: str = "--out") -> None:
    """The ``--overwrite`` option of a command that writes a folder (see fabkit.files.atomic)."""
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help=f"replace the files an earlier fabkit run wrote into {option} (without it such "
        "a folder is refused; files fabkit did not write are never touched)",
    )


Handler = Callable[[argparse.Namespace], int]
"""A sub-command's handler: the parsed command line in, the exit code out."""


def in_out_folder(handler: Handler) -> Handler:
    """``handler``, writing into the ``--out`` folder of a command with :func:`add_overwrite`:
    the folder is claimed while it runs (:func:`fabkit.files.atomic.output_folder`)."""

    @functools.wraps(handler)
    def run(args: argparse.Namespace) -> int:
        from fabkit.files.atomic import output_folder

        with output_folder(args.out, f"--out {args.out}", args.overwrite):
            return handler(args)

    return run


def add_api_key(parser: argparse._ActionsContainer) -> None:
    """``--api-key KEY`` and ``--api-key-file FILE``, the key of a printer host (else the
    environment's FABKIT_API_KEY), in ``args.api_key`` and ``args.api_key_file``."""
    keys = parser.add_mutually_exclusive_group()
    keys.add_argument(
        "--api-key",
        metavar="KEY",
        help="the printer host's API key (visible to other users in the process list: "
        "prefer --api-key-file or the environment variable FABKIT_API_KEY)",
    )
    keys.add_argument(
        "--api-key-file", metavar="FILE", help="a file whose first line is the API key"
    )


def add_strict(parser: argparse._ActionsContainer, help: str) -> None:
    """``--strict``: exit 1 (not 0) when the command did its work but the result falls
    short (``help`` says of what); errors still exit 2."""
    parser.add_argument("--strict", action="store_true", help=help)


def add_machine(parser: argparse._ActionsContainer, help: str) -> None:
    """``--machine NAME|FILE``: a shipped profile's name or a profile's .toml path."""
    parser.add_argument("--machine", metavar="NAME|FILE", help=help)


def add_process(parser: argparse._ActionsContainer, help: str) -> None:
    """``--process FILE``: a TOML whose [process] table stands for the machine's; its path is
    ``args.process_file``, as the options of every stage name it."""
    parser.add_argument("--process", metavar="FILE", dest="process_file", help=help)


def chosen_process(args: argparse.Namespace) -> Process:
    """The process of ``--process`` (``args.process_file``), else that of ``--machine``
    (default marlin_diw_pneumatic), each file read once; a bad ``--machine`` is reported
    even with ``--process``."""
    from fabkit.machines import DEFAULT_MACHINE, load_machine
    from fabkit.toolpath.process_file import load_process

    machine = load_machine(args.machine or DEFAULT_MACHINE)
    return load_process(args.process_file) if args.process_file else machine.process


def given_process(args: argparse.Namespace) -> Process | None:
    """The process of ``--process``, read once, or None (the machine's)."""
    from fabkit.toolpath.process_file import load_process

    return load_process(args.process_file) if args.process_file else None


def given_baromorph(args: argparse.Namespace) -> BaromorphSettings | None:
    """The channel settings of ``--baromorph``, read once, or None."""
    from fabkit.toolpath.baromorph import load_baromorph

    return load_baromorph(args.baromorph) if args.baromorph else None


def add_ignore_feature(parser: argparse._ActionsContainer, help: str) -> None:
    """``--ignore-feature NAME`` (repeatable): features left out on purpose, in
    ``args.ignore_features``, as the options of every stage name them."""
    parser.add_argument(
        "--ignore-feature",
        action="append",
        default=[],
        metavar="NAME",
        dest="ignore_features",
        help=help,
    )


def add_length(parser: argparse._ActionsContainer, flag: str, help: str, **kwargs: Any) -> None:
    """A length option ``flag MM``, in ``args.<name>_mm`` (``--road-width``:
    ``road_width_mm``), the name the stages' options give it; ``kwargs`` as argparse's."""
    dest = flag.removeprefix("--").replace("-", "_") + "_mm"
    parser.add_argument(flag, type=float, metavar="MM", dest=dest, help=help, **kwargs)


def add_scale(parser: argparse._ActionsContainer, size_help: str, scale_help: str) -> None:
    """The design's scale, one of ``--size MM`` (the part's longest side) and ``--scale
    MM_PER_UNIT``, in ``args.size_mm`` and ``args.mm_per_unit``."""
    scale = parser.add_mutually_exclusive_group()
    add_length(scale, "--size", size_help)
    scale.add_argument(
        "--scale", type=float, metavar="MM_PER_UNIT", dest="mm_per_unit", help=scale_help
    )


def point_mm(*counts: int) -> Callable[[str], tuple[float, ...]]:
    """An argparse type: a point in mm written X,Y (count 2) or X,Y,Z (count 3), with as
    many coordinates as one of ``counts``."""
    forms = " or ".join(",".join("XYZ"[:count]) for count in counts)

    def point(text: str) -> tuple[float, ...]:
        try:
            values = tuple(float(v) for v in text.split(","))
        except ValueError:
            values = ()
        if len(values) not in counts:
            raise argparse.ArgumentTypeError(f"expected {forms} in mm, got {text!r}")
        return values

    return point


def call_with(target: Callable[..., T], args: argparse.Namespace, **given: Any) -> T:
    """Call a stage's function or options dataclass ``target`` with the parsed command line:
    each parameter named like an option's destination gets the option's value (a repeatable
    option's list as a tuple), ``given`` the values made from the options; the other
    parameters keep their defaults."""
    import inspect  # here: fabkit --help need not load it

    values = {
        name: getattr(args, name)
        for name in inspect.signature(target).parameters
        if hasattr(args, name)
    }
    values = {name: tuple(v) if isinstance(v, list) else v for name, v in values.items()}
    return target(**(values | given))
