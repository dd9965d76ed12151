"""The attack-table harness: a bad input must be refused in one line, quickly, writing nothing.

A row (:class:`Case`) is one ``fabkit ARGS`` command line and the phrases its error must
contain. :func:`assert_refused` runs it in-process and asserts what the README promises
for bad input:

* exit code 2 (or ``code`` for a row that expects another, e.g. 130);
* exactly one line on stderr, starting with ``fabkit: error:``, naming every phrase;
* no traceback, and no Python warning (on the command line it would be a second line);
* none of the row's outputs created, and (rows whose outputs are ``{out}``) nothing at
  all created in the test's folder: no ``*.part``, nothing beside or above ``--out``;
* a file that was in the way (``{blocker}``) left untouched;
* done within the row's time bound (default :data:`SECONDS`): a command still running
  then is stopped by SIGALRM and the row fails.

Every ``tests/test_attack_*.py`` file and ``tests/test_cli_errors.py`` hold such rows in a
list called ``CASES``; ``tests/test_attack_table.py`` counts them and checks that the first
phrase of every row is listed in docs/troubleshooting.md.
"""

from __future__ import annotations

import signal
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

SECONDS = 10.0
"""Default time bound of one row, in seconds."""
BLOCKER_TEXT = "a file in the way of an output folder\n"
EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
SHIPPED = {
    "spec": str(EXAMPLES / "two_shapes.toml"),
    "three": str(EXAMPLES / "three_shapes.toml"),
    "swimmer": str(EXAMPLES / "swimmer.toml"),
    "channels": str(EXAMPLES / "baromorph_channels.toml"),
}
"""Placeholders every row may use: the shipped Fig. 1 and Fig. 3 specs, the swimmer and
the baromorph channel settings (a test's own ``places`` of the same name win)."""


@dataclass(frozen=True)
class Case:
    """``fabkit ARGS`` must fail naming ``says`` (says[0]: the documented phrase)."""

    args: str
    says: tuple[str, ...]
    outputs: tuple[str, ...] = ("{out}",)
    seconds: float = SECONDS
    code: int = 2


def case(
    args: str,
    *says: str,
    outputs: tuple[str, ...] = ("{out}",),
    id: str,
    seconds: float = SECONDS,
    code: int = 2,
    slow: bool = False,
):
    """One row, as a pytest parameter with its id (marked ``slow``, out of the quick
    subset, if ``slow``)."""
    marks = (pytest.mark.slow,) if slow else ()
    return pytest.param(Case(args, says, outputs, seconds, code), id=id, marks=marks)


def edited(text: str, old: str, new: str) -> str:
    """``text`` with its first ``old`` replaced by ``new`` (``old`` must be there)."""
    assert old in text, old
    return text.replace(old, new, 1)


def write_texts(folder: Path, texts: dict[str, str], suffix: str) -> dict[str, str]:
    """Write every text of ``texts`` (name -> text) to ``folder/<name><suffix>``; returns
    the paths by name, to merge into a test's ``places``."""
    paths = {}
    for name, text in texts.items():
        path = folder / f"{name}{suffix}"
        path.write_text(text)
        paths[name] = str(path)
    return paths


class TookTooLong(Exception):
    """Raised by SIGALRM inside a command that outlived its row's time bound."""


def _alarm(signum, frame):  # noqa: ARG001 - the signal handler's signature
    raise TookTooLong


def run_bounded(run: Callable[[], tuple[int, str, str]], seconds: float):
    """``run()`` stopped by SIGALRM after ``seconds``; returns (result, elapsed s)."""
    previous = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    start = time.perf_counter()
    try:
        result = run()
    except TookTooLong:
        pytest.fail(f"still running after {seconds:g} s")
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
    return result, time.perf_counter() - start


def assert_refused(bad: Case, places: dict[str, str], tmp_path: Path, run_cli) -> str:
    """Run ``bad`` with ``{name}`` placeholders from ``places``; assert the promise; return err.

    ``{out}``, ``{missing}`` and ``{blocker}`` are added here, inside ``tmp_path``, and
    the examples of :data:`SHIPPED` where ``places`` has no such name.
    """
    blocker = tmp_path / "blocker"
    blocker.write_text(BLOCKER_TEXT)
    out, missing = str(tmp_path / "out"), str(tmp_path / "missing")
    places = {**SHIPPED, **places, "out": out, "missing": missing}
    places["blocker"] = str(blocker)
    before = sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*"))
    args = [arg.format(**places) for arg in bad.args.split()]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        (code, _, err), _ = run_bounded(lambda: run_cli(*args), bad.seconds)
    assert not caught, [str(w.message) for w in caught]
    assert code == bad.code, err
    prefix = "fabkit: error: " if bad.code == 2 else "fabkit: "
    assert err.startswith(prefix) and err.count("\n") == 1, err
    assert "Traceback" not in err
    for phrase in bad.says:
        assert phrase in err, (phrase, err)
    for output in bad.outputs:
        assert not (tmp_path / output.format(out="out")).exists(), output
    if bad.outputs == ("{out}",):
        after = sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*"))
        assert after == before, sorted(set(after) - set(before))
    assert [p for p in tmp_path.rglob("*") if ".part" in p.name] == []
    assert blocker.read_text() == BLOCKER_TEXT
    return err
