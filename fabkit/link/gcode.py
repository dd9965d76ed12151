"""G-code as the link sees it: commands with their file line numbers, words, framing.

A *command* is one non-empty file line with its comments (``; ...`` and ``( ... )``) and
surrounding blanks removed; the text is otherwise sent exactly as written, so an
emulator trace can be compared with the file command by command.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from fabkit.errors import FabkitError

_PAREN_COMMENT = re.compile(r"\([^)]*\)")
_WORD = re.compile(r"([A-Za-z])\s*([-+]?(?:\d+\.?\d*|\.\d+))")


@dataclass(frozen=True)
class Command:
    """One command of a job: its 1-based line in the file and its text (comments removed)."""

    file_line: int
    text: str


def strip_comment(line: str) -> str:
    """``line`` without ``;`` and ``( )`` comments and surrounding blanks."""
    return _PAREN_COMMENT.sub("", line.split(";", 1)[0]).strip()


def commands_from_lines(lines: Iterable[str], first_line: int = 1) -> list[Command]:
    """The commands of ``lines`` (blank and comment-only lines skipped)."""
    out = []
    for number, line in enumerate(lines, start=first_line):
        text = strip_comment(line)
        if text:
            out.append(Command(number, text))
    return out


def read_job(path: str | Path) -> list[Command]:
    """Read a G-code file into commands; a missing or non-ASCII file is a FabkitError."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise FabkitError(f"cannot read G-code file {path}: {exc.strerror}") from None
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise FabkitError(f"{path}:{line}: non-ASCII byte in G-code") from None
    return commands_from_lines(text.splitlines())


def words(text: str) -> dict[str, float]:
    """The letter/number words of a command, letters upper-cased (``G1 X10`` -> G, X)."""
    return {letter.upper(): float(value) for letter, value in _WORD.findall(text)}


def code_of(text: str) -> str:
    """The command word, upper-cased: ``G1``, ``M104``, ``G38.2``, ``$H``, ``T0``.

    A line that starts with an axis word (GRBL's modal motion) gives that letter;
    an extended (Klipper-style) command gives its name.
    """
    match = re.match(r"\s*([A-Za-z$])\s*([-+]?\d*\.?\d*)", text)
    if match is None:
        return text.split()[0].upper() if text.split() else ""
    letter, number = match.groups()
    if letter == "$":
        return "$" + text.strip()[1:2].upper()
    if letter.upper() in "GMT" and number:
        value = float(number)
        return f"{letter.upper()}{int(value)}" if value.is_integer() else f"{letter.upper()}{value}"
    head = text.split()[0].upper()
    return head if "_" in head or len(head) > 1 and head.isalpha() else letter.upper()


def marlin_checksum(payload: bytes) -> int:
    """XOR of all bytes of ``payload`` (Marlin, RepRap and Klipper line checksum)."""
    value = 0
    for byte in payload:
        value ^= byte
    return value


def frame_marlin(number: int, text: str) -> bytes:
    """``N<number> <text>*<checksum>\\n`` as bytes."""
    payload = f"N{number} {text}".encode("ascii")
    return payload + b"*%d\n" % marlin_checksum(payload)
