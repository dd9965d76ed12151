"""The lines of a stripe pattern (:mod:`fabkit.toolpath.stripes`): :func:`stripe_lines`
extracts the zero-phase lines of a solved :class:`~fabkit.toolpath.stripes.StripePattern`
near a region, by marching squares on a finer grid inside each coarse cell, where psi is
interpolated by blending the plane waves of the cell's four corners; the crossings are
chained into polylines (mm), closed loops repeating their first point.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import shapely
from scipy.sparse.csgraph import connected_components, depth_first_order

from fabkit.toolpath.stripes import StripePattern

# Marching squares: fine-cell corners 00, 10, 11, 01 (bits 1, 2, 4, 8 when Im psi > 0);
# edges 0 bottom (00-10), 1 right (10-11), 2 top (01-11), 3 left (00-01).
_FIRST = np.array(
    [[-1, -1], [0, 3], [0, 1], [3, 1], [1, 2], [0, 1], [0, 2], [3, 2]]
    + [[2, 3], [0, 2], [0, 3], [1, 2], [3, 1], [0, 1], [0, 3], [-1, -1]]
)
_SECOND = np.full((16, 2), -1)
_SECOND[5], _SECOND[10] = [2, 3], [1, 2]
_SADDLE_OTHER = {5: ([0, 3], [1, 2]), 10: ([0, 1], [2, 3])}
"""Saddles 5 and 10 pair the edges as in _FIRST/_SECOND when the centre is positive, and
as listed here when it is negative."""


def stripe_lines(
    pattern: StripePattern,
    region: shapely.Geometry,
    subdivisions: int = 5,
    phase: float = 0.0,
) -> list[np.ndarray]:
    """The lines of ``pattern`` (zero phase, shifted by ``phase`` rad) near ``region``.

    Returns polylines (n, 2) in mm; closed loops repeat their first point at the end.
    """
    k = int(subdivisions)
    cells = _cells_near(pattern, region)
    values = _fine_values(pattern, cells, k, phase)  # (C, k+1, k+1) complex
    crossings = _Crossings.find(values, cells, pattern.shape, k)
    first, second = _segments(values.imag, crossings)
    scale = pattern.h / k
    lines = _chains(first, second, crossings.ids, crossings.points)
    return [
        np.column_stack([pattern.x0 + scale * p[:, 0], pattern.y0 + scale * p[:, 1]]) for p in lines
    ]


def _cells_near(pattern: StripePattern, region: shapely.Geometry) -> np.ndarray:
    nx, ny = pattern.shape
    ci, cj = np.meshgrid(np.arange(nx - 1), np.arange(ny - 1), indexing="ij")
    centre_x = pattern.x0 + (ci + 0.5) * pattern.h
    centre_y = pattern.y0 + (cj + 0.5) * pattern.h
    reach = region.buffer(pattern.h)
    shapely.prepare(reach)
    psi = pattern.psi
    solved = (psi[:-1, :-1] != 0) & (psi[1:, :-1] != 0) & (psi[1:, 1:] != 0) & (psi[:-1, 1:] != 0)
    near = shapely.contains_xy(reach, centre_x, centre_y) & solved
    return np.column_stack([ci[near], cj[near]])


def _fine_values(pattern: StripePattern, cells: np.ndarray, k: int, phase: float) -> np.ndarray:
    """psi on the (k+1) x (k+1) fine nodes of each cell, in the cell's own orientation.

    Each corner predicts a plane wave exp(i wavenumber normal . (p - corner)); predictions
    are blended with bilinear weights. Corners whose normal opposes corner 00's are
    conjugated (and their normal flipped) first.
    """
    h = pattern.h
    t = np.arange(k + 1) / k
    ci, cj = cells[:, 0], cells[:, 1]
    reference = pattern.normal[ci, cj]
    psi = pattern.psi * np.exp(-1j * phase)
    values = np.zeros((len(cells), k + 1, k + 1), complex)
    for di, dj in ((0, 0), (1, 0), (0, 1), (1, 1)):
        m = pattern.normal[ci + di, cj + dj]
        flip = (m * reference).sum(axis=1) < 0
        m = np.where(flip[:, None], -m, m)
        corner = np.where(flip, np.conj(psi[ci + di, cj + dj]), psi[ci + di, cj + dj])
        kx = pattern.wavenumber[ci + di, cj + dj] * m[:, 0] * h
        ky = pattern.wavenumber[ci + di, cj + dj] * m[:, 1] * h
        wave_x = np.exp(1j * kx[:, None] * (t[None, :] - di))  # (C, k+1)
        wave_y = np.exp(1j * ky[:, None] * (t[None, :] - dj))
        weight_x = t if di else 1 - t
        weight_y = t if dj else 1 - t
        values += (corner[:, None, None] * (wave_x * weight_x)[:, :, None]) * (wave_y * weight_y)[
            :, None, :
        ]
    return values


@dataclass(frozen=True)
class _Crossings:
    """Zero crossings of Im psi on the fine edges, in compressed form.

    ``horizontal`` (C, k, k+1) and ``vertical`` (C, k+1, k) hold the index of the crossing on
    each fine edge of each cell, or -1; ``ids`` the global fine-edge id of each crossing
    (shared by the cells on either side), ``points`` its position in fine units and
    ``real`` Re psi there.
    """

    horizontal: np.ndarray
    vertical: np.ndarray
    ids: np.ndarray
    points: np.ndarray
    real: np.ndarray

    @classmethod
    def find(
        cls, values: np.ndarray, cells: np.ndarray, shape: tuple[int, int], k: int
    ) -> _Crossings:
        nj = (shape[1] - 1) * k + 1
        positive = values.imag > 0
        found = []
        for axis in (1, 2):  # edges along fine x (axis 1), then along fine y (axis 2)
            low = [slice(None)] * 3
            high = [slice(None)] * 3
            low[axis], high[axis] = slice(None, -1), slice(1, None)
            change = positive[tuple(low)] != positive[tuple(high)]
            cell, u, v = np.nonzero(change)
            step = (1, 0) if axis == 1 else (0, 1)
            z0 = values[cell, u, v]
            z1 = values[cell, u + step[0], v + step[1]]
            t = _crossing_fraction(z0, z1)
            big_u = cells[cell, 0] * k + u
            big_v = cells[cell, 1] * k + v
            index = np.full(change.shape, -1, np.int64)
            found.append(
                (
                    index,
                    (cell, u, v),
                    2 * (big_u * nj + big_v) + (axis - 1),
                    np.column_stack([big_u + t * step[0], big_v + t * step[1]]),
                    z0.real + t * (z1.real - z0.real),
                )
            )
        offset = 0
        for index, where, ids, _, _ in found:
            index[where] = offset + np.arange(len(ids))
            offset += len(ids)
        return cls(
            horizontal=found[0][0],
            vertical=found[1][0],
            ids=np.concatenate([found[0][2], found[1][2]]),
            points=np.concatenate([found[0][3], found[1][3]]),
            real=np.concatenate([found[0][4], found[1][4]]),
        )


def _crossing_fraction(z0: np.ndarray, z1: np.ndarray) -> np.ndarray:
    """Where along an edge Im psi vanishes: by interpolating the phase (exact for a plane
    wave) for zero-phase crossings, Im psi linearly for the others (which are dropped)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        linear = z0.imag / (z0.imag - z1.imag)
        by_phase = -np.angle(z0) / np.angle(z1 * np.conj(z0))
    zero_phase = (z0.real + linear * (z1.real - z0.real)) > 0
    t = np.where(zero_phase & (np.abs(by_phase - 0.5) <= 0.5), by_phase, linear)
    return np.where(np.isfinite(t), t, 0.5)


def _segments(imag: np.ndarray, crossings: _Crossings) -> tuple[np.ndarray, np.ndarray]:
    """Marching-squares segments as pairs of crossing indices, kept where Re psi > 0."""
    f00, f10 = imag[:, :-1, :-1], imag[:, 1:, :-1]
    f11, f01 = imag[:, 1:, 1:], imag[:, :-1, 1:]
    case = (f00 > 0) * 1 + (f10 > 0) * 2 + (f11 > 0) * 4 + (f01 > 0) * 8
    cell, u, v = np.nonzero((case != 0) & (case != 15))
    case = case[cell, u, v]
    centre_negative = (f00 + f10 + f11 + f01)[cell, u, v] <= 0
    # crossing index on edges 0 bottom, 1 right, 2 top, 3 left of each active fine cell
    edge = np.column_stack(
        [
            crossings.horizontal[cell, u, v],
            crossings.vertical[cell, u + 1, v],
            crossings.horizontal[cell, u, v + 1],
            crossings.vertical[cell, u, v],
        ]
    )
    first, second = _FIRST[case], _SECOND[case]
    for saddle, (pair_one, pair_two) in _SADDLE_OTHER.items():
        swap = (case == saddle) & centre_negative
        first[swap], second[swap] = pair_one, pair_two
    rows = np.arange(len(case))
    pairs = [np.column_stack([edge[rows, first[:, 0]], edge[rows, first[:, 1]]])]
    two = second[:, 0] >= 0
    pairs.append(
        np.column_stack([edge[rows[two], second[two, 0]], edge[rows[two], second[two, 1]]])
    )
    pairs = np.concatenate(pairs)
    pairs = pairs[(pairs >= 0).all(axis=1)]
    positive = (crossings.real[pairs[:, 0]] > 0) & (crossings.real[pairs[:, 1]] > 0)
    return pairs[positive, 0], pairs[positive, 1]


def _chains(
    first: np.ndarray, second: np.ndarray, ids: np.ndarray, points: np.ndarray
) -> list[np.ndarray]:
    """Join segments that share a fine edge into polylines (fine units)."""
    if len(first) == 0:
        return []
    ends = np.concatenate([ids[first], ids[second]])
    node_of = np.unique(ends, return_inverse=True)[1]
    n = node_of.max() + 1
    a, b = node_of[: len(first)], node_of[len(first) :]
    position = np.zeros((n, 2))
    position[a], position[b] = points[first], points[second]
    keep = a != b
    a, b = a[keep], b[keep]
    degree = np.bincount(np.concatenate([a, b]), minlength=n)
    graph = sp.coo_matrix((np.ones(len(a)), (a, b)), shape=(n, n)).tocsr()
    count, label = connected_components(graph, directed=False)
    key = np.where(degree == 1, 0, n) + np.arange(n)
    start_key = np.full(count, 2 * n)
    np.minimum.at(start_key, label, key)
    starts = start_key % n
    open_component = start_key < n
    rows = np.concatenate([a, starts, np.full(count, n)])
    cols = np.concatenate([b, np.full(count, n), starts])
    full = sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n + 1, n + 1)).tocsr()
    order, predecessor = depth_first_order(full, n, directed=False, return_predecessors=True)
    order = order[1:]
    breaks = np.flatnonzero(predecessor[order][1:] != order[:-1]) + 1
    lines = []
    for chain in np.split(order, breaks):
        if len(chain) < 2:
            continue
        line = position[chain]
        closed = not open_component[label[chain[0]]] and len(chain) > 2
        lines.append(np.vstack([line, line[:1]]) if closed else line)
    return lines
