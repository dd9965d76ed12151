"""Data targets: height maps and meshes against the analytic surfaces they sample.

"Relative error of K over the interior", used throughout: at 20 000 random points (fixed
seed) at least 5 grid cells from the border of the sampled domain, keep those where
|K_true| >= 10 % of the largest |K_true| among them (relative error is meaningless
where K crosses zero), and take the median of |K_fit - K_true| / |K_true| there.
"""

from __future__ import annotations

import copy
import importlib.util
import os

import numpy as np
import pytest
import trimesh
from PIL import Image

from fabkit.design.check import check_design
from fabkit.design.solver import solve
from fabkit.errors import FabkitError
from fabkit.files.tomlfile import Table
from fabkit.problem.spec import build_spec
from fabkit.problem.surfaces import build_surface
from fabkit.problem.surfaces.data import HOLE_MARGIN
from tests.conftest import EXAMPLES, example_table

N = 200
"""Nodes per side of the sampled height maps and meshes."""
BUMP = ("exp(-(x**2 + y**2/4))", [-4.0, 4.0, -6.0, 6.0])
"""Fig. 1's Gaussian bump and the domain it is sampled on."""
WAVY = ("sin(x)*sin(y/4)", [-8.0, 8.0, -12.0, 12.0])
"""Fig. 3's wavy sheet and the domain it is sampled on."""
SAMPLED = {"bump": BUMP, "wavy": WAVY}
FACE_GEOMETRY = {"kind": "heightmap", "file": "data/face.npy", "extent": [-16, 16, 0, 40]}


def _load_make_face():
    spec = importlib.util.spec_from_file_location("make_face", EXAMPLES / "make_face.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


make_face = _load_make_face()


def analytic(expression: str):
    return build_surface("analytic", Table({"kind": "graph", "z": expression}, "", "test"))


def sampled(expression: str, extent: list[float], n: int = N):
    """Node coordinates and heights (n, n) of z = expression over extent."""
    x = np.linspace(extent[0], extent[1], n)
    y = np.linspace(extent[2], extent[3], n)
    xx, yy = np.meshgrid(x, y)
    return xx, yy, analytic(expression).embed(np.stack([xx, yy], -1))[..., 2]


def interior_points(extent: list[float], n: int = N, count: int = 20000) -> np.ndarray:
    """Random points (count, 2) at least 5 cells from the border of extent."""
    hx = (extent[1] - extent[0]) / (n - 1)
    hy = (extent[3] - extent[2]) / (n - 1)
    rng = np.random.default_rng(7)
    return np.stack(
        [
            rng.uniform(extent[0] + 5 * hx, extent[1] - 5 * hx, count),
            rng.uniform(extent[2] + 5 * hy, extent[3] - 5 * hy, count),
        ],
        axis=-1,
    )


def k_error(surface, expression: str, points: np.ndarray) -> float:
    """Median relative error of K where |K_true| >= 10 % of max |K_true| (module docstring)."""
    truth = analytic(expression).curvature(points)
    keep = np.abs(truth) >= 0.1 * np.abs(truth).max()
    return float(
        np.median(np.abs(surface.curvature(points[keep]) - truth[keep]) / np.abs(truth[keep]))
    )


def heightmap(tmp_path, z: np.ndarray, extent: list[float], name: str = "map.npy", **keys):
    np.save(tmp_path / name, z)
    table = {"kind": "heightmap", "file": name, "extent": extent, **keys}
    return build_surface("data", Table(table, "", "surfaces[1].geometry"), tmp_path)


def write_stl(path, xx, yy, zz) -> None:
    make_face.grid_mesh(xx, yy, zz).export(path)


def mesh(tmp_path, name: str = "map.stl", **keys):
    table = {"kind": "mesh", "file": name, **keys}
    return build_surface("data", Table(table, "", "surfaces[1].geometry"), tmp_path)


# --- K accuracy -----------------------------------------------------------------------------


@pytest.mark.parametrize("expression, extent", [BUMP, WAVY], ids=["bump", "wavy"])
def test_heightmap_curvature_and_christoffel_match_analytic(tmp_path, expression, extent):
    surface = heightmap(tmp_path, sampled(expression, extent)[2], extent)
    points = interior_points(extent)
    assert k_error(surface, expression, points) <= 0.02
    g, gamma, _ = surface.geometry(points)
    g_true, gamma_true, _ = analytic(expression).geometry(points)
    assert np.max(np.abs(g - g_true)) <= 1e-3 * np.max(np.abs(g_true))
    assert np.max(np.abs(gamma - gamma_true)) <= 1e-2 * np.max(np.abs(gamma_true))


@pytest.mark.slow
@pytest.mark.parametrize("expression, extent", [BUMP, WAVY], ids=["bump", "wavy"])
def test_stl_curvature_matches_analytic(tmp_path, expression, extent):
    write_stl(tmp_path / "map.stl", *sampled(expression, extent))
    surface = mesh(tmp_path)
    assert surface.fit.shape == (N, N)
    assert k_error(surface, expression, interior_points(extent)) <= 0.02


@pytest.mark.parametrize("expression, extent", [BUMP, WAVY], ids=["bump", "wavy"])
def test_noisy_heightmap_curvature_within_five_percent(tmp_path, expression, extent):
    z = sampled(expression, extent)[2]
    sigma = 0.01 * np.ptp(z)
    noisy = z + sigma * np.random.default_rng(3).standard_normal(z.shape)
    surface = heightmap(tmp_path, noisy, extent)
    assert k_error(surface, expression, interior_points(extent)) <= 0.05
    assert surface.fit.chosen and abs(surface.fit.noise / sigma - 1) < 0.1
    assert "chosen from noise" in surface.describe()


@pytest.mark.slow
def test_irregular_mesh_is_fitted_through_its_vertices(tmp_path):
    """A jittered Delaunay mesh (not a lattice) is resampled by local quadratics."""
    from scipy.spatial import Delaunay

    expression, extent = BUMP
    xx, yy, _ = sampled(expression, extent, n=120)
    rng = np.random.default_rng(1)
    jitter = rng.uniform(-0.3, 0.3, (xx.size, 2)) * [xx[0, 1] - xx[0, 0], yy[1, 0] - yy[0, 0]]
    points = np.clip(np.stack([xx.ravel(), yy.ravel()], -1) + jitter, extent[::2], extent[1::2])
    heights = analytic(expression).embed(points)[:, 2:]
    faces = Delaunay(points).simplices
    trimesh.Trimesh(np.hstack([points, heights]), faces, process=False).export(tmp_path / "m.stl")
    surface = mesh(tmp_path, "m.stl")
    assert surface.fit.shape != (120, 120)
    assert k_error(surface, expression, interior_points(extent, n=120)) <= 0.05


@pytest.mark.parametrize("axis, order", [("x", (2, 0, 1)), ("y", (1, 2, 0))])
def test_mesh_height_along_another_axis(tmp_path, axis, order):
    """axis = "x" has chart (y, z) and height x; axis = "y" has chart (z, x) and height y."""
    expression, extent = BUMP
    xx, yy, zz = sampled(expression, extent, n=80)
    columns = (xx.ravel(), yy.ravel(), zz.ravel())
    vertices = np.stack([columns[k] for k in order], axis=-1)
    faces = make_face.grid_mesh(xx, yy, zz).faces
    trimesh.Trimesh(vertices, faces, process=False).export(tmp_path / "m.stl")
    surface = mesh(tmp_path, "m.stl", axis=axis)
    assert surface.chart == {"x": ("y", "z"), "y": ("z", "x")}[axis]
    assert k_error(surface, expression, interior_points(extent, n=80)) <= 0.02
    r = np.array([[0.3, -0.7]])
    assert np.allclose(surface.embed(r)[0], vertices_of(r[0], expression, order), atol=1e-4)


def vertices_of(r: np.ndarray, expression: str, order: tuple[int, int, int]) -> np.ndarray:
    point = analytic(expression).embed(r)
    return point[list(order)]


def test_explicit_smoothing_is_used_and_reported(tmp_path):
    expression, extent = BUMP
    z = sampled(expression, extent, n=60)[2]
    noisy = z + 0.01 * np.random.default_rng(0).standard_normal(z.shape)
    interpolating = heightmap(tmp_path, noisy, extent, smoothing=0)
    assert interpolating.fit.smoothing == (0.0, 0.0) and not interpolating.fit.chosen
    assert interpolating.fit.residual < 1e-9
    assert "(set)" in interpolating.describe()
    smooth = heightmap(tmp_path, noisy, extent, name="b.npy", smoothing=[0.2, 0.4])
    assert smooth.fit.smoothing == (0.2, 0.4)
    assert 0.005 < smooth.fit.residual < 0.02


# --- holes and the footprint ------------------------------------------------------------------


@pytest.mark.slow
def test_holes_leave_the_footprint_and_the_rest_stays_accurate(tmp_path):
    expression, extent = BUMP
    z = sampled(expression, extent)[2]
    z[90:110, 80:110] = np.nan
    surface = heightmap(tmp_path, z, extent)
    h = np.array([(extent[1] - extent[0]) / (N - 1), (extent[3] - extent[2]) / (N - 1)])
    origin = np.array([extent[0], extent[2]])
    hole_centre = origin + h * [95, 100]
    assert not surface.contains(hole_centre)
    next_to_hole = origin + h * [79.5 - HOLE_MARGIN, 100]
    assert not surface.contains(next_to_hole)
    points = interior_points(extent)
    nodes = (points - origin) / h
    far = (
        (nodes[:, 0] < 80 - HOLE_MARGIN - 1)
        | (nodes[:, 0] > 109 + HOLE_MARGIN + 1)
        | (nodes[:, 1] < 90 - HOLE_MARGIN - 1)
        | (nodes[:, 1] > 109 + HOLE_MARGIN + 1)
    )
    assert surface.contains(points[far]).all()
    assert k_error(surface, expression, points[far]) <= 0.02
    assert "footprint 98%" in surface.describe()


def test_contains_is_false_outside_the_extent_and_for_nan(tmp_path):
    surface = heightmap(tmp_path, sampled(*BUMP, n=40)[2], BUMP[1])
    points = np.array([[0.0, 0.0], [-4.01, 0.0], [0.0, 6.01], [np.nan, 0.0], [3.99, -5.99]])
    assert surface.contains(points).tolist() == [True, False, False, False, True]


@pytest.mark.slow
def test_npz_mask_and_nodata_make_holes(tmp_path):
    z = sampled(*BUMP, n=60)[2]
    mask = np.zeros(z.shape, dtype=bool)
    mask[20:30, 20:30] = True
    np.savez(tmp_path / "m.npz", z=z, mask=mask)
    masked = build_surface(
        "d", Table({"kind": "heightmap", "file": "m.npz", "extent": BUMP[1]}, "", "g"), tmp_path
    )
    with_nodata = heightmap(tmp_path, np.where(mask, -999.0, z), BUMP[1], nodata=-999)
    for surface in (masked, with_nodata):
        assert surface.footprint[20:29, 20:29].sum() == 0
        assert surface.footprint.mean() < 0.95


# --- file formats -----------------------------------------------------------------------------


def test_formats_give_the_same_surface(tmp_path):
    """npy, npz with coordinates, csv, 16-bit png and 16-bit tif of one grid agree in K."""
    expression, extent = BUMP
    xx, yy, z = sampled(expression, extent, n=80)
    reference = heightmap(tmp_path, z, extent)
    np.savez(tmp_path / "m.npz", z=z, x=xx[0], y=yy[:, 0])
    np.savetxt(tmp_path / "m.csv", z, delimiter=",")
    low, span = z.min(), np.ptp(z)
    levels = np.round((z - low) / span * 65535).astype(np.uint16)
    for suffix in (".png", ".tif"):
        Image.fromarray(levels[::-1]).save(tmp_path / f"m{suffix}")
    tables = [
        {"file": "m.npz"},
        {"file": "m.csv", "extent": extent},
        {"file": "m.png", "extent": extent, "z_scale": span / 65535},
        {"file": "m.tif", "extent": extent, "z_scale": span / 65535},
    ]
    points = interior_points(extent, n=80, count=2000)
    for table in tables:
        surface = build_surface("d", Table({"kind": "heightmap", **table}, "", "g"), tmp_path)
        assert surface.bounds == reference.bounds
        difference = np.abs(surface.curvature(points) - reference.curvature(points))
        assert np.median(difference) <= 0.01, table["file"]


def test_image_top_row_is_the_largest_y(tmp_path):
    ramp = np.tile(np.arange(20, dtype=np.uint16)[:, None] * 1000, (1, 20))
    Image.fromarray(ramp).save(tmp_path / "ramp.png")
    table = {"kind": "heightmap", "file": "ramp.png", "extent": [0, 19, 0, 19]}
    surface = build_surface("d", Table(table, "", "g"), tmp_path)
    bottom, top = surface.embed(np.array([[9.5, 0.5], [9.5, 18.5]]))[:, 2]
    assert top < bottom


def test_fit_is_cached_and_refitted_when_the_file_changes(tmp_path):
    z = sampled(*BUMP, n=40)[2]
    first = heightmap(tmp_path, z, BUMP[1])
    table = {"kind": "heightmap", "file": "map.npy", "extent": BUMP[1]}
    assert build_surface("d", Table(table, "", "surfaces[1].geometry"), tmp_path).fit is first.fit
    path = tmp_path / "map.npy"
    np.save(path, 2 * z)
    later = path.stat().st_mtime_ns + 10**9
    os.utime(path, ns=(later, later))
    changed = build_surface("d", Table(table, "", "surfaces[1].geometry"), tmp_path)
    origin = np.zeros((1, 2))
    assert np.isclose(changed.embed(origin)[0, 2], 2 * first.embed(origin)[0, 2])


# --- refusals ---------------------------------------------------------------------------------


def write_bytes(name: str, data: bytes):
    """A maker of file ``name`` holding ``data``: called with a folder, returns the name."""

    def make(tmp_path) -> str:
        (tmp_path / name).write_bytes(data)
        return name

    return make


def write_array(name: str, array: np.ndarray):
    """A maker of the .npy file ``name`` holding ``array`` (as :func:`write_bytes`)."""

    def make(tmp_path) -> str:
        np.save(tmp_path / name, array)
        return name

    return make


def write_mesh(name: str, build):
    """A maker of the mesh file ``name`` of ``build()`` (as :func:`write_bytes`)."""

    def make(tmp_path) -> str:
        build().export(tmp_path / name)
        return name

    return make


def absent(name: str):
    """A maker that makes nothing: the file ``name`` is not there."""
    return lambda tmp_path: name


def folded_sheet() -> trimesh.Trimesh:
    """A strip that runs right, folds back over itself and runs left above."""
    x = np.array([0.0, 2.0, 0.5])
    z = np.array([0.0, 0.5, 1.0])
    vertices = np.array([[xi, y, zi] for xi, zi in zip(x, z, strict=True) for y in (0.0, 1.0)])
    faces = [[0, 2, 3], [0, 3, 1], [2, 4, 5], [2, 5, 3]]
    return trimesh.Trimesh(vertices, faces, process=False)


def stacked_sheets() -> trimesh.Trimesh:
    """Two separate square sheets, one above the other: both face up, but overlap."""
    square = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=float)
    vertices = np.vstack([square, square + [0.2, 0.2, 1.0]])
    faces = [[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]]
    return trimesh.Trimesh(vertices, faces, process=False)


GRID = sampled(*BUMP, n=20)[2]
UNIT = {"extent": [0, 1, 0, 1]}
"""The table keys of a height map whose extent plays no part in its refusal."""
REFUSALS = [
    ("missing", absent("nowhere.npy"), UNIT, "does not exist"),
    ("empty", write_bytes("e.npy", b""), UNIT, "is empty"),
    ("all-nan", write_array("n.npy", np.full((20, 20), np.nan)), UNIT, "no finite heights"),
    (
        "infinite",
        write_array("i.npy", np.where(GRID > 0.5, np.inf, GRID)),
        {"extent": BUMP[1]},
        "infinite heights",
    ),
    ("corrupt npy", write_bytes("c.npy", b"\x93NUMPY garbage" * 10), UNIT, "not an .npy file"),
    (
        "corrupt npz",
        write_bytes("c.npz", b"PK\x03\x04 not a zip" * 10),
        UNIT,
        "not an .npz archive",
    ),
    (
        "corrupt png",
        write_bytes("c.png", b"\x89PNG\r\n\x1a\n" + b"x" * 100),
        UNIT,
        "not a readable image",
    ),
    ("text csv", write_bytes("c.csv", b"a,b\n1,2\n"), UNIT, "not a grid of numbers"),
    (
        "holes everywhere",
        write_array("h.npy", np.where(np.indices((20, 20)).sum(0) % 4 == 0, np.nan, GRID)),
        {"extent": BUMP[1]},
        "too many holes",
    ),
    ("3d array", write_array("t.npy", np.zeros((20, 20, 3))), UNIT, "a height grid is 2D"),
    ("tiny grid", write_array("s.npy", np.zeros((4, 20))), UNIT, "nodes per side"),
    ("bad suffix", write_bytes("m.txt", b"1"), UNIT, "unsupported format"),
    ("no extent", write_array("g.npy", GRID), {}, "missing key 'extent'"),
    ("reversed extent", write_array("g.npy", GRID), {"extent": [1, 0, 0, 1]}, "x0 < x1"),
    ("extent aspect", write_array("g.npy", GRID), {"extent": [0, 100, 0, 1]}, "transposed grid"),
    (
        "zero z_scale",
        write_array("g.npy", GRID),
        {"extent": BUMP[1], "z_scale": 0},
        "z_scale: expected a non-zero number, got 0",
    ),
    (
        "bad smoothing",
        write_array("g.npy", GRID),
        {"extent": BUMP[1], "smoothing": -1},
        "smoothing: expected a number >= 0 at most 1e\\+06, got -1",
    ),
    (
        "unknown key",
        write_array("g.npy", GRID),
        {"extent": BUMP[1], "scale": 2},
        "geometry\\.scale: unknown key \\(allowed: extent, file",
    ),
]
MESH_REFUSALS = [
    (
        "corrupt ascii stl",
        write_bytes("c.stl", b"solid x\nfacet normal garbage\n" * 5),
        {},
        "no triangles \\(empty or corrupt\\)",
    ),
    (
        "corrupt binary stl",
        write_bytes("c.stl", np.random.default_rng(0).bytes(3000)),
        {},
        "not a readable mesh \\(corrupt",
    ),
    (
        "corrupt ply",
        write_bytes("c.ply", b"ply\nformat ascii 1.0\nelement vertex 3\nend_header\n1 2\n"),
        {},
        "not a readable mesh|no triangles",
    ),
    ("fold", write_mesh("f.stl", folded_sheet), {}, "faces face the other way"),
    (
        "closed solid",
        write_mesh("b.stl", lambda: trimesh.creation.box()),
        {},
        "faces face the other way",
    ),
    ("stacked sheets", write_mesh("s.ply", stacked_sheets), {}, "overlapping sheets"),
    (
        "bad axis",
        write_mesh("s.ply", stacked_sheets),
        {"axis": "w"},
        "axis: expected one of x, y, z, got 'w'",
    ),
]


@pytest.mark.parametrize(
    "kind, make, keys, message",
    [
        *[pytest.param("heightmap", *row[1:], id=f"heightmap-{row[0]}") for row in REFUSALS],
        *[pytest.param("mesh", *row[1:], id=f"mesh-{row[0]}") for row in MESH_REFUSALS],
    ],
)
def test_data_file_refusals(tmp_path, kind, make, keys, message):
    table = {"kind": kind, "file": make(tmp_path), **keys}
    with pytest.raises(FabkitError, match=message) as error:
        build_surface("d", Table(table, "", "surfaces[2].geometry"), tmp_path)
    assert "\n" not in str(error.value) and str(error.value).startswith("surfaces[2].geometry")


def test_extent_must_match_the_files_coordinates(tmp_path):
    xx, yy, z = sampled(*BUMP, n=30)
    np.savez(tmp_path / "m.npz", z=z, x=xx[0], y=yy[:, 0])
    table = {"kind": "heightmap", "file": "m.npz", "extent": [-4, 4, -6, 7]}
    with pytest.raises(FabkitError, match="does not match the file's coordinates"):
        build_surface("d", Table(table, "", "g"), tmp_path)


# --- the face of Fig. 3 -----------------------------------------------------------------------


def test_shipped_face_files_are_what_the_script_makes(tmp_path):
    # to the last bits of numpy's vectorised exp, which differ between CPU instruction sets
    make_face.main(tmp_path)
    made = np.load(tmp_path / "face.npy", allow_pickle=False)
    shipped = np.load(EXAMPLES / "data" / "face.npy", allow_pickle=False)
    assert made.shape == shipped.shape
    np.testing.assert_allclose(made, shipped, rtol=1e-12, atol=1e-12)
    made, shipped = (_stl_floats(path) for path in (tmp_path, EXAMPLES / "data"))
    assert made.shape == shipped.shape
    np.testing.assert_allclose(made, shipped, rtol=1e-6, atol=1e-6)
    assert sum(p.stat().st_size for p in (EXAMPLES / "data").iterdir()) < 2_000_000


def _stl_floats(folder) -> np.ndarray:
    """The normals and corners (n, 12) of the binary STL ``folder``/face.stl."""
    data = (folder / "face.stl").read_bytes()
    count = int(np.frombuffer(data[80:84], dtype="<u4")[0])
    rows = np.frombuffer(data[84 : 84 + 50 * count], dtype=np.uint8).reshape(count, 50)
    return rows[:, :48].copy().view("<f4").reshape(count, 12)


@pytest.mark.slow
def test_face_heightmap_and_stl_follow_the_face_function():
    points = np.stack(np.meshgrid(np.linspace(-14, 14, 60), np.linspace(2, 38, 80)), -1)
    points = points.reshape(-1, 2)
    truth = face_curvature(points)
    scale = np.abs(truth).max()
    assert 0.3 < scale < 1.5 and truth.min() < -0.1
    for geometry, tolerance in (
        (FACE_GEOMETRY, 0.01),
        ({"kind": "mesh", "file": "data/face.stl"}, 0.05),
    ):
        surface = build_surface("face", Table(geometry, "", "g"), EXAMPLES)
        assert surface.bounds == ((-16.0, 16.0), (0.0, 40.0))
        error = np.abs(surface.curvature(points) - truth)
        assert np.percentile(error, 95) <= tolerance * scale, geometry["kind"]
        heights = surface.embed(points)[:, 2]
        expected = make_face.face_height(points[:, 0], points[:, 1])
        assert np.max(np.abs(heights - expected)) <= tolerance


def face_curvature(points: np.ndarray, e: float = 1e-3) -> np.ndarray:
    """K of the face function by central differences (step e)."""
    f = make_face.face_height
    x, y = points[:, 0], points[:, 1]
    fx = (f(x + e, y) - f(x - e, y)) / (2 * e)
    fy = (f(x, y + e) - f(x, y - e)) / (2 * e)
    fxx = (f(x + e, y) - 2 * f(x, y) + f(x - e, y)) / e**2
    fyy = (f(x, y + e) - 2 * f(x, y) + f(x, y - e)) / e**2
    fxy = (f(x + e, y + e) - f(x + e, y - e) - f(x - e, y + e) + f(x - e, y - e)) / (4 * e**2)
    return (fxx * fyy - fxy**2) / (1 + fx**2 + fy**2) ** 2


def test_spec_summary_names_footprint_residual_smoothing_and_k_range(tmp_path, run_cli):
    text = (EXAMPLES / "three_shapes.toml").read_text()
    start = text.index('[[surfaces]]\nname = "face"')
    line_start = text.index("geometry =", start)
    line_end = text.index("\n", line_start)
    path = EXAMPLES / "data" / "face.npy"
    face = f'geometry = {{ kind = "heightmap", file = "{path}", extent = [-16, 16, 0, 40] }}'
    (tmp_path / "spec.toml").write_text(text[:line_start] + face + text[line_end:])
    code, out, _ = run_cli("spec", tmp_path / "spec.toml")
    assert code == 0
    line = next(row for row in out.splitlines() if "face:" in row)
    for part in ("heightmap face.npy", "footprint 100%", "fit rms", "smoothing", "K in ["):
        assert part in line, part


# --- designs against data and analytic surfaces -----------------------------------------------


def solved_check(table: dict):
    return check_design(solve(build_spec(table, EXAMPLES)).design)


def assert_isometry_within_twice(data_report, analytic_report):
    for data, exact in zip(data_report.surfaces, analytic_report.surfaces, strict=True):
        assert data.points >= 0.9 * exact.points, data.name
        assert data.isometry.median <= 2 * exact.isometry.median, data.name
        assert data.isometry.p95 <= 2 * exact.isometry.p95, data.name


@pytest.fixture(scope="module")
def stl_files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("targets")
    for name, (expression, extent) in SAMPLED.items():
        xx, yy, z = sampled(expression, extent)
        np.save(folder / f"{name}.npy", z)
        write_stl(folder / f"{name}.stl", xx, yy, z)
    return folder


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["heightmap", "mesh"])
@pytest.mark.parametrize(
    ("example", "index", "name", "step"),
    [
        pytest.param("two_shapes.toml", 2, "bump", 0.05, id="fig1-bump"),
        pytest.param("three_shapes.toml", 3, "wavy", 0.1, id="fig3-wavy"),
    ],
)
def test_design_against_data(stl_files, example, index, name, step, kind):
    """A figure's design with target ``index`` (analytic) swapped for its samples, as a
    height map or a mesh: the isometry residuals stay within twice the analytic ones."""
    table = example_table(example)
    table["solver"].update(step=step, diagonals=40)
    exact = solved_check(copy.deepcopy(table))
    suffix = "npy" if kind == "heightmap" else "stl"
    geometry = {"kind": kind, "file": str(stl_files / f"{name}.{suffix}")}
    if kind == "heightmap":
        geometry["extent"] = SAMPLED[name][1]
    table["surfaces"][index]["geometry"] = geometry
    assert_isometry_within_twice(solved_check(table), exact)


@pytest.mark.slow
@pytest.mark.parametrize(
    "geometry", [FACE_GEOMETRY, {"kind": "mesh", "file": "data/face.stl"}], ids=["npy", "stl"]
)
def test_three_shapes_with_the_face_passes_check(geometry):
    table = example_table("three_shapes.toml")
    table["surfaces"][2]["geometry"] = dict(geometry)
    table["solver"].update(diagonals=60)
    report = solved_check(table)
    assert report.passed, report.table()
    face = next(s for s in report.surfaces if s.name == "face")
    assert face.points > 1000


@pytest.mark.slow
def test_a_hole_in_the_data_stops_the_design(stl_files, fig3, tmp_path):
    """Marching into a hole of the wavy height map is a chart stop on that surface, and no
    solved point of the design lands in the hole."""
    extent = WAVY[1]
    z = np.load(stl_files / "wavy.npy")
    x = np.linspace(extent[0], extent[1], N)
    y = np.linspace(extent[2], extent[3], N)
    hole = (np.abs(x[None, :] - 1.0) < 1.0) & (np.abs(y[:, None] - 3.5) < 1.0)
    np.save(tmp_path / "holed.npy", np.where(hole, np.nan, z))
    geometry = {"kind": "heightmap", "file": str(tmp_path / "holed.npy"), "extent": extent}
    fig3["surfaces"][3]["geometry"] = geometry
    fig3["solver"].update(step=0.1, diagonals=40)
    solution = solve(build_spec(fig3, EXAMPLES))
    stops = [s for s in solution.stops if s.reason == "target point left its chart"]
    assert any(s.surface == "wavy" for s in stops)
    points = solution.design.r[3][solution.design.valid]
    assert not np.any((np.abs(points[:, 0] - 1.0) < 1.0) & (np.abs(points[:, 1] - 3.5) < 1.0))
