"""Files that ship with fabkit: the machine profiles and the examples.

Both are edited in the repository's top-level folders (``machines/``, ``examples/``). The
build maps them into the package as ``fabkit/profiles`` and ``fabkit/examples``
(pyproject.toml), so a wheel or a plain ``pip install .`` carries them; an editable
install, or a source checkout, reads the top-level folders themselves.
"""

from __future__ import annotations

from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent.parent


def _shipped(installed: str, checkout: str) -> Path:
    inside = _PACKAGE / installed
    return inside if inside.is_dir() else _PACKAGE.parent / checkout


PROFILES_DIR = _shipped("profiles", "machines")
"""The shipped machine profiles (``*.toml``)."""
EXAMPLES_DIR = _shipped("examples", "examples")
"""The shipped examples: specs, director files, data."""


def user_or_example(path: str | Path) -> Path:
    """``path`` itself; or, when it does not exist and reads ``examples/...``, the shipped
    example of that name, so that ``fabkit run examples/two_shapes.toml`` works from any
    folder after ``pip install``. A file of the user's always wins."""
    path = Path(path)
    if path.exists() or path.is_absolute() or not path.parts or path.parts[0] != "examples":
        return path
    shipped = EXAMPLES_DIR.joinpath(*path.parts[1:])
    return shipped if shipped.is_file() else path
