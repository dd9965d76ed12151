"""Attack rows of issue 17: bad ``--outline``, ``--min-width`` and ``--trim`` input.

Each row is a bad part option of ``run``, ``toolpath``, ``channels``, ``export``,
``verify`` or ``simulate``: an unknown shape, a file that is no closed outline, a length
that is negative or not finite, an outline or a width that leaves nothing of the sheet.
Each must be one line naming the problem, exit 2, nothing written (tests/attack.py).
"""

from __future__ import annotations

import json

import ezdxf
import pytest

from tests.attack import assert_refused, case
from tests.conftest import coarse_design

pytestmark = pytest.mark.filterwarnings("error")  # a warning would be a second line on stderr

TOOLPATH = "toolpath {design} --size 20 --machine marlin_diw_pneumatic --out {out}"

CASES = [
    case(
        f"{TOOLPATH} --min-width -1",
        "expected a non-negative finite number",
        "--min-width -1",
        id="part_min_width_negative",
    ),
    case(
        "run {spec} --min-width inf --out {out}",
        "expected a non-negative finite number",
        "--min-width inf",
        id="part_run_min_width_infinite",
    ),
    case(
        f"{TOOLPATH} --trim nan",
        "expected a non-negative finite number",
        "--trim nan",
        id="part_trim_not_a_number",
    ),
    case(
        "simulate {design} --stimulus sphere --trim -2 --out {out}/sphere.ply",
        "expected a non-negative finite number",
        "--trim -2",
        id="part_simulate_trim_negative",
    ),
    case(
        f"{TOOLPATH} --min-width 100",
        "nothing of the solved domain is left for the part",
        "min width",
        "--min-width",
        id="part_min_width_too_large",
    ),
    case(
        f"{TOOLPATH} --outline {{far}}",
        "nothing of the solved domain is left for the part",
        "outline -",
        "an --outline that overlaps the sheet",
        id="part_outline_misses_the_sheet",
    ),
    case(
        f"{TOOLPATH} --outline blob:3",
        "expected a shape",
        "blob:3",
        "outline file",
        id="part_outline_unknown_shape",
    ),
    case(
        "run {spec} --outline disc:-3 --out {out}",
        "'disc' needs 1 positive number(s)",
        "--outline",
        id="part_run_outline_negative_disc",
    ),
    case(
        f"{TOOLPATH} --outline disc:1e308",
        "sizes must be between 0.001 and 1e+06 mm",
        "--outline",
        id="part_outline_disc_overflow",
    ),
    case(
        "export {design} --size 20 --machine marlin_diw_pneumatic --format dxf "
        "--outline {missing}.csv --out {out}",
        "does not exist",
        "outline file",
        id="part_export_outline_missing",
    ),
    case(
        f"{TOOLPATH} --outline {{open_csv}}",
        "no closed path with an area",
        "open.csv",
        id="part_outline_open_csv",
    ),
    case(
        f"{TOOLPATH} --outline {{bad_csv}}",
        "expected 'x,y' in mm",
        "line 3",
        id="part_outline_csv_bad_line",
    ),
    case(
        f"{TOOLPATH} --outline {{point_geojson}}",
        "not a polygon",
        "Point",
        id="part_outline_geojson_point",
    ),
    case(
        f"{TOOLPATH} --outline {{line_dxf}}",
        "no closed path",
        "line.dxf",
        id="part_outline_dxf_without_closed_path",
    ),
    case(
        f"{TOOLPATH} --outline {{entity_svg}}",
        "an SVG with a DOCTYPE or entities is not read",
        id="part_outline_svg_entities",
    ),
    case(
        "channels {design} --size 20 --baromorph {channels} --outline {open_svg} --out {out}",
        "no closed path",
        "open.svg",
        id="part_channels_svg_open_path",
    ),
    case(
        f"{TOOLPATH} --outline {{huge_csv}}",
        "a coordinate is not finite or beyond",
        id="part_outline_coordinate_too_large",
    ),
]


@pytest.fixture(scope="module")
def places(folder) -> dict[str, str]:
    """A coarse Fig. 1 design and outline files that are no usable outline."""
    design = folder / "design.npz"
    coarse_design().save(design)
    files = {
        "far.csv": "x,y\n100,100\n110,100\n110,110\n100,110\n",
        "open.csv": "1,2\n3,4\n",
        "bad.csv": "x,y\n0,0\nten,0\n10,10\n",
        "huge.csv": "0,0\n1e30,0\n0,10\n",
        "point.geojson": json.dumps({"type": "Point", "coordinates": [0, 0]}),
        "entity.svg": '<?xml version="1.0"?>\n<!DOCTYPE svg [<!ENTITY a "aaaa">]>\n'
        '<svg xmlns="http://www.w3.org/2000/svg"><path d="M0 0 L10 0 L10 10 z"/></svg>\n',
        "open.svg": '<svg xmlns="http://www.w3.org/2000/svg"><path d="M0 0 L10 0 L10 10"/></svg>\n',
    }
    for name, text in files.items():
        (folder / name).write_text(text)
    drawing = ezdxf.new()
    drawing.modelspace().add_line((0, 0), (10, 0))
    drawing.saveas(folder / "line.dxf")
    return {
        "design": str(design),
        **{name.replace(".", "_"): str(folder / name) for name in (*files, "line.dxf")},
        "far": str(folder / "far.csv"),
    }


@pytest.mark.parametrize("bad", CASES)
def test_part_refusals(bad, places, run_cli, tmp_path):
    assert_refused(bad, places, tmp_path, run_cli)
