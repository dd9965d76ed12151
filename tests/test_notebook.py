"""examples/notebook.ipynb runs from top to bottom in a Jupyter kernel (nbclient), and a
design, its check and a verification show themselves there as HTML: the verdict first,
then the pictures (fabkit.plot.notebook)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import nbclient
import nbformat
import pytest

from tests.conftest import coarse_design

NOTEBOOK = Path(__file__).parents[1] / "examples" / "notebook.ipynb"
PICTURE = '<img src="data:image/png;base64,'


@pytest.fixture(scope="module")
def executed(tmp_path_factory):
    """The notebook executed in a folder of its own; its code cells' outputs."""
    notebook = nbformat.read(NOTEBOOK, as_version=4)
    folder = tmp_path_factory.mktemp("notebook")
    client = nbclient.NotebookClient(
        notebook, timeout=600, kernel_name="python3", resources={"metadata": {"path": folder}}
    )
    client.execute()
    return [cell.outputs for cell in notebook.cells if cell.cell_type == "code"]


def _html(outputs) -> str:
    return "".join(o.get("data", {}).get("text/html", "") for o in outputs)


@pytest.mark.slow
def test_the_notebook_runs_and_every_stage_shows_itself(executed):
    assert not [o for outputs in executed for o in outputs if o.output_type == "error"]
    design, check, _, verification, sent = executed
    assert "valid points on a" in _html(design) and _html(design).count(PICTURE) == 2
    assert "The design's check passed" in _html(check)
    shown = _html(verification)
    # the verdict first, then its lines, the table and a picture per target
    assert shown.index("the sheet as fabricated") < shown.index("<pre>verify ")
    assert "sphere: " in shown and "bump: " in shown and shown.count(PICTURE) == 2
    assert "sent " in "".join(o.get("text", "") for o in sent)


def test_importing_fabkit_outside_a_notebook_loads_no_display_code():
    code = (
        "import sys, fabkit; print('fabkit.plot.notebook' in sys.modules, 'IPython' in sys.modules)"
    )
    shown = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert shown.stdout.split() == ["False", "False"]


def test_a_design_shows_every_surface_with_its_stimulus_and_two_pictures():
    from fabkit.plot.notebook import design_html

    shown = design_html(coarse_design(diagonals=20))
    assert "<td>sphere</td>" in shown and "<td>bump</td>" in shown and "<td>flat</td>" in shown
    assert shown.count(PICTURE) == 2 and "1 layer</p>" in shown
