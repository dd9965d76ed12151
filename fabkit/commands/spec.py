"""``fabkit spec FILE``: validate a spec and print its summary."""

from __future__ import annotations

import argparse

from fabkit.commands import add_command


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = add_command(subparsers, "spec")
    parser.add_argument("file", help="spec file (TOML), e.g. examples/two_shapes.toml")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from fabkit.problem.spec import describe_spec, load_spec

    print(describe_spec(load_spec(args.file)))
    return 0
