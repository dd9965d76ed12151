"""Surface geometry: closed-form curvatures and Christoffel symbols against the metric."""

from __future__ import annotations

import numpy as np
import pytest

from fabkit.files.tomlfile import Table
from fabkit.problem.surfaces import build_surface

RNG = np.random.default_rng(7)


def christoffel_from_metric(surface, r: np.ndarray, h: float = 1e-5) -> np.ndarray:
    """Gamma^i_jk = 1/2 g^il (d_j g_lk + d_k g_lj - d_l g_jk) with finite differences of g."""
    dg = np.stack(
        [(surface.metric(r + h * e) - surface.metric(r - h * e)) / (2 * h) for e in np.eye(2)],
        axis=-3,
    )  # dg[..., m, i, j] = d_m g_ij
    inverse = np.linalg.inv(surface.metric(r))
    lowered = 0.5 * (
        np.einsum("...jlk->...ljk", dg) + np.einsum("...klj->...ljk", dg) - dg
    )  # [..., l, j, k]
    return np.einsum("...il,...ljk->...ijk", inverse, lowered)


SURFACES = {
    "sphere": ({"kind": "sphere", "radius": 2.0}, np.array([[0.7, 0.3], [2.0, -1.0]])),
    "graph": ({"kind": "graph", "z": "exp(-(x**2 + y**2/4))"}, RNG.normal(size=(5, 2))),
    "torus": (
        {
            "kind": "parametric",
            "x": "(3 + cos(b))*cos(a)",
            "y": "(3 + cos(b))*sin(a)",
            "z": "sin(b)",
        },
        RNG.uniform(-3, 3, size=(5, 2)),
    ),
    "poincare": (
        {"kind": "metric", "g11": "1/b**2", "g22": "1/b**2"},
        RNG.uniform(0.5, 2, size=(5, 2)),
    ),
}


def test_sphere_curvature_is_inverse_radius_squared():
    sphere = build_surface("s", Table({"kind": "sphere", "radius": 2.5}, "", "s"))
    assert np.allclose(sphere.curvature(np.array([[0.4, 1.0], [2.0, 3.0]])), 1 / 2.5**2)


def test_graph_curvature_formula():
    graph = build_surface("g", Table({"kind": "graph", "z": "sin(x)*cos(2*y) + x**3*y"}, "", "s"))
    x, y = RNG.normal(size=(2, 20))
    fx = np.cos(x) * np.cos(2 * y) + 3 * x**2 * y
    fy = -2 * np.sin(x) * np.sin(2 * y) + x**3
    fxx = -np.sin(x) * np.cos(2 * y) + 6 * x * y
    fyy = -4 * np.sin(x) * np.cos(2 * y)
    fxy = -2 * np.cos(x) * np.sin(2 * y) + 3 * x**2
    expected = (fxx * fyy - fxy**2) / (1 + fx**2 + fy**2) ** 2
    assert np.allclose(graph.curvature(np.stack([x, y], -1)), expected, rtol=1e-10)


def test_torus_curvature():
    torus = build_surface("t", Table(SURFACES["torus"][0], "", "s"))
    r = SURFACES["torus"][1]
    expected = np.cos(r[:, 1]) / (1 * (3 + np.cos(r[:, 1])))
    assert np.allclose(torus.curvature(r), expected, rtol=1e-10)


def test_poincare_half_plane_has_curvature_minus_one():
    plane = build_surface("p", Table(SURFACES["poincare"][0], "", "s"))
    assert np.allclose(plane.curvature(SURFACES["poincare"][1]), -1.0)


@pytest.mark.parametrize("name", SURFACES)
def test_christoffel_symbols_match_metric_derivatives(name):
    table, points = SURFACES[name]
    surface = build_surface(name, Table(table, "", "s"))
    assert np.allclose(
        surface.christoffel(points), christoffel_from_metric(surface, points), atol=1e-6
    )


@pytest.mark.parametrize("name", ["sphere", "graph", "torus"])
def test_metric_is_pullback_of_embedding(name):
    table, points = SURFACES[name]
    surface = build_surface(name, Table(table, "", "s"))
    h = 1e-6
    jacobian = np.stack(
        [
            (surface.embed(points + h * e) - surface.embed(points - h * e)) / (2 * h)
            for e in np.eye(2)
        ],
        -1,
    )
    assert np.allclose(
        np.einsum("...ki,...kj->...ij", jacobian, jacobian), surface.metric(points), atol=1e-6
    )


def test_chart_domain():
    sphere = build_surface("s", Table({"kind": "sphere"}, "", "s"))
    assert sphere.contains(np.array([[1.0, 0.0], [-0.1, 0.0], [np.pi + 0.1, 0.0]])).tolist() == [
        True,
        False,
        False,
    ]
    bounded = build_surface(
        "g", Table({"kind": "graph", "z": "x", "domain": [0, 1, 0, 2]}, "", "s")
    )
    assert bounded.contains(np.array([[0.5, 1.5], [1.5, 1.0], [np.nan, 1.0]])).tolist() == [
        True,
        False,
        False,
    ]
