"""One self-contained HTML page with every picture (embedded) and the key figures."""

from __future__ import annotations

import base64
import html
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from fabkit.atomic import atomic_path


def html_report(
    title: str,
    figures: Mapping[str, Any],
    pictures: Sequence[tuple[str, Path]],
    path: str | Path,
) -> None:
    """Write ``path``: a table of key figures, then each (caption, PNG file) inline."""
    rows = "\n".join(
        f"<tr><th>{html.escape(str(k))}</th><td>{html.escape(_format(v))}</td></tr>"
        for k, v in figures.items()
    )
    blocks = []
    for caption, picture in pictures:
        data = base64.b64encode(Path(picture).read_bytes()).decode("ascii")
        blocks.append(
            f'<figure><img alt="{html.escape(caption)}" src="data:image/png;base64,{data}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>"
        )
    page = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>
body {{ font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1200px; color: #222; }}
table {{ border-collapse: collapse; margin-bottom: 2em; }}
th, td {{ border: 1px solid #ccc; padding: 0.3em 0.8em; text-align: left; vertical-align: top; }}
th {{ background: #f4f4f4; }}
td {{ font-family: ui-monospace, monospace; white-space: pre-wrap; }}
figure {{ margin: 2em 0; }} img {{ max-width: 100%; }}
figcaption {{ color: #555; }}
</style></head>
<body><h1>{html.escape(title)}</h1>
<table>{rows}</table>
{"".join(blocks)}
</body></html>
"""
    with atomic_path(path) as tmp:
        tmp.write_text(page, encoding="utf-8")


def _format(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, str):
        return value
    return json.dumps(value, indent=1)
