"""One wording for every mistake in every TOML file fabkit reads (fabkit/files/tomlfile.py).

Each row edits a shipped file of one of the six kinds (spec, machine profile, process,
baromorph, swimmer, director), loads it through its public loader, and checks the one
line against the common format: ``FILE: KEY PATH: expected WHAT, got FOUND``,
``FILE: KEY PATH: missing (expected WHAT)`` or ``FILE: KEY PATH: unknown key (allowed:
...)``.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from fabkit.errors import FabkitError
from fabkit.field.director_file import load_director_file
from fabkit.machines import MACHINES_DIR, load_machine
from fabkit.problem.spec import load_spec
from fabkit.swimmer.spec import load_swimmer
from fabkit.toolpath.baromorph import load_baromorph
from fabkit.toolpath.process_file import load_process
from tests.conftest import ROOT

EXAMPLES = ROOT / "examples"

KINDS = {
    "spec": (EXAMPLES / "two_shapes.toml", load_spec),
    "machine": (MACHINES_DIR / "marlin_generic.toml", load_machine),
    "process": (EXAMPLES / "processes" / "fig3_lce_hydrogel.toml", load_process),
    "baromorph": (EXAMPLES / "baromorph_channels.toml", load_baromorph),
    "swimmer": (EXAMPLES / "swimmer.toml", load_swimmer),
    "director": (EXAMPLES / "directors" / "azimuthal.toml", load_director_file),
}

FORMAT = re.compile(
    r"^(?P<file>[^\n]+?\.toml): (?P<key>[\w.\[\]]+): "
    r"(?:expected (?P<expected>.+), got (?P<found>.+)"
    r"|missing \(expected (?P<needed>.+)\)"
    r"|unknown key \(allowed: (?P<allowed>.+)\))$"
)

WRONG, MISSING, UNKNOWN = "wrong", "missing", "unknown"

# (kind, old text, new text, key path, mistake, fragment of what was found or allowed)
ROWS = [
    ("spec", "step = 0.05", 'step = "fine"', "solver.step", WRONG, "'fine' (a string)"),
    ("spec", "radius = 1.0 }", "radius = nan }", "surfaces[1].geometry.radius", WRONG, "nan"),
    ("spec", "step = 0.05", "step = -0.05", "solver.step", WRONG, "-0.05"),
    ("spec", "diagonals = 200", "diagonals = 200\nstpe = 1", "solver.stpe", UNKNOWN, "step"),
    ("spec", "stimulus = [2]\n", "", "surfaces[2].stimulus", MISSING, ""),
    ("machine", "x_mm_s = 300", 'x_mm_s = "fast"', "limits.x_mm_s", WRONG, "'fast' (a string)"),
    ("machine", "z_mm_s = 5", "z_mm_s = -5", "limits.z_mm_s", WRONG, "-5"),
    ("machine", "z_mm_s = 5", "z_mm_s = inf", "limits.z_mm_s", WRONG, "inf"),
    ("machine", "[envelope]", 'colour = "red"\n[envelope]', "colour", UNKNOWN, "flavour"),
    ("machine", "y_mm_s = 300\n", "", "limits.y_mm_s", MISSING, ""),
    (
        "process",
        "road_width_mm = 0.41",
        'road_width_mm = "wide"',
        "process.road_width_mm",
        WRONG,
        "'wide' (a string)",
    ),
    (
        "process",
        "layer_height_mm = 0.3",
        "layer_height_mm = -0.3",
        "process.layer_height_mm",
        WRONG,
        "-0.3",
    ),
    ("process", "eps = [0.0, 0.2,", "eps = [nan, 0.2,", "process.encode[0].eps[0]", WRONG, "nan"),
    (
        "process",
        "travel_speed_mm_s = 30",
        "travel_speed_mm_s = 30\ncolour = 1",
        "process.colour",
        UNKNOWN,
        "road_width_mm",
    ),
    ("process", "print_speed_mm_s = 8\n", "", "process.print_speed_mm_s", MISSING, ""),
    (
        "baromorph",
        "pitch_mm = 3.0",
        'pitch_mm = "wide"',
        "baromorph.pitch_mm",
        WRONG,
        "'wide' (a string)",
    ),
    ("baromorph", "min_wall_mm = 0.6", "min_wall_mm = nan", "baromorph.min_wall_mm", WRONG, "nan"),
    ("baromorph", "plate_mm = 3.0", "plate_mm = -3.0", "baromorph.plate_mm", WRONG, "-3.0"),
    (
        "baromorph",
        "border_mm = 4.0",
        "border_mm = 4.0\ncolour = 1",
        "baromorph.colour",
        UNKNOWN,
        "pitch_mm",
    ),
    ("baromorph", "manifold_width_mm = 2.0", "", "baromorph.manifold_width_mm", MISSING, ""),
    ("swimmer", "radius = 10.0", 'radius = "big"', "sheet.radius", WRONG, "'big' (a string)"),
    ("swimmer", "young = 1.0e6", "young = -1.0", "mechanics.young", WRONG, "-1.0"),
    ("swimmer", "viscosity = 1.0", "viscosity = nan", "hydrodynamics.viscosity", WRONG, "nan"),
    ("swimmer", "[sheet]", "[sheet]\ncolour = 1", "sheet.colour", UNKNOWN, "radius, thickness"),
    ("swimmer", "thickness = 0.6", "", "sheet.thickness", MISSING, ""),
    (
        "director",
        'shape = "disc:10"',
        'outline = [[0, 0], [10, 0], [10, "a"]]',
        "director.outline[2][1]",
        WRONG,
        "'a' (a string)",
    ),
    (
        "director",
        'shape = "disc:10"',
        "outline = [[0, 0], [10, 0], [10, nan]]",
        "director.outline[2][1]",
        WRONG,
        "nan",
    ),
    (
        "director",
        'shape = "disc:10"',
        'shape = "disc:10"\ncolour = 1',
        "director.colour",
        UNKNOWN,
        "theta",
    ),
    ("director", 'theta = "phi + pi/2"\n', "", "director.theta", MISSING, ""),
]


def _write(tmp_path: Path, kind: str, old: str, new: str) -> Path:
    source, _ = KINDS[kind]
    text = source.read_text()
    assert old in text, (kind, old)
    path = tmp_path / f"bad_{kind}.toml"
    path.write_text(text.replace(old, new, 1))
    return path


def test_every_kind_is_covered_for_every_mistake():
    covered = {(row[0], row[4]) for row in ROWS}
    assert covered == {(kind, m) for kind in KINDS for m in (WRONG, MISSING, UNKNOWN)}
    for kind in KINDS:  # a string where a number belongs, and nan or a negative value
        found = [row[5] for row in ROWS if row[0] == kind and row[4] == WRONG]
        assert any("(a string)" in f for f in found), kind
        assert any(f in ("nan", "inf") or f.startswith("-") for f in found), kind


@pytest.mark.parametrize(
    ("kind", "old", "new", "key", "mistake", "fragment"),
    ROWS,
    ids=[f"{row[0]}-{row[4]}-{row[3]}" for row in ROWS],
)
def test_one_wording_per_mistake(tmp_path, kind, old, new, key, mistake, fragment):
    path = _write(tmp_path, kind, old, new)
    _, load = KINDS[kind]
    with pytest.raises(FabkitError) as info:
        load(path)
    message = str(info.value)
    assert "\n" not in message
    match = FORMAT.match(message)
    assert match, message
    assert Path(match["file"]).name == path.name, message
    assert match["key"] == key, message
    if mistake == WRONG:
        assert match["expected"] and fragment in match["found"], message
    elif mistake == MISSING:
        assert match["needed"], message
    else:
        assert fragment in match["allowed"], message


def _row(key: str) -> tuple:
    return next(row for row in ROWS if row[3] == key)


@pytest.mark.parametrize(
    ("arguments", "row"),
    [
        (("spec", "{path}"), _row("solver.step")),
        (("swimmer", "{path}", "--out", "{out}"), _row("sheet.radius")),
    ],
    ids=["spec", "swimmer"],
)
def test_the_command_line_prints_the_one_line(tmp_path, run_cli, arguments, row):
    kind, old, new, key, *_ = row
    path = _write(tmp_path, kind, old, new)
    out = tmp_path / "out"
    code, _, err = run_cli(*(a.format(path=path, out=out) for a in arguments))
    assert code == 2
    lines = err.splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith("fabkit: error: ")
    message = lines[0].removeprefix("fabkit: error: ")
    assert FORMAT.match(message) and f": {key}: expected " in message, message
    assert not out.exists()
