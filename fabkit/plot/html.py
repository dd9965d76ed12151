"""One self-contained HTML page: a :class:`~fabkit.plot.page.Page` written out.

The pictures are embedded (PNG, base64), and so is plotly.js where the page has a 3D view
(:mod:`fabkit.plot.view3d`): the page loads nothing else, no script, font or style sheet
from elsewhere; its links point at files the run wrote beside it.
"""

from __future__ import annotations

import base64
import html
from pathlib import Path

from plotly.offline import get_plotlyjs

from fabkit.files.atomic import atomic_path
from fabkit.plot.page import (
    Block,
    Code,
    Facts,
    Link,
    Page,
    Paragraph,
    Section,
    Table,
    Text,
    View3D,
)
from fabkit.plot.view3d import view_html

STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1200px; color: #222;
       padding: 0 1em; line-height: 1.45; }
h1 { margin-bottom: 0.2em; } h2 { margin-top: 1.8em; border-bottom: 1px solid #ddd; }
code { font-family: ui-monospace, monospace; font-size: 0.92em; background: #f3f3f3;
       padding: 0 0.2em; border-radius: 3px; }
table { border-collapse: collapse; margin: 0.6em 0 1em; }
th, td { border: 1px solid #ccc; padding: 0.3em 0.7em; text-align: left; vertical-align: top; }
th { background: #f4f4f4; font-weight: 600; }
table.facts th { font-weight: 500; }
p.headline { font-size: 1.35em; font-weight: 600; }
p.formed, p.missed { padding: 0.5em 0.8em; border-left: 6px solid; border-radius: 3px; }
p.formed { background: #eaf6ea; border-color: #2e7d32; }
p.missed { background: #fdecea; border-color: #c62828; font-weight: 600; }
p.notice { color: #b00; font-weight: 600; }
figure { margin: 1.5em 0; } img { max-width: 100%; }
figcaption { color: #555; max-width: 70em; }
"""


def html_report(page: Page, path: str | Path) -> None:
    """Write ``page`` as one HTML file at ``path`` (atomically)."""
    sections = "\n".join(_section(section) for section in page.sections)
    views = any(isinstance(b, View3D) for section in page.sections for b in section.blocks)
    script = f"<script>{get_plotlyjs()}</script>" if views else ""
    document = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(page.title)}</title>
<style>{STYLE}</style>{script}</head>
<body>
{f'<p class="notice">{_text(page.notice)}</p>' if page.notice else ""}
<h1>{_text(page.heading)}</h1>
{sections}
</body></html>
"""
    with atomic_path(path) as tmp:
        tmp.write_text(document, encoding="utf-8")


def _section(section: Section) -> str:
    blocks = "\n".join(_block(block) for block in section.blocks)
    return f"<section>\n<h2>{html.escape(section.heading)}</h2>\n{blocks}\n</section>"


def _block(block: Block) -> str:
    """One block as HTML."""
    if isinstance(block, Paragraph):
        style = f' class="{block.style}"' if block.style else ""
        return f"<p{style}>{_text(block.text)}</p>"
    if isinstance(block, Facts):
        rows = "".join(
            f"<tr><th>{html.escape(label)}</th><td>{_text(value)}</td></tr>"
            for label, value in block.rows
        )
        return f'<table class="facts">{rows}</table>'
    if isinstance(block, Table):
        head = "".join(f"<th>{html.escape(label)}</th>" for label in block.header)
        body = "".join(
            "<tr>" + "".join(f"<td>{_text(cell)}</td>" for cell in row) + "</tr>"
            for row in block.rows
        )
        return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"
    if isinstance(block, View3D):
        caption = html.escape(block.caption)
        return f"<figure>{view_html(block, 'view3d')}<figcaption>{caption}</figcaption></figure>"
    data = base64.b64encode(block.path.read_bytes()).decode("ascii")
    caption = html.escape(block.caption)
    return (
        f'<figure><img alt="{caption}" src="data:image/png;base64,{data}">'
        f"<figcaption>{caption}</figcaption></figure>"
    )


def _text(text: Text | str) -> str:
    """Spans as HTML: names as ``<code>``, links as ``<a>``, the rest escaped."""
    if isinstance(text, str):
        return html.escape(text)
    out = []
    for span in text:
        if isinstance(span, Code):
            out.append(f"<code>{html.escape(span.text)}</code>")
        elif isinstance(span, Link):
            link = f"<code>{html.escape(span.text)}</code>"  # a file's name, as written
            out.append(f'<a href="{html.escape(span.href)}">{link}</a>')
        else:
            out.append(html.escape(span))
    return "".join(out)
