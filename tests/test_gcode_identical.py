"""The G-code written for every example is byte-identical before and after a change that
should not change it (issue 28: splitting modules along their seams).

Covered (the cases of :func:`tests.golden.cases`):

* every example whose machine file is G-code with its default machine
  (marlin_diw_pneumatic): Fig. 1 (``two_shapes.toml``), Fig. 3 (``three_shapes.toml``),
  Fig. 3 with the joint table (``processes/fig3_joint.toml``: the pressure channel), Fig. 1
  with the LCE process (``directors/process_lce.toml``) and the swimmer
  (``swimmer.toml``, two printed layers). Left out: ``baromorph.toml`` (``fabkit run``
  writes a DXF for it, default machine laser_cutter: ``fabkit run --help``,
  :func:`fabkit.run.inputs.with_defaults`), ``baromorph_channels.toml`` (channel settings,
  not a spec) and the photoalignment runs (laser patterns);
* every machine profile of machines/ that takes G-code (flavours marlin, klipper, grbl,
  hyrel), from the one stored toolpath :data:`tests.golden.PROFILE_TOOLPATH`;
* the writer options the profiles do not choose: relative E on an absolute profile, E in
  volume and in pulses, nominal E.

The solve's last digits drift with the unpinned numpy, scipy and numba, so the test does
not solve: each case's G-code is written again (through
:func:`fabkit.writers.export.write_machine_file`, as ``fabkit run`` writes it) from a
coarse toolpath stored in ``tests/data/toolpaths/`` (made by ``python -m tests.golden``,
which checks that each is the toolpath its example's run wrote its G-code from), and its
SHA-256 compared with ``tests/data/gcode_sha256.json``. The version in the header line
``;Generated with fabkit X`` is left out of the hash (a release changes it, not the
writer). On a mismatch the test names the first line that differs (found from a 16-bit
digest per line, ``tests/data/gcode_lines.npz``) and shows it.

After an intended change of the G-code, remake the references (and say so in the commit)::

    FABKIT_UPDATE_GOLDEN=1 python -m pytest -n 0 tests/test_gcode_identical.py
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np
import pytest

import fabkit
from fabkit.machines import load_machine
from fabkit.toolpath.model import load_toolpath
from fabkit.writers.export import ExportOptions, write_machine_file
from fabkit.writers.gcode import GcodeOptions
from tests.golden import DATA, HASHES, TOOLPATHS, Case, cases

LINES = DATA / "gcode_lines.npz"
UPDATE = os.environ.get("FABKIT_UPDATE_GOLDEN") == "1"
CASES = cases()
VERSION_LINE = f";Generated with fabkit {fabkit.__version__} ".encode()


def written(case: Case, folder: Path) -> bytes:
    """The case's G-code, written from its stored toolpath as ``fabkit run`` writes it,
    with the fabkit version in the header replaced by ``VERSION``."""
    toolpath = load_toolpath(TOOLPATHS / f"{case.toolpath}.npz")
    options = ExportOptions(gcode=GcodeOptions(**case.options))
    out = folder / "sheet.gcode"
    write_machine_file(toolpath, load_machine(case.machine), "gcode", out, options)
    text = out.read_bytes()
    assert text.count(VERSION_LINE) == 1, "the header names the fabkit version once"
    return text.replace(VERSION_LINE, b";Generated with fabkit VERSION ")


def line_digests(text: bytes) -> np.ndarray:
    """A 16-bit digest of every line (enough to find the first one that changed)."""
    return np.array(
        [int.from_bytes(hashlib.sha256(line).digest()[:2], "big") for line in text.split(b"\n")],
        dtype=np.uint16,
    )


def stored() -> tuple[dict[str, str], dict[str, np.ndarray]]:
    hashes = json.loads(HASHES.read_text())
    with np.load(LINES, allow_pickle=False) as lines:
        return hashes, {name: lines[name] for name in lines.files}


def first_difference(text: bytes, reference: np.ndarray) -> str:
    """Where ``text`` first differs from the reference's line digests, and that line."""
    lines = text.split(b"\n")
    now = line_digests(text)
    common = min(len(now), len(reference))
    differ = np.flatnonzero(now[:common] != reference[:common])
    if len(differ):
        k = int(differ[0])
        return f"line {k + 1} differs; it is now {lines[k].decode(errors='replace')!r}"
    if len(now) != len(reference):
        return f"the first {common} lines match; {len(now)} lines now, {len(reference)} before"
    return "every line's digest matches (a change the 16-bit digests miss)"


@pytest.mark.skipif(UPDATE, reason="the references are being remade")
def test_every_case_has_a_stored_toolpath():
    assert {c.toolpath for c in CASES} == {p.stem for p in TOOLPATHS.glob("*.npz")}
    total = sum(p.stat().st_size for p in DATA.glob("toolpaths/*.npz")) + LINES.stat().st_size
    assert total < 400_000, "the stored references stay small (coarse toolpaths)"


def test_a_change_is_shown_at_its_first_line():
    text = b"G1 X1\nG1 X2\nG1 X3\n"
    reference = line_digests(text)
    assert "line 2 differs; it is now 'G1 X9'" in first_difference(
        text.replace(b"X2", b"X9"), reference
    )
    assert "line 4 differs; it is now 'M84'" in first_difference(text + b"M84\n", reference)


@pytest.mark.skipif(not UPDATE, reason="FABKIT_UPDATE_GOLDEN=1 remakes the references")
def test_update_references(tmp_path):
    hashes, lines = {}, {}
    for case in CASES:
        text = written(case, tmp_path)
        hashes[case.name] = hashlib.sha256(text).hexdigest()
        lines[case.name] = line_digests(text)
    HASHES.write_text(json.dumps(hashes, indent=1) + "\n")
    with open(LINES, "wb") as handle:
        np.savez_compressed(handle, **lines)


@pytest.mark.skipif(UPDATE, reason="the references are being remade")
@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_gcode_is_byte_identical(case, tmp_path):
    hashes, lines = stored()
    assert set(hashes) == {c.name for c in CASES} == set(lines)
    text = written(case, tmp_path)
    digest = hashlib.sha256(text).hexdigest()
    if digest != hashes[case.name]:
        pytest.fail(
            f"{case.name}: the G-code for {case.machine} {case.options or ''} changed: "
            f"{first_difference(text, lines[case.name])}"
        )
