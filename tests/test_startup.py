"""The quick commands import no heavy stage: ``fabkit --help`` never loads matplotlib.

Wall times are in ``benchmarks/startup.py``; this test guards the cause of a slow start
(a stage imported while the command line is parsed), which a time bound would catch only
on a quiet machine. Each command runs in a fresh interpreter that then lists what it
imported.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from fabkit.cli import build_parser
from fabkit.commands import COMMANDS
from tests.conftest import EXAMPLES

HEAVY = ("matplotlib", "scipy", "shapely", "trimesh", "ezdxf", "PIL", "manifold3d", "contourpy")
"""Libraries that cost tenths of a second each to import."""

_PROBE = """
import contextlib, io, json, sys
from fabkit.cli import main
with contextlib.redirect_stdout(io.StringIO()):
    try:
        code = main(sys.argv[1:])
    except SystemExit as exc:  # --version and --help exit from argparse
        code = exc.code
print(json.dumps([code, sorted(m for m in sys.modules if '.' not in m)]))
"""


def imported(*args: str) -> tuple[int, list[str]]:
    """Exit code of ``fabkit ARGS`` in a fresh interpreter, and the top-level modules loaded."""
    process = subprocess.run(
        [sys.executable, "-c", _PROBE, *map(str, args)], capture_output=True, text=True,
        timeout=120, check=True,
    )  # fmt: skip
    code, modules = json.loads(process.stdout.splitlines()[-1])
    return code, modules


@pytest.mark.parametrize(
    "args",
    [
        ["--version"],
        ["--help"],
        ["machines"],
        ["spec", EXAMPLES / "two_shapes.toml"],
        ["send", "--help"],
        ["nosuchcommand"],
    ],
    ids=["version", "help", "machines", "spec", "send-help", "unknown-command"],
)
def test_quick_commands_import_no_heavy_library(args, tmp_path):
    code, modules = imported(*args)
    assert code in (0, 2)
    assert not set(HEAVY) & set(modules), f"fabkit {args[0]} imported {set(HEAVY) & set(modules)}"


def test_send_dry_run_imports_no_heavy_library(tmp_path):
    job = tmp_path / "job.gcode"
    job.write_text("G21\nG90\nG28\nG1 X10 Y10 F3000\nG1 X20 Y10 F1200\n", encoding="utf-8")
    code, modules = imported("send", job, "--dry-run", "--machine", "marlin_generic")
    assert code == 0
    assert not set(HEAVY) & set(modules)


def test_every_command_is_listed_and_registered_by_its_module():
    """The list in fabkit.commands and the modules' own parsers name the same commands."""
    helps = {name: command.help for name, command in COMMANDS.items()}
    for parser in (build_parser(), build_parser([])):
        action = parser._subparsers._group_actions[0]  # argparse keeps the sub-commands here
        assert {a.dest: a.help for a in action._choices_actions} == helps


_BLAS = """
import atexit, json, sys


def threads():  # numpy's and scipy's OpenBLAS load here, after the command's first lines
    import scipy.linalg
    from threadpoolctl import threadpool_info

    info = threadpool_info()
    print(json.dumps([i["num_threads"] for i in info if i["internal_api"] == "openblas"]))


atexit.register(threads)
sys.argv = ["fabkit", "machines"]
from fabkit.entry import run

run()
"""


@pytest.mark.parametrize("given", [None, "2"])
def test_a_command_runs_openblas_on_one_thread_unless_told_otherwise(given):
    # fabkit/entry.py: idle OpenBLAS threads spun beside the simulations' and pictures'
    # processes (the README's main command: 35-48 s with them, 26-27 s without, loaded)
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    if given:
        env["OPENBLAS_NUM_THREADS"] = given
    process = subprocess.run(
        [sys.executable, "-c", _BLAS], capture_output=True, text=True, timeout=120, env=env
    )
    threads = json.loads(process.stdout.strip().splitlines()[-1])
    assert len(threads) == 2 and set(threads) == {int(given or 1)}, process.stdout
