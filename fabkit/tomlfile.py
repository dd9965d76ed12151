"""Reading a user's TOML file (spec, process, machine, baromorph, director, swimmer) with
one-line errors, bounded in size (TEXT_BYTES) and in nesting depth (NESTING_DEPTH), and
validating its tables: :func:`check_keys` (no unknown key) and :func:`number` (a finite
number), the checks every reader of a user's table uses.

Python's TOML parser recurses once per nested array or inline table and slows down on
long dotted keys, so :func:`scan_depth` measures both in one cheap pass over the raw
text before it is parsed; the parsed tables are measured again exactly.
"""

from __future__ import annotations

import re
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from fabkit.errors import FabkitError
from fabkit.limits import NESTING_DEPTH, TEXT_BYTES
from fabkit.readfile import check_depth, decode_utf8, read_limited

_STRINGS_AND_COMMENTS = re.compile(
    # Every alternative matches once it has started (an unterminated string runs to the
    # end of its line or of the text), so the pattern never retries: linear time.
    rb'"""(?:[^"\\]|\\.?|"(?!""))*(?:"""|\Z)'  # multi-line basic string
    rb"|'''.*?(?:'''|\Z)"  # multi-line literal string
    rb'|"(?:[^"\\\n]|\\[^\n]?)*(?:"|$)'  # basic string
    rb"|'[^'\n]*(?:'|$)"  # literal string
    rb"|#[^\n]*",  # comment
    re.S | re.M,
)
_OPEN, _CLOSE = np.frombuffer(b"[{", np.uint8), np.frombuffer(b"]}", np.uint8)
_SEPARATORS = np.frombuffer(b"[]{},=\n", np.uint8)


def read_toml(path: str | Path, what: str, shown: str | None = None) -> dict[str, Any]:
    """The tables of the TOML file ``path``; ``what`` names the file in errors ("spec").

    A missing, unreadable (not UTF-8, a folder), too large, too deeply nested or malformed
    file is a FabkitError whose one-line message names the file (as ``shown``, default
    ``path``) and the problem.
    """
    path = Path(path)
    shown = str(path) if shown is None else shown
    data = read_limited(path, f"{what} file", TEXT_BYTES)
    text = decode_utf8(data, f"{what} file", shown)
    if scan_depth(data) > NESTING_DEPTH:
        raise FabkitError(f"{shown}: nested deeper than {NESTING_DEPTH} levels")
    try:
        table = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise FabkitError(f"{shown}: not valid TOML: {exc}") from None
    except RecursionError:  # a nesting scan_depth under-counted; the parser's stack ran out
        raise FabkitError(f"{shown}: nested deeper than {NESTING_DEPTH} levels") from None
    return check_depth(table, shown)


def scan_depth(data: bytes) -> int:
    """How deep the TOML text ``data`` nests as its parser sees it: brackets and braces
    open, plus the dots of the dotted key being read, outside strings and comments.

    Linear time, in C: strings and comments are cut out with one pattern, the rest is
    counted with numpy. (Table headers set the context of the lines below them, so the
    parsed tables may nest deeper; :func:`read_toml` measures those too.)
    """
    plain = np.frombuffer(_STRINGS_AND_COMMENTS.sub(b"", data), np.uint8)
    level = np.cumsum(np.isin(plain, _OPEN).astype(np.int64) - np.isin(plain, _CLOSE))
    dots = np.cumsum(plain == ord("."))
    reset = np.flatnonzero(np.isin(plain, _SEPARATORS))
    since = np.zeros(len(plain) + 1, np.int64)
    since[reset + 1] = dots[reset]
    since = np.maximum.accumulate(since)[1:]
    return int(np.max(level + dots - since, initial=0))


def check_keys(table: Mapping[str, Any], allowed: set[str], where: str) -> None:
    """Refuse unknown keys with a message naming them and the allowed ones."""
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise FabkitError(
            f"{where}: unknown key '{unknown[0]}' (allowed: {', '.join(sorted(allowed))})"
        )


def number(value: Any, where: str, positive: bool = False) -> float:
    """A finite float from a spec value, with a one-line error otherwise."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise FabkitError(f"{where}: expected a number, got {value!r}")
    value = float(value)
    if not np.isfinite(value) or (positive and value <= 0):
        raise FabkitError(f"{where}: expected a {'positive ' if positive else ''}finite number")
    return value
