"""fabkit installs anywhere: every package is listed, and a built wheel runs the README's
main command from a folder outside the checkout, with its shipped profiles and examples."""

from __future__ import annotations

import re
import subprocess
import sys
import sysconfig
import tomllib
import venv
from pathlib import Path

import pytest

from tests.conftest import ROOT

README_FILES = (
    "design.npz", "design.json", "pictures/flat_sheet.png", "pictures/eps.png",
    "pictures/surfaces.png", "pictures/residuals.png", "patches/1_sphere.ply",
    "patches/2_bump.ply", "toolpath/toolpath.npz", "toolpath/quality.json",
    "toolpath/preview.png", "toolpath/preview.svg", "sheet.gcode", "report.html", "report.json",
)  # fmt: skip
"""The files the README says its main command writes (checked after running it)."""


def readme_main_command() -> str:
    """The ``fabkit ...`` part of the README's first quickstart command."""
    quickstart = (ROOT / "README.md").read_text().split("## Quickstart", 1)[1]
    first = re.findall(r"```sh\n(.*?)\n```", quickstart, flags=re.S)[0]
    return first.split("&&", 1)[1].strip()


def test_every_package_folder_is_listed_in_pyproject():
    listed = set(
        tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]
    )
    folders = {
        ".".join(p.parent.relative_to(ROOT).parts) for p in (ROOT / "fabkit").rglob("__init__.py")
    }
    assert folders <= listed, f"add to [tool.setuptools] packages: {sorted(folders - listed)}"
    assert {"fabkit.profiles", "fabkit.examples"} <= listed


@pytest.mark.slow
def test_a_wheel_runs_the_readme_command_from_another_folder(tmp_path):
    wheels = tmp_path / "wheels"
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", str(ROOT), "--no-deps", "--no-build-isolation",
         "-q", "-w", str(wheels)],
        check=True, capture_output=True, text=True,
    )  # fmt: skip
    (wheel,) = wheels.glob("fabkit-*.whl")
    env_dir = tmp_path / "venv"
    venv.create(env_dir, with_pip=False)
    python = env_dir / "bin" / "python"
    # The dependencies come from the test's own environment (no network in tests); a path
    # line in a .pth file adds that folder without running its .pth files, so the editable
    # fabkit of the checkout stays out of sight.
    site = subprocess.run(
        [python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        check=True, capture_output=True, text=True,
    ).stdout.strip()  # fmt: skip
    Path(site, "dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "-q",
         str(wheel)],
        check=True, capture_output=True, text=True,
    )  # fmt: skip
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    found = subprocess.run(
        [python, "-c", "import fabkit; print(fabkit.__file__)"],
        cwd=elsewhere, check=True, capture_output=True, text=True,
    ).stdout  # fmt: skip
    assert str(env_dir) in found, found
    fabkit = str(env_dir / "bin" / "fabkit")
    machines = subprocess.run([fabkit, "machines"], cwd=elsewhere, capture_output=True, text=True)
    assert machines.returncode == 0 and "marlin_diw_pneumatic" in machines.stdout, machines.stderr
    command = readme_main_command().split()
    assert command[0] == "fabkit"
    args = [a.strip("\"'") for a in command[1:]]
    # verbatim, as a new user types it (CI runs it nowhere else)
    run = subprocess.run(
        [fabkit, *args], cwd=elsewhere, capture_output=True, text=True, timeout=600
    )
    assert run.returncode == 0, run.stderr
    for name in README_FILES:
        assert (elsewhere / "out" / name).stat().st_size > 0, name
