"""``report.html`` in a real browser: it loads with no console error and shows every picture.

A coarse ``fabkit run`` writes the report; headless Chromium (Debian's ``chromium``,
driven over the DevTools pipe by :mod:`tests.browser`, no network) opens it from a
``file://`` URL. Every ``<img>`` must be decoded with its caption under it, and the
screenshot of the whole page must show it: the screenshot's pixels where the browser
laid it out match the PNG file (scaled as shown) within a few percent.
"""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from tests.browser import CHROMIUM, Browser
from tests.conftest import EXAMPLES

if not CHROMIUM.exists():
    pytest.skip(
        f"no browser: {CHROMIUM} is not installed and .ci/run could not install it "
        "(apt-get install chromium)",
        allow_module_level=True,
    )

_IMAGES = """Array.from(document.images).map(i => {
  const r = i.getBoundingClientRect();
  const caption = i.closest('figure')?.querySelector('figcaption')?.textContent ?? '';
  return {complete: i.complete, natural: [i.naturalWidth, i.naturalHeight], alt: i.alt,
          box: [r.left + scrollX, r.top + scrollY, r.width, r.height], caption: caption};
})"""


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    from fabkit.cli import main

    out = tmp_path_factory.mktemp("browser") / "out"
    args = ["run", str(EXAMPLES / "two_shapes.toml"), "--out", str(out), "--step", "0.1"]
    assert main([*args, "--diagonals", "30", "--size", "20", "--no-verify"]) == 0
    return out / "report.html"


@pytest.mark.slow
def test_the_report_loads_without_console_errors_and_shows_every_picture(report):
    with Browser() as browser:
        browser.open(report.resolve().as_uri())
        images = browser.evaluate(_IMAGES)
        shot = Image.open(io.BytesIO(browser.screenshot())).convert("RGB")
        errors = list(browser.errors)
    assert errors == []
    assert len(images) == 5  # flat sheet, eps, surfaces, residuals, toolpath preview
    for image in images:
        assert image["complete"] and min(image["natural"]) > 0, image["alt"]
        assert image["caption"] == image["alt"] and len(image["caption"]) > 20
        left, top, width, height = (int(round(v)) for v in image["box"])
        assert width > 300 and height > 150, image["alt"]
        shown = np.asarray(shot.crop((left, top, left + width, top + height)), float)
        assert shown.std() > 10, f"{image['alt']}: blank where the picture should be"
        assert _difference(shown, _picture(report, image["alt"]), width, height) < 0.03, image[
            "alt"
        ]


def _picture(report, alt: str) -> Image.Image:
    """The PNG file behind the picture captioned ``alt`` (the report embeds it)."""
    import base64
    import html
    import re

    page = report.read_text()
    pictures = dict(re.findall(r'<img alt="([^"]*)" src="data:image/png;base64,([^"]+)"', page))
    data = pictures[html.escape(alt, quote=True)]
    return Image.open(io.BytesIO(base64.b64decode(data)))


def _difference(shown: np.ndarray, picture: Image.Image, width: int, height: int) -> float:
    """Mean absolute difference (0-1) between the screenshot's region and the picture
    scaled to it, the picture's transparency over white as the page shows it."""
    canvas = Image.new("RGBA", picture.size, "white")
    flat = Image.alpha_composite(canvas, picture.convert("RGBA")).convert("RGB")
    expected = np.asarray(flat.resize((width, height), Image.Resampling.BILINEAR), float)
    return float(np.abs(shown - expected).mean() / 255)
