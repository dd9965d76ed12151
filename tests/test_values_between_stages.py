"""Issue 20: each command parses the spec once and computes the residual maps once; `fabkit
run` hands the design and the toolpath from stage to stage in memory (the files it writes
are side outputs, read by no later stage). Issue 28: every command reads each of its
TOML files (spec, machine profile, process, baromorph settings) once, and the stages take
the values."""

from __future__ import annotations

import contextlib
import importlib
import io
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import shapely

import fabkit.design.check
import fabkit.files.tomlfile
import fabkit.problem.spec
import fabkit.toolpath.model
from fabkit.cli import main
from fabkit.design.design import Design
from fabkit.design.summary import solve_to_file
from fabkit.field.design_field import field_from_design
from fabkit.machines import load_machine
from fabkit.problem.spec import load_spec
from fabkit.toolpath.model import load_toolpath
from fabkit.writers.export import Exported, export, write_machine_file

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
COARSE = ("--step", "0.1", "--diagonals", "30", "--size", "20")


@contextlib.contextmanager
def counting():
    """Counts of the spec parses, residual-map computations and file reloads while the
    block runs: every fabkit module that holds the function (imported by name) gets the
    counting wrapper."""
    for module in (
        "fabkit.run.pipeline",
        "fabkit.commands.verify",
        "fabkit.commands.toolpath",
        "fabkit.commands.export",
        "fabkit.commands.send",
        "fabkit.link.host.send",
    ):
        importlib.import_module(module)  # load every stage before wrapping
    calls: Counter[str] = Counter()
    with pytest.MonkeyPatch.context() as patch:

        def count(real, key: str) -> None:
            def wrapper(*args, **kwargs):
                calls[key] += 1
                return real(*args, **kwargs)

            for name, module in list(sys.modules.items()):
                if name.startswith("fabkit"):
                    for attribute, value in list(vars(module).items()):
                        if value is real:
                            patch.setattr(module, attribute, wrapper)

        real_read = fabkit.files.tomlfile.read_toml

        def read_toml(path, what, *args, **kwargs):
            calls[f"{what} reads"] += 1
            return real_read(path, what, *args, **kwargs)

        for name, module in list(sys.modules.items()):
            if name.startswith("fabkit") and getattr(module, "read_toml", None) is real_read:
                patch.setattr(module, "read_toml", read_toml)
        count(fabkit.problem.spec.build_spec, "spec parses")
        count(fabkit.design.check.residual_maps, "residual maps")
        count(fabkit.toolpath.model.load_toolpath, "toolpath loads")
        real_load = Design.load.__func__

        def load(cls, *args, **kwargs):
            calls["design loads"] += 1
            return real_load(cls, *args, **kwargs)

        patch.setattr(Design, "load", classmethod(load))
        yield calls


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """One coarse `fabkit run` of Fig. 1, counted: its output folder and the counts."""
    out = tmp_path_factory.mktemp("values") / "out"
    with counting() as calls, contextlib.redirect_stdout(io.StringIO()):
        code = main(["run", str(EXAMPLES / "two_shapes.toml"), "--out", str(out), *COARSE])
    assert code == 0
    return out, Counter(calls)


@pytest.mark.slow
def test_run_parses_once_computes_maps_once_and_reloads_nothing(run):
    out, calls = run
    once = {"spec reads": 1, "machine reads": 1}
    assert calls == {"spec parses": 1, "residual maps": 1, **once}, calls
    assert (out / "design.npz").is_file() and (out / "sheet.gcode").is_file()


@pytest.mark.slow
def test_verify_and_toolpath_parse_the_embedded_spec_once(run, tmp_path, run_cli):
    out, _ = run
    verify = ("verify", out / "design.npz", out / "sheet.gcode", "--no-simulate")
    with counting() as calls:
        code, _, err = run_cli(*verify, "--machine", "marlin_diw_pneumatic")
    assert code == 0, err
    assert calls == {"spec parses": 1, "design loads": 1, "machine reads": 1}, calls
    toolpath = ("toolpath", out / "design.npz", "--size", "20", "--out", tmp_path / "tp")
    with counting() as calls:
        assert run_cli(*toolpath)[0] == 0
    assert calls == {"spec parses": 1, "design loads": 1, "machine reads": 1}, calls


def process_file(folder: Path) -> Path:
    """A process file holding the default machine's own [process] table."""
    text = (EXAMPLES.parent / "machines" / "marlin_diw_pneumatic.toml").read_text()
    path = folder / "process.toml"
    path.write_text("[process]" + text.split("\n[process]", 1)[1].split("\n[inks]", 1)[0])
    return path


@pytest.mark.slow
def test_every_command_reads_each_file_once(run, tmp_path, run_cli):
    """The machine profile, the process and the baromorph settings are read once per
    command, whatever stages the command runs (a file read twice could change between
    the reads, and is work done twice)."""
    out, _ = run
    design, gcode, process = out / "design.npz", out / "sheet.gcode", process_file(tmp_path)
    channels = EXAMPLES / "baromorph_channels.toml"
    commands = {
        "verify, the machine its header names": (
            ("verify", design, gcode, "--no-simulate"),
            {"machine reads": 1},
        ),
        "verify with a process": (
            ("verify", design, gcode, "--no-simulate", "--process", process),
            {"machine reads": 1, "process reads": 1},
        ),
        "toolpath with a process": (
            ("toolpath", design, "--size", "20", "--process", process, "--out", tmp_path / "t"),
            {"machine reads": 1, "process reads": 1},
        ),
        "channels": (
            ("channels", "--director", "arctan2(y, x)", "--shape", "disc:20", "--eps", "0.4")
            + ("--out", tmp_path / "c", "--baromorph", channels),
            {"baromorph reads": 1},
        ),
        "send": (
            ("send", gcode, "--port", "sim://marlin?baud=0&time_scale=0"),
            {"machine reads": 1},
        ),
    }
    for name, (argv, reads) in commands.items():
        with counting() as calls:
            code, _, err = run_cli(*argv)
        assert code == 0, f"{name}: {err}"
        counted = {key: n for key, n in calls.items() if key.endswith(" reads")}
        assert counted == reads, (name, calls)


@pytest.mark.slow
def test_a_baromorph_run_reads_its_settings_once(tmp_path):
    out = tmp_path / "out"
    argv = ["run", str(EXAMPLES / "baromorph.toml"), "--out", str(out), *COARSE, "--size", "60"]
    argv += ["--no-pictures"]
    argv += ["--baromorph", str(EXAMPLES / "baromorph_channels.toml"), "--no-simulate"]
    with counting() as calls, contextlib.redirect_stdout(io.StringIO()):
        assert main(argv) == 0
    counted = {key: n for key, n in calls.items() if key.endswith(" reads")}
    assert counted == {"spec reads": 1, "machine reads": 1, "baromorph reads": 1}, calls


@pytest.mark.slow
def test_export_from_a_value_writes_what_export_from_the_file_writes(run, tmp_path):
    out, _ = run
    toolpath = load_toolpath(out / "toolpath" / "toolpath.npz")
    machine = load_machine("marlin_diw_pneumatic")
    from_value = write_machine_file(toolpath, machine, "gcode", tmp_path / "value.gcode")
    from_file = export(
        out / "toolpath" / "toolpath.npz", machine.name, "gcode", tmp_path / "file.gcode"
    )
    assert isinstance(from_value, Exported) and from_value.format == "gcode"
    assert from_value.machine == machine.name == from_file.machine
    assert (tmp_path / "value.gcode").read_bytes() == (tmp_path / "file.gcode").read_bytes()
    # the run wrote the same machine file from the toolpath it held in memory
    assert (out / "sheet.gcode").read_bytes() == (tmp_path / "file.gcode").read_bytes()
    assert from_value.summary.startswith(f"wrote {tmp_path / 'value.gcode'}: ")


def test_the_design_in_memory_gives_the_field_its_file_gives(tmp_path):
    spec = load_spec(EXAMPLES / "two_shapes.toml").with_solver(step=0.1, diagonals=30)
    solved = solve_to_file(spec, tmp_path / "design.npz")
    in_memory = field_from_design(solved.solution.design, size_mm=60.0)
    from_file = field_from_design(tmp_path / "design.npz", size_mm=60.0)
    assert in_memory.outline.equals(from_file.outline)
    x0, y0, x1, y1 = from_file.outline.bounds
    points = np.stack(np.meshgrid(np.linspace(x0, x1, 40), np.linspace(y0, y1, 40)), -1)
    points = points.reshape(-1, 2)
    inside = shapely.contains_xy(from_file.outline, points[:, 0], points[:, 1])
    assert inside.sum() > 100
    assert np.array_equal(in_memory.theta(points[inside]), from_file.theta(points[inside]))
    for name, eps in from_file.features.items():
        xy = points[inside]
        assert np.array_equal(in_memory.features[name](xy[:, 0], xy[:, 1]), eps(xy[:, 0], xy[:, 1]))
