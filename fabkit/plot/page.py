"""A run's figures in words: the report page as plain data, and the words it is made of.

A :class:`Page` is sections of sentences, label-value lists and flat tables, every label
in words and every figure with its unit; :mod:`fabkit.plot.page_sections` builds it from
``fabkit run``'s key figures (``report.json``'s data) or ``fabkit plot``'s, and
:mod:`fabkit.plot.html` writes it as HTML. Names a user or a file chose (files, the
machine profile, spec keys) are :class:`Code` (:func:`as_spans`); figures are written with
:func:`number` and :func:`percent`, process parameters' keys in words (:func:`in_words`);
the raw figures stay in ``report.json`` (docs/report.md).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fabkit.calibration import LABELS


@dataclass(frozen=True)
class Code:
    """A name as written in a file or on the command line (a file, a machine, a key)."""

    text: str


@dataclass(frozen=True)
class Link:
    """A link to a file the run wrote (``href`` relative to the page)."""

    text: str
    href: str


Span = str | Code | Link
Text = tuple[Span, ...]


@dataclass(frozen=True)
class Paragraph:
    """Sentences; ``style``: "" (plain), "headline", "formed", "missed" or "notice"."""

    text: Text
    style: str = ""


@dataclass(frozen=True)
class Facts:
    """Label-value rows (the value with its unit)."""

    rows: tuple[tuple[str, Text], ...]


@dataclass(frozen=True)
class Table:
    """A flat table: ``header`` labels and ``rows`` of cells."""

    header: tuple[str, ...]
    rows: tuple[tuple[Text, ...], ...]


@dataclass(frozen=True)
class Figure:
    """A picture (PNG) the run wrote, with its ``caption`` (also its alternative text)."""

    path: Path
    caption: str


@dataclass(frozen=True, eq=False)
class Shape3D:
    """One target and the sheet's shape under its stimulus, to turn and zoom: vertices
    (V, 3) in mm of the target and of the sheet (placed on it) on the same ``triangles``
    (F, 3), each sheet vertex's ``distance_mm`` to the target, and the ``title`` (the
    verdict's words)."""

    name: str
    target_mm: np.ndarray
    sheet_mm: np.ndarray
    triangles: np.ndarray
    distance_mm: np.ndarray
    title: str


@dataclass(frozen=True)
class View3D:
    """A 3D view of ``shapes``, one at a time (a button per target), with its ``caption``."""

    shapes: tuple[Shape3D, ...]
    caption: str


Block = Paragraph | Facts | Table | Figure | View3D


@dataclass(frozen=True)
class Section:
    heading: str
    blocks: tuple[Block, ...]


@dataclass(frozen=True)
class Page:
    """The page: its ``title`` (the browser's), ``heading`` and ``sections``; ``folder`` is
    where it is written (links and pictures are relative to it); ``notice``, if any, is its
    first line (features left out of the machine file on purpose)."""

    title: str
    heading: Text
    sections: tuple[Section, ...]
    folder: Path
    notice: Text = ()


def as_sentence(text: str) -> str:
    """``text`` with a capital first letter and a full stop."""
    return text[:1].upper() + text[1:] + ("" if text.endswith(".") else ".")


def number(value: float) -> str:
    """A figure to 4 significant digits, without an exponent below 10,000."""
    return f"{value:.4g}" if abs(value) < 1e4 else f"{value:.0f}"


def percent(fraction: float) -> str:
    """A fraction as a percentage."""
    return f"{100 * fraction:.2f} %"


FORMATS = {"gcode": "G-code", "dxf": "DXF drawing", "laser": "laser patterns"}
"""Machine file formats in words."""


def in_words(text: str) -> str:
    """``text`` with every process parameter's key in words (``print_speed_mm_s`` -> print
    speed (mm/s))."""
    for key, label in sorted(LABELS.items(), key=lambda item: -len(item[0])):
        text = re.sub(rf"\b{key}\b", label, text)
    return text


def _is_name(token: str) -> bool:
    """Whether a word is a name as written in a file or a command: it has an underscore,
    it is a path, or it is a dotted key or file name (``solver.tolerance``, ``sheet.gcode``)."""
    return (
        "_" in token
        or (token.count("/") > 1 or token[:1] == "/" or ("/" in token and "." in token))
        or re.fullmatch(r"[A-Za-z]\w+(\.\w{2,})+", token) is not None
    )


def as_spans(text: str) -> Text:
    """``text`` with process parameters in words (:func:`in_words`) and every name
    (:func:`_is_name`) as :class:`Code`."""
    text = in_words(text)
    spans: list[Span] = []
    end = 0
    for match in re.finditer(r"[^\s(),;]+", text):
        name = match.group().rstrip(":.")
        if not _is_name(name):
            continue
        spans += [text[end : match.start()], Code(name)]
        end = match.start() + len(name)
    spans.append(text[end:])
    return tuple(s for s in spans if s != "")
