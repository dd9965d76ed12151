"""Attack rows for sending (issue 18): the machine named in the header, the machine's own
buffer, emulator options. Each is one line, exit 2, nothing written (tests/attack.py)."""

from __future__ import annotations

import pytest

from tests.attack import assert_refused, case
from tests.test_link_support import grbl_job

pytestmark = pytest.mark.filterwarnings("error")  # a warning would be a second line on stderr

SIM = "sim://marlin?baud=0&time_scale=0"
GRBL = "sim://grbl?baud=0&time_scale=0"
DIW_HEADER = ";Generated with fabkit 0.1.0 for machine marlin_diw_pneumatic"

CASES = [
    case(
        f"send {{diw}} --machine marlin_generic --port {SIM}",
        "was written for machine",
        "marlin_diw_pneumatic (its header), not marlin_generic",
        "--force",
        outputs=(),
        id="link-header-names-another-machine",
    ),
    case(
        "send {diw} --machine grbl_diw --dry-run",
        "was written for machine",
        "marlin_diw_pneumatic",
        outputs=(),
        id="link-header-names-another-machine-dry-run",
    ),
    case(
        f"send {{grbl}} --port {GRBL}&rx=64",
        "byte receive buffer",
        "reports a 64-byte receive buffer ([OPT:V,15,64])",
        "rx_buffer_bytes = 128: set it to 64",
        outputs=(),
        id="link-grbl-buffer-smaller-than-the-profile",
    ),
    case(
        f"send {{grbl}} --port {GRBL}&rx=64&opt=0",
        "byte receive buffer",
        "reports a 64-byte receive buffer (Bf:15,64)",
        outputs=(),
        id="link-grbl-buffer-smaller-than-the-profile-bf",
    ),
    case(
        f"send {{diw}} --port {SIM}&dialect=teacup",
        "cannot open port",
        "dialect='teacup': must be one of marlin-2.1",
        outputs=(),
        id="link-sim-unknown-dialect",
    ),
    case(
        f"send {{diw}} --port {SIM}&accel=-5",
        "cannot open port",
        "accel='-5': must be a finite number >= 0",
        outputs=(),
        id="link-sim-negative-acceleration",
    ),
    case(
        f"send {{diw}} --port {SIM} --resume-from 999",
        "is outside",
        "--resume-from 999 is outside",
        outputs=(),
        id="link-resume-from-past-the-end",
    ),
]


@pytest.fixture(scope="module")
def files(folder) -> dict[str, str]:
    diw = folder / "diw.gcode"
    moves = [f"G1 X{50 + k % 40} Y{60 + k % 7} F600" for k in range(30)]
    body = ["G21", "G90", "M42 P4 S0", "G28", "G1 Z1 F600", "M42 P4 S255", *moves, "M42 P4 S0"]
    diw.write_text("\n".join([";FLAVOR:Marlin", DIW_HEADER, *body]) + "\n")
    grbl = folder / "grbl.gcode"
    grbl.write_text("\n".join(c.text for c in grbl_job(30)) + "\n")
    return {"diw": str(diw), "grbl": str(grbl)}


@pytest.mark.parametrize("bad", CASES)
def test_send_refusals_are_one_line(bad, files, run_cli, tmp_path):
    assert_refused(bad, files, tmp_path, run_cli)
