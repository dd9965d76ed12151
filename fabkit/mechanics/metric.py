"""Reference metrics on a flat mesh: from directors and stretches, compatible across edges.

A face's reference metric abar (2 x 2, flat-sheet coordinates) is built from the
reference lengths of its three edges: abar is the one metric with e_i^T abar e_i =
lbar_i^2. Neighbouring faces then agree on their shared edge, so the discrete metric is
that of a polyhedral surface and its angle defects converge to the integrated Gaussian
curvature. (Sampling the metric at each face's centroid instead does not converge near
a director defect: a cone's integrated curvature stays 29 % off at any resolution.)

Each edge's reference length is the length of the segment in the continuous metric:
Gauss-Legendre quadrature of sqrt(e^T a(p) e) along the flat segment when a(p) is a
function; for a design, the trapezoidal rule along the straight segment between grid
points in material coordinates (u, v), where the designed metric is diagonal and smooth
(the flat sheet's cells can be far from square there).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from fabkit.errors import FabkitError

QUADRATURE_POINTS = 4


def metric_from_director(
    director: np.ndarray, lambda1: np.ndarray, lambda2: np.ndarray
) -> np.ndarray:
    """Reference metric a = R diag(lambda1^2, lambda2^2) R^T (..., 2, 2).

    ``director`` (..., 2) is the flat-sheet director (any non-zero length), ``lambda1``
    the stretch along it and ``lambda2`` across it (...); R rotates x onto the director.
    """
    n = director / np.linalg.norm(director, axis=-1, keepdims=True)
    perp = np.stack([-n[..., 1], n[..., 0]], -1)
    along = n[..., :, None] * n[..., None, :]
    across = perp[..., :, None] * perp[..., None, :]
    return lambda1[..., None, None] ** 2 * along + lambda2[..., None, None] ** 2 * across


def face_edges(points: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start points and vectors (F, 3, 2) of each face's edges; edge i is opposite vertex i."""
    corners = points[triangles]
    start = corners[:, [1, 2, 0]]
    return start, corners[:, [2, 0, 1]] - start


def edge_lengths(
    points: np.ndarray,
    triangles: np.ndarray,
    metric: Callable[[np.ndarray], np.ndarray],
) -> np.ndarray:
    """Reference lengths (F, 3) of every face's edges in a metric field.

    ``metric(p)`` maps flat points (..., 2) to metrics (..., 2, 2); it is sampled only
    inside the edges (Gauss points), so a director defect at a vertex is harmless.
    """
    nodes, weights = np.polynomial.legendre.leggauss(QUADRATURE_POINTS)
    start, vectors = face_edges(points, triangles)
    samples = start[:, :, None, :] + 0.5 * (nodes + 1)[:, None] * vectors[:, :, None, :]
    values = metric(samples)
    speed = np.sqrt(np.einsum("fei,fegij,fej->feg", vectors, values, vectors))
    return 0.5 * speed @ weights


def grid_edge_lengths(
    triangles: np.ndarray,
    grid: np.ndarray,
    step: float,
    stretch_u: np.ndarray,
    stretch_v: np.ndarray,
) -> np.ndarray:
    """Reference lengths (F, 3) of edges between material grid points (trapezoidal rule).

    The metric is diagonal in material coordinates, ds^2 = stretch_u^2 du^2 +
    stretch_v^2 dv^2 (for a design: stretch_u = alpha lambda1, stretch_v = beta lambda2);
    ``grid`` (V, 2) int grid indices of the vertices, ``step`` the grid step,
    ``stretch_u``, ``stretch_v`` (V,) the vertices' values.
    """
    start, end = triangles[:, [1, 2, 0]], triangles[:, [2, 0, 1]]
    du, dv = np.moveaxis(step * (grid[end] - grid[start]), -1, 0)
    speed = [np.sqrt((du * stretch_u[k]) ** 2 + (dv * stretch_v[k]) ** 2) for k in (start, end)]
    return 0.5 * (speed[0] + speed[1])


def length_system(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(F, 3, 3): row i maps a face's metric (a11, a12, a22) to the squared length of its
    edge i, e_i^T a e_i (edge i opposite vertex i)."""
    _, vectors = face_edges(points, triangles)
    x, y = vectors[..., 0], vectors[..., 1]
    return np.stack([x * x, 2 * x * y, y * y], -1)


def metric_from_lengths(
    points: np.ndarray, triangles: np.ndarray, lengths: np.ndarray
) -> np.ndarray:
    """Per-face metric (F, 2, 2) with e_i^T a e_i = lengths[:, i]^2 for the three edges.

    Raises :class:`FabkitError` when some face's lengths break the triangle inequality
    (the mesh is too coarse for the metric's variation there).
    """
    system = length_system(points, triangles)
    a11, a12, a22 = np.moveaxis(np.linalg.solve(system, (lengths**2)[..., None])[..., 0], -1, 0)
    metric = np.stack([np.stack([a11, a12], -1), np.stack([a12, a22], -1)], -2)
    bad = np.count_nonzero(~(np.linalg.eigvalsh(metric)[:, 0] > 0))
    if bad:
        raise FabkitError(
            f"{bad} face(s) get no valid reference metric (edge lengths break the triangle "
            "inequality): the mesh is too coarse for the metric's variation"
        )
    return metric
