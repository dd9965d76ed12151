"""``fabkit send``: check a G-code file against a machine and stream it to a port."""

from __future__ import annotations

import argparse

from fabkit.link.send import send_file


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "send",
        help="check a G-code file and stream it to a machine",
        description=(
            "Check FILE against the machine profile (envelope, speeds, temperatures, "
            "commands), then stream it to PORT with the machine's protocol. PORT is a "
            "device (/dev/ttyUSB0, COM3) or a pyserial URL; sim://marlin and sim://grbl "
            "are built-in emulators (docs/link.md). Ctrl-C aborts with the profile's "
            "safe-stop snippet; Ctrl-Z pauses and resumes."
        ),
    )
    parser.add_argument("file", metavar="FILE", help="G-code file")
    parser.add_argument("--port", help="device or pyserial URL (not needed with --dry-run)")
    parser.add_argument("--baud", type=int, help="baud rate (default: the profile's)")
    parser.add_argument(
        "--machine",
        help="profile name or .toml path (default: grbl_diw on sim://grbl, else marlin_generic)",
    )
    parser.add_argument("--log", metavar="LOGFILE", help="write all traffic to LOGFILE")
    parser.add_argument(
        "--resume-from", type=int, metavar="LINE", help="start at file line LINE (1-based)"
    )
    parser.add_argument(
        "--dry-run", action="store_true", help="check the file against the machine, send nothing"
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    result = send_file(
        args.file,
        args.port,
        baud=args.baud,
        machine=args.machine,
        log_path=args.log,
        resume_from=args.resume_from,
        dry_run=args.dry_run,
    )
    print(result.summary())
    return 0
