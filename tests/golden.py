"""The stored toolpaths of the G-code guard (tests/test_gcode_identical.py), and how to
remake them.

Every case is a coarse toolpath (``tests/data/toolpaths/NAME.npz``) and the machine
profile and writer options its G-code is written with; the test writes each case's G-code
again from its stored toolpath and compares the SHA-256 of the bytes with
``tests/data/gcode_sha256.json``. The toolpaths are stored rather than remade in the test
because the solve's last digits may drift with the (unpinned) versions of numpy, scipy and
numba; the writer is then the only thing under test.

Remake the toolpaths (only when their inputs change: the examples, the planner, the
toolpath format), from the repository root::

    python -m tests.golden

which runs every example below through ``fabkit run`` / ``fabkit swimmer`` on coarse
settings, keeps each run's ``toolpath.npz`` and checks that the G-code the run wrote is
byte for byte the G-code written again from the stored file; then remake the hashes::

    FABKIT_UPDATE_GOLDEN=1 python -m pytest -n 0 tests/test_gcode_identical.py

Remake the hashes alone (with the toolpaths kept) only after an intended change of the
G-code, and say so in the commit.
"""

from __future__ import annotations

import shutil
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "tests" / "data"
TOOLPATHS = DATA / "toolpaths"
HASHES = DATA / "gcode_sha256.json"
COARSE = ["--step", "0.1", "--diagonals", "30", "--no-verify", "--layers", "1"]
"""``fabkit run`` settings of the stored toolpaths: a coarse solve, no read-back (the
guard needs only the toolpath) and one layer (the swimmer prints two); each example
adds a small ``--size`` (mm) to keep the stored files small (a few hundred KB in all)."""


@dataclass(frozen=True)
class Example:
    """A stored toolpath: ``name`` (its file), the command that makes it (``fabkit`` and
    its arguments, ``OUT`` for the output folder), the G-code file that command writes and
    the machine it writes it for (every example's default; :func:`make` checks it)."""

    name: str
    command: tuple[str, ...]
    gcode: str = "sheet.gcode"
    machine: str = "marlin_diw_pneumatic"


EXAMPLES = (
    Example(
        "two_shapes", ("run", "examples/two_shapes.toml", "--out", "OUT", "--size", "20", *COARSE)
    ),
    Example(
        "three_shapes",
        ("run", "examples/three_shapes.toml", "--out", "OUT", "--size", "12", *COARSE),
    ),
    Example(
        "three_shapes_joint",
        (
            "run",
            "examples/three_shapes.toml",
            "--out",
            "OUT",
            "--process",
            "examples/processes/fig3_joint.toml",
            "--size",
            "12",
            *COARSE,
        ),
    ),
    Example(
        "two_shapes_lce",
        (
            "run",
            "examples/two_shapes.toml",
            "--out",
            "OUT",
            "--process",
            "examples/directors/process_lce.toml",
            "--size",
            "20",
            *COARSE,
        ),
    ),
    Example("swimmer", ("swimmer", "SWIMMER", "--out", "OUT"), gcode="swimmer.gcode"),
)
"""Every example of examples/README.md whose machine file is G-code (the baromorph gives a
DXF, the photoalignment runs laser patterns; ``fabkit toolpath`` alone writes no G-code),
but Fig. 3 with processes/fig3_lce_hydrogel.toml: its toolpath carries the same channels
as Fig. 3's own (print speed and ink share) on the same machine, so it would add nothing
to the writer's cover but 60 KB."""


@dataclass(frozen=True)
class Case:
    """One G-code file of the guard: the stored ``toolpath`` written for ``machine`` with
    the :class:`~fabkit.writers.gcode.GcodeOptions` ``options``."""

    name: str
    toolpath: str
    machine: str
    options: dict[str, object] = field(default_factory=dict)


PROFILE_TOOLPATH = "two_shapes"
"""The stored toolpath every G-code profile of machines/ writes (its one channel, the
print speed, is one every G-code machine carries)."""
PROFILES = (
    "marlin_diw_pneumatic",
    "marlin_generic",
    "klipper_generic",
    "grbl_diw",
    "hyrel_pulse",
)
"""The profiles of machines/ that take G-code (flavours marlin, klipper, grbl, hyrel);
dmd_photoalign (flavour none), laser_cutter and scan_photoalign (laser writers) take
none."""


def cases() -> tuple[Case, ...]:
    """Every G-code file the guard writes: each example for its own machine (as its command
    writes it), the profile toolpath for every G-code profile, and the writer's options
    the profiles do not choose (relative E on marlin_generic, E in volume and in pulses,
    nominal E in relative and absolute mode)."""
    own = [Case(e.name, e.name, e.machine) for e in EXAMPLES]
    profiles = [Case(f"{PROFILE_TOOLPATH}@{p}", PROFILE_TOOLPATH, p) for p in PROFILES[1:]]
    options = [
        Case("two_shapes@marlin_generic+relative", PROFILE_TOOLPATH, "marlin_generic",
             {"e_mode": "relative"}),
        Case("two_shapes@klipper_generic+volume", PROFILE_TOOLPATH, "klipper_generic",
             {"e_units": "volume"}),
        Case("two_shapes@klipper_generic+pulses", PROFILE_TOOLPATH, "klipper_generic",
             {"e_units": "pulses", "pulses_per_mm3": 2.0}),
        Case("two_shapes@marlin_diw_pneumatic+nominal_e", PROFILE_TOOLPATH,
             "marlin_diw_pneumatic", {"nominal_e": True}),
        Case("three_shapes@marlin_diw_pneumatic+nominal_e", "three_shapes",
             "marlin_diw_pneumatic", {"nominal_e": True, "e_mode": "absolute"}),
    ]  # fmt: skip
    return (*own, *profiles, *options)


def coarse_swimmer(folder: Path) -> Path:
    """examples/swimmer.toml with small meshes (as tests/test_examples.py runs it) and half
    its radius (a quarter of the toolpath to store)."""
    text = (ROOT / "examples" / "swimmer.toml").read_text()
    replaced = [("rings = 12", "rings = 5"), ("rings = 20", "rings = 7")]
    for old, new in [*replaced, ("radius = 10.0 ", "radius = 5.0 ")]:
        assert old in text, old
        text = text.replace(old, new)
    path = folder / "swimmer.toml"
    path.write_text(text)
    return path


def make(names: list[str]) -> None:
    """Run the named examples (all when empty) and store their toolpaths."""
    from fabkit.cli import main
    from fabkit.machines import load_machine
    from fabkit.swimmer.fabricate import fabrication_settings
    from fabkit.swimmer.spec import load_swimmer
    from fabkit.toolpath.model import load_toolpath
    from fabkit.writers.gcode import gcode_bytes

    TOOLPATHS.mkdir(parents=True, exist_ok=True)
    table = load_swimmer(ROOT / "examples" / "swimmer.toml").fabrication
    if fabrication_settings(table).machine != EXAMPLES[-1].machine:
        raise SystemExit("examples/swimmer.toml prints on another machine: update EXAMPLES")
    for example in EXAMPLES:
        if names and example.name not in names:
            continue
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "out"
            swimmer = str(coarse_swimmer(Path(tmp)))
            args = [
                str(out) if a == "OUT" else swimmer if a == "SWIMMER" else a
                for a in example.command
            ]
            print("fabkit", " ".join(args), flush=True)
            if main(args) != 0:
                raise SystemExit(f"{example.name}: the command failed")
            source = out / "toolpath" / "toolpath.npz"
            if not source.is_file():
                source = out / "toolpath.npz"
            target = TOOLPATHS / f"{example.name}.npz"
            shutil.copyfile(source, target)
            written = (out / example.gcode).read_bytes()
            again, _ = gcode_bytes(load_toolpath(target), load_machine(example.machine))
            if written != again:
                raise SystemExit(
                    f"{example.name}: the G-code written again from the stored toolpath "
                    "differs from the run's"
                )
            print(f"  {target.relative_to(ROOT)}: {target.stat().st_size} bytes", flush=True)


if __name__ == "__main__":
    make(sys.argv[1:])
