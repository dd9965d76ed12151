"""Sub-commands of the ``fabkit`` CLI, one module each, registered by :mod:`fabkit.cli`.

A module here defines ``register(subparsers)`` and nothing with logic of its own. It
imports only argparse-level things at its top (and the constants its options list); the
stage a handler runs is imported inside the handler, so that ``fabkit --help`` and the
quick commands start in a fraction of a second.

:data:`COMMANDS` is the one list of sub-commands: the CLI shows it in ``fabkit --help``
without importing any of the modules, and imports only the module of the command it runs.
"""

from __future__ import annotations

import argparse
from typing import NamedTuple


class Command(NamedTuple):
    """A sub-command: the module (in this package) that registers it, its one-line help."""

    module: str
    help: str


COMMANDS: dict[str, Command] = {
    "check": Command(
        "check", "measure how well a design realises each target (exit 1 if over tolerance)"
    ),
    "energy": Command("energy", "work bounds: frustrated stretching energy of a design held flat"),
    "export": Command("export", "write G-code, DXF or laser-writer patterns for a machine"),
    "machines": Command("machines", "list the machine profiles"),
    "optimise": Command(
        "optimise", "vary a spec's initial data to cover the most area (docs/optimise.md)"
    ),
    "plot": Command("plot", "draw a design: pictures, actuated patches as meshes, HTML report"),
    "run": Command(
        "run", "spec to machine files in one go: solve, check, pictures, toolpath, export, send"
    ),
    "send": Command("send", "check a G-code file and stream it to a machine"),
    "simulate": Command(
        "simulate", "simulate the designed sheet at a stimulus and compare with its target"
    ),
    "solve": Command("solve", "solve a design spec into design.npz"),
    "spec": Command("spec", "validate a design spec and print a summary"),
    "swimmer": Command(
        "swimmer", "simulate the bilayer swimmer's cycle, its motion per cycle, and make it"
    ),
    "toolpath": Command(
        "toolpath",
        "print lines along the director of a design or director field (docs/toolpath.md)",
    ),
    "channels": Command(
        "toolpath", "baromorph channels along the director, and their casting mould (STL)"
    ),
    "verify": Command(
        "verify",
        "read a machine file back (G-code, DXF, laser pattern) and check it against its "
        "design, then simulate the sheet as fabricated",
    ),
}
"""Every sub-command by name, in the order ``fabkit --help`` lists them."""


def help_of(name: str) -> str:
    """The one-line help of sub-command ``name`` (for its module's ``add_parser``)."""
    return COMMANDS[name].help


def add_overwrite(parser: argparse.ArgumentParser, option: str = "--out") -> None:
    """The ``--overwrite`` option of a command that writes a folder (see fabkit.atomic)."""
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help=f"replace the files an earlier fabkit run wrote into {option} (without it such "
        "a folder is refused; files fabkit did not write are never touched)",
    )
