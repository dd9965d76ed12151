"""The package's imports run one way (docs/architecture.md, "Rules of the house").

Every ``import`` of a fabkit module in fabkit/ (at the top, inside functions and under
``TYPE_CHECKING`` alike) is an arrow between two *rooms*: a sub-package (``fabkit/link/``,
``fabkit/verify/`` ...) or a top-level module (``fabkit/machines.py``). The rooms' arrows
form no circle, so every room stands above all it imports and nothing runs back up; and
inside every sub-package the modules' arrows form no circle either.
"""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "fabkit"


def _module(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path) -> set[str]:
    """The fabkit modules ``path`` imports (a name imported from a package counts as its
    module when there is one)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names if alias.name.startswith("fabkit")}
        elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("fabkit"):
            for alias in node.names:  # from fabkit import commands: the module itself
                candidate = f"{node.module}.{alias.name}"
                found.add(candidate if _path(candidate) is not None else node.module)
    return found


def _path(module: str) -> Path | None:
    base = ROOT.joinpath(*module.split("."))
    for path in (base.with_suffix(".py"), base / "__init__.py"):
        if path.is_file():
            return path
    return None


def _room(module: str) -> str:
    """``fabkit.link.host.marlin`` -> ``fabkit.link``; ``fabkit.machines`` -> itself."""
    parts = module.split(".")
    if len(parts) > 2 or (len(parts) == 2 and (PACKAGE / parts[1]).is_dir()):
        return ".".join(parts[:2])
    return module


def _graph(room_of) -> dict[str, set[str]]:
    arrows: dict[str, set[str]] = defaultdict(set)
    for path in PACKAGE.rglob("*.py"):
        source = _module(path)
        for target in _imports(path):
            a, b = room_of(source), room_of(target)
            if a is not None and b is not None and a != b:
                arrows[a].add(b)
    return arrows


def _circle(arrows: dict[str, set[str]]) -> list[str] | None:
    """A circle of arrows, or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(arrows.get(node, ())):
            if state.get(nxt) == 1:
                return stack[stack.index(nxt) :] + [nxt]
            if nxt not in state and (found := visit(nxt)):
                return found
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(arrows):
        if node not in state and (found := visit(node)):
            return found
    return None


def test_the_rooms_import_one_way():
    arrows = _graph(lambda module: None if module == "fabkit" else _room(module))
    assert len(arrows) > 20  # the graph was read
    assert _circle(arrows) is None, " -> ".join(_circle(arrows))


def test_no_module_imports_the_package_face():
    """``fabkit/__init__`` is the public API, above every stage: no module of fabkit
    imports it (``fabkit.version`` holds the version the writers print)."""
    for path in PACKAGE.rglob("*.py"):
        if path.name != "__init__.py" or path.parent != PACKAGE:
            assert "fabkit" not in _imports(path), path


def test_the_modules_of_every_package_import_one_way():
    arrows = _graph(lambda module: module)
    assert _circle(arrows) is None, " -> ".join(_circle(arrows))
