"""Two inks alternated along the roads so that their share follows a fraction field.

A machine with two inks and one nozzle (two valves, or two tools) cannot mix them: every
piece of road holds one ink. :func:`alternate_inks` chooses the ink of every segment so
that, over a few road widths, the share of the second ink is the encoded fraction f.

It is error diffusion with hysteresis, in print order. The error is the printed length
of the second ink minus the length f asked for (mm). Along a road, its own error is
carried exactly from the road's start (so a road's share is right to within half a
piece anywhere along it); across roads, the error the roads printed before left in a
Gaussian neighbourhood (:data:`SIGMA` road widths, on a grid of one road width) is added
with weight :data:`COUPLING`, so a road also corrects its neighbours and the error left
is pushed to short scales, which the sheet averages out. A road switches ink when the
error passes half a piece (``piece_mm``, the shortest run the valves or tools make) on
the side the other ink corrects, and a run is never shorter than half a piece except
where a road ends.

Layer on layer, the error a layer left is carried into the next with its sign turned
(the next layer starts from minus it): each layer then repeats the rounding of the one
below, and two layers differ where their fractions differ, not by rounding. A layered
sheet (:mod:`fabkit.design.layers`) carries its curvature in the difference between its
layers' fractions, about one per cent of the range on Fig. 3's wavy sheet, less than the
rounding of one layer; on one layer repeated, the layers get one pattern. (Carried with
its sign kept, as one grid over all layers would, the next layer undoes the one below's
rounding: right in their mean, twice as wrong in their difference.)
"""

from __future__ import annotations

import math

import numpy as np

SIGMA = 1.5
"""Standard deviation of the neighbourhood of earlier roads, in road widths."""
COUPLING = 3.0
"""Weight of the earlier roads' error against a road's own."""
REACH = 3.0
"""The neighbourhood is cut at REACH x SIGMA."""


def alternate_inks(
    xy: np.ndarray,
    start: np.ndarray,
    prints: np.ndarray,
    fraction: np.ndarray,
    width: float,
    piece_mm: float,
    layer: np.ndarray | None = None,
) -> np.ndarray:
    """The ink (0 or 1) of every vertex's segment (V,); 0 outside print moves.

    ``xy`` (V, 2) vertex positions (mm), ``start`` (M + 1,) the moves' first vertices,
    ``prints`` the indices of the print moves in machine order, ``fraction`` (V,) the
    second ink's share for the segment ending at each vertex, ``width`` the road width
    (mm), ``piece_mm`` the shortest run of one ink (mm), ``layer`` (M,) every move's layer
    (default: one layer).
    """
    ink = np.zeros(len(xy), dtype=np.int8)
    if not len(prints):
        return ink
    grid = _Grid(xy, start, prints, width)
    half = 0.5 * piece_mm
    layers = np.zeros(int(prints.max()) + 1, dtype=int) if layer is None else layer
    below = grid.error.copy()  # the grid when the current layer began
    current = layers[prints[0]]
    for move in prints.tolist():
        if layers[move] != current:  # the next layer repeats this one's rounding
            grid.error = -(grid.error - below)
            below, current = grid.error.copy(), layers[move]
        deposits = []
        own, using, run = 0.0, -1, 0.0
        for v in range(int(start[move]) + 1, int(start[move + 1])):
            i, j = grid.cells[v - 1]
            share, length = float(fraction[v]), float(grid.length[v - 1])
            error = own + COUPLING * grid.near(i, j)
            if using < 0:
                using = int(abs(error + length * (1 - share)) < abs(error - length * share))
            elif run >= half and (error < -half if using == 0 else error > half):
                using, run = 1 - using, 0.0
            ink[v] = using
            step = length * (using - share)
            own += step
            run += length
            deposits.append((i, j, step))
        grid.add(deposits)
    return ink


class _Grid:
    """The error earlier roads left, on cells one road width wide, and the segments' cells
    and lengths."""

    def __init__(self, xy: np.ndarray, start: np.ndarray, prints: np.ndarray, width: float):
        self.radius = max(1, math.ceil(REACH * SIGMA))
        offsets = np.arange(-self.radius, self.radius + 1)
        kernel = np.exp(-0.5 * (offsets[:, None] ** 2 + offsets[None, :] ** 2) / SIGMA**2)
        self.kernel = kernel / kernel.sum()
        owned = np.concatenate([np.arange(start[m], start[m + 1]) for m in prints.tolist()])
        low, high = xy[owned].min(axis=0), xy[owned].max(axis=0)
        shape = np.ceil((high - low) / width).astype(int) + 1 + 2 * self.radius
        self.error = np.zeros(shape)
        middle = np.nan_to_num(0.5 * (xy[1:] + xy[:-1]), nan=0.0)
        cells = np.floor((middle - low) / width).astype(int) + self.radius
        self.cells = np.clip(cells, self.radius, shape - self.radius - 1).tolist()
        self.length = np.linalg.norm(np.diff(xy, axis=0), axis=1)

    def near(self, i: int, j: int) -> float:
        """The Gaussian-weighted mean error per cell around cell (i, j), times the
        kernel's cells: the error the earlier roads left nearby (mm)."""
        r = self.radius
        window = self.error[i - r : i + r + 1, j - r : j + r + 1]
        return float((self.kernel * window).sum())

    def add(self, deposits: list[tuple[int, int, float]]) -> None:
        for i, j, step in deposits:
            self.error[i, j] += step
