"""``fabkit machines``: list the shipped machine profiles."""

from __future__ import annotations

import argparse

from fabkit.commands import help_of
from fabkit.machines import list_machines, machine_table


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "machines",
        help=help_of("machines"),
        description="List the machine profiles in machines/ (see docs/machines.md).",
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    print(machine_table(list_machines()))
    return 0
