"""Pictures, patch meshes and the HTML report of a solved design."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from fabkit.design.design import Design
from fabkit.design.patches import grid_triangles, patch_mesh, write_patch_mesh
from fabkit.errors import FabkitError
from fabkit.files.atomic import MANIFEST
from tests.conftest import coarse_design


@pytest.fixture(scope="module")
def fig1_design(tmp_path_factory) -> Design:
    path = tmp_path_factory.mktemp("design") / "design.npz"
    coarse_design(diagonals=20).save(path)
    return Design.load(path)


def test_grid_triangles_cover_solved_cells():
    valid = np.zeros((4, 4), dtype=bool)
    valid[:3, :3] = True
    points, triangles = grid_triangles(valid)
    assert len(points) == 9 and len(triangles) == 8
    corners = points[triangles]
    a, b = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    signed = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    assert np.all(signed > 0)


def test_patch_meshes_lie_on_their_targets(fig1_design, tmp_path):
    vertices, triangles = patch_mesh(fig1_design, 1)
    assert np.allclose(np.linalg.norm(vertices, axis=1), 1.0)  # the unit sphere
    vertices, _ = patch_mesh(fig1_design, 2)
    assert np.allclose(vertices[:, 2], np.exp(-(vertices[:, 0] ** 2 + vertices[:, 1] ** 2 / 4)))
    for suffix in ("ply", "stl", "glb"):
        write_patch_mesh(fig1_design, 1, tmp_path / f"sphere.{suffix}")
        mesh = trimesh.load(tmp_path / f"sphere.{suffix}", force="mesh")
        assert len(mesh.faces) == len(triangles)
    with pytest.raises(FabkitError, match="mesh format"):
        write_patch_mesh(fig1_design, 1, tmp_path / "sphere.xyz")


@pytest.mark.slow
def test_cli_plot_writes_pictures_meshes_and_report(run_cli, fig1_design, tmp_path):
    design_path = tmp_path / "design.npz"
    fig1_design.save(design_path)
    code, out, _ = run_cli("plot", design_path, "--out", tmp_path / "plots")
    assert code == 0
    plots = tmp_path / "plots"
    names = {p.relative_to(plots).as_posix() for p in plots.rglob("*")}
    expected = {  # where fabkit run writes them (issue 37)
        "pictures/flat_sheet.png",
        "pictures/eps.png",
        "pictures/surfaces.png",
        "pictures/residuals.png",
        "report.html",
        "patches/0_flat.ply",
        "patches/1_sphere.ply",
        "patches/2_bump.ply",
    }
    assert expected <= names
    leftovers = [n for n in names - {MANIFEST} if n.rsplit("/", 1)[-1].startswith(".")]
    assert not leftovers  # no temporary files left
    page = (tmp_path / "plots" / "report.html").read_text()
    assert page.count("data:image/png;base64,") == 4 and "check passed" in page
    for name in ("flat_sheet.png", "surfaces.png"):
        assert (plots / "pictures" / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_drawn_grid_curves_stay_on_the_patch(fig1_design):
    # issue 37: surfaces.png drew the initial curves, valid along their whole length,
    # as arcs running far past the solved patch
    from fabkit.field.part import solved_nodes
    from fabkit.plot.scene import surface_views

    patch = solved_nodes(fig1_design)
    assert (fig1_design.valid & ~patch).any()  # valid nodes beside no solved cell exist
    for j, view in enumerate(surface_views(fig1_design), start=1):
        surface = fig1_design.problem.targets[j].surface
        on_patch = surface.embed(fig1_design.r[j][patch])
        for curve in (*view.u_curves, *view.v_curves):
            gaps = np.min(np.linalg.norm(curve[:, None, :] - on_patch[None], axis=2), axis=1)
            assert gaps.max() < 1e-9


def test_the_surface_behind_the_curves_is_the_patch_and_its_margin(fig1_design):
    # issue 37: the sphere's backdrop was its patch's whole chart box, an open band around
    # the sphere far wider than the patch
    from scipy.spatial import cKDTree

    from fabkit.field.part import solved_nodes
    from fabkit.plot.scene import surface_views

    sphere = fig1_design.problem.targets[1]
    patch = sphere.surface.embed(fig1_design.r[1][solved_nodes(fig1_design)])
    view = surface_views(fig1_design)[0]
    drawn = view.backdrop[np.isfinite(view.backdrop).all(axis=-1)]
    far = cKDTree(patch).query(drawn)[0]
    extent = float(np.ptp(patch, axis=0).max())
    assert len(drawn) > 100 and far.max() < 0.15 * extent  # 0.107 (the chart box: 0.267)
