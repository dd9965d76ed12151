"""The public API (``import fabkit``): docs/api.md's script runs and its results hold, every
name in ``fabkit.__all__`` resolves, and ``import fabkit`` loads no stage."""

from __future__ import annotations

import json
import re
import runpy
import subprocess
import sys
import time

import pytest

import fabkit
import fabkit.api
from fabkit.design.check import check_design
from fabkit.link.host.send import send_file
from fabkit.problem.spec import load_spec
from tests.conftest import ROOT

HEAVY = ("numpy", "scipy", "matplotlib", "shapely", "sympy", "trimesh", "ezdxf", "PIL")
"""Libraries a stage imports: ``import fabkit`` loads none of them."""

LIGHT = {"fabkit", "fabkit.errors", "fabkit.version", "fabkit.verify"}
"""The fabkit modules ``import fabkit`` loads: the package, its error type, its version
and the callable :mod:`fabkit.verify` package (a docstring)."""


def docs_script() -> str:
    """The one python block of docs/api.md."""
    blocks = re.findall(r"```python\n(.*?)```", (ROOT / "docs" / "api.md").read_text(), re.S)
    assert len(blocks) == 1, "docs/api.md: expected one ```python block"
    return blocks[0]


def command_lines(path) -> list[str]:
    """The lines of a G-code file a machine executes (comments and blank lines left out)."""
    lines = path.read_text(encoding="utf-8").splitlines()
    return [line for line in lines if line.split(";", 1)[0].strip()]


def test_docs_script_runs_from_spec_to_machine(tmp_path, monkeypatch, capsys):
    script = tmp_path / "sheet.py"
    script.write_text(docs_script(), encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    started = time.perf_counter()
    result = runpy.run_path(str(script), run_name="__main__")
    seconds = time.perf_counter() - started
    printed = capsys.readouterr().out
    assert seconds < 30, f"the docs script took {seconds:.1f} s"  # about 2 s

    report = result["report"]
    assert report.passed, report.table()
    for surface in report.surfaces:
        assert surface.points > 0
        assert surface.isometry.median < report.tolerances.isometry_median
        assert surface.curvature.median < report.tolerances.curvature_median
    assert "isometry and curvature check: passed" in printed

    gcode = tmp_path / "fabkit-api-out" / "sheet.gcode"
    assert result["exported"].path == gcode.relative_to(tmp_path)
    lines = command_lines(gcode)
    motions = [line for line in lines if re.match(r"G0?[01]\b", line)]
    assert len(motions) > 100
    assert result["exported"].figures["print_length_mm"] > 100

    verification = result["verification"]
    assert verification.machine == "marlin_diw_pneumatic"
    assert verification.director_mean_deg < 3
    assert verification.director_p95_deg < 10
    assert verification.empty_fraction < 0.1

    sent = result["sent"]
    assert sent.job_lines == len(lines)  # every line the machine executes, once
    assert sent.last_file_line == len(gcode.read_text(encoding="utf-8").splitlines())
    assert sent.resends == 0
    assert sent.warnings == ()
    assert (tmp_path / "fabkit-api-out" / "design.npz").is_file()


def test_every_public_name_resolves_with_a_docstring():
    assert len(set(fabkit.__all__)) == len(fabkit.__all__)
    assert set(fabkit.__all__) == {"FabkitError", "__version__", *fabkit._PUBLIC}
    for name in fabkit.__all__:
        value = getattr(fabkit, name)
        assert name in dir(fabkit)
        if name != "__version__":
            assert (value.__doc__ or "").strip(), f"fabkit.{name} has no docstring"
    for name in ("load_spec", "solve", "check", "plan_toolpath", "write_machine_file"):
        assert callable(getattr(fabkit, name))
    assert fabkit.load_spec is load_spec
    assert fabkit.check is check_design
    assert fabkit.send is send_file
    assert fabkit.solve is fabkit.api.solve
    with pytest.raises(AttributeError, match="no attribute 'nosuchname'"):
        fabkit.nosuchname  # noqa: B018


def test_verify_is_the_function_and_the_package():
    """``fabkit.verify`` is both: the import system sets the subpackage on ``fabkit``."""
    import fabkit.verify.machine_file as machine_file

    assert callable(fabkit.verify)
    assert fabkit.verify.machine_file is machine_file
    assert sys.modules["fabkit.verify"] is fabkit.verify


def test_verify_calls_the_api(monkeypatch):
    calls = []
    monkeypatch.setattr(fabkit.api, "verify", lambda *args, **kw: calls.append((args, kw)))
    fabkit.verify("design.npz", "sheet.gcode", simulate=False)
    assert calls == [(("design.npz", "sheet.gcode"), {"simulate": False})]


def test_plan_toolpath_refuses_an_unknown_setting():
    with pytest.raises(TypeError, match="unexpected keyword arguments: out, preview"):
        fabkit.plan_toolpath(None, out="x", preview=False)


_PROBE = """
import json, sys
import {module}
print(json.dumps(sorted(sys.modules)))
"""


@pytest.mark.parametrize("module", ["fabkit", "fabkit.api"])
def test_import_loads_no_stage(module):
    process = subprocess.run(
        [sys.executable, "-c", _PROBE.format(module=module)],
        capture_output=True, text=True, timeout=120, check=True, cwd=ROOT,
    )  # fmt: skip
    modules = set(json.loads(process.stdout.splitlines()[-1]))
    heavy = {m for m in modules if m.split(".")[0] in HEAVY}
    assert not heavy, f"import {module} imported {sorted(heavy)}"
    stages = {m for m in modules if m.startswith("fabkit")} - LIGHT - {"fabkit.api"}
    assert not stages, f"import {module} imported {sorted(stages)}"
