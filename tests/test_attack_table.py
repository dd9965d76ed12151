"""The attack table as a whole: its size, and every error phrase documented.

The rows live in ``tests/test_cli_errors.py`` and ``tests/test_attack_*.py`` (each a list
``CASES`` of :func:`tests.attack.case` rows); this file gathers them.
"""

from __future__ import annotations

import importlib
from pathlib import Path

from tests.conftest import ROOT

MIN_ROWS = 150


def all_rows() -> dict[str, list]:
    """Every attack row, by the test module that holds it."""
    names = ["test_cli_errors"] + sorted(
        p.stem
        for p in Path(__file__).parent.glob("test_attack_*.py")
        if p.stem != Path(__file__).stem
    )
    return {name: importlib.import_module(f"tests.{name}").CASES for name in names}


def test_the_table_holds_enough_rows_with_unique_ids():
    rows = [row for module in all_rows().values() for row in module]
    assert len(rows) >= MIN_ROWS, len(rows)
    ids = [row.id for row in rows]
    assert len(ids) == len(set(ids)), sorted({i for i in ids if ids.count(i) > 1})


def test_every_error_phrase_is_in_troubleshooting():
    guide = (ROOT / "docs" / "troubleshooting.md").read_text()
    rows = [row for module in all_rows().values() for row in module]
    missing = sorted({r.values[0].says[0] for r in rows if r.values[0].says[0] not in guide})
    assert missing == [], f"add to docs/troubleshooting.md: {missing}"
