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
    n = len(prefix_ids)
    numbers = [_digits(values[:, k], present[:, k], word) for k, word in enumerate(words)]
    width = (
        table.shape[1]
        + 1
        + sum(
            len(w.lead) + 1 + 3 * len(num[0]) + (w.decimals + 1 if w.decimals else 0)
            for w, num in zip(words, numbers, strict=True)
        )
    )
    canvas = _Canvas(n, width)
    canvas.put(table[prefix_ids], used[prefix_ids], table.shape[1])
    for word, (int_part, frac, is_present, negative) in zip(words, numbers, strict=True):
        _put_number(canvas, word, int_part, frac, is_present, negative)
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


def _digits(
    values: np.ndarray, present: np.ndarray, word: Word
) -> tuple[list[np.ndarray], np.ndarray, np.ndarray, np.ndarray]:
    """Split a column into 3-digit groups of the integer part (most significant first),
    the fraction as an integer of ``decimals`` digits, and the sign."""
    shown = np.where(present, values, 0.0)
    if not np.isfinite(shown).all():
        raise FabkitError(f"a{word.lead} word has a non-finite value")
    scale = 10**word.decimals
    scaled = np.rint(np.abs(shown) * scale).astype(np.int64)
    whole, frac = np.divmod(scaled, scale)
    groups = max(1, -(-len(str(int(whole.max()))) // 3))
    int_part = [whole // 1000**g % 1000 for g in range(groups - 1, -1, -1)]
    return int_part, frac, present, present & (shown < 0) & (scaled > 0)


def _put_number(
    canvas: _Canvas,
    word: Word,
    int_part: list[np.ndarray],
    frac: np.ndarray,
    present: np.ndarray,
    negative: np.ndarray,
) -> None:
    lead = np.frombuffer(word.lead.encode("ascii"), dtype=np.uint8)
    column = present[:, None]
    canvas.put(lead, column, len(lead))
    canvas.put(ord("-"), negative[:, None], 1)
    started = np.zeros(len(present), dtype=bool)
    for g, group in enumerate(int_part):
        digits, significant = _group_tables()
        last = g == len(int_part) - 1
        keep = started[:, None] | significant[group]
        if last:
            keep[:, 2] = True
        canvas.put(digits[group], column & keep, 3)
        started |= group > 0
    if word.decimals:
        has_frac = present & (frac > 0)
        canvas.put(ord("."), has_frac[:, None], 1)
        digits, kept = _fraction_tables(word.decimals)
        canvas.put(digits[frac], has_frac[:, None] & kept[frac], word.decimals)


@cache
def _group_tables() -> tuple[np.ndarray, np.ndarray]:
    """For 0..999: its three digit characters, and which are significant (no leading 0)."""
    values = np.arange(1000)
    powers = np.array([100, 10, 1])
    digits = (values[:, None] // powers % 10 + _ZERO).astype(np.uint8)
    return digits, values[:, None] >= powers


@cache
def _fraction_tables(decimals: int) -> tuple[np.ndarray, np.ndarray]:
    """For 0..10**decimals - 1: its digit characters, and which survive trailing-0 trimming."""
    values = np.arange(10**decimals)
    powers = 10 ** np.arange(decimals - 1, -1, -1)
    digits = (values[:, None] // powers % 10 + _ZERO).astype(np.uint8)
    return digits, values[:, None] % (powers * 10) > 0
