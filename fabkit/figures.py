"""Figures printed in more than one place, each defined once here.

The solve summary (``design.json``), ``fabkit solve``/``run``/``energy`` and the reports
(``report.json``, ``report.html``) all take a surface's area from :func:`cell_integral`:
the integral over the *solved cells*, those whose four corners are solved grid points
(design units^2). Counting each solved point's step^2 instead (the old ``design.json``
figure) gives a different number for the same name; there is one definition now.
"""

from __future__ import annotations

import numpy as np

AREA_UNIT = "design units^2"


def cell_integral(values: np.ndarray, valid: np.ndarray, step: float) -> float:
    """Integral of ``values`` (nu, nv) du dv over the cells whose four corners are valid.

    Each cell contributes step^2 times the mean of its corners (bilinear trapezoid);
    ``step`` is the grid step in design units, so an area comes out in design units^2.
    """
    corners = [values[:-1, :-1], values[1:, :-1], values[:-1, 1:], values[1:, 1:]]
    masks = [valid[:-1, :-1], valid[1:, :-1], valid[:-1, 1:], valid[1:, 1:]]
    cells = np.logical_and.reduce(masks)
    total = sum(np.where(cells, corner, 0.0) for corner in corners)
    return float(step**2 * total.sum() / 4)
