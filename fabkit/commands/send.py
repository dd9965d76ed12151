"""``fabkit send``: check a G-code file against a machine and stream it to a port, or print
it through a printer host (OctoPrint, Moonraker)."""

from __future__ import annotations

import argparse

from fabkit.commands import add_api_key, add_command, add_strict, call_with


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = add_command(subparsers, "send")
    parser.add_argument("path", metavar="FILE", help="G-code file")
    link = parser.add_mutually_exclusive_group()
    link.add_argument("--port", help="device or pyserial URL (not needed with --dry-run)")
    link.add_argument(
        "--host",
        metavar="URL",
        help="a printer host: octoprint+http://HOST:PORT, moonraker+http://HOST:PORT "
        "(+https too), or http://HOST:PORT to ask the server which it is",
    )
    parser.add_argument("--baud", type=int, help="baud rate (default: the profile's)")
    parser.add_argument(
        "--machine",
        help="profile name or .toml path (default: the machine in FILE's header, else "
        "grbl_diw on sim://grbl, klipper_generic through Moonraker, else marlin_generic)",
    )
    parser.add_argument(
        "--force",
        action="store_true",
        help="send with --machine even if FILE's header names another machine",
    )
    add_api_key(parser)
    parser.add_argument(
        "--no-start", action="store_true", help="with --host: upload the file, do not start it"
    )
    parser.add_argument(
        "--log", metavar="LOGFILE", dest="log_path", help="write all traffic to LOGFILE"
    )
    parser.add_argument(
        "--resume-from", type=int, metavar="LINE", help="start at file line LINE (1-based)"
    )
    parser.add_argument(
        "--dry-run",
        action="store_true",
        help="check the file against the machine and estimate its duration, send nothing",
    )
    add_strict(
        parser,
        "exit 1 when the machine may not have run a line it was sent (the summary's first "
        "line names it: the machine asked for the line again, then refused the copy as a "
        "line it had); without it such a send exits 0 with that warning",
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from fabkit.link.host.send import send_file
    from fabkit.link.host.session import SendReport

    def say(text: str) -> None:
        print(text, flush=True)

    # Ctrl-C: a SendInterrupted, which fabkit.cli prints with where the job stopped (exit 130)
    result = call_with(send_file, args, say=say)
    print(result.summary())
    unrun = isinstance(result, SendReport) and result.may_not_have_run
    return 1 if args.strict and unrun else 0
