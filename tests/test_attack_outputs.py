"""Output folders: a folder holding an earlier run's files, or anyone else's, is refused.

Every command that writes a folder (``run``, ``plot``, ``toolpath``, ``channels``,
``swimmer``, laser ``export``, ``compare``) claims it first
(:func:`fabkit.files.atomic.output_folder`):
without ``--overwrite`` an earlier fabkit run's files there are a one-line error naming
them; a file fabkit did not write there is a one-line error even with ``--overwrite``.
Each row must leave the folder exactly as it was. Then the behaviour behind the rows:
``--overwrite`` removes exactly the earlier run's files (the second machine's run leaves
no first machine's G-code beside its laser patterns), and never anything else.
"""

from __future__ import annotations

import pytest

from fabkit.files.atomic import MANIFEST
from tests.attack import assert_refused, case
from tests.conftest import EXAMPLES, coarse_design

pytestmark = pytest.mark.filterwarnings("error")  # a warning would be a second line on stderr

COARSE = "--step 0.1 --diagonals 30 --size 20"
TWO = EXAMPLES / "two_shapes.toml"
DISC = "--director arctan2(y,x) --shape disc:5"

_COMMANDS = {
    "run": f"run {TWO} {COARSE} --out",
    "plot": "plot {design} --out",
    "toolpath": f"toolpath {DISC} --out",
    "channels": f"channels {DISC} --baromorph {EXAMPLES / 'baromorph_channels.toml'} --out",
    "swimmer": f"swimmer {EXAMPLES / 'swimmer.toml'} --no-convergence --out",
    "export": "export {design} --machine dmd_photoalign --format laser --size 20 -o",
    "compare": f"compare {EXAMPLES / 'data' / 'sphere_scan.ply'} {{run}} --target sphere "
    "--units m --out",
}

_OCCUPIED = {
    "earlier-run": ("{earlier}", ("of an earlier fabkit run", "give --overwrite", "preview.png")),
    "foreign-file": ("{foreign} --overwrite", ("fabkit did not write", "notes.txt")),
}
"""Two ways a folder is occupied: the ``--out`` argument naming it, and what the refusal names."""

CASES = [
    *[
        case(f"{command} {folder}", *says, outputs=(), id=f"outputs-{name}-{kind}")
        for kind, (folder, says) in _OCCUPIED.items()
        for name, command in _COMMANDS.items()
    ],
    case(
        f"toolpath {DISC} --out {{escaping}} --overwrite",
        "fabkit did not write",
        "link",
        outputs=(),
        id="outputs-listed-link",
    ),
]


def snapshot(folder) -> dict[str, bytes]:
    """Every file under ``folder`` by relative name, with its bytes."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


@pytest.fixture(scope="module")
def places(folder) -> dict[str, str]:
    """A design, a folder with an earlier toolpath run, one with a user's file beside it,
    and one whose manifest names a link to a file outside it, and that file itself."""
    from fabkit.cli import main

    coarse_design().save(folder / "design.npz")
    earlier = folder / "earlier"
    assert main(["toolpath", *DISC.split(), "--out", str(earlier)]) == 0
    foreign = folder / "foreign"
    assert main(["toolpath", *DISC.split(), "--out", str(foreign)]) == 0
    (foreign / "notes.txt").write_text("the user's own notes\n")
    escaping = folder / "escaping"
    escaping.mkdir()
    (folder / "precious.txt").write_text("not fabkit's\n")
    (escaping / "link").symlink_to(folder / "precious.txt")
    (escaping / MANIFEST).write_text("link\n../precious.txt\n")
    return {
        "design": str(folder / "design.npz"),
        "earlier": str(earlier),
        "foreign": str(foreign),
        "escaping": str(escaping),
        "root": str(folder),
        "run": str(EXAMPLES.parent / "tests" / "data" / "compare_run"),
    }


@pytest.mark.parametrize("bad", CASES)
def test_an_occupied_output_folder_is_refused_and_left_alone(bad, places, run_cli, tmp_path):
    from pathlib import Path

    root = Path(places["root"])
    before = snapshot(root)
    assert_refused(bad, places, tmp_path, run_cli)
    assert snapshot(root) == before
