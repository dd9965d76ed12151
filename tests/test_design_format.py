"""design.npz carries a format tag (like toolpath.npz); untagged files are format 1."""

from __future__ import annotations

import numpy as np
import pytest

from fabkit.design.design import FORMAT, Design
from fabkit.errors import FabkitError
from tests.conftest import coarse_design


@pytest.fixture(scope="module")
def saved(tmp_path_factory) -> tuple:
    """A coarse Fig. 1 design written by this version, and its arrays as read by numpy."""
    path = tmp_path_factory.mktemp("format") / "design.npz"
    coarse_design(diagonals=20).save(path)
    with np.load(path, allow_pickle=False) as data:
        return path, {key: data[key] for key in data.files}


def test_a_written_design_carries_the_format_tag(saved):
    _, arrays = saved
    assert str(arrays["format"]) == FORMAT == "fabkit-design/2"


def test_an_untagged_design_reads_as_format_1(saved, tmp_path):
    path, arrays = saved
    np.savez_compressed(tmp_path / "old.npz", **{k: v for k, v in arrays.items() if k != "format"})
    old, new = Design.load(tmp_path / "old.npz"), Design.load(path)
    assert np.array_equal(old.r, new.r, equal_nan=True) and old.spec == new.spec


def test_a_foreign_tag_is_refused_in_one_line(saved, tmp_path):
    _, arrays = saved
    np.savez_compressed(tmp_path / "next.npz", **{**arrays, "format": np.array("fabkit-design/3")})
    with pytest.raises(FabkitError, match="format 'fabkit-design/3'") as caught:
        Design.load(tmp_path / "next.npz")
    assert "\n" not in str(caught.value)


@pytest.mark.slow
def test_export_still_tells_a_design_from_a_toolpath(saved, run_cli, tmp_path):
    path, _ = saved
    out = tmp_path / "mask"
    code, _, err = run_cli(
        "export",
        path,
        "--machine",
        "dmd_photoalign",
        "--format",
        "laser",
        "--size",
        "5",  # mm: a small mask set (at 30 mm, 2.5M pixels and 18 s)
        "--out",
        out,
    )
    assert code == 0, err
    assert list(out.glob("*.png"))
