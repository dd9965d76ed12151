"""The picture of a scan compared with its target (``fabkit compare``).

The target (grey, left) beside the scan fitted to it (right), the scan's points coloured
by their distance to the target (mm), from one view and at one scale, as the pictures of
``run``'s shapes (:mod:`fabkit.plot.shapes`, whose view and colours these are): turned
so that the target's least spread direction points up, equal lengths on every axis, the
colour bar marking the RMS distance and the limit. The input is plain arrays.
"""

from __future__ import annotations

import numpy as np

from fabkit.plot.design import png
from fabkit.plot.shapes import (
    COLOURS,
    _box,
    _colour_bar,
    _facing_up,
    _frame,
    _nice_top,
    _surface,
    _view_frame,
)

SHOWN_POINTS = 15_000
"""Most scan points drawn (a seeded random choice of the measured ones)."""


def scan_picture(
    target_mm: np.ndarray,
    triangles: np.ndarray,
    points_mm: np.ndarray,
    distance_mm: np.ndarray,
    rms_mm: float,
    limit_mm: float,
    title: str,
    scan_title: str,
) -> bytes:
    """PNG bytes: the target (``target_mm`` (V, 3), ``triangles`` (F, 3)) beside the scan's
    points ``points_mm`` (n, 3) coloured by ``distance_mm`` (n,), the colour bar marking
    ``rms_mm`` and ``limit_mm``; ``title`` over both, ``scan_title`` over the scan."""
    import matplotlib.pyplot as plt
    from matplotlib.colors import Normalize

    if len(points_mm) > SHOWN_POINTS:
        chosen = np.random.default_rng(0).choice(len(points_mm), SHOWN_POINTS, replace=False)
        points_mm, distance_mm = points_mm[chosen], distance_mm[chosen]
    centre = target_mm.mean(0)
    turn = _view_frame(target_mm)
    target = (target_mm - centre) @ turn
    scan = (points_mm - centre) @ turn
    box = _box(np.vstack([target, scan]))
    norm = Normalize(0.0, _nice_top(max(float(distance_mm.max(initial=0.0)), limit_mm)))
    figure = plt.figure(figsize=(11.0, 5.0))
    left = figure.add_axes((-0.03, 0.0, 0.46, 0.86), projection="3d")
    right = figure.add_axes((0.38, 0.0, 0.46, 0.86), projection="3d")
    faces = _facing_up(target, triangles)
    _surface(left, target, faces, np.full(len(faces), np.nan), norm)
    right.scatter(*scan.T, c=distance_mm, cmap=COLOURS, norm=norm, s=1.5, depthshade=False)
    for axes in (left, right):
        _frame(axes, box)
    left.set_title("the target", fontsize=11)
    right.set_title(scan_title, fontsize=11)
    _colour_bar(figure, norm, rms_mm, limit_mm, False)
    figure.text(0.01, 0.02, "lengths in mm", fontsize=8, color="0.3")
    figure.suptitle(title, fontsize=12, y=0.97)
    return png(figure, tight=False)
