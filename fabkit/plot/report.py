"""One self-contained HTML page with every picture (embedded) and the key figures."""

from __future__ import annotations

import base64
import html
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from fabkit.atomic import atomic_path

STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1200px; color: #222; }
table { border-collapse: collapse; margin-bottom: 1em; }
th, td { border: 1px solid #ccc; padding: 0.3em 0.8em; text-align: left; vertical-align: top; }
th { background: #f4f4f4; font-weight: 600; }
td td, td th { padding: 0.15em 0.5em; }
td table { margin: 0; font-size: 0.92em; }
.no { color: #b00; font-weight: 600; }
figure { margin: 2em 0; } img { max-width: 100%; }
figcaption { color: #555; }
"""


def html_report(
    title: str,
    figures: Mapping[str, Any],
    pictures: Sequence[tuple[str, Path]],
    path: str | Path,
    notice: str = "",
) -> None:
    """Write ``path``: the key figures as tables, then each (caption, PNG file) inline.

    ``figures`` is plain JSON-like data: a mapping becomes a two-column table, a list of
    mappings a table with one row per item and one column per (nested) key. ``notice``,
    if any, is the page's first line (in red).
    """
    blocks = []
    for caption, picture in pictures:
        data = base64.b64encode(Path(picture).read_bytes()).decode("ascii")
        blocks.append(
            f'<figure><img alt="{html.escape(caption)}" src="data:image/png;base64,{data}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>"
        )
    page = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>{STYLE}</style></head>
<body>{f'<p class="no">{html.escape(notice)}</p>' if notice else ""}
<h1>{html.escape(title)}</h1>
<h2>Key figures</h2>
{_html(figures)}
<h2>Pictures</h2>
{"".join(blocks)}
</body></html>
"""
    with atomic_path(path) as tmp:
        tmp.write_text(page, encoding="utf-8")


def _html(value: Any) -> str:
    """``value`` as HTML: tables for mappings and lists of mappings, escaped text else."""
    if isinstance(value, Mapping):
        rows = "".join(
            f"<tr><th>{html.escape(str(key))}</th><td>{_html(item)}</td></tr>"
            for key, item in value.items()
        )
        return f"<table>{rows}</table>" if rows else "none"
    if isinstance(value, list | tuple):
        if value and all(isinstance(item, Mapping) for item in value):
            return _rows_table([_flatten(item) for item in value])
        return "<br>".join(_html(item) for item in value) or "none"
    if isinstance(value, bool):
        return "yes" if value else '<span class="no">no</span>'
    if isinstance(value, float):
        return f"{value:.4g}"
    return "none" if value is None else html.escape(str(value))


def _rows_table(rows: list[dict[str, Any]]) -> str:
    """One row per mapping, one column per key met in any of them."""
    columns = list(dict.fromkeys(key for row in rows for key in row))
    head = "".join(f"<th>{html.escape(column)}</th>" for column in columns)
    body = "".join(
        "<tr>" + "".join(f"<td>{_html(row.get(column))}</td>" for column in columns) + "</tr>"
        for row in rows
    )
    return f"<table><tr>{head}</tr>{body}</table>"


def _flatten(row: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested mappings as one level: ``{"a": {"b": 1}}`` -> ``{"a b": 1}``."""
    flat: dict[str, Any] = {}
    for key, item in row.items():
        if isinstance(item, Mapping):
            flat.update(_flatten(item, f"{prefix}{key} "))
        else:
            flat[f"{prefix}{key}"] = item
    return flat
