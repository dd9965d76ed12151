"""Every command in examples/README.md runs, on coarse grids, and writes its files.

The commands are read from the README's ``sh`` blocks, so the page and this test cannot
drift apart. ``fabkit run`` gets ``--step 0.1 --diagonals 30 --size 20`` appended (a
coarse solver grid and a small part: the last --size given counts), ``--no-verify`` and
``--no-simulate`` (the ``fabkit verify`` example reads a run back, simulations included);
a spec's first run draws the pictures, later runs of the same spec add ``--no-pictures``;
the swimmer runs on a copy of its spec with small meshes and two stations per leg (as in
tests/test_swimmer.py). ``fabkit compare`` reads the run of the README's main command
(``out/``, two layers, verified and simulated: too slow here) from its stored copy,
tests/data/compare_run. Outputs go to the test's folder, never to ``out/``.
"""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import pytest

from tests.conftest import EXAMPLES, ROOT

README = EXAMPLES / "README.md"
COARSE_SOLVE = ["--step", "0.1", "--diagonals", "30", "--size", "20"]


def example_commands() -> list[str]:
    """The ``fabkit ...`` lines of the README's ``sh`` blocks."""
    blocks = re.findall(r"```sh\n(.*?)```", README.read_text(), flags=re.S)
    return [line for block in blocks for line in block.splitlines() if line.startswith("fabkit ")]


def out_name(command: str) -> str:
    """The command's output folder (``verify``: the folder of the run it reads)."""
    words = shlex.split(command)
    if words[1] == "verify":
        return str(Path(words[2]).parent) + "-verify"
    return words[words.index("--out") + 1]


def coarse_swimmer(folder) -> str:
    text = (EXAMPLES / "swimmer.toml").read_text()
    for old, new in [("rings = 12", "rings = 5"), ("rings = 20", "rings = 7")]:
        assert old in text
        text = text.replace(old, new)
    path = folder / "swimmer.toml"
    path.write_text(text)
    return str(path)


def draws_pictures(command: str) -> bool:
    """Whether the run ``command`` is the page's first of its spec: it draws the pictures,
    the later ones of the same spec (another process, machine or layer count) add
    ``--no-pictures``; tests/test_pictures_read.py looks at them."""
    spec = shlex.split(command)[2]
    runs = [c for c in example_commands() if c.startswith("fabkit run")]
    return next(c for c in runs if shlex.split(c)[2] == spec) == command


RUNS: dict[str, str] = {}
"""Output folders of the run examples already made in this session, by README folder."""


def run_of(folder: str) -> str:
    """The README's ``fabkit run`` command that writes ``folder``."""
    (command,) = [
        c for c in example_commands() if c.startswith("fabkit run") and out_name(c) == folder
    ]
    return command


@pytest.mark.slow
@pytest.mark.parametrize("command", example_commands(), ids=out_name)
def test_example_runs(command, run_cli, tmp_path):
    args = shlex.split(command)[1:]
    if args[0] == "verify":  # reads what a run of the page wrote (made above, or now)
        folder = str(Path(args[1]).parent)
        if folder not in RUNS:
            made = shlex.split(run_of(folder))[1:]
            made[made.index("--out") + 1] = RUNS[folder] = str(tmp_path / folder)
            made = [str(ROOT / a) if a.startswith("examples/") else a for a in made]
            assert run_cli(*made, *COARSE_SOLVE, "--no-verify", "--no-simulate")[0] == 0
        args = [a.replace(folder, RUNS[folder], 1) if a.startswith(folder) else a for a in args]
        code, text, err = run_cli(*args)
        assert code == 0, err
        assert "director error" in text and "as fabricated vs" in text
        return
    if args[0] == "compare":  # the README's main command's run, stored
        args[args.index("out")] = str(ROOT / "tests" / "data" / "compare_run")
    out = tmp_path / out_name(command).removeprefix("out/")
    args[args.index("--out") + 1] = str(out)
    args = [str(ROOT / a) if a.startswith("examples/") else a for a in args]
    name = args[0]
    if name == "run":  # fabkit verify runs in its own example below and in test_verify; the
        # verdicts on the examples' shapes, in tests/test_run_layers.py and test_verify.py
        # (and the layers' share chosen by simulation there: not simulated, the whole one)
        args += [*COARSE_SOLVE, "--no-verify", "--no-simulate"]
        if not draws_pictures(command):
            args += ["--no-pictures"]
    if name == "swimmer":
        args[args.index(str(EXAMPLES / "swimmer.toml"))] = coarse_swimmer(tmp_path)
        args += ["--stations", "2"]
    code, _, err = run_cli(*args)
    assert code == 0, err
    if name == "calibrate":  # writes one file, the table
        assert out.stat().st_size > 0
        return
    if name == "run":
        RUNS[out_name(command)] = str(out)
    assert [p for p in out.rglob("*") if ".part" in p.name] == []
    expected = {
        "run": ["design.npz", "report.html", "report.json"],
        "swimmer": ["summary.json", "stroke.npz", "swimmer.gcode"],
        "toolpath": ["toolpath.npz", "quality.json", "preview.png"],
        "channels": ["channels.json", "mould.stl", "channels.png"],
        "compare": ["compare.json", "compare.png", "scan_aligned.ply"],
    }[name]
    if name == "run":
        if "--baromorph" in args:
            expected += ["channels.dxf", "channels/mould.stl"]
        elif "dmd_photoalign" in args:
            expected += ["laser/manifest.json", "laser/angle.png"]
            assert json.loads((out / "laser" / "manifest.json").read_text())
            assert not (out / "toolpath").exists()  # a laser writer needs no print lines
            assert (
                "binning error" in json.loads((out / "report.json").read_text())["exports"]["laser"]
            )
        else:
            expected += ["sheet.gcode", "toolpath/toolpath.npz"]
        assert json.loads((out / "report.json").read_text())["exports"]
    for file in expected:
        assert (out / file).stat().st_size > 0, file


def test_every_example_file_has_a_command():
    commands = "\n".join(example_commands())
    for path in sorted(EXAMPLES.rglob("*.toml")):
        assert f"examples/{path.relative_to(EXAMPLES)}" in commands, path


def test_examples_are_linked_from_the_readme():
    assert "](examples/README.md)" in (ROOT / "README.md").read_text()
