"""fabkit in Jupyter: a design, its check and a verification show themselves as HTML.

``import fabkit`` in a notebook (an IPython shell) calls :func:`register`, which tells
IPython's HTML formatter how to show a :class:`~fabkit.design.design.Design` (its targets
and the pictures of ``fabkit plot``: the flat sheet, the surfaces), a
:class:`~fabkit.design.check.CheckReport` (passed or not, the residual table) and a
:class:`~fabkit.verify.machine_file.Verification` (the verdict first, its lines, the
report's table and the picture of every target beside the sheet as fabricated). The
formatters are registered by the types' names, so nothing is imported before a value is
shown, and the design module need not import this later, plotting one. Outside IPython
nothing happens. The sentences are the command line's: one figure, one source.
"""

from __future__ import annotations

import base64
import html
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from fabkit.design.check import CheckReport
    from fabkit.design.design import Design
    from fabkit.verify.machine_file import Verification

SHOWN = {
    ("fabkit.design.design", "Design"): "design_html",
    ("fabkit.design.check", "CheckReport"): "check_html",
    ("fabkit.verify.machine_file", "Verification"): "verification_html",
}
"""The types shown as HTML (module, name) and the function here that shows each."""
WIDTH_PX = 900
"""The widest a picture is shown, in CSS pixels."""


def register(shell: Any) -> None:
    """Show fabkit's values as HTML in the IPython ``shell`` (its ``display_formatter``)."""
    formatter = shell.display_formatter.formatters["text/html"]
    for (module, name), function in SHOWN.items():
        formatter.for_type_by_name(module, name, globals()[function])


def design_html(design: Design) -> str:
    """The design: its grid, every target with its stimulus, and the pictures of the flat
    sheet (director and features) and of the surfaces."""
    from fabkit.plot.design import actuated_surfaces, flat_sheet
    from fabkit.plot.scene import scene

    spec = design.problem
    rows = "".join(
        f"<tr><td>{html.escape(t.name)}</td><td>{_stimulus(design, k)}</td></tr>"
        for k, t in enumerate(spec.targets)
    )
    shown = scene(design)
    return (
        f"<p><b>Design</b>: {int(design.valid.sum())} valid points on a "
        f"{design.valid.shape[0]} x {design.valid.shape[1]} grid (step {design.step:g} design "
        f"units), features {', '.join(spec.material.features)}, "
        f"{design.layers} layer{'s' if design.layers > 1 else ''}</p>"
        f"<table><tr><th>surface</th><th>stimulus</th></tr>{rows}</table>"
        + _picture(flat_sheet(shown), "the flat sheet")
        + _picture(actuated_surfaces(shown), "the surfaces")
    )


def check_html(report: CheckReport) -> str:
    """The check: passed or failed, then its table of residuals."""
    verdict = "passed" if report.passed else "FAILED"
    return f"<p><b>The design's check {verdict}</b></p>{_pre(report.table())}"


def verification_html(verification: Verification) -> str:
    """The verification: the verdict's headline and lines (when the sheet was simulated),
    the report's table, and every target beside the sheet as fabricated."""
    from fabkit.plot.shapes import shape_pictures

    verdict = verification.verdict
    parts = []
    if verdict is not None:
        style = "color:#1a7f37" if verdict.formed else "color:#b42318"
        parts.append(f'<p style="{style}"><b>{html.escape(verdict.headline())}</b></p>')
        parts.append("<ul>" + "".join(f"<li>{html.escape(x)}</li>" for x in verdict.lines()))
        parts.append("</ul>")
    parts.append(_pre(verification.table()))
    if verdict is not None and all(shape.mesh is not None for shape in verdict.shapes):
        for shape, picture in zip(
            verdict.shapes, shape_pictures(verdict.what, verdict.shapes), strict=True
        ):
            parts.append(_picture(picture, f"{shape.target}: the sheet {verdict.what}"))
    return "".join(parts)


def _stimulus(design: Design, index: int) -> str:
    names = design.problem.material.stimuli
    values = design.stimuli[index]
    return ", ".join(f"{html.escape(n)} = {v:g}" for n, v in zip(names, values, strict=True))


def _picture(data: bytes, alt: str) -> str:
    encoded = base64.b64encode(data).decode("ascii")
    return (
        f'<img src="data:image/png;base64,{encoded}" alt="{html.escape(alt)}" '
        f'style="max-width:{WIDTH_PX}px;width:100%">'
    )


def _pre(text: str) -> str:
    return f"<pre>{html.escape(text)}</pre>"
