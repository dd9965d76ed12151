"""``report.html`` in a real browser, as a reader sees it: the verdict first, in words.

Two coarse ``fabkit run``s, verified (Fig. 1 and Fig. 3), write their reports; headless
Chromium (Debian's ``chromium``, driven over the DevTools pipe by :mod:`tests.browser`, no
network) opens each from a ``file://`` URL. The visible text holds a verdict line per
target with its figures (as ``report.json`` has them) and no raw key (a word with an
underscore: names as written in a file or a command are set as ``<code>``); every
``<img>`` is decoded with its caption under it, and the screenshot of the whole page
shows it (its pixels where the browser laid it out match the PNG within a few percent);
the page logs no console error and asks for nothing but itself and the pictures embedded
in it.
"""

from __future__ import annotations

import base64
import html
import io
import json
import re

import numpy as np
import pytest
from PIL import Image

from tests.browser import CHROMIUM, Browser
from tests.conftest import validate_report

if not CHROMIUM.exists():
    pytest.skip(
        f"no browser: {CHROMIUM} is not installed and .ci/run could not install it "
        "(apt-get install chromium)",
        allow_module_level=True,
    )

pytestmark = pytest.mark.slow

_IMAGES = """Array.from(document.images).map(i => {
  const r = i.getBoundingClientRect();
  const caption = i.closest('figure')?.querySelector('figcaption')?.textContent ?? '';
  return {complete: i.complete, natural: [i.naturalWidth, i.naturalHeight], alt: i.alt,
          box: [r.left + scrollX, r.top + scrollY, r.width, r.height], caption: caption};
})"""
_PROSE = """(() => { const body = document.body.cloneNode(true);
  body.querySelectorAll('code, script').forEach(c => c.remove());
  return body.innerText; })()"""
_NAMES = "Array.from(document.querySelectorAll('code')).map(c => c.textContent)"
_VIEW = """(() => { const g = document.getElementById('view3d');
  const r = g.getBoundingClientRect();
  return {traces: g.data.map(d => d.name), visible: g.data.map(d => d.visible),
          buttons: Array.from(g.querySelectorAll('.updatemenu-button')).map(b => b.textContent),
          webgl: g.querySelectorAll('canvas').length, title: g.layout.title.text,
          box: [r.left + scrollX, r.top + scrollY, r.width, r.height]}; })()"""
_CLICK_LAST = """(() => { const b = document.querySelectorAll('#view3d .updatemenu-button');
  b[b.length - 1].dispatchEvent(new MouseEvent('click', {bubbles: true})); return b.length; })()"""
SPECS = {"Fig. 1": "two_shapes.toml", "Fig. 3": "three_shapes.toml"}


@pytest.fixture(scope="module", params=sorted(SPECS))
def seen(request, coarse_run):
    """A coarse verified run of the figure, and what the browser shows of its report."""
    out, _ = coarse_run(SPECS[request.param])
    with Browser() as browser:
        browser.open((out / "report.html").resolve().as_uri())
        shown = {
            "images": browser.evaluate(_IMAGES),
            "text": browser.evaluate("document.body.innerText"),
            "prose": browser.evaluate(_PROSE),
            "names": browser.evaluate(_NAMES),
            "shot": Image.open(io.BytesIO(browser.screenshot())).convert("RGB"),
            "view": browser.evaluate(_VIEW),
        }
        browser.evaluate(_CLICK_LAST)
        shown["view after the last button"] = browser.evaluate(_VIEW)
        shown["errors"], shown["requests"] = list(browser.errors), list(browser.requests)
    figures = json.loads((out / "report.json").read_text())
    return {"out": out, "figures": figures, **shown}


def test_the_verdict_comes_first_with_a_line_per_target_and_its_figures(seen):
    text, verdict = seen["text"], seen["figures"]["verdicts"][-1]
    assert verdict["what"] == "as fabricated"  # the run read its machine file back
    first = text.index("Verdict")
    assert first < text.index("The shapes it will make") < text.index("The design")
    for target in verdict["targets"]:
        line = target["line"]
        assert text.index(line) > first, line
        assert line.startswith(f"{target['target']}: {'formed' if target['formed'] else 'NOT'}")
        assert f"{target['rms_pct']:.2f} % ({target['rms_mm']:.3g} mm) RMS" in line
        assert f"max {target['max_pct']:.2f} % ({target['max_mm']:.3g} mm)" in line
        assert f"limit {target['limit_pct']:.3g} % ({target['limit_mm']:.3g} mm)" in line
    headline = seen["figures"]["verdict"]["headline"]
    assert text.index(headline[:1].upper() + headline[1:]) > first


def test_no_raw_key_is_shown(seen):
    """Words with underscores are names as written (files, the machine, spec keys), set as
    code; everything else is in words."""
    assert re.findall(r"[a-z]+_[a-z_]+", seen["prose"]) == []
    machine = seen["figures"]["machine"]
    for name in seen["names"]:
        assert name == machine or "." in name or "/" in name, name


def test_the_page_asks_for_nothing_but_itself_and_logs_no_error(seen):
    assert seen["errors"] == []
    page = (seen["out"] / "report.html").resolve().as_uri()
    assert seen["requests"][0] == page
    for url in seen["requests"][1:]:  # the pictures, embedded in the page
        assert url.startswith("data:image/png;base64,"), url[:80]


def test_every_picture_is_decoded_and_shown_with_its_caption(seen):
    targets = [t["target"] for t in seen["figures"]["verdicts"][-1]["targets"]]
    images = seen["images"]
    # the shapes (one per target), flat sheet, eps, surfaces, residuals, toolpath preview
    assert len(images) == len(targets) + 5
    for image, target in zip(images, targets, strict=False):
        assert image["alt"].startswith(f"{target}: the target (left, grey) and the sheet")
    for image in images:
        assert image["complete"] and min(image["natural"]) > 0, image["alt"]
        assert image["caption"] == image["alt"] and len(image["caption"]) > 20
        left, top, width, height = (int(round(v)) for v in image["box"])
        assert width > 300 and height > 150, image["alt"]
        shown = np.asarray(seen["shot"].crop((left, top, left + width, top + height)), float)
        assert shown.std() > 10, f"{image['alt']}: blank where the picture should be"
        difference = _difference(shown, _picture(seen["out"], image["alt"]), width, height)
        assert difference < 0.03, image["alt"]


def test_the_shapes_turn_in_3d_one_target_at_a_time(seen):
    """Issue 37: the shapes in a 3D view (plotly.js, embedded): per target its surface and
    the sheet's, one target shown at a time, a button per target; WebGL draws it."""
    targets = [t["target"] for t in seen["figures"]["verdicts"][-1]["targets"]]
    view = seen["view"]
    assert view["buttons"] == targets and view["webgl"] >= 1
    assert view["traces"] == [f"{t}: {part}" for t in targets for part in ("target", "the sheet")]
    assert view["visible"] == [k < 2 for k in range(2 * len(targets))]
    first = seen["figures"]["verdicts"][-1]["targets"][0]
    assert view["title"].startswith("formed" if first["formed"] else "NOT formed")
    left, top, width, height = (int(round(v)) for v in view["box"])
    drawn = np.asarray(seen["shot"].crop((left, top, left + width, top + height)), float)
    assert width > 800 and drawn.std() > 10, "the 3D view is blank"
    after = seen["view after the last button"]
    assert after["visible"] == [k >= 2 * len(targets) - 2 for k in range(2 * len(targets))]
    assert after["title"] != view["title"]


def test_report_json_follows_its_schema(seen):
    validate_report(seen["figures"])  # verified: the read-back figures and verdict too


def test_the_shapes_are_written_beside_the_page(seen):
    import trimesh

    shapes = seen["figures"]["shapes"]
    assert shapes["what"] == "as fabricated" and shapes["folder"] == "as_fabricated"
    for shape in shapes["targets"]:
        mesh = trimesh.load(seen["out"] / shape["mesh"], process=False)
        distance = mesh.metadata["_ply_raw"]["vertex"]["data"]["distance_mm"]
        assert len(distance) == len(mesh.vertices) and np.all(distance >= 0)
        # the target's mesh where the sheet is placed: the distances are between the two
        target = trimesh.load(seen["out"] / shape["target_mesh"], process=False)
        assert np.array_equal(target.faces, mesh.faces)
        between = np.linalg.norm(mesh.vertices - target.vertices, axis=1)
        np.testing.assert_allclose(between, distance, atol=1e-4)
        assert (seen["out"] / shape["picture"]).read_bytes()[:4] == b"\x89PNG"
        assert f'href="{shape["mesh"]}"' in (seen["out"] / "report.html").read_text()


def _picture(out, alt: str) -> Image.Image:
    """The PNG file behind the picture captioned ``alt`` (the report embeds it)."""
    page = (out / "report.html").read_text()
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
