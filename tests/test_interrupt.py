"""Ctrl-C in the middle of ``fabkit run`` leaves no half-written file under a final name.

The interrupt is simulated where it hurts most: while a file is half-written in its
temporary place (the G-code, a laser pattern folder), or sent for real while the
second process draws the pictures. Afterwards every file
under a final name must be complete, nothing ``*.part`` may remain, and the command
prints one line and exits with 130.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

from fabkit.design.design import Design
from fabkit.files.atomic import MANIFEST
from tests.conftest import EXAMPLES

COARSE = ("--step", "0.1", "--diagonals", "30", "--size", "20")


def assert_complete(out: Path) -> list[str]:
    """Every file under ``out`` reads back whole; returns their relative names."""
    names = []
    for path in sorted(p for p in out.rglob("*") if p.is_file()):
        name = str(path.relative_to(out))
        names.append(name)
        assert ".part" not in name and ".old" not in name, name
        suffix = path.suffix
        if name == "design.npz":
            Design.load(path)
        elif suffix == ".npz":
            with np.load(path, allow_pickle=False) as data:
                for key in data.files:
                    data[key]  # reading checks every member's CRC
        elif suffix == ".json":
            json.loads(path.read_text())
        elif suffix in (".png", ".tif"):
            with Image.open(path) as image:
                image.load()
        elif suffix == ".svg":
            ET.parse(path)
        elif suffix == ".ply":
            assert len(trimesh.load(path).faces) > 0
        elif suffix == ".html":
            assert path.read_text().rstrip().endswith("</html>")
        elif suffix == ".gcode":
            assert path.read_text().endswith("\n")
        elif name == MANIFEST:  # every file the run finished is listed for --overwrite
            listed = set(path.read_text().split())
            present = {str(p.relative_to(out)) for p in out.rglob("*") if p.is_file()}
            assert present - {MANIFEST} <= listed
        else:
            raise AssertionError(f"unexpected file {name}")
    return names


@pytest.mark.slow
def test_ctrl_c_while_writing_gcode(run_cli, tmp_path, monkeypatch):
    real_replace = os.replace

    def interrupted(src, dst):
        if Path(dst).name == "sheet.gcode":
            data = Path(src).read_bytes()
            Path(src).write_bytes(data[: len(data) // 2])  # half-written in its temporary
            raise KeyboardInterrupt
        real_replace(src, dst)

    monkeypatch.setattr("fabkit.files.atomic.os.replace", interrupted)
    out = tmp_path / "out"
    code, _, err = run_cli("run", EXAMPLES / "two_shapes.toml", "--out", out, *COARSE)
    assert code == 130
    assert err == "fabkit: interrupted\n"
    names = assert_complete(out)
    assert "sheet.gcode" not in names and "report.json" not in names
    assert {"design.npz", "design.json", "toolpath/toolpath.npz"} <= set(names)


@pytest.mark.slow
def test_ctrl_c_while_the_worker_draws_the_pictures(tmp_path):
    """A real Ctrl-C, sent to the whole process group as a terminal does, while the
    picture worker draws (:mod:`fabkit.background`): the run answers with one line and
    130, no picture is half-written or written at all, and no process of the run is left.
    """
    out = tmp_path / "out"
    command = [sys.executable, "-m", "fabkit", "run", str(EXAMPLES / "two_shapes.toml")]
    process = subprocess.Popen(
        [*command, "--out", str(out), *COARSE],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=tmp_path,
        start_new_session=True,  # its own process group: the run and its worker
    )
    for line in process.stdout:
        if line.startswith("[3/7]"):  # the pictures were handed to the worker just now
            os.killpg(process.pid, signal.SIGINT)
            break
    _, err = process.communicate(timeout=120)
    assert process.returncode == 130, err
    assert err == "fabkit: interrupted\n"
    names = assert_complete(out)
    assert not [n for n in names if n.startswith("pictures/")] and "report.json" not in names
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        try:
            os.killpg(process.pid, 0)  # any process of the group still there?
        except ProcessLookupError:
            break
        time.sleep(0.1)
    else:
        pytest.fail("the picture worker outlived the interrupted run")


@pytest.mark.slow
def test_ctrl_c_while_writing_a_laser_pattern(run_cli, tmp_path, monkeypatch):
    real_save = Image.Image.save

    def interrupted(image, target, *args, **kwargs):
        if "laser" in str(target) and Path(target).name.startswith("exposure"):
            Path(target).write_bytes(b"\x89PNG\r\n\x1a\n half an exposure")
            raise KeyboardInterrupt
        return real_save(image, target, *args, **kwargs)

    monkeypatch.setattr(Image.Image, "save", interrupted)
    out = tmp_path / "out"
    code, _, err = run_cli(
        "run", EXAMPLES / "two_shapes.toml", "--out", out, "--machine", "dmd_photoalign",
        *COARSE, "--no-simulate",
    )  # fmt: skip
    assert code == 130
    assert err == "fabkit: interrupted\n"
    names = assert_complete(out)
    assert not any(name.startswith("laser") for name in names)
    assert "design.npz" in names and "report.json" not in names


_INTERRUPT_AT_IMPORT = """
import builtins, sys
real_import = builtins.__import__
def interrupting_import(name, *args, **kwargs):
    if name == TARGET:
        raise KeyboardInterrupt
    return real_import(name, *args, **kwargs)
builtins.__import__ = interrupting_import
from fabkit.entry import run
run()
"""


@pytest.mark.slow
@pytest.mark.parametrize("module", ["fabkit.cli", "fabkit.run.pipeline", "numba", "scipy"])
def test_ctrl_c_while_the_command_starts_is_one_line(tmp_path, module):
    """Ctrl-C while the CLI and its stages are imported: exit 130, one line, no traceback.

    The interrupt is raised exactly when ``module`` is imported (a timed SIGINT would race
    the interpreter's own start-up on a loaded machine).
    """
    script = _INTERRUPT_AT_IMPORT.replace("TARGET", repr(module))
    args = ["run", str(EXAMPLES / "two_shapes.toml"), "--out", str(tmp_path / "out"), *COARSE]
    process = subprocess.run(
        [sys.executable, "-c", script, *args], capture_output=True, text=True, cwd=tmp_path,
        timeout=120,
    )  # fmt: skip
    assert process.returncode == 130, process.stderr
    assert process.stderr == "fabkit: interrupted\n"
    assert not (tmp_path / "out").exists()


def test_an_unexpected_exception_is_one_line_and_exit_1(run_cli, monkeypatch):
    def broken(*_):
        raise ZeroDivisionError("division by zero")

    monkeypatch.setattr("fabkit.commands.machines.machine_table", broken)
    code, _, err = run_cli("machines")
    assert code == 1
    assert err.startswith("fabkit: internal error: ZeroDivisionError: division by zero")
    assert err.count("\n") == 1 and "Traceback" not in err
    code, _, err = run_cli("--debug", "machines")
    assert code == 1 and "Traceback" in err
