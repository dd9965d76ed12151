"""The ``fabkit`` command line: one entry point, one thin sub-command per stage.

Each module in :mod:`fabkit.commands` defines ``register(subparsers)``, which adds
its sub-command(s) with a handler ``func(args) -> int``. The CLI holds no logic:
handlers parse nothing beyond their arguments and call one stage function.
A :class:`~fabkit.errors.FabkitError` becomes one line on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

import fabkit
import fabkit.commands
from fabkit.errors import FabkitError


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every sub-command found in :mod:`fabkit.commands`."""
    parser = argparse.ArgumentParser(
        prog="fabkit",
        description="Design flat active sheets that morph into several shapes, and make them.",
    )
    parser.add_argument("--version", action="version", version=f"fabkit {fabkit.__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for info in sorted(pkgutil.iter_modules(fabkit.commands.__path__), key=lambda m: m.name):
        module = importlib.import_module(f"fabkit.commands.{info.name}")
        module.register(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the command line; return the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except FabkitError as exc:
        print(f"fabkit: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("fabkit: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
