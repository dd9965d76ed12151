"""Attack rows for nominal E: ``fabkit export --nominal-e`` where it is not safe.

Nominal E is written only on a Marlin machine without an E axis, and only within its
``[limits] e_mm_s``; anywhere else the export is refused in one line, writing nothing.
"""

from __future__ import annotations

import pytest

from fabkit.files.shipped import PROFILES_DIR
from fabkit.toolpath import PRINT, Layer, Move, Toolpath
from fabkit.toolpath.model import save_toolpath
from tests.attack import assert_refused, case

pytestmark = pytest.mark.filterwarnings("error")  # a warning would be a second line on stderr

EXPORT = "export {toolpath} --format gcode -o {out} --nominal-e --machine"

CASES = [
    case(
        f"{EXPORT} grbl_diw", "nominal E needs flavour marlin", "grbl", id="viewer-nominal-e-grbl"
    ),
    case(
        f"{EXPORT} marlin_generic",
        "nominal E is for machines without an E axis",
        id="viewer-nominal-e-e-axis",
    ),
    case(
        f"{EXPORT} {{slow_e}}",
        "E rate",
        "raise [limits] e_mm_s",
        id="viewer-nominal-e-rate",
    ),
]


@pytest.fixture(scope="module")
def places(folder) -> dict[str, str]:
    move = Move.make(PRINT, [[0, 0], [10, 0], [10, 1]], 0.3, 0.41, 8.0)
    save_toolpath(Toolpath((Layer(0.3, 0.3, (move,)),)), folder / "toolpath.npz")
    profile = folder / "slow_e.toml"
    text = (PROFILES_DIR / "marlin_diw_pneumatic.toml").read_text()
    profile.write_text(text.replace("e_mm_s = 5", "e_mm_s = 0.01"))
    return {"toolpath": str(folder / "toolpath.npz"), "slow_e": str(profile)}


@pytest.mark.parametrize("bad", CASES)
def test_nominal_e_is_refused_where_it_is_not_safe(bad, places, tmp_path, run_cli):
    assert_refused(bad, places, tmp_path, run_cli)
