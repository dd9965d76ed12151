"""Vectorised formatting of many G-code-like lines at once.

A line is a *prefix* (a short fixed text such as ``G1`` or ``;LAYER:``, chosen per row
from a small vocabulary) followed by optional numeric *words* (``X12.5``, ``F2400``) and a
newline. :func:`render` builds every line of a table in one pass over a (rows, chars)
byte matrix: digits come from integer arithmetic and digit look-up tables on whole
columns, and padding is dropped by one mask, so no Python code runs per line. Numbers are
written in fixed point with trailing zeros (and a bare trailing dot) trimmed, no
exponent and no ``-0``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache

import numpy as np

from fabkit.errors import FabkitError

_ZERO = ord("0")
_CHUNK = 1 << 16
"""Rows formatted together: small enough for the canvas to stay in cache."""


@dataclass(frozen=True)
class Word:
    """A numeric word: the text before the number (``" X"``, or ``""``) and its decimals."""

    lead: str
    decimals: int


class _Canvas:
    """A (rows, chars) byte matrix and its keep-mask, filled column block by block."""

    def __init__(self, rows: int, width: int) -> None:
        self.chars = np.zeros((rows, width), dtype=np.uint8)
        self.keep = np.zeros((rows, width), dtype=bool)
        self.col = 0

    def put(self, chars: np.ndarray | int, keep: np.ndarray | bool, width: int) -> None:
        """Write a (rows, width) block (or a broadcastable value) at the current column."""
        block = slice(self.col, self.col + width)
        self.chars[:, block] = chars
        self.keep[:, block] = keep
        self.col += width

    def text(self) -> bytes:
        return np.compress(self.keep.ravel(), self.chars.ravel()).tobytes()


def render(
    prefix_ids: np.ndarray,
    prefixes: Sequence[str],
    values: np.ndarray,
    present: np.ndarray,
    words: Sequence[Word],
) -> bytes:
    """The ASCII text of every row, each ending in a newline.

    ``prefix_ids`` (n,) int indexes ``prefixes``; ``values`` (n, w) float and ``present``
    (n, w) bool give the words of each row in the order of ``words`` (a word is written
    only where present, and its value must then be finite).
    """
    prefix_ids = np.asarray(prefix_ids)
    table, used = _prefix_table(tuple(prefixes))
    chunks = [
        _render_chunk(
            prefix_ids[a : a + _CHUNK],
            table,
            used,
            values[a : a + _CHUNK],
            present[a : a + _CHUNK],
            words,
        )
        for a in range(0, len(prefix_ids), _CHUNK)
    ]
    return b"".join(chunks)


def _render_chunk(
    prefix_ids: np.ndarray,
    table: np.ndarray,
    used: np.ndarray,
    values: np.ndarray,
    present: np.ndarray,
    words: Sequence[Word],
) -> bytes:
    shown = [k for k in range(len(words)) if present[:, k].any()]
    numbers = [_Number.of(values[:, k], present[:, k], words[k]) for k in shown]
    width = table.shape[1] + 1 + sum(number.width for number in numbers)
    canvas = _Canvas(len(prefix_ids), width)
    canvas.put(_rows(table, prefix_ids), _rows(used, prefix_ids), table.shape[1])
    for number in numbers:
        number.put(canvas)
    canvas.put(ord("\n"), True, 1)
    return canvas.text()


def _prefix_table(prefixes: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    encoded = [p.encode("ascii") for p in prefixes]
    width = max(1, *(len(p) for p in encoded))
    table = np.zeros((len(encoded), width), dtype=np.uint8)
    used = np.zeros((len(encoded), width), dtype=bool)
    for i, text in enumerate(encoded):
        table[i, : len(text)] = np.frombuffer(text, dtype=np.uint8)
        used[i, : len(text)] = True
    return table, used


@dataclass(frozen=True)
class _Number:
    """One word column split for the digit tables: 3-digit groups of the integer part
    (most significant first) and the fraction as an integer, both as table rows where
    the row past the end stands for "not written"."""

    word: Word
    present: np.ndarray
    negative: np.ndarray
    groups: list[np.ndarray]
    frac: np.ndarray

    @classmethod
    def of(cls, values: np.ndarray, present: np.ndarray, word: Word) -> _Number:
        shown = np.where(present, values, 0.0)
        if not np.isfinite(shown).all():
            raise FabkitError(f"a{word.lead} word has a non-finite value")
        scale = 10**word.decimals
        scaled = np.rint(np.abs(shown) * scale).astype(np.int64)
        whole, frac = np.divmod(scaled, scale)
        count = max(1, -(-len(str(int(whole.max()))) // 3))
        groups = [whole // 1000**g % 1000 for g in range(count - 1, -1, -1)]
        absent = ~present
        started = np.zeros(len(values), dtype=bool)
        for g, group in enumerate(groups):
            last = g == count - 1
            # table rows: 0..999 significant digits only, 1000..1999 all three digits
            group += np.where(started, 1000, 0)
            if not last:
                started |= group > 0
            group[absent] = _ABSENT_GROUP
        frac[absent] = scale
        return cls(word, present, present & (shown < 0) & (scaled > 0), groups, frac)

    @property
    def width(self) -> int:
        fraction = self.word.decimals + 1 if self.word.decimals else 0
        return len(self.word.lead) + 1 + 3 * len(self.groups) + fraction

    def put(self, canvas: _Canvas) -> None:
        lead = np.frombuffer(self.word.lead.encode("ascii"), dtype=np.uint8)
        canvas.put(lead, self.present[:, None], len(lead))
        canvas.put(ord("-"), self.negative[:, None], 1)
        for g, group in enumerate(self.groups):
            digits, keep = _group_tables(g == len(self.groups) - 1)
            canvas.put(_rows(digits, group), _rows(keep, group), 3)
        if self.word.decimals:
            digits, keep = _fraction_tables(self.word.decimals)
            kept = _rows(keep, self.frac)
            canvas.put(ord("."), kept[:, :1], 1)
            canvas.put(_rows(digits, self.frac), kept, self.word.decimals)


_ABSENT_GROUP = 2000


def _rows(table: np.ndarray, index: np.ndarray) -> np.ndarray:
    """``table[index]`` (np.take is several times faster than fancy indexing here)."""
    return np.take(table, index, axis=0)


@cache
def _group_tables(last: bool) -> tuple[np.ndarray, np.ndarray]:
    """Rows 0..999: the three digits of the value and which are significant (no leading
    zeros; the units digit of the last group always); rows 1000..1999: the same digits,
    all kept (a more significant group was non-zero); row 2000: nothing kept."""
    values = np.arange(1000)
    powers = np.array([100, 10, 1])
    digits = (values[:, None] // powers % 10 + _ZERO).astype(np.uint8)
    significant = values[:, None] >= powers
    if last:
        significant[:, 2] = True
    keep = np.vstack([significant, np.ones((1000, 3), bool), np.zeros((1, 3), bool)])
    return np.vstack([digits, digits, digits[:1]]), keep


@cache
def _fraction_tables(decimals: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows 0..10**decimals - 1: the fraction's digits and which survive trailing-zero
    trimming (column 0 doubles as "write the dot"); the last row: nothing kept."""
    values = np.arange(10**decimals)
    powers = 10 ** np.arange(decimals - 1, -1, -1)
    digits = (values[:, None] // powers % 10 + _ZERO).astype(np.uint8)
    keep = values[:, None] % (powers * 10) > 0
    return np.vstack([digits, digits[:1]]), np.vstack([keep, np.zeros((1, decimals), bool)])
