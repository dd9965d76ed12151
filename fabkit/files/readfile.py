"""Reading a user's file with bounds: its size before its bytes, its encoding, its nesting.

Every reader of a text file (TOML, JSON, CSV, G-code templates) goes through
:func:`read_limited`, so that a 10 GB file, a FIFO or a device is refused before a byte is
read, and through :func:`decode_utf8` / :func:`parse_json`, so that bad bytes and deep
nesting are one-line errors rather than tracebacks or a blown stack.
"""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path
from typing import Any

from fabkit.errors import FabkitError
from fabkit.limits import JSON_BYTES, NESTING_DEPTH


def size_text(count: float) -> str:
    """A byte count as people read it: ``512 B``, ``4.0 MB``, ``10.0 GB`` (powers of 1024)."""
    units, power = ("B", "KB", "MB", "GB", "TB", "PB"), 0
    while count >= 1024 and power < len(units) - 1:
        count, power = count / 1024, power + 1
    return f"{count:.0f} B" if power == 0 else f"{count:.1f} {units[power]}"


def check_size(path: str | os.PathLike[str], what: str, limit: int) -> int:
    """The size in bytes of the regular file ``path``; refuses a missing file, anything but a
    regular file (a folder, FIFO or device) and a file over ``limit`` bytes.

    ``what`` names the file in errors, like ``"spec file"``.
    """
    path = Path(path)
    try:
        status = path.stat()
    except FileNotFoundError:
        raise FabkitError(f"{what} '{path}' does not exist") from None
    except OSError as exc:
        raise FabkitError(f"cannot read {what} '{path}': {exc.strerror}") from None
    if not stat.S_ISREG(status.st_mode):
        kind = "a folder" if stat.S_ISDIR(status.st_mode) else "not a regular file"
        raise FabkitError(f"cannot read {what} '{path}': it is {kind}")
    if status.st_size > limit:
        raise FabkitError(
            f"{what} '{path}' is {size_text(status.st_size)}, more than the limit of "
            f"{size_text(limit)}"
        )
    return status.st_size


def read_limited(path: str | os.PathLike[str], what: str, limit: int) -> bytes:
    """The bytes of the regular file ``path``, refused (see :func:`check_size`) before they
    are read when there are more than ``limit``; a file that grows meanwhile is cut off and
    refused too."""
    check_size(path, what, limit)
    try:
        with open(path, "rb") as handle:
            data = handle.read(limit + 1)
    except OSError as exc:
        raise FabkitError(f"cannot read {what} '{path}': {exc.strerror}") from None
    if len(data) > limit:
        raise FabkitError(f"{what} '{path}' is more than the limit of {size_text(limit)}")
    return data


def decode_utf8(data: bytes, what: str, path: str | os.PathLike[str]) -> str:
    """``data`` as UTF-8 text; else a one-line error naming the first bad byte's offset."""
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise FabkitError(
            f"cannot read {what} '{path}': not UTF-8 text (byte 0x{data[exc.start]:02x} at "
            f"offset {exc.start}); save it as UTF-8"
        ) from None


def nesting_depth(value: Any, limit: int = NESTING_DEPTH) -> int:
    """How deep dicts and lists nest in ``value`` (a scalar: 0, ``{}``: 1), counted without
    recursion; stops counting once past ``limit``."""
    deepest, stack = 0, [(value, 0)]
    while stack and deepest <= limit:
        item, depth = stack.pop()
        if isinstance(item, dict):
            children = item.values()
        elif isinstance(item, list | tuple):
            children = item
        else:
            continue
        deepest = max(deepest, depth + 1)
        stack.extend((child, depth + 1) for child in children)
    return deepest


def check_depth(value: Any, where: str) -> Any:
    """``value`` if it nests at most NESTING_DEPTH deep; else a one-line error."""
    if nesting_depth(value) > NESTING_DEPTH:
        raise FabkitError(f"{where}: nested deeper than {NESTING_DEPTH} levels")
    return value


def parse_json(text: str, where: str) -> Any:
    """The JSON value of ``text``; malformed or too deeply nested text is a one-line error
    starting with ``where`` (JSON's own parser recurses, so depth is bounded twice)."""
    try:
        value = json.loads(text)
    except RecursionError:
        raise FabkitError(f"{where}: nested deeper than {NESTING_DEPTH} levels") from None
    except ValueError as exc:
        raise FabkitError(f"{where}: not valid JSON ({exc})") from None
    return check_depth(value, where)


def read_json(path: str | os.PathLike[str], what: str, limit: int = JSON_BYTES) -> Any:
    """The JSON value of the file ``path`` (at most ``limit`` bytes, UTF-8)."""
    text = decode_utf8(read_limited(path, what, limit), what, path)
    return parse_json(text, f"{what} '{path}'")
