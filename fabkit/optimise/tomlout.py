"""Writing a spec table as TOML (Python reads TOML, it does not write it).

Enough for what a spec holds: tables of strings, numbers, booleans, lists and inline
tables, ``[[surfaces]]``, and ``[optimise.parameters]`` (a table of inline tables).
Strings are written as JSON strings, which are TOML basic strings; numbers by ``repr``
(finite only: a spec never holds others). ``tests/test_optimise.py`` reads the text back.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping
from typing import Any

from fabkit.errors import FabkitError

_BARE = re.compile(r"[A-Za-z0-9_-]+")


def dumps(table: Mapping[str, Any], header: str = "") -> str:
    """TOML text of a table of tables (a spec), after the comment lines of ``header``."""
    lines = [f"# {line}" if line else "#" for line in header.splitlines()]
    for key, value in table.items():
        if isinstance(value, list) and value and all(isinstance(v, Mapping) for v in value):
            for item in value:
                lines += ["", f"[[{_key(key)}]]", *_table(item, key)]
        elif isinstance(value, Mapping):
            lines += ["", f"[{_key(key)}]", *_table(value, key)]
        else:
            raise FabkitError(f"spec: top-level key '{key}' is not a table")
    return "\n".join(lines).lstrip("\n") + "\n"


def _table(table: Mapping[str, Any], name: str) -> list[str]:
    """The lines of one table: its values, then its tables of tables as sub-tables."""
    lines, subtables = [], []
    for key, value in table.items():
        nested = isinstance(value, Mapping) and value
        if nested and all(isinstance(v, Mapping) for v in value.values()):
            subtables.append((key, value))
        else:
            lines.append(f"{_key(key)} = {_value(value)}")
    for key, value in subtables:
        lines += ["", f"[{_key(name)}.{_key(key)}]"]
        lines += [f"{_key(k)} = {_value(v)}" for k, v in value.items()]
    return lines


def _key(key: str) -> str:
    return key if _BARE.fullmatch(key) else json.dumps(key)


def _value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise FabkitError(f"cannot write the number {value} in a spec")
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(_value(v) for v in value) + "]"
    if isinstance(value, Mapping):
        return "{ " + ", ".join(f"{_key(k)} = {_value(v)}" for k, v in value.items()) + " }"
    raise FabkitError(f"cannot write {type(value).__name__} in a spec")
