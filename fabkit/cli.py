"""The ``fabkit`` command line: one entry point, one thin sub-command per stage.

Each module in :mod:`fabkit.commands` defines ``register(subparsers)``, which adds
its sub-command(s) with a handler ``func(args) -> int``. The CLI holds no logic:
handlers parse nothing beyond their arguments and call one stage function. Only the
module of the command being run is imported (the others are listed from
:data:`fabkit.commands.COMMANDS`), and a handler imports its stage itself, so that
``fabkit --version``, ``--help`` and the quick commands start at once
(``python benchmarks/startup.py``).
A :class:`~fabkit.errors.FabkitError`, a bad command line and an operating-system error
(a path that cannot be written, a full disk) become one line on stderr and exit code 2.
Ctrl-C at any moment, the sub-commands' imports included, becomes one line and exit code
130. Any other exception is a bug: one line ``fabkit: internal error: ...`` and exit code
1, with the traceback only under ``--debug``.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import traceback
from collections.abc import Iterable
from typing import NoReturn

from fabkit.commands import COMMANDS
from fabkit.errors import FabkitError
from fabkit.version import __version__


class _UsageError(Exception):
    """A command line argparse refuses: reported as one line, like a FabkitError."""


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line, not a usage block and a message."""

    def error(self, message: str) -> NoReturn:
        raise _UsageError(f"{message} (see {self.prog} --help)")


def build_parser(commands: Iterable[str] | None = None) -> argparse.ArgumentParser:
    """The argument parser; ``commands`` are registered in full (None: every one).

    Every other sub-command is only listed, by its name and one-line help, so that its
    module is not imported.
    """
    modules = {COMMANDS[name].module for name in (COMMANDS if commands is None else commands)}
    parser = _Parser(
        prog="fabkit",
        description="Design flat active sheets that morph into several shapes, and make them.",
    )
    parser.add_argument("--version", action="version", version=f"fabkit {__version__}")
    parser.add_argument(
        "--debug", action="store_true", help="print the traceback of an internal error"
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, command in COMMANDS.items():
        if command.module not in modules:
            subparsers.add_parser(name, help=command.help)
        elif command.module == name:  # the module registers all of its sub-commands
            importlib.import_module(f"fabkit.commands.{command.module}").register(subparsers)
    return parser


def _command(argv: list[str]) -> str | None:
    """The sub-command named on the command line (the global options take no value)."""
    return next((arg for arg in argv if not arg.startswith("-")), None)


def main(argv: list[str] | None = None) -> int:
    """Run the command line; return the process exit code."""
    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        return _run(argv)
    except KeyboardInterrupt as exc:  # a send's says where it stopped and how to resume
        print(f"fabkit: interrupted: {exc}" if str(exc) else "fabkit: interrupted", file=sys.stderr)
        return 130
    except FabkitError as exc:
        return _error(str(exc))
    except OSError as exc:  # a safety net: stages report the files they know about themselves
        if exc.strerror and exc.filename is not None:
            return _error(f"{exc.filename}: {exc.strerror}")
        return _error(str(exc))
    except MemoryError:
        return _error("out of memory: try a coarser grid or a smaller sheet")
    except Exception as exc:  # a bug: one line, the traceback only when asked for
        if "--debug" in argv:
            traceback.print_exc()
        message = " ".join(f"{type(exc).__name__}: {exc}".splitlines())[:300]
        print(
            f"fabkit: internal error: {message} (run with --debug for the traceback)",
            file=sys.stderr,
        )
        return 1


def _run(argv: list[str]) -> int:
    command = _command(argv)
    parser = build_parser([command] if command in COMMANDS else [])
    try:
        args = parser.parse_args(argv)
    except _UsageError as exc:
        return _error(str(exc))
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    return int(args.func(args) or 0)


def _error(message: str) -> int:
    """Print ``fabkit: error: <message>`` as one line; return exit code 2."""
    print(f"fabkit: error: {' '.join(message.splitlines())}", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
