"""``--out`` into a folder fabkit wrote before: refused, or ``--overwrite`` replaces exactly
the earlier run's files (listed in the folder's manifest), never anything else; and the
README's table lists every file a run writes."""

from __future__ import annotations

import fnmatch
import os
import re
from pathlib import Path

import pytest

from fabkit.files.atomic import MANIFEST
from tests.conftest import EXAMPLES, ROOT

DISC = ["--director", "arctan2(y, x)", "--shape", "disc:5"]
COARSE = ["--step", "0.1", "--diagonals", "30", "--size", "20", "--no-verify"]


def files(folder: Path) -> set[str]:
    """Every file under ``folder`` but the manifest, relative."""
    return {
        p.relative_to(folder).as_posix()
        for p in folder.rglob("*")
        if p.is_file() and p.name != MANIFEST
    }


def listed(folder: Path) -> set[str]:
    return set((folder / MANIFEST).read_text().split())


@pytest.mark.slow
def test_overwrite_removes_exactly_the_earlier_files(run_cli, tmp_path):
    out = tmp_path / "out"
    assert run_cli("toolpath", *DISC, "--out", out, "--json")[0] == 0
    assert "toolpath.json" in files(out) and listed(out) == files(out)
    code, _, err = run_cli("toolpath", *DISC, "--out", out)
    assert code == 2 and "of an earlier fabkit run" in err and "toolpath.json" in err
    assert run_cli("toolpath", *DISC, "--out", out, "--overwrite")[0] == 0
    assert "toolpath.json" not in files(out)  # the earlier run's file is gone ...
    assert (
        listed(out)
        == files(out)
        == {  # ... and the manifest lists this run's only
            "toolpath.npz",
            "quality.json",
            "preview.png",
            "preview.svg",
        }
    )


@pytest.mark.slow
def test_overwrite_with_bad_input_leaves_the_earlier_files(run_cli, tmp_path):
    out = tmp_path / "out"
    assert run_cli("toolpath", *DISC, "--out", out, "--json")[0] == 0
    before = {name: (out / name).read_bytes() for name in files(out)}
    code, _, err = run_cli(
        "toolpath", "--director", "foo(x)", "--shape", "disc:5", "--out", out, "--overwrite"
    )
    assert code == 2 and "foo" in err
    assert {name: (out / name).read_bytes() for name in files(out)} == before


@pytest.mark.slow
def test_an_interrupted_run_lists_what_it_wrote(run_cli, tmp_path, monkeypatch):
    """Ctrl-C halfway: the files written so far are listed, so --overwrite clears them."""
    real_replace = os.replace

    def interrupted(src, dst):
        if Path(dst).name == "preview.png":
            raise KeyboardInterrupt
        real_replace(src, dst)

    monkeypatch.setattr("fabkit.files.atomic.os.replace", interrupted)
    out = tmp_path / "out"
    assert run_cli("toolpath", *DISC, "--out", out)[0] == 130
    monkeypatch.setattr("fabkit.files.atomic.os.replace", real_replace)
    assert files(out) and files(out) <= listed(out)
    assert run_cli("toolpath", *DISC, "--out", out)[0] == 2
    assert run_cli("toolpath", *DISC, "--out", out, "--overwrite")[0] == 0
    assert listed(out) == files(out)


@pytest.mark.slow
def test_a_users_file_is_never_touched(run_cli, tmp_path):
    out = tmp_path / "out"
    assert run_cli("toolpath", *DISC, "--out", out)[0] == 0
    (out / "sub").mkdir()
    (out / "sub" / "mine.txt").write_text("mine\n")
    code, _, err = run_cli("toolpath", *DISC, "--out", out, "--overwrite")
    assert code == 2 and "fabkit did not write (sub/mine.txt)" in err
    assert (out / "sub" / "mine.txt").read_text() == "mine\n" and "preview.png" in files(out)


@pytest.mark.slow
def test_a_run_with_another_machine_leaves_no_file_of_the_first(run_cli, tmp_path):
    """The issue's case: G-code run, then a laser-writer run into the same --out."""
    out, spec = tmp_path / "out", EXAMPLES / "two_shapes.toml"
    assert run_cli("run", spec, "--out", out, *COARSE, "--layers", "1")[0] == 0
    assert {"sheet.gcode", "toolpath/toolpath.npz"} <= files(out) and (out / "as_designed").is_dir()
    # it leaves no shapes of its own; 5 mm: few pixels to write
    laser = ("--machine", "dmd_photoalign", "--no-simulate", "--size", "5")
    code, _, err = run_cli("run", spec, "--out", out, *COARSE, *laser)
    assert code == 2 and "give --overwrite" in err
    assert run_cli("run", spec, "--out", out, *COARSE, *laser, "--overwrite")[0] == 0
    names = files(out)
    assert "sheet.gcode" not in names and not (out / "toolpath").exists()
    assert not (out / "as_designed").exists()  # the first run's shapes went with it
    assert "laser/manifest.json" in names and listed(out) == names


@pytest.mark.slow
def test_laser_export_into_its_earlier_folder(run_cli, tmp_path):
    design = tmp_path / "design.npz"
    code, _, err = run_cli(
        "solve", EXAMPLES / "two_shapes.toml", "--out", design, "--step", "0.1",
        "--diagonals", "30",
    )  # fmt: skip
    assert code == 0, err
    args = ("export", design, "--machine", "dmd_photoalign", "--format", "laser", "--size", "5")
    out = tmp_path / "laser"
    assert run_cli(*args, "-o", out)[0] == 0
    assert listed(out) == files(out) and "manifest.json" in files(out)
    code, _, err = run_cli(*args, "-o", out)
    assert code == 2 and "give --overwrite" in err
    assert run_cli(*args, "-o", out, "--overwrite")[0] == 0
    assert listed(out) == files(out)


def readme_files() -> list[str]:
    """The README's table of the files ``fabkit run`` writes, as patterns (``NAME`` a
    target's name, a folder ``x/`` every file in it)."""
    readme = (ROOT / "README.md").read_text()
    table = readme.split("| file | what |", 1)[1].split("\n\n", 1)[0]
    rows = [line.split("|")[1] for line in table.splitlines()[2:]]
    names = [name for row in rows for name in re.findall(r"`([^`]+)`", row)]
    return [name.replace("NAME", "*") + ("*" if name.endswith("/") else "") for name in names]


@pytest.mark.slow
def test_the_readme_lists_every_file_a_run_writes(run_cli, tmp_path):
    out = tmp_path / "out"
    verified = [option for option in COARSE if option != "--no-verify"]
    assert run_cli("run", EXAMPLES / "two_shapes.toml", "--out", out, *verified)[0] == 0
    written = files(out) | {MANIFEST}
    patterns = readme_files()
    for name in written:
        assert any(fnmatch.fnmatch(name, p) for p in patterns), f"{name} is not in the README"
    for pattern in patterns:
        assert fnmatch.filter(written, pattern), f"the README lists {pattern}, not written"
    assert {"as_fabricated/sphere.ply", "as_fabricated/bump.png"} <= written
