"""Shared helpers: the example specs as editable tables, coarse designs, and a CLI runner."""

from __future__ import annotations

import contextlib
import copy
import fcntl
import io
import os
import tempfile
import tomllib
from collections.abc import Callable
from pathlib import Path

import pytest
from hypothesis import settings

from fabkit.cli import main
from fabkit.design.design import Design
from fabkit.design.solver import solve
from fabkit.problem.spec import build_spec

# CI explores the same property-test examples on every run (a fixed seed per test), so that
# a red CI means a change broke something; runs elsewhere explore new examples each time.
settings.register_profile("ci", derandomize=True, print_blob=True)
if os.environ.get("FABKIT_CI"):
    settings.load_profile("ci")

# The test files run in parallel already (pytest-xdist, a worker per core): a verdict's
# simulations run in the test's own process, not in a pool of their own on the same cores
# (tests/test_background.py tests the pool).
if os.environ.get("PYTEST_XDIST_WORKER"):
    os.environ.setdefault("FABKIT_WORKERS", "1")
# Simulations are kept by everything they depend on (fabkit.mechanics.cache): the tests
# share one cache of their own, not the user's (tests/test_mechanics_cache.py tests it).
os.environ.setdefault("FABKIT_CACHE", str(Path(tempfile.gettempdir()) / "fabkit-test-cache"))

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples"


def validate_report(figures: dict) -> None:
    """A run's ``report.json`` figures against ``docs/report.schema.json`` (raises
    jsonschema's ValidationError where they differ)."""
    import json

    import jsonschema

    schema = json.loads((ROOT / "docs" / "report.schema.json").read_text())
    jsonschema.Draft202012Validator.check_schema(schema)
    jsonschema.validate(figures, schema, cls=jsonschema.Draft202012Validator)


def example_table(name: str) -> dict:
    """An example spec as nested dicts, to edit in a test and pass to build_spec."""
    with open(EXAMPLES / name, "rb") as handle:
        return copy.deepcopy(tomllib.load(handle))


def coarse_design(
    example: str = "two_shapes.toml", *, step: float = 0.1, diagonals: int = 30
) -> Design:
    """An example spec's design solved on a coarse grid (``step``, ``diagonals``): quick,
    for tests that need a design rather than its accuracy."""
    table = example_table(example)
    table["solver"].update(step=step, diagonals=diagonals)
    return solve(build_spec(table, EXAMPLES)).design


@pytest.fixture(scope="module")
def folder(tmp_path_factory, request) -> Path:
    """A folder of one test module's own, for the inputs its module fixtures make once."""
    return tmp_path_factory.mktemp(request.module.__name__.rsplit(".", 1)[-1])


@pytest.fixture
def fig1() -> dict:
    return example_table("two_shapes.toml")


@pytest.fixture
def fig3() -> dict:
    return example_table("three_shapes.toml")


@pytest.fixture
def run_cli(capsys):
    """Run ``fabkit ARGS``; returns (exit code, stdout, stderr)."""

    def run(*args: str) -> tuple[int, str, str]:
        code = main([str(a) for a in args])
        captured = capsys.readouterr()
        return code, captured.out, captured.err

    return run


COARSE_RUN = ("--step", "0.1", "--diagonals", "30", "--size", "20")
"""A coarse ``fabkit run`` of an example (a 20 mm part, verified): what the tests that
read a run's whole output share (:func:`coarse_run`)."""


@pytest.fixture(scope="session")
def coarse_run(tmp_path_factory) -> Callable[[str], tuple[Path, str]]:
    """``fabkit run examples/SPEC --out OUT`` with :data:`COARSE_RUN`, made once per test
    session for every worker (in the session's temporary folder, which pytest-xdist's
    workers share and pytest removes with old sessions; a lock file orders the workers):
    ``(OUT, its stdout)``. Read it, never write into it."""
    base = tmp_path_factory.getbasetemp()
    shared = (base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base) / "coarse-runs"
    shared.mkdir(exist_ok=True)

    def made(spec: str) -> tuple[Path, str]:
        out, printed = shared / spec / "out", shared / f"{spec}.stdout"
        with open(shared / f"{spec}.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            if not printed.exists():
                buffer = io.StringIO()
                with contextlib.redirect_stdout(buffer):
                    assert main(["run", str(EXAMPLES / spec), "--out", str(out), *COARSE_RUN]) == 0
                printed.write_text(buffer.getvalue())
        return out, printed.read_text()

    return made


LONGEST_FIRST = (
    "test_examples.py",
    "test_run_layers.py",
    "test_run.py",
    "test_compare_scan.py",
    "test_mechanics_adjoint.py",
    "test_packaging.py",
    "test_link_marlin.py",
    "test_gcode_columns.py",
    "test_run_refine.py",
    "test_report_browser.py",
    "test_pictures_read.py",
    "test_link_resend_property.py",
    "test_optimise.py",
    "test_link_grbl_buffer.py",
    "test_swimmer.py",
    "test_outputs.py",
    "test_values_between_stages.py",
    "test_link_octoprint.py",
    "test_solve_layers.py",
    "test_interrupt.py",
    "test_verify.py",
    "test_optimise_dask.py",
    "test_notebook.py",
)
"""The test files that take longest (``pytest --durations=0`` summed per file, stop 49:
125 s for test_examples.py, 65-73 s for test_run_layers.py, test_run.py,
test_compare_scan.py, test_mechanics_adjoint.py and test_packaging.py, down to about
15 s), longest first. pytest-xdist hands whole files
to its workers in collection order (``--dist loadfile --no-loadscope-reorder``,
pyproject.toml): these start first, so that no long file starts last on one worker while
the other has nothing left to do."""


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The :data:`LONGEST_FIRST` files first, the others after them in their own order."""

    def rank(item: pytest.Item) -> int:
        name = item.path.name
        return LONGEST_FIRST.index(name) if name in LONGEST_FIRST else len(LONGEST_FIRST)

    items.sort(key=rank)
