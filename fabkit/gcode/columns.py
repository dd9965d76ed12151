"""Plain moves read a slice of a job at a time into columns, for the fast path of the
pre-flight check and of the duration plan.

A *plain move* is a command in the one text form the Marlin-family reader
(:func:`fabkit.gcode.read.read_marlin`, Klipper's included) reads at once and
unambiguously: ``G0`` or ``G1``, then words each after exactly one blank, an upper-case
letter of ``X Y Z E F`` and a plain decimal number (``[-+]``, digits, at most one ``.``,
no exponent), each letter at most once, the whole command at most ``limit`` characters.
Such a command reads as ``Block(("G1",), {letter: float(number), ...})``; the columns hold
exactly those numbers (each parsed by ``float``). Anything else (comments are already
gone from a command's text) is left to the per-command path.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

LETTERS = "XYZEF"
"""The columns of :attr:`MoveRun.values`, in order."""
_COLUMN = np.full(256, -1, dtype=np.int64)
_COLUMN[np.frombuffer(LETTERS.encode("ascii"), np.uint8)] = np.arange(len(LETTERS))


@dataclass(frozen=True)
class MoveRun:
    """Consecutive plain moves of a job, and other commands the caller named. ``first``:
    the job index of the first; ``g0`` (n,) bool: the command is G0 (else G1, or another);
    ``values`` (n, 5) float64: X, Y, Z, E, F as written (mm, mm/min), NaN where absent;
    ``given`` (n, 5) bool: the letter is there; ``other`` (n,) int8: -1 for a plain move,
    else the caller's number for the command's text (:func:`read_columns`)."""

    first: int
    g0: np.ndarray
    values: np.ndarray
    given: np.ndarray
    other: np.ndarray

    def __len__(self) -> int:
        return len(self.g0)


@dataclass(frozen=True)
class MoveColumns:
    """A slice of a job starting at job index ``first``: ``plain`` (n,) bool, the commands
    that are plain moves or named others, and the columns of :class:`MoveRun` (meaningful
    where plain)."""

    first: int
    plain: np.ndarray
    g0: np.ndarray
    values: np.ndarray
    given: np.ndarray
    other: np.ndarray

    def spans(self) -> Iterator[tuple[int, int, bool]]:
        """``(start, stop, plain)``: the slice cut where ``plain`` changes (slice indices)."""
        cuts = np.flatnonzero(self.plain[1:] != self.plain[:-1]) + 1
        bounds = [0, *cuts.tolist(), len(self.plain)]
        for start, stop in zip(bounds[:-1], bounds[1:], strict=True):
            if stop > start:
                yield start, stop, bool(self.plain[start])

    def run(self, start: int, stop: int) -> MoveRun:
        """The plain moves ``start:stop`` of the slice (all plain)."""
        part = slice(start, stop)
        return MoveRun(
            self.first + start, self.g0[part], self.values[part], self.given[part], self.other[part]
        )


_OTHER, _BLANK, _LETTER, _SIGN, _DIGIT, _DOT, _END = range(7)
_CLASS = np.full(256, _OTHER, dtype=np.int8)
_CLASS[[ord(" "), ord("\n"), ord("-"), ord("+"), ord(".")]] = [_BLANK, _END, _SIGN, _SIGN, _DOT]
_CLASS[np.frombuffer(LETTERS.encode("ascii"), np.uint8)] = _LETTER
_CLASS[ord("0") : ord("9") + 1] = _DIGIT
_FOLLOWS = np.zeros((7, 7), dtype=bool)
"""Which byte class may follow which in a plain move's words (`` X-1.5 Y2``)."""
for _before, _after in [
    (_BLANK, _LETTER), (_LETTER, _SIGN), (_LETTER, _DIGIT), (_LETTER, _DOT), (_SIGN, _DIGIT),
    (_SIGN, _DOT), (_DIGIT, _DIGIT), (_DIGIT, _DOT), (_DIGIT, _BLANK), (_DIGIT, _END),
    (_DOT, _DIGIT), (_DOT, _BLANK), (_DOT, _END),
]:  # fmt: skip
    _FOLLOWS[_before, _after] = True
MAX_DIGITS = 15
"""Most digits in a plain number: below 2**53, so that its digits over 10**(digits after
the point) is one correctly rounded division of two exact numbers: the very number
``float`` reads from the text."""
_POW10 = np.array([10.0**k for k in range(MAX_DIGITS + 1)])
CHUNK_COMMANDS = 65536
"""Commands read into columns at once (bounds the memory of a million-line job)."""
MIN_RUN = 4
"""Fewest consecutive plain commands taken as a run (fewer: the per-command path)."""


def plain_codes(flavour: str) -> str:
    """The G codes whose plain commands a run may hold on firmware ``flavour``: Hyrel
    reads F on a G0 for that move only, so its G0s take the per-command path."""
    return "1" if flavour == "hyrel" else "01"


def job_spans(
    texts: Sequence[str], limit: int, codes: str, others: Mapping[str, int]
) -> Iterator[tuple[int, int, MoveRun | None]]:
    """The job ``texts`` cut into ``(start, stop, run)`` (job indices): a run of at least
    :data:`MIN_RUN` plain commands (:func:`read_columns`), or None where the per-command
    path must read ``texts[start:stop]``; :data:`CHUNK_COMMANDS` at a time."""
    for first in range(0, len(texts), CHUNK_COMMANDS):
        columns = read_columns(texts[first : first + CHUNK_COMMANDS], first, limit, codes, others)
        for start, stop, plain in columns.spans():
            run = columns.run(start, stop) if plain and stop - start >= MIN_RUN else None
            yield first + start, first + stop, run


def read_columns(
    texts: Sequence[str], first: int, limit: int, codes: str, others: Mapping[str, int]
) -> MoveColumns:
    """The plain moves among the commands ``texts`` (job indices from ``first``): G codes
    among ``codes`` (``"01"``), at most ``limit`` characters, read into columns by array
    operations over their joined bytes (no Python loop per command but a look-up of each
    text in ``others``: commands whose text is one of its keys count as plain too, with
    its value, 0-127, in :attr:`MoveRun.other`)."""
    n = len(texts)
    joined = "\n".join(texts) + "\n"
    if not joined.isascii() or joined.count("\n") != n:  # a line break inside a command
        return _none_plain(first, n)
    data = np.frombuffer(joined.encode("ascii"), np.uint8)
    kind = _CLASS.take(data)
    end = kind == _END
    ends = np.flatnonzero(end)
    starts = np.concatenate(([0], ends[:-1] + 1))
    other = _others(texts, data[starts], others)
    line = np.cumsum(end, dtype=np.int32) - end  # each byte's line
    body = ~end  # the bytes after "G0" / "G1"
    body[starts] = False
    body[np.minimum(starts + 1, ends)] = False
    plain = _heads(data, kind, starts, ends, limit, codes)
    pairs = kind[:-1] * np.int8(len(_FOLLOWS)) + kind[1:]
    wrong = np.flatnonzero(body[:-1] & ~_FOLLOWS.ravel().take(pairs))
    plain[line[wrong]] = False
    words = _Words(data, kind, line, body & plain.take(line))
    plain[words.line[~words.readable]] = False
    count = np.bincount(words.line * 5 + words.column, minlength=5 * n).reshape(n, 5)
    plain &= (count <= 1).all(axis=1)  # a letter twice: the reader refuses it
    values = np.full((n, len(LETTERS)), np.nan)
    values[words.line, words.column] = words.values()
    given = (count == 1) & plain[:, None]
    g0 = plain & (data[starts + 1] == ord("0"))
    other[plain] = -1  # a plain move is one, whatever ``others`` say
    return MoveColumns(first, plain | (other >= 0), g0, values, given, other)


def _others(texts: Sequence[str], heads: np.ndarray, others: Mapping[str, int]) -> np.ndarray:
    """(n,) int8: each text's value in ``others``, -1 for none (only texts whose first
    character starts one of its keys are looked up)."""
    other = np.full(len(texts), -1, dtype=np.int8)
    firsts = np.frombuffer("".join({key[:1] for key in others}).encode("ascii"), np.uint8)
    for k in np.flatnonzero(np.isin(heads, firsts)).tolist():
        other[k] = others.get(texts[k], -1)
    return other


def _heads(
    data: np.ndarray, kind: np.ndarray, starts: np.ndarray, ends: np.ndarray, limit: int, codes: str
) -> np.ndarray:
    """(n,) bool: the line is ``G`` and a digit of ``codes`` then a blank or its end, and
    2 to ``limit`` characters long."""
    length = ends - starts
    second = data[np.minimum(starts + 1, ends)]
    third = kind[np.minimum(starts + 2, ends)]
    return (
        (length >= 2)
        & (length <= limit)
        & (data[starts] == ord("G"))
        & np.isin(second, np.frombuffer(codes.encode("ascii"), np.uint8))
        & ((third == _BLANK) | (third == _END))
    )


class _Words:
    """The words (letter and number) of the lines that may be plain moves: ``inside``
    (bytes,) bool, their body bytes. ``line``, ``column`` (words,): each word's line
    and letter (index into :data:`LETTERS`); ``readable``: its number has a digit, at
    most one point and at most :data:`MAX_DIGITS` digits."""

    def __init__(self, data: np.ndarray, kind: np.ndarray, line: np.ndarray, inside: np.ndarray):
        kind = np.where(inside, kind, _OTHER)
        is_letter = kind == _LETTER
        letters = np.flatnonzero(is_letter)
        self.line, self.column = line[letters], _COLUMN[data[letters]]
        word = np.cumsum(is_letter, dtype=np.int32) - 1  # each byte's word
        self.digits = np.flatnonzero(kind == _DIGIT)
        self.digit_word = word[self.digits]
        dots = np.flatnonzero(kind == _DOT)
        n = len(letters)
        self.count = np.bincount(self.digit_word, minlength=n)
        points = np.bincount(word[dots], minlength=n)
        self.readable = (self.count >= 1) & (self.count <= MAX_DIGITS) & (points <= 1)
        self.point = np.full(n, len(data))
        self.point[word[dots]] = dots
        self.negative = data[letters + 1] == ord("-")
        self.data = data

    def values(self) -> np.ndarray:
        """(words,) float64: each readable word's number, exactly as ``float`` reads it
        (garbage for the others): its digits as a whole number (each digit times a power
        of ten, summed: exact below 2**53) over 10**(digits after its point)."""
        last = np.cumsum(self.count) - 1  # each word's last digit (index into digits)
        if not len(self.digits):
            return np.full(len(last), np.nan)
        place = np.clip(last[self.digit_word] - np.arange(len(self.digits)), 0, MAX_DIGITS)
        digit = self.data[self.digits] - float(ord("0"))
        whole = np.bincount(self.digit_word, weights=digit * _POW10[place], minlength=len(last))
        after = self.digits[np.maximum(last, 0)] - self.point  # last digit's place after "."
        value = whole / _POW10[np.clip(after, 0, MAX_DIGITS)]
        return np.where(self.negative, -value, value)


def _none_plain(first: int, n: int) -> MoveColumns:
    shape = (n, len(LETTERS))
    nothing = np.zeros(n, bool)
    return MoveColumns(
        first, nothing, nothing, np.full(shape, np.nan), np.zeros(shape, bool), np.full(n, -1)
    )


def filled(initial: float, given: np.ndarray, new: np.ndarray) -> np.ndarray:
    """(n,) float64: a modal value after each of n commands: ``new`` (one per True of
    ``given``, in order) where ``given``, else the last one before (``initial`` before the
    first; NaN for none)."""
    choices = np.concatenate(([initial], new))
    return choices[np.cumsum(given)]


def accumulated(initial: float, steps: np.ndarray) -> np.ndarray:
    """(m,) float64: ``initial`` plus each prefix of ``steps``, added one at a time in order
    (as a loop of ``x += step`` rounds; NaN stays NaN)."""
    return np.cumsum(np.concatenate(([initial], steps)))[1:]


class Rows:
    """A table of ``width`` float64 columns filled one row at a time (a row of numbers or
    None, for NaN) or many at once, kept as arrays: bounded memory for long jobs (a
    per-command path and a run's columns writing one table in the job's order)."""

    FLUSH = 65536

    def __init__(self, width: int) -> None:
        self.width = width
        self.count = 0
        self.pending: list[Sequence[float | None]] = []
        self.chunks: list[np.ndarray] = []

    def append(self, row: Sequence[float | None]) -> None:
        self.pending.append(tuple(row))
        self.count += 1
        if len(self.pending) >= self.FLUSH:
            self._flush()

    def extend(self, rows: np.ndarray) -> None:
        """(k, width) rows."""
        self._flush()
        self.chunks.append(rows)
        self.count += len(rows)

    def array(self) -> np.ndarray:
        """(count, width) float64."""
        self._flush()
        if not self.chunks:
            return np.zeros((0, self.width))
        return np.concatenate(self.chunks)

    def _flush(self) -> None:
        if self.pending:
            self.chunks.append(np.array(self.pending, dtype=float).reshape(-1, self.width))
            self.pending = []
