"""Reading a samples CSV for ``fabkit calibrate`` (docs/calibrate.md).

One header row naming the columns, then one row per measured sample: a column per
feature and per stimulus (named as in the spec), ``lambda1`` and ``lambda2`` (the
measured stretches along and across the director) and optionally ``lambda1_sd``,
``lambda2_sd`` (their spread, standard deviations). Blank lines and lines starting with
``#`` are skipped. Every mistake is one line naming the file, the row (1-based, as a
spreadsheet numbers it) and the column.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fabkit.errors import FabkitError
from fabkit.files.readfile import decode_utf8, read_limited
from fabkit.limits import CSV_BYTES

STRETCHES = ("lambda1", "lambda2")
SPREADS = ("lambda1_sd", "lambda2_sd")


@dataclass(frozen=True)
class Samples:
    """Measured samples: ``points`` (n, d) feature then stimulus values, ``stretches``
    (n, 2) lambda1 and lambda2, ``spreads`` (n, 2) their standard deviations (NaN where
    not given)."""

    features: tuple[str, ...]
    stimuli: tuple[str, ...]
    points: np.ndarray
    stretches: np.ndarray
    spreads: np.ndarray


def read_samples(path: str | Path, features: tuple[str, ...], stimuli: tuple[str, ...]) -> Samples:
    """The samples of the CSV file ``path`` whose columns are ``features``, ``stimuli``,
    lambda1, lambda2 and optionally lambda1_sd, lambda2_sd, in any order."""
    shown = str(path)
    text = decode_utf8(read_limited(path, "samples CSV", CSV_BYTES), "samples CSV", path)
    text = text.removeprefix("\ufeff")  # the byte order mark a spreadsheet may write
    rows = [
        (number, row)
        for number, row in enumerate(csv.reader(io.StringIO(text)), start=1)
        if row and any(cell.strip() for cell in row) and not row[0].lstrip().startswith("#")
    ]
    if not rows:
        raise FabkitError(f"{shown}: empty (expected a header row naming the columns)")
    (_, header), body = rows[0], rows[1:]
    columns = _columns([cell.strip() for cell in header], features, stimuli, shown)
    if not body:
        raise FabkitError(f"{shown}: no samples below the header")
    values = np.array([_row(number, row, header, shown) for number, row in body])
    index = {name: i for i, name in enumerate(columns)}
    points = values[:, [index[n] for n in features + stimuli]]
    stretches = values[:, [index[n] for n in STRETCHES]]
    spreads = np.stack(
        [values[:, index[n]] if n in index else np.full(len(values), np.nan) for n in SPREADS],
        axis=1,
    )
    _check_positive(stretches, spreads, [number for number, _ in body], shown)
    return Samples(features, stimuli, points, stretches, spreads)


def _columns(
    header: list[str], features: tuple[str, ...], stimuli: tuple[str, ...], shown: str
) -> list[str]:
    """The header's column names, checked: each once, every needed one there, no other."""
    needed = features + stimuli + STRETCHES
    allowed = set(needed) | set(SPREADS)
    for name in header:
        if header.count(name) > 1:
            raise FabkitError(f"{shown}: column '{name}' appears twice in the header")
        if name not in allowed:
            raise FabkitError(
                f"{shown}: unknown column '{name}' (expected {', '.join(needed)} and "
                f"optionally {', '.join(SPREADS)})"
            )
    missing = [name for name in needed if name not in header]
    if missing:
        raise FabkitError(
            f"{shown}: no column '{missing[0]}' (expected {', '.join(needed)} and "
            f"optionally {', '.join(SPREADS)})"
        )
    return header


def _row(number: int, row: list[str], header: list[str], shown: str) -> list[float]:
    if len(row) != len(header):
        raise FabkitError(
            f"{shown}: row {number}: {len(row)} values for {len(header)} columns "
            f"({', '.join(header)})"
        )
    values = []
    for name, cell in zip(header, row, strict=True):
        cell = cell.strip()
        if not cell:
            raise FabkitError(f"{shown}: row {number}, column {name}: empty")
        try:
            value = float(cell)
        except ValueError:
            raise FabkitError(
                f"{shown}: row {number}, column {name}: not a number: {cell[:40]!r}"
            ) from None
        if not math.isfinite(value) or abs(value) > 1e6:
            raise FabkitError(
                f"{shown}: row {number}, column {name}: expected a finite number of at most "
                f"1e6 in size, got {cell[:40]!r}"
            )
        values.append(value)
    return values


def _check_positive(
    stretches: np.ndarray, spreads: np.ndarray, numbers: list[int], shown: str
) -> None:
    """A stretch must be positive, a spread positive where given."""
    for what, table in (("a positive stretch", stretches), ("a positive spread", spreads)):
        bad = np.argwhere(table <= 0)
        if bad.size:
            row, column = bad[0]
            name = (STRETCHES if table is stretches else SPREADS)[column]
            raise FabkitError(
                f"{shown}: row {numbers[row]}, column {name}: expected {what}, "
                f"got {table[row, column]:g}"
            )
