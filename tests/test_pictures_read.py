"""Every picture of a run reads at the size report.html shows it (issue 37).

The report shows a picture at most :data:`fabkit.plot.design.SHOWN_PX` wide (its body's
width at a 1280 px window): a wider one is scaled down, and its text with it. A coarse run
of Fig. 1 and of Fig. 3 draws its pictures in this process (the worker replaced by a
direct call), and every ``savefig`` is looked at: each visible text's height (its font
size at the picture's dpi, times the scale the report shows the picture at) is at least
:data:`fabkit.plot.design.MIN_TEXT_PX`, and no text runs past the saved picture's edge.
The residual maps were 1925 px wide with 9 pt titles: 8.3 px as shown.
"""

from __future__ import annotations

import contextlib

import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.text import Text

from fabkit import background
from fabkit.plot.design import MIN_TEXT_PX, SHOWN_PX
from tests.conftest import EXAMPLES

pytestmark = pytest.mark.slow


class _Done:
    def __init__(self, value) -> None:
        self.value = value

    def get(self):
        return self.value


class _HereWorker:
    """The picture worker, run in this process (so that savefig can be watched)."""

    def start(self, function: str, *args):
        return _Done(background._call(function, args))


@contextlib.contextmanager
def _here(warm=()):
    yield _HereWorker()


def _looked_at(figure: Figure, dpi: float, bbox_inches) -> dict:
    """The smallest text as the report shows it (px), and whether anything drawn runs past
    the edge of the saved picture (``bbox_inches`` as savefig had it: "tight", a box
    worked out before, e.g. the preview's for all its formats, or None)."""
    renderer = FigureCanvasAgg(figure).get_renderer()
    figure.draw(renderer)  # lays the labels out where the saved picture has them
    tight = bbox_inches is not None
    if bbox_inches == "tight":
        saved = figure.get_tightbbox(renderer)
    else:
        saved = bbox_inches or figure.bbox_inches
    shown = min(1.0, SHOWN_PX / (saved.width * dpi))
    texts = [t for t in figure.findobj(Text) if t.get_visible() and t.get_text().strip()]
    heights = [(t.get_fontsize() * dpi / 72 * shown, t.get_text()) for t in texts]
    drawn = figure.get_tightbbox(renderer)  # inches: everything drawn, ticks shown only
    canvas = figure.bbox_inches
    past = not tight and (
        drawn.x0 < canvas.x0 - 0.01
        or drawn.y0 < canvas.y0 - 0.01
        or drawn.x1 > canvas.x1 + 0.01
        or drawn.y1 > canvas.y1 + 0.01
    )
    return {"smallest": min(heights), "past": past, "width": saved.width * dpi}


@pytest.mark.parametrize("spec", ["two_shapes.toml", "three_shapes.toml"])
def test_every_picture_reads_at_the_size_the_report_shows_it(spec, tmp_path, monkeypatch):
    from fabkit.cli import main

    seen = []
    save = Figure.savefig

    def watched(figure, fname, *args, **kwargs):
        dpi = kwargs.get("dpi") or figure.dpi
        seen.append(_looked_at(figure, dpi, kwargs.get("bbox_inches")))
        return save(figure, fname, *args, **kwargs)

    monkeypatch.setattr("fabkit.run.pipeline.worker", _here)
    monkeypatch.setattr(Figure, "savefig", watched)
    args = ["run", str(EXAMPLES / spec), "--out", str(tmp_path / "out"), "--step", "0.1"]
    args += ["--layers", "1"]  # the same pictures as two layers, without choosing a share
    assert main([*args, "--diagonals", "30", "--size", "20"]) == 0
    assert len(seen) >= 6  # design, eps, surfaces, residuals, preview, a shape per target
    for picture in seen:
        height, text = picture["smallest"]
        assert height >= MIN_TEXT_PX - 0.05, (picture["width"], text, height)
        assert not picture["past"], picture
