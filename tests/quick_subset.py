"""The quick subset (``pytest -m "not slow"``): its time, and every fabkit module in it.

Run ``python -m tests.quick_subset`` from the repository root. It runs the quick subset
with this module as a pytest plugin, prints its wall time against the 60 s budget and
lists every module of the ``fabkit`` package that no selected test imports; it exits 1 if
there is one (or a test fails), else 0.

A module counts as imported by the quick subset when a selected test imports it while it
runs (a new entry in ``sys.modules`` during the test), or when it is in the import
closure of a test file that has a selected test: the fabkit modules the file names in an
``import`` statement or a ``runpy.run_module`` call (anywhere in the file), and
transitively every fabkit module those import at their top level (read from the source,
so the order pytest imports files in does not matter). Modules imported only by the
files of slow tests do not count.
"""

from __future__ import annotations

import ast
import functools
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "fabkit"
BUDGET_S = 60.0
REPORT = "quick subset: "


@functools.cache
def fabkit_modules(folder: Path = PACKAGE) -> frozenset[str]:
    """Every module of the package (``fabkit.x.y``), packages' ``__init__`` as ``fabkit.x``
    (or of another folder of the repository, such as ``tests``)."""
    names = set()
    for path in folder.rglob("*.py"):
        parts = path.relative_to(ROOT).with_suffix("").parts
        names.add(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    return frozenset(names)


def _module_path(name: str) -> Path | None:
    base = ROOT.joinpath(*name.split("."))
    for path in (base.with_suffix(".py"), base / "__init__.py"):
        if path.exists():
            return path
    return None


@functools.cache
def _imports(path: Path, top_level_only: bool) -> frozenset[str]:
    """fabkit modules named by the import statements of ``path`` (with their parents, which
    Python imports first); only those run at import time when ``top_level_only``."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    nodes = tree.body if top_level_only else list(ast.walk(tree))
    found: set[str] = set()
    for node in nodes:
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
            found.update(f"{node.module}.{alias.name}" for alias in node.names)
        elif _runs_module(node):  # runpy.run_module("fabkit") runs fabkit/__main__.py
            found.add(f"{node.args[0].value}.__main__")
    known = fabkit_modules() | fabkit_modules(ROOT / "tests")  # test helpers import fabkit
    out = set()
    for name in found:
        parts = name.split(".")
        out.update(".".join(parts[:k]) for k in range(1, len(parts) + 1))
    return frozenset(out & known)


def _runs_module(node: ast.AST) -> bool:
    """``node`` is a call ``runpy.run_module("name", ...)``."""
    return (
        isinstance(node, ast.Call)
        and isinstance(node.func, ast.Attribute)
        and node.func.attr == "run_module"
        and bool(node.args)
        and isinstance(node.args[0], ast.Constant)
        and isinstance(node.args[0].value, str)
    )


def closure(path: Path) -> set[str]:
    """The fabkit modules importing the test file ``path`` brings in, and their top-level
    imports, transitively."""
    todo, seen = list(_imports(path, top_level_only=False)), set()
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        source = _module_path(name)
        if source is not None:
            todo.extend(_imports(source, top_level_only=True) - seen)
    return seen


class Plugin:
    """Collects the fabkit modules each selected test imports, and the selected files.

    Under pytest-xdist each worker collects its own and hands them to the controller
    (``workeroutput``), which reports for them all."""

    def __init__(self, config) -> None:
        self.config = config
        self.files: set[Path] = set()
        self.imported: set[str] = set()

    @property
    def worker(self) -> bool:
        return hasattr(self.config, "workerinput")

    def pytest_collection_modifyitems(self, items) -> None:  # after -m deselected
        self.files = {Path(str(item.fspath)) for item in items}

    @pytest.hookimpl(wrapper=True)
    def pytest_runtest_call(self, item):
        before = set(sys.modules)
        try:
            return (yield)
        finally:
            self.imported |= {name for name in sys.modules if name.startswith("fabkit")} - before

    @pytest.hookimpl(optionalhook=True)
    def pytest_testnodedown(self, node, error) -> None:  # the controller, a worker's data
        output = getattr(node, "workeroutput", {})
        self.files |= {Path(name) for name in output.get("fabkit_files", ())}
        self.imported |= set(output.get("fabkit_imported", ()))

    def pytest_sessionfinish(self, session) -> None:
        if self.worker:
            self.config.workeroutput["fabkit_files"] = sorted(map(str, self.files))
            self.config.workeroutput["fabkit_imported"] = sorted(self.imported)
            return
        covered = set(self.imported)
        for path in self.files:
            covered |= closure(path)
        missing = sorted(fabkit_modules() - covered)
        print(f"\n{REPORT}{len(self.files)} test files; fabkit modules not imported: "
              f"{', '.join(missing) or 'none'}")  # fmt: skip
        if missing and session.exitstatus == 0:
            session.exitstatus = 1


def pytest_configure(config) -> None:
    config.pluginmanager.register(Plugin(config), "fabkit-quick-subset")


def main() -> int:
    """Run the quick subset with the plugin; print its time; exit as it did."""
    started = time.perf_counter()
    command = [sys.executable, "-m", "pytest", "-m", "not slow", "-q", "-p", "no:cacheprovider"]
    code = subprocess.call([*command, "-p", "tests.quick_subset"], cwd=ROOT)
    seconds = time.perf_counter() - started
    print(f"{REPORT}{seconds:.1f} s wall (budget {BUDGET_S:g} s)")
    return code


if __name__ == "__main__":
    sys.exit(main())
