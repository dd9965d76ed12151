"""Reading a user's TOML file (spec, process, baromorph, director, swimmer) with one-line errors."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

from fabkit.errors import FabkitError


def read_toml(path: str | Path, what: str) -> dict[str, Any]:
    """The tables of the TOML file ``path``; ``what`` names the file in errors ("spec").

    A missing, unreadable (not UTF-8, a directory) or malformed file is a FabkitError whose
    one-line message names the file and the problem.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise FabkitError(f"{what} file '{path}' does not exist") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise FabkitError(f"cannot read {what} file '{path}': {exc}") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise FabkitError(f"{path}: not valid TOML: {exc}") from None
