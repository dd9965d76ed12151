"""``fabkit machines``: list the shipped machine profiles."""

from __future__ import annotations

import argparse

from fabkit.commands import add_command
from fabkit.machines import list_machines, machine_table


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = add_command(subparsers, "machines")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    print(machine_table(list_machines()))
    return 0
