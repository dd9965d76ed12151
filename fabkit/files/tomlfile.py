"""Reading a user's TOML file (spec, process, machine, baromorph, director, swimmer) with
one-line errors, bounded in size (TEXT_BYTES) and in nesting depth (NESTING_DEPTH), and
validating its tables with :class:`Table`, the one reader every file kind uses.

Every mistake in a table is one line naming the file (as shown to the user), the key path
(dotted, with 0-based positions in arrays: ``tool.nozzle_diameter_mm``,
``surfaces[1].geometry.radius``, ``process.encode[0].eps[2]``), what was expected and
what was found, in one of three wordings::

    FILE: KEY PATH: expected WHAT, got FOUND       a wrong type or value
    FILE: KEY PATH: missing (expected WHAT)        a required key is absent
    FILE: KEY PATH: unknown key (allowed: A, B)    a key the table does not take

for example ``machines/x.toml: tool.nozzle_diameter_mm: expected a positive number at
most 1e+06, got 'abc' (a string)`` or ``spec.toml: solver.stp: unknown key (allowed:
diagonals, extrapolate, max_strain, quadrants, step, tolerance)``. FOUND is the value as
TOML writes it (strings quoted, long ones shortened) with its type when that is not a
number. A ``where`` string below is ``FILE: KEY PATH`` (:meth:`Table.at`); checks that
need more than a type (a range, a relation between keys) word their refusal the same way
through :func:`expected`.

Python's TOML parser recurses once per nested array or inline table and slows down on
long dotted keys, so :func:`scan_depth` measures both in one cheap pass over the raw
text before it is parsed; the parsed tables are measured again exactly.
"""

from __future__ import annotations

import math
import re
import tomllib
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from fabkit.errors import FabkitError
from fabkit.files.readfile import check_depth, decode_utf8, read_limited
from fabkit.limits import NESTING_DEPTH, TEXT_BYTES

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


REQUIRED: Any = object()
"""The default of a getter whose key must be present."""


def found(value: Any) -> str:
    """A value as an error shows it: numbers as they are, other values with their type."""
    if isinstance(value, bool):
        return f"{str(value).lower()} (a boolean)"
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, str):
        shown = value if len(value) <= 40 else value[:37] + "..."
        return f"{shown!r} (a string)"
    if isinstance(value, list):
        if any(isinstance(item, Mapping) for item in value):
            return f"an array of {len(value)} tables"
        text = repr(value)
        return f"{text if len(text) <= 60 else text[:57] + '...'} (an array)"
    if isinstance(value, Mapping):
        return "a table"
    return f"{value!r} (a {type(value).__name__})"


def expected(where: str, what: str, value: Any) -> NoReturn:
    """Refuse ``value`` at ``where`` (``FILE: KEY PATH``): ``expected WHAT, got FOUND``."""
    raise FabkitError(f"{where}: expected {what}, got {found(value)}")


def missing(where: str, what: str) -> NoReturn:
    """Refuse the absence of the key at ``where``: ``missing (expected WHAT)``."""
    raise FabkitError(f"{where}: missing (expected {what})")


def describe_number(
    *, positive: bool = False, nonnegative: bool = False, bound: float | None = None
) -> str:
    """What :func:`real` expects, in words ("a positive number at most 1e+06")."""
    if positive:
        return (
            "a positive finite number" if bound is None else f"a positive number at most {bound:g}"
        )
    if nonnegative:
        return "a finite number >= 0" if bound is None else f"a number >= 0 at most {bound:g}"
    return "a finite number" if bound is None else f"a number within +-{bound:g}"


def real(
    value: Any,
    where: str,
    *,
    positive: bool = False,
    nonnegative: bool = False,
    bound: float | None = None,
) -> float:
    """``value`` as a finite float (> 0 if ``positive``, >= 0 if ``nonnegative``, at most
    ``bound`` in size), or a FabkitError at ``where``."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        ok = False
    else:
        ok = bool(
            math.isfinite(value)
            and not (positive and value <= 0)
            and not (nonnegative and value < 0)
            and not (bound is not None and abs(value) > bound)
        )
    if not ok:
        what = describe_number(positive=positive, nonnegative=nonnegative, bound=bound)
        expected(where, what, value)
    return float(value)


def whole(value: Any, where: str, *, minimum: int = 1) -> int:
    """``value`` as an integer >= ``minimum``, or a FabkitError at ``where``."""
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        what = "a positive integer" if minimum == 1 else f"an integer >= {minimum}"
        expected(where, what, value)
    return value


class Table:
    """One table of a user's TOML file, read key by key with one wording per mistake
    (module docstring).

    ``shown`` names the file ("" for a table that comes from no file), ``path`` is the
    table's key path ("" for the file's top level). Getters mark their key as read;
    :meth:`finish` refuses any key not read, and :meth:`check_keys` any key outside a
    given set.
    """

    def __init__(self, data: Any, shown: str, path: str = "") -> None:
        self.shown, self.path = shown, path
        if not isinstance(data, Mapping):
            expected(self.at(), "a table", data)
        self.data: dict[str, Any] = dict(data)
        self.seen: set[str] = set()

    # ------------------------------------------------------------------ places

    def key(self, key: str | int) -> str:
        """The key path of ``key`` (a name, or a position in an array)."""
        if isinstance(key, int):
            return f"{self.path}[{key}]"
        return f"{self.path}.{key}" if self.path else key

    def at(self, key: str | int | None = None) -> str:
        """``FILE: KEY PATH`` of ``key`` (of the table itself if None): the start of
        every message about it."""
        path = self.path if key is None else self.key(key)
        return ": ".join(part for part in (self.shown, path) if part)

    def fail(self, message: str, key: str | int | None = None) -> NoReturn:
        """Refuse with ``FILE: KEY PATH: message`` (a check beyond one key's type)."""
        raise FabkitError(f"{self.at(key)}: {message}")

    def expected(self, key: str | int | None, what: str, value: Any) -> NoReturn:
        expected(self.at(key), what, value)

    # ------------------------------------------------------------------ mapping

    def __contains__(self, key: str) -> bool:
        return key in self.data

    def __getitem__(self, key: str) -> Any:
        return self.data[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self.data)

    def has(self, key: str) -> bool:
        """Whether the table holds ``key`` (a key the reader knows: marked as read)."""
        self.seen.add(key)
        return key in self.data

    def get(self, key: str, default: Any = None) -> Any:
        """The raw value of ``key`` (``default`` if absent), marked as read."""
        self.seen.add(key)
        return self.data.get(key, default)

    def raw(self, key: str, what: str) -> Any:
        """The raw value of the required ``key``; ``what`` says what it should be."""
        self.seen.add(key)
        if key not in self.data:
            missing(self.at(key), what)
        return self.data[key]

    def require(self, keys: tuple[str, ...], what: Callable[[str], str] | str) -> None:
        """Refuse the first of ``keys`` that is absent."""
        for key in keys:
            if key not in self.data:
                missing(self.at(key), what if isinstance(what, str) else what(key))

    def check_keys(self, allowed: set[str] | tuple[str, ...]) -> None:
        """Refuse the first key (sorted) outside ``allowed``."""
        unknown = sorted(set(self.data) - set(allowed))
        if unknown:
            self.unknown(unknown[0], allowed)

    def finish(self) -> None:
        """Refuse the first key (sorted) that no getter read."""
        unknown = sorted(set(self.data) - self.seen)
        if unknown:
            self.unknown(unknown[0], self.seen)

    def unknown(self, key: str, allowed: set[str] | tuple[str, ...]) -> NoReturn:
        raise FabkitError(f"{self.at(key)}: unknown key (allowed: {', '.join(sorted(allowed))})")

    def optional(self, key: str, read: Callable[[str], Any], default: Any) -> Any:
        """``read(key)`` (one of the typed getters) if the table has ``key``, else ``default``."""
        self.seen.add(key)
        return read(key) if key in self.data else default

    # ------------------------------------------------------------------ typed getters

    def _value(self, key: str, default: Any, what: str) -> Any:
        if default is not REQUIRED:
            self.seen.add(key)
            return self.data.get(key, default)
        return self.raw(key, what)

    def text(
        self, key: str, choices: tuple[str, ...] | None = None, *, default: Any = REQUIRED
    ) -> str:
        """A string (one of ``choices`` if given)."""
        what = "a string" if choices is None else f"one of {', '.join(choices)}"
        value = self._value(key, default, what)
        if not isinstance(value, str) or (choices is not None and value not in choices):
            self.expected(key, what, value)
        return value

    def number(
        self,
        key: str,
        *,
        positive: bool = False,
        nonnegative: bool = False,
        bound: float | None = None,
        default: Any = REQUIRED,
    ) -> float:
        """A finite number (see :func:`real`)."""
        what = describe_number(positive=positive, nonnegative=nonnegative, bound=bound)
        value = self._value(key, default, what)
        return real(value, self.at(key), positive=positive, nonnegative=nonnegative, bound=bound)

    def flag(self, key: str, *, default: Any = REQUIRED) -> bool:
        value = self._value(key, default, "true or false")
        if not isinstance(value, bool):
            self.expected(key, "true or false", value)
        return value

    def integer(self, key: str, *, minimum: int = 1, default: Any = REQUIRED) -> int:
        what = "a positive integer" if minimum == 1 else f"an integer >= {minimum}"
        return whole(self._value(key, default, what), self.at(key), minimum=minimum)

    def array(self, key: str, what: str, *, default: Any = REQUIRED) -> list[Any]:
        """An array (``what`` describes it in the error)."""
        value = self._value(key, default, what)
        if not isinstance(value, list):
            self.expected(key, what, value)
        return value

    def numbers(
        self, key: str, *, length: int | None = None, bound: float | None = None
    ) -> tuple[float, ...]:
        """An array of finite numbers (``length`` of them if given), each within +-bound."""
        what = "an array of numbers" if length is None else f"an array of {length} numbers"
        value = self.array(key, what)
        if length is not None and len(value) != length:
            self.expected(key, what, value)
        return tuple(real(v, self.at(f"{key}[{i}]"), bound=bound) for i, v in enumerate(value))

    def span(self, key: str, *, bound: float | None = None) -> tuple[float, float]:
        """``[min, max]`` with min < max."""
        low, high = self.numbers(key, length=2, bound=bound)
        if not low < high:
            self.expected(key, "[min, max] with min < max", [low, high])
        return low, high

    def matrix(self, key: str, *, bound: float | None = None) -> tuple[tuple[float, ...], ...]:
        """An array of arrays of finite numbers."""
        what = "an array of arrays of numbers"
        rows = self.array(key, what)
        out = []
        for i, row in enumerate(rows):
            if not isinstance(row, list):
                expected(self.at(f"{key}[{i}]"), "an array of numbers", row)
            where = self.at(f"{key}[{i}]")
            out.append(tuple(real(v, f"{where}[{j}]", bound=bound) for j, v in enumerate(row)))
        return tuple(out)

    def table(self, key: str, *, default: Any = REQUIRED) -> Table:
        """The sub-table ``key`` (``default``, a mapping, if absent)."""
        return Table(self._value(key, default, "a table"), self.shown, self.key(key))

    def count(self, key: str) -> int:
        """How many tables the array of tables ``key`` holds (0 if absent)."""
        value = self.get(key, [])
        if not isinstance(value, list):
            self.expected(key, f"an array of tables ([[{self.key(key)}]])", value)
        return len(value)

    def item(self, key: str, index: int) -> Table:
        """Table ``index`` of the array of tables ``key``."""
        return Table(self.data[key][index], self.shown, f"{self.key(key)}[{index}]")
