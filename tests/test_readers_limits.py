"""The readers' limits: each one holds at its boundary, is documented, and leaves fabkit's
own files well inside it; and names never become paths outside the output folder."""

from __future__ import annotations

import ast
import os
import re
import threading
import time
import zipfile

import numpy as np
import pytest

from fabkit import limits
from fabkit.design.design import Design
from fabkit.design.patches import patch_paths
from fabkit.errors import FabkitError
from fabkit.files.atomic import inside
from fabkit.files.npzfile import read_npz
from fabkit.files.readfile import parse_json, read_limited, size_text
from fabkit.files.tomlfile import read_toml, scan_depth
from fabkit.machines import GCODE_KEYS, list_machines
from fabkit.problem.spec import build_spec, load_spec
from tests import hostile as h
from tests.conftest import EXAMPLES, ROOT, coarse_design, example_table


def limit_names() -> list[str]:
    """The constants fabkit/limits.py defines (except the unit sizes MIB and GIB)."""
    tree = ast.parse((ROOT / "fabkit" / "limits.py").read_text())
    names = [t.id for node in tree.body if isinstance(node, ast.Assign) for t in node.targets]
    return [name for name in names if name not in ("MIB", "GIB")]


def test_every_limit_is_listed_in_troubleshooting():
    section = (ROOT / "docs" / "troubleshooting.md").read_text().split("## Limits")[1]
    missing = [name for name in limit_names() if f"`{name}`" not in section]
    assert missing == []


@pytest.fixture(scope="module")
def design_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("limits") / "design.npz"
    coarse_design().save(path)
    return path


# ----------------------------------------------------------------------------- text


def test_toml_nesting_is_refused_just_past_the_limit(tmp_path):
    depth = limits.NESTING_DEPTH
    for kind in ("array", "inline", "dotted", "header"):
        path = tmp_path / f"{kind}.toml"
        path.write_text(h.deep_toml(kind, depth - 1))
        read_toml(path, "spec")
        path.write_text(h.deep_toml(kind, depth + 1))
        with pytest.raises(FabkitError, match="nested deeper than 32 levels"):
            read_toml(path, "spec")


def test_brackets_in_strings_and_comments_do_not_count():
    text = b"a = \"[[[[{{{{\" # [[[[[[\nb = '[[['\nc = \"\"\"\n[[[[\n\"\"\"\nd = '''{{{'''\n"
    assert scan_depth(text) == 0


@pytest.mark.parametrize(
    "text",
    [b'"\\' * 1_300_000, b'"""' + b'"\\' * 1_300_000, b"'" * 4_000_000, b'[""' * 1_300_000],
    ids=["open-basic-strings", "open-multiline", "quotes", "many-strings"],
)
def test_the_depth_scan_is_linear_on_hostile_text(text):
    start = time.perf_counter()
    scan_depth(text)
    assert time.perf_counter() - start < 5.0  # a quadratic scan takes hours here


def test_text_over_the_size_limit_is_refused_before_it_is_read(tmp_path):
    path = h.sparse(tmp_path / "big.toml", limits.TEXT_BYTES + 1)
    with pytest.raises(FabkitError, match="more than the limit of 1.0 MB"):
        read_toml(path, "spec")
    path = h.sparse(tmp_path / "fits.toml", limits.TEXT_BYTES, b"# ")
    with pytest.raises(FabkitError, match="not valid TOML"):  # read whole: NUL bytes
        read_toml(path, "spec")


def test_a_fifo_is_refused_without_blocking(tmp_path):
    fifo = tmp_path / "spec.toml"
    os.mkfifo(fifo)
    result = []
    reader = threading.Thread(target=lambda: result.append(_error(read_limited, fifo)))
    reader.start()
    reader.join(5)
    assert not reader.is_alive() and "not a regular file" in result[0]


def _error(function, *args) -> str:
    try:
        function(*args, "spec file", 100)
    except FabkitError as exc:
        return str(exc)
    return ""


def test_json_nesting_is_refused_at_any_depth():
    parse_json(h.deep_json(limits.NESTING_DEPTH), "x")
    for depth in (limits.NESTING_DEPTH + 1, 500, 100_000):
        with pytest.raises(FabkitError, match="nested deeper than"):
            parse_json(h.deep_json(depth), "x")


def test_sizes_read_as_people_read_them():
    assert [size_text(n) for n in (512, 4 << 20, 10 << 30, 3 << 40)] == [
        "512 B",
        "4.0 MB",
        "10.0 GB",
        "3.0 TB",
    ]


# ----------------------------------------------------------------------------- npz


def test_fabkit_s_own_archives_stay_well_inside_the_ratio_limit(design_file):
    with zipfile.ZipFile(design_file) as archive:
        ratios = [i.file_size / i.compress_size for i in archive.infolist()]
    assert max(ratios) < limits.COMPRESSION_RATIO


def test_the_member_count_limit(tmp_path):
    members = {f"a{k}.npy": h.npy_bytes(np.zeros(1)) for k in range(limits.ARCHIVE_MEMBERS)}
    assert len(read_npz(h.write_npz(tmp_path / "fits.npz", members), "x")) == 64
    members["one_more.npy"] = h.npy_bytes(np.zeros(1))
    with pytest.raises(FabkitError, match="more than the limit of 64 members"):
        read_npz(h.write_npz(tmp_path / "over.npz", members), "x")


def test_the_declared_size_limit_counts_every_member(tmp_path):
    """Two stored (ratio 1) members that each fit the limit and together do not."""
    half = limits.ARCHIVE_BYTES // 2 + 1024
    path = tmp_path / "two.npz"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as archive:
        for key in ("a", "b"):
            archive.writestr(f"{key}.npy", h.npy_header((half // 8,)) + bytes(64))
            info = archive.getinfo(f"{key}.npy")
            info.file_size = info.compress_size = half
    with pytest.raises(FabkitError, match="its arrays would take 1.0 GB in memory"):
        read_npz(path, "x")


def test_a_header_is_checked_before_any_data_is_read(tmp_path):
    """A lying 80 GB header is refused without allocating: this would fail with a
    MemoryError or take minutes if numpy were asked to read it."""
    members = {"z.npy": h.npy_header((100_000, 100_000)) + bytes(64)}
    path = h.write_npz(tmp_path / "lying.npz", members)
    seen = []
    with pytest.raises(FabkitError, match="declares a 100000 x 100000 float64 array"):
        read_npz(path, "x", check=seen.append)
    assert seen == []


def test_the_key_check_comes_before_any_header(tmp_path, design_file):
    toolpath_like = h.write_npz(tmp_path / "t.npz", {"format.npy": h.npy_bytes(np.array("x"))})
    with pytest.raises(FabkitError, match="not a fabkit design file"):
        Design.load(toolpath_like)


def test_values_outside_valid_points_become_nan(tmp_path, design_file):
    arrays = h.arrays_of(design_file)
    arrays["alpha"] = np.where(arrays["valid"], arrays["alpha"], 1e300)
    np.savez(tmp_path / "outside.npz", **arrays)
    design = Design.load(tmp_path / "outside.npz")
    assert np.isnan(design.alpha[~design.valid]).all()
    assert np.array_equal(design.alpha[design.valid], arrays["alpha"][arrays["valid"]])


# ----------------------------------------------------------------------------- names


@pytest.mark.parametrize("name", ["x/../../name", "../up", "/tmp/abs", "a\\b", "..", ""])
def test_a_name_that_would_leave_the_folder_is_refused(name, tmp_path):
    table = example_table("two_shapes.toml")
    spec = build_spec(table, ROOT)
    target = spec.targets[1]
    renamed = type(target)(name, target.surface, target.stimulus, target.start, target.director)
    with pytest.raises(FabkitError, match="must be 1-64 letters"):
        patch_paths([spec.targets[0], renamed], tmp_path / "patches")


def test_mesh_files_stay_inside_their_folder(tmp_path):
    spec = load_spec(EXAMPLES / "two_shapes.toml")
    paths = patch_paths(spec.targets, tmp_path / "patches", "ply")
    names = [p.name for _, p in paths]
    assert names == ["0_flat.ply", "1_sphere.ply", "2_bump.ply"]
    with pytest.raises(FabkitError, match="outside the output folder"):
        patch_paths(spec.targets, tmp_path / "patches", "ply/../../../x")
    assert inside(tmp_path, "a.ply") == tmp_path / "a.ply"


# ----------------------------------------------------------------------------- profiles


def test_shipped_templates_render_well_inside_the_limits():
    for profile in list_machines():
        if profile.gcode is None:
            continue
        for key in GCODE_KEYS:
            lines = profile.render(key)
            assert all(len(line) <= limits.TEMPLATE_LINE_CHARS // 4 for line in lines)


def test_a_template_with_a_format_spec_is_refused(tmp_path):
    from fabkit.machines import load_machine

    text = (ROOT / "machines" / "marlin_generic.toml").read_text()
    for field in ("{bed_c:>9}", "{bed_c!s}", "{bed_c:{nozzle_c}}", "{bed_c:.3}"):
        path = tmp_path / "profile.toml"
        path.write_text(text.replace("{bed_c}", field, 1))
        with pytest.raises(
            FabkitError,
            match=re.escape("gcode.start_gcode: expected plain {bed_c}, got a format spec"),
        ):
            load_machine(path)


# ----------------------------------------------------------------------------- meshes


def test_a_mesh_never_opens_the_files_it_names(tmp_path, monkeypatch, capsys):
    """An OBJ's material library and a PLY's TextureFile may name a decompression bomb
    (or any file): the mesh is read from its own bytes, nothing else is opened."""
    import PIL.Image
    import trimesh

    from fabkit.problem.surfaces.meshes import read_mesh

    h.png_bomb(tmp_path / "texture.png", 12_000)
    (tmp_path / "m.mtl").write_text("newmtl a\nmap_Kd texture.png\n")
    grid = trimesh.load(h.grid_stl(tmp_path / "grid.stl", side=6), force="mesh")
    obj = grid.export(file_type="obj").replace("v ", "mtllib m.mtl\nusemtl a\nv ", 1)
    (tmp_path / "m.obj").write_text(obj)
    ply = grid.export(file_type="ply", encoding="ascii").decode()
    texture = "format ascii 1.0\ncomment TextureFile texture.png\n"
    (tmp_path / "m.ply").write_text(ply.replace("format ascii 1.0\n", texture, 1))

    opened = []

    def refuse(*args, **kwargs):
        opened.append(args)
        raise OSError("no image may be opened")

    monkeypatch.setattr(PIL.Image, "open", refuse)
    for name in ("m.obj", "m.ply"):
        vertices, faces = read_mesh(tmp_path / name, "surfaces[1].geometry")
        assert len(faces) == len(grid.faces) and np.isfinite(vertices).all()
    assert opened == []
    assert capsys.readouterr().err == ""
