"""Property tests over every file reader: any bytes give a valid object or a FabkitError.

Each reader gets random mutations (flipped, inserted and deleted bytes, truncation) of a
valid file of its kind, and some gets wholly random input: it must return what it
returns for a good file or raise :class:`FabkitError` with a one-line message, never
another exception, and quickly. Round trips check that what the readers accept is read
exactly.
"""

from __future__ import annotations

import io
import json
import struct
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from fabkit.design.design import Design
from fabkit.errors import FabkitError
from fabkit.files.npzfile import NUMBER_KINDS, read_npy, read_npz
from fabkit.files.readfile import nesting_depth, parse_json
from fabkit.files.tomlfile import Table, read_toml, scan_depth
from fabkit.machines import MachineProfile, load_machine
from fabkit.problem.surfaces.grids import read_grid
from fabkit.problem.surfaces.meshes import read_mesh
from fabkit.swimmer.spec import SwimmerSpec, load_swimmer
from fabkit.toolpath.baromorph import BaromorphSettings, load_baromorph
from fabkit.toolpath.job import ToolpathJob, run_job
from fabkit.toolpath.model import Toolpath, load_toolpath
from fabkit.toolpath.process_file import Process, load_process
from fabkit.writers.export import load_geometry
from tests import hostile as h
from tests.conftest import EXAMPLES, ROOT, coarse_design

SECONDS = 5.0
"""Most time one read may take (a safety bound on a shared 2-core machine)."""
FEW = settings(
    max_examples=40,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)


@st.composite
def mutated(draw, base: bytes) -> bytes:
    """``base`` with a few random edits: flipped, inserted or deleted bytes, or cut short."""
    data = bytearray(base)
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["flip", "insert", "delete", "truncate"]))
        at = draw(st.integers(0, max(len(data) - 1, 0)))
        if kind == "flip" and data:
            data[at] ^= draw(st.integers(1, 255))
        elif kind == "insert":
            data[at:at] = draw(st.binary(min_size=1, max_size=16))
        elif kind == "delete":
            del data[at : at + draw(st.integers(1, 64))]
        else:
            del data[at:]
    return bytes(data)


def refused_or(read, expected: type | tuple[type, ...]):
    """``read()`` is an ``expected`` object or a one-line FabkitError, within SECONDS, and
    prints no warning (a warning is a second line on the command line's stderr)."""
    start = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            result = read()
        except FabkitError as exc:
            assert "\n" not in str(exc) and str(exc)
            result = None
    assert time.perf_counter() - start < SECONDS
    assert [str(w.message) for w in caught] == []
    assert result is None or isinstance(result, expected), type(result)
    return result


@pytest.fixture(scope="module")
def design_file(folder) -> Path:
    path = folder / "design.npz"
    coarse_design(step=0.2, diagonals=10).save(path)
    return path


@pytest.fixture(scope="module")
def toolpath_file(folder) -> Path:
    run_job(ToolpathJob(director="arctan2(y, x)", shape="disc:3", out=str(folder / "tp")))
    return folder / "tp" / "toolpath.npz"


def written(folder: Path, name: str, data: bytes) -> Path:
    path = folder / name
    path.write_bytes(data)
    return path


# ----------------------------------------------------------------------------- TOML


TOML_READERS = {
    "spec": (EXAMPLES / "two_shapes.toml", lambda p: read_toml(p, "spec"), dict),
    "machine": (ROOT / "machines" / "marlin_generic.toml", load_machine, MachineProfile),
    "process": (EXAMPLES / "directors" / "process_lce.toml", load_process, Process),
    "baromorph": (EXAMPLES / "baromorph_channels.toml", load_baromorph, BaromorphSettings),
    "swimmer": (EXAMPLES / "swimmer.toml", load_swimmer, SwimmerSpec),
}


@pytest.mark.slow
@pytest.mark.parametrize("kind", list(TOML_READERS))
@FEW
@given(data=st.data())
def test_a_mutated_toml_file_is_read_or_refused(kind, data, folder):
    source, read, expected = TOML_READERS[kind]
    text = data.draw(mutated(source.read_bytes()))
    path = written(folder, f"mutated_{kind}.toml", text)
    refused_or(lambda: read(path), expected)


@FEW
@given(text=st.binary(max_size=400))
def test_random_bytes_as_toml_are_read_or_refused(text, folder):
    path = written(folder, "random.toml", text)
    refused_or(lambda: read_toml(path, "spec"), dict)


scalars = st.one_of(
    st.integers(-(10**6), 10**6),
    st.floats(-1e6, 1e6, allow_nan=False),
    st.text(max_size=8),
    st.booleans(),
)
values = st.recursive(
    scalars,
    lambda inner: (
        st.lists(inner, max_size=3)
        | st.dictionaries(st.from_regex(r"[a-z]{1,4}", fullmatch=True), inner, max_size=3)
    ),
    max_leaves=12,
)


def inline(value) -> str:
    """``value`` as an inline TOML value."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(inline(v) for v in value) + "]"
    return "{" + ", ".join(f"{k} = {inline(v)}" for k, v in value.items()) + "}"


@pytest.mark.slow
@settings(max_examples=200, deadline=None)
@given(value=values)
def test_the_depth_scan_sees_the_nesting_of_any_value(value):
    text = f"a = {inline(value)}\n".encode()
    # a float's decimal point counts as a dot: the scan may see one level more, never less
    assert nesting_depth(value) <= scan_depth(text) <= nesting_depth(value) + 1


@settings(max_examples=100, deadline=None)
@given(text=st.binary(max_size=2000))
def test_the_depth_scan_takes_any_bytes(text):
    assert scan_depth(text) >= 0


# ----------------------------------------------------------------------------- JSON


@FEW
@given(text=st.text(max_size=300))
def test_any_text_as_json_is_parsed_or_refused(text):
    refused_or(lambda: parse_json(text, "x"), (dict, list, str, int, float, bool, type(None)))


@FEW
@given(data=st.data())
def test_mutated_geojson_is_read_or_refused(data, folder):
    feature = {
        "type": "Feature",
        "properties": {"layer": "outline"},
        "geometry": {"type": "Polygon", "coordinates": [[[0, 0], [10, 0], [10, 10], [0, 0]]]},
    }
    base = json.dumps({"type": "FeatureCollection", "features": [feature]}).encode()
    path = written(folder, "geometry.json", data.draw(mutated(base)))
    refused_or(lambda: load_geometry(path), dict)


def test_a_geojson_feature_of_an_unknown_geometry_type_is_refused_in_one_line(folder):
    """shapely raises its own GeometryTypeError for it (hypothesis found "Qolygon")."""
    geometry = {"type": "Qolygon", "coordinates": [[[0, 0], [10, 0], [10, 10], [0, 0]]]}
    feature = {"type": "Feature", "properties": {"layer": "outline"}, "geometry": geometry}
    path = folder / "qolygon.json"
    path.write_text(json.dumps({"type": "FeatureCollection", "features": [feature]}))
    with pytest.raises(FabkitError, match=r"feature 0: Unknown geometry type") as refused:
        load_geometry(path)
    assert "\n" not in str(refused.value)


# ----------------------------------------------------------------------------- npz / npy

REAL_DTYPES = hnp.boolean_dtypes() | hnp.integer_dtypes() | hnp.floating_dtypes()
OTHER_DTYPES = hnp.complex_number_dtypes() | hnp.datetime64_dtypes() | hnp.byte_string_dtypes()


@pytest.mark.slow
@FEW
@given(
    arrays=st.dictionaries(
        st.from_regex(r"[a-z][a-z0-9_]{0,6}", fullmatch=True),
        hnp.arrays(REAL_DTYPES | OTHER_DTYPES, hnp.array_shapes(min_dims=0, max_side=5)),
        min_size=1,
        max_size=4,
    ),
    compress=st.booleans(),
)
def test_an_npz_of_real_arrays_is_read_exactly_and_others_refused(arrays, compress, folder):
    path = folder / "round.npz"
    (np.savez_compressed if compress else np.savez)(path, **arrays)
    real = all(a.dtype.kind in NUMBER_KINDS for a in arrays.values())
    if real:
        read = read_npz(path, "x")
        assert set(read) == set(arrays)
        for key, array in arrays.items():
            assert read[key].dtype == array.dtype and read[key].shape == array.shape
            np.testing.assert_array_equal(read[key], array)
    else:
        with pytest.raises(FabkitError, match="expected real numbers"):
            read_npz(path, "x")


@FEW
@given(data=st.data())
def test_a_mutated_npz_is_read_or_refused(data, folder):
    buffer = io.BytesIO()
    np.savez_compressed(buffer, z=np.arange(64.0).reshape(8, 8), mask=np.eye(8, dtype=bool))
    path = written(folder, "mutated.npz", data.draw(mutated(buffer.getvalue())))
    refused_or(lambda: read_npz(path, "x"), dict)


@FEW
@given(data=st.data())
def test_a_mutated_npy_is_read_or_refused(data, folder):
    path = written(folder, "mutated.npy", data.draw(mutated(h.npy_bytes(np.zeros((8, 9))))))
    refused_or(lambda: read_npy(path, "x"), np.ndarray)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_a_mutated_design_file_is_loaded_or_refused(data, design_file, folder):
    path = written(folder, "mutated_design.npz", data.draw(mutated(design_file.read_bytes())))
    design = refused_or(lambda: Design.load(path), Design)
    if design is not None:
        assert np.isfinite(design.r[:, design.valid]).all()


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_a_design_with_edited_members_is_loaded_or_refused(data, design_file, folder):
    """Members swapped for random real arrays (any shape, any values)."""
    arrays = h.arrays_of(design_file)
    key = data.draw(st.sampled_from(sorted(k for k in arrays if k != "spec")))
    shape = data.draw(hnp.array_shapes(min_dims=0, max_dims=4, max_side=6))
    arrays[key] = data.draw(hnp.arrays(REAL_DTYPES, shape))
    path = folder / "edited_design.npz"
    np.savez_compressed(path, **arrays)
    refused_or(lambda: Design.load(path), Design)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_a_mutated_toolpath_is_loaded_or_refused(data, toolpath_file, folder):
    path = written(folder, "mutated_tp.npz", data.draw(mutated(toolpath_file.read_bytes())))
    refused_or(lambda: load_toolpath(path), Toolpath)


@pytest.mark.slow
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_a_toolpath_with_edited_members_is_loaded_or_refused(data, toolpath_file, folder):
    arrays = h.arrays_of(toolpath_file)
    key = data.draw(st.sampled_from(sorted(k for k in arrays if k not in ("format", "meta"))))
    if key in ("parameter", "channels"):
        arrays[key] = np.array(data.draw(st.text(max_size=20)))
    else:
        shape = data.draw(hnp.array_shapes(min_dims=0, max_dims=3, max_side=6))
        arrays[key] = data.draw(hnp.arrays(REAL_DTYPES, shape))
    path = folder / "edited_tp.npz"
    np.savez_compressed(path, **arrays)
    refused_or(lambda: load_toolpath(path), Toolpath)


@FEW
@given(data=st.data())
def test_a_mutated_toolpath_json_is_loaded_or_refused(data, toolpath_file, folder):
    json_file = folder / "tp.json"
    if not json_file.exists():
        from fabkit.toolpath.model import save_toolpath

        save_toolpath(load_toolpath(toolpath_file), json_file)
    path = written(folder, "mutated_tp.json", data.draw(mutated(json_file.read_bytes())))
    refused_or(lambda: load_toolpath(path), Toolpath)


# ----------------------------------------------------------------------------- height maps


def _grid_reader(path: Path):
    return lambda: read_grid(path, "surfaces[1].geometry")


@pytest.mark.slow
@FEW
@given(data=st.data())
def test_a_mutated_csv_height_map_is_read_or_refused(data, folder):
    base = "\n".join(",".join(str(i * j) for i in range(9)) for j in range(9)).encode()
    path = written(folder, "mutated.csv", data.draw(mutated(base)))
    refused_or(_grid_reader(path), tuple)


@pytest.mark.slow
@FEW
@given(data=st.data())
def test_a_mutated_png_height_map_is_read_or_refused(data, folder):
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(np.arange(256, dtype=np.uint16).reshape(16, 16)).save(buffer, "PNG")
    path = written(folder, "mutated.png", data.draw(mutated(buffer.getvalue())))
    refused_or(_grid_reader(path), tuple)


@FEW
@given(data=st.data())
def test_a_mutated_npy_height_map_is_read_or_refused(data, folder):
    path = written(folder, "mutated_h.npy", data.draw(mutated(h.npy_bytes(np.ones((9, 9))))))
    refused_or(_grid_reader(path), tuple)


def test_an_npy_header_with_a_bad_escape_is_refused_without_a_warning(folder):
    """numpy's header parser warns about the escape before it fails (hypothesis found it)."""
    text = h.npy_bytes(np.ones((9, 9))).replace(b"'<f8'", b"'\\<f8'")
    path = written(folder, "escaped.npy", text)
    assert refused_or(lambda: read_npy(path, "x"), np.ndarray) is None


@FEW
@given(data=st.data(), suffix=st.sampled_from([".stl", ".ply", ".obj"]))
def test_a_mutated_mesh_is_read_or_refused(data, suffix, folder):
    import trimesh

    source = folder / f"grid{suffix}"
    if not source.exists():
        h.grid_stl(folder / "grid_source.stl", side=6)
        trimesh.load(folder / "grid_source.stl", force="mesh").export(source)
    path = written(folder, f"mutated{suffix}", data.draw(mutated(source.read_bytes())))
    refused_or(lambda: read_mesh(path, "surfaces[1].geometry"), tuple)


coordinates = st.one_of(
    st.floats(-10, 10, allow_nan=False),
    st.sampled_from([0.0, 1.0, 1e300, -1e300, float("nan"), float("inf"), 1e-300]),
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    triangles=hnp.arrays(
        np.float64, st.tuples(st.integers(1, 30), st.just(3), st.just(3)), elements=coordinates
    )
)
def test_any_triangles_make_a_mesh_surface_or_a_one_line_error(triangles, folder):
    from fabkit.problem.surfaces.data import MeshSurface

    path = h.ascii_stl(folder / "random.stl", triangles)
    table = {"kind": "mesh", "file": path.name}
    refused_or(
        lambda: MeshSurface.from_table("m", Table(table, "", "surfaces[1].geometry"), folder),
        MeshSurface,
    )


heights = st.one_of(
    st.floats(-10, 10, allow_nan=False),
    st.floats(-10, 10, allow_nan=False),
    st.sampled_from([0.0, 1e6, -1e6, 1e300, float("nan"), float("inf"), 1e-300]),
)


@st.composite
def extents(draw) -> list[float]:
    """[x0, x1, y0, y1], mostly increasing, of any scale."""
    x0, y0 = (draw(st.floats(-1e3, 1e3)) for _ in range(2))
    scale = draw(st.sampled_from([1e-9, 1e-3, 1.0, 1e3, 1e7]))
    width, height = (scale * draw(st.floats(0.25, 4)) for _ in range(2))
    return [x0, x0 + width, y0, y0 + height]


@pytest.mark.slow
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    z=hnp.arrays(np.float64, st.tuples(st.integers(8, 14), st.integers(8, 14)), elements=heights),
    extent=extents(),
    z_scale=st.sampled_from([1.0, -2.0, 1e-300, 1e300]),
)
def test_any_height_grid_makes_a_surface_or_a_one_line_error(z, extent, z_scale, folder):
    from fabkit.problem.surfaces.data import HeightMap

    np.save(folder / "random_h.npy", z)
    table = {"kind": "heightmap", "file": "random_h.npy", "extent": extent, "z_scale": z_scale}
    refused_or(
        lambda: HeightMap.from_table("h", Table(table, "", "surfaces[1].geometry"), folder),
        HeightMap,
    )


def _zip_fields(raw: bytes, flag: int | None = None, version: int | None = None) -> bytes:
    """``raw`` (a zip) with every local and central header's flag bits or needed version set."""
    out = bytearray(raw)
    for signature, flag_at, version_at in ((b"PK\x03\x04", 6, 4), (b"PK\x01\x02", 8, 6)):
        at = out.find(signature)
        while at >= 0:
            if flag is not None:
                out[at + flag_at : at + flag_at + 2] = struct.pack("<H", flag)
            if version is not None:
                out[at + version_at : at + version_at + 2] = struct.pack("<H", version)
            at = out.find(signature, at + 4)
    return bytes(out)


@pytest.mark.parametrize(
    ("fields", "phrase"),
    [
        ({"flag": 1}, "encrypted"),
        ({"flag": 1 << 5}, "patched data"),
        ({"flag": 1 << 6}, "strong encryption"),
        ({"version": 109}, "version 10.9"),
    ],
    ids=["encrypted", "patched", "strong-encryption", "zip-version"],
)
def test_zip_features_zipfile_does_not_implement_are_refused_in_one_line(fields, phrase, folder):
    """zipfile raises NotImplementedError for these (found by the mutation test above)."""
    buffer = io.BytesIO()
    np.savez_compressed(buffer, z=np.arange(4.0))
    path = written(folder, "feature.npz", _zip_fields(buffer.getvalue(), **fields))
    with pytest.raises(FabkitError, match=phrase) as caught:
        read_npz(path, "x")
    assert "\n" not in str(caught.value)
