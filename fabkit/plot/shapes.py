"""Pictures of the shapes a sheet takes: per target, the target beside the simulated sheet.

Each picture shows one target (grey) and the sheet simulated under its stimulus, coloured
by the distance from each point of the sheet to its own point of the target (mm), from
the same view and at the same scale: both are turned so that the target's least spread
direction points up (the view looks down on it at an angle), with equal lengths on every
axis. The colour bar marks the sheet's RMS distance (the verdict's figure, quoted) and
the verdict's RMS limit. A sheet that takes the target's mirror image is shown as it is,
coloured by its distance to the target itself; its title quotes the verdict's distance
to the mirror image, so that the picture and the verdict never give one word two
numbers. The
input is plain data (a verdict's :class:`~fabkit.mechanics.verdict.Shape` with its
:class:`~fabkit.mechanics.compare.FormedShape`), drawn in ``fabkit run``'s worker.
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.colors import LightSource, Normalize  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402

from fabkit.mechanics.verdict import Shape  # noqa: E402
from fabkit.plot.design import png  # noqa: E402

COLOURS = "viridis"
"""The colour map of the distance to the target."""
TARGET_GREY = "0.8"
EDGES = (0.0, 0.0, 0.0, 0.25)
"""The mesh's edges, faint: they show how the surface curves."""
LIGHT = LightSource(azdeg=300, altdeg=60)
ELEVATION_DEG, AZIMUTH_DEG = 38.0, -62.0
"""The view: how high above the target's mean plane, and from which side (degrees)."""
MIN_HEIGHT = 0.25
"""The box around a picture is at least this share of its widest side high (the scales
stay equal on every axis: a nearly flat shape sits low in the box)."""


def shape_pictures(what: str, shapes: tuple[Shape, ...]) -> tuple[bytes, ...]:
    """One PNG per target (:func:`shape_picture`) of the sheet ``what`` ("as fabricated"
    or "as designed"), in order; every shape has its mesh."""
    return tuple(shape_picture(what, shape) for shape in shapes)


def shape_picture(what: str, verdict: Shape) -> bytes:
    """The target (left) and the sheet coloured by its distance to the target in mm
    (right), from one view; the colour bar marks the RMS distance and the verdict's RMS
    limit."""
    shape = verdict.mesh
    limit_mm = verdict.tolerance * shape.diameter_mm
    turn = _view_frame(shape.target_mm)
    target = (shape.target_mm - shape.target_mm.mean(0)) @ turn
    sheet = (shape.vertices_mm - shape.target_mm.mean(0)) @ turn
    triangles = _facing_up(target, shape.triangles)
    box = _box(np.vstack([target, sheet]))
    if verdict.mirrored:  # the distances drawn are to the target itself, not the verdict's
        rms = float(np.sqrt(np.mean(shape.distance_mm**2)))
    else:
        rms = verdict.mm(verdict.rms)  # the verdict's figure, quoted
    norm = Normalize(0.0, _nice_top(max(float(shape.distance_mm.max()), limit_mm)))
    figure = plt.figure(figsize=(11.0, 5.0))
    left = figure.add_axes((-0.03, 0.0, 0.46, 0.86), projection="3d")
    right = figure.add_axes((0.38, 0.0, 0.46, 0.86), projection="3d")
    _surface(left, target, triangles, np.full(len(triangles), np.nan), norm)
    _surface(right, sheet, triangles, shape.distance_mm[triangles].mean(axis=1), norm)
    for axes in (left, right):
        _frame(axes, box)
    left.set_title(f"the target, {shape.name}", fontsize=11)
    right.set_title(sheet_title(what, verdict), fontsize=11)
    _colour_bar(figure, norm, rms, limit_mm, verdict.mirrored)
    figure.text(0.01, 0.02, "lengths in mm", fontsize=8, color="0.3")
    to = "the target itself" if verdict.mirrored else "it"
    figure.suptitle(
        f"{shape.name}: the sheet {what} beside the target, coloured by its distance to {to} "
        f"(patch diameter {shape.diameter_mm:.3g} mm)",
        fontsize=12,
        y=0.995 if verdict.mirrored else 0.97,
    )
    return png(figure, tight=False)


def sheet_title(what: str, verdict: Shape) -> str:
    """The title over the sheet: for a mirror image, the verdict's RMS distance to it in
    mm, written as the verdict's line writes it."""
    if not verdict.mirrored:
        return f"the sheet {what}"
    from_mirror = verdict.mm(verdict.rms)
    return (
        f"the sheet {what}: the target's mirror image\n({from_mirror:.3g} mm RMS from it, "
        "the verdict's figure), shown as it is"
    )


def _colour_bar(figure, norm: Normalize, rms: float, limit: float, mirrored: bool) -> None:
    """The distance colour bar (mm), the RMS distance and the limit marked on it."""
    bar = figure.colorbar(
        plt.cm.ScalarMappable(norm, COLOURS), cax=figure.add_axes((0.915, 0.1, 0.018, 0.7))
    )
    bar.set_label(f"distance to the target{' itself' if mirrored else ''} (mm)")
    for value, label, colour in ((rms, "RMS", "black"), (limit, "limit", "red")):
        bar.ax.axhline(value, color=colour, lw=2)
        bar.ax.text(
            -0.4, value, f"{label} {value:.2g}", ha="right", va="center", fontsize=8,
            color=colour, transform=bar.ax.get_yaxis_transform(),
        )  # fmt: skip


def _view_frame(points: np.ndarray) -> np.ndarray:
    """An orthonormal frame (3, 3) whose columns are the points' principal directions,
    the least spread last (the "up" of the view), turned so that the middle of the
    patch lies above its rim."""
    centred = points - points.mean(0)
    _, _, axes = np.linalg.svd(centred, full_matrices=False)
    frame = axes.T.copy()
    height = centred @ frame[:, 2]
    middle = np.argmin(np.linalg.norm(centred @ frame[:, :2], axis=1))
    if height[middle] < np.mean(height):
        frame[:, 2] *= -1
    if np.linalg.det(frame) < 0:
        frame[:, 1] *= -1  # a proper rotation: the view is not a mirror image
    return frame


def _facing_up(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """``triangles`` ordered so that their normals on ``points`` point up on the whole
    (the light shades the side the view sees)."""
    a, b, c = (points[triangles[:, k]] for k in range(3))
    up = np.cross(b - a, c - a)[:, 2].sum()
    return triangles if up >= 0 else triangles[:, ::-1]


def _box(points: np.ndarray) -> np.ndarray:
    """The (3, 2) limits around ``points`` (n, 3) on x, y and z: a little margin, and a
    height of at least :data:`MIN_HEIGHT` of the widest side."""
    low, high = points.min(0), points.max(0)
    centre, half = (low + high) / 2, (high - low) / 2 * 1.03
    half[2] = max(half[2], MIN_HEIGHT * half.max())
    return np.column_stack([centre - half, centre + half])


def _nice_top(value: float) -> float:
    """The colour bar's top: ``value`` rounded up to 1, 2, 2.5 or 5 times a power of ten."""
    if not np.isfinite(value) or value <= 0:
        return 1.0
    power = 10.0 ** np.floor(np.log10(value))
    return float(next(step * power for step in (1, 2, 2.5, 5, 10) if step * power >= value))


def _surface(
    axes, points: np.ndarray, triangles: np.ndarray, values: np.ndarray, norm: Normalize
) -> None:
    """Triangles of ``points``, coloured by ``values`` per face (NaN: grey), shaded."""
    colours = plt.get_cmap(COLOURS)(norm(values))
    colours[~np.isfinite(values)] = matplotlib.colors.to_rgba(TARGET_GREY)
    axes.add_collection3d(
        Poly3DCollection(
            points[triangles],
            facecolors=colours,
            edgecolors=EDGES,
            linewidths=0.15,
            shade=True,
            lightsource=LIGHT,
        )
    )


def _frame(axes, box: np.ndarray) -> None:
    """The view, equal scales in mm on every axis, a few ticks."""
    from matplotlib.ticker import MaxNLocator

    for setter, (low, high) in zip((axes.set_xlim, axes.set_ylim, axes.set_zlim), box, strict=True):
        setter(low, high)
    axes.set_box_aspect(tuple(box[:, 1] - box[:, 0]), zoom=0.95)
    axes.view_init(ELEVATION_DEG, AZIMUTH_DEG)
    for axis in (axes.xaxis, axes.yaxis, axes.zaxis):
        axis.set_major_locator(MaxNLocator(4))
        axis.set_tick_params(labelsize=7, pad=0)
