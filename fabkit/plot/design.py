"""Pictures of a design: the flat sheet, eps, every actuated surface, the residuals (PNG).

Each drawing takes a :class:`~fabkit.plot.scene.Scene` (plain data) and returns PNG
bytes; the caller writes the files.
"""

from __future__ import annotations

import io
from collections.abc import Sequence

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import shapely  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402
from matplotlib.colors import LogNorm  # noqa: E402
from matplotlib.tri import Triangulation  # noqa: E402

from fabkit.design.check import RESIDUAL_TITLES, RESIDUALS, Tolerances  # noqa: E402
from fabkit.design.design import Design  # noqa: E402
from fabkit.design.patches import grid_triangles  # noqa: E402
from fabkit.field.part import Part, solved_nodes  # noqa: E402
from fabkit.plot.scene import Scene, curve_stride, grid_lines, true_runs  # noqa: E402

DPI = 110
"""Pixels per inch of the report's pictures."""
SHOWN_PX = 1168
"""The widest a picture is shown in report.html (its body's width, px): a wider one is
scaled down, its text with it."""
MIN_TEXT_PX = 10.0
"""The smallest text height a reader sees in the report (px)."""
PANEL_INCHES = 4.0
TITLE_Y = 1.0
"""Where a panel's title sits (axes fraction: on its top edge, as matplotlib puts it when
nothing is above the panel). Given, matplotlib does not measure every panel's tick labels
at each draw to see whether the title must move up (nothing is ever above these panels):
0.1-0.3 s of a picture of 4-16 panels on Fig. 3."""


def readable_points(width_inches: float, points: float = 9.0) -> float:
    """A font size (pt) at least ``points`` that the report shows at least
    :data:`MIN_TEXT_PX` tall in a picture ``width_inches`` wide."""
    shown = min(1.0, SHOWN_PX / (width_inches * DPI))
    return max(points, round(MIN_TEXT_PX / shown * 72 / DPI + 0.05, 1))


def png(figure: plt.Figure, tight: bool = True) -> bytes:
    """The figure as PNG bytes (:data:`DPI`; ``tight``: cropped to what is drawn); closes it."""
    buffer = io.BytesIO()
    figure.savefig(buffer, dpi=DPI, bbox_inches="tight" if tight else None, format="png")
    plt.close(figure)
    return buffer.getvalue()


def flat_sheet(scene: Scene) -> bytes:
    """The flat sheet: director lines (u-curves) coloured by the first feature, v-curves
    grey, the solved region's border grey and the part's outline black."""
    design = scene.design
    flat = design.r[0]
    figure, axes = plt.subplots(figsize=(6.5, 6))
    lines = grid_lines(flat, design.valid, 1, curve_stride(design, 1))
    if lines:
        xy = _one_line(lines)
        axes.plot(xy[:, 0], xy[:, 1], color="0.75", lw=0.6, zorder=1)
    segments, colours = [], []
    eps = design.eps[0]
    for k in range(0, flat.shape[1], max(1, curve_stride(design, 0) // 2)):
        for run in true_runs(design.valid[:, k]):
            if len(run) > 1:
                points = flat[run, k]
                segments.extend(np.stack([points[:-1], points[1:]], 1))
                colours.extend(0.5 * (eps[run[:-1], k] + eps[run[1:], k]))
    collection = LineCollection(segments, array=np.array(colours), cmap="viridis", lw=1.4)
    axes.add_collection(collection)
    figure.colorbar(collection, ax=axes, label=scene.features[0])
    _outline(axes, scene.part)
    axes.set_aspect("equal")
    axes.autoscale()
    axes.set_xlabel("x (design units)")
    axes.set_ylabel("y (design units)")
    axes.set_title("flat sheet: director lines (coloured) and v-curves (grey)", y=TITLE_Y)
    return png(figure)


def _outline(axes, part: Part) -> None:
    """Draw the border of the solved region (grey) and the part's outline (black)."""
    for geometry, colour, width in ((part.solved, "0.55", 0.8), (part.outline, "black", 1.4)):
        for polygon in shapely.get_parts(geometry):
            for ring in (polygon.exterior, *polygon.interiors):
                xy = np.asarray(ring.coords)
                axes.plot(xy[:, 0], xy[:, 1], color=colour, lw=width, zorder=3)


def eps_maps(scene: Scene) -> bytes:
    """Every feature on the flat sheet (left column) and on the (u, v) grid (right column)."""
    design, features = scene.design, scene.features
    patch = solved_nodes(design)  # an initial curve's valid nodes run past the patch
    points, triangles = grid_triangles(patch)
    height = 4.6 * len(features)
    figure, axes = plt.subplots(
        len(features),
        2,
        figsize=(11, height),
        squeeze=False,
        gridspec_kw=_EPS_GRID | {"bottom": 0.55 / height, "top": 1 - 0.35 / height},
    )
    xy = design.r[0][points[:, 0], points[:, 1]]
    extent = [design.u[0], design.u[-1], design.v[0], design.v[-1]]
    for row, name in enumerate(features):
        values = design.eps[row]
        if len(triangles):
            mesh = Triangulation(xy[:, 0], xy[:, 1], triangles)
            shading = axes[row, 0].tripcolor(
                mesh, values[points[:, 0], points[:, 1]], shading="gouraud", cmap="viridis"
            )
            figure.colorbar(shading, ax=axes[row, 0], label=name)
        axes[row, 0].set_aspect("equal")
        axes[row, 0].set_xlabel("x (design units)")
        axes[row, 0].set_ylabel("y (design units)")
        axes[row, 0].set_title(f"{name} on the flat sheet", y=TITLE_Y)
        solved = np.where(patch, values, np.nan)
        _zoom(axes[row, 1], design, patch)  # before the image: it then keeps these limits
        image = axes[row, 1].imshow(
            solved.T, origin="lower", extent=extent, cmap="viridis", aspect="auto"
        )
        figure.colorbar(image, ax=axes[row, 1], label=name)
        axes[row, 1].set_xlabel("u")
        axes[row, 1].set_ylabel("v")
        axes[row, 1].set_title(f"{name} on the material grid", y=TITLE_Y)
    return png(figure)


_EPS_GRID = {"left": 0.07, "right": 0.98, "wspace": 0.22, "hspace": 0.28}
"""The panels of :func:`eps_maps` (figure fractions, and gaps as a share of a panel), laid
out as constrained layout did: it measured every tick label twice a draw (eps_maps 1.56 s
-> 0.98 s on Fig. 3 without it, with the titles at :data:`TITLE_Y`)."""


def _zoom(axes, design: Design, shown: np.ndarray | None = None) -> None:
    """Limit a (u, v) panel to the grid points ``shown`` (default: the solved ones)."""
    shown = design.valid if shown is None else shown
    rows = np.nonzero(shown.any(axis=1))[0]
    cols = np.nonzero(shown.any(axis=0))[0]
    if len(rows):
        axes.set_xlim(design.u[rows[0]], design.u[rows[-1]])
        axes.set_ylim(design.v[cols[0]], design.v[cols[-1]])


def actuated_surfaces(scene: Scene) -> bytes:
    """Every target in 3D: the surface near the patch, with the patch's u- and v-curves.

    Equal scales on x, y and z (a cube around the patch; the target surface is cut to it),
    labelled axes in design units, a few ticks each.
    """
    views = scene.surfaces
    width = 5.5 * max(len(views), 1)
    figure = plt.figure(figsize=(width, 5.8))
    ticks, labels = readable_points(width, 8.0), readable_points(width)
    for column, view in enumerate(views):
        axes = figure.add_subplot(1, len(views), column + 1, projection="3d")
        _equal_3d(axes, view.box, ticks, labels)  # first: what is drawn then keeps the box
        if view.backdrop is not None:
            xyz = view.backdrop
            axes.plot_surface(
                xyz[..., 0], xyz[..., 1], xyz[..., 2], color="0.85", alpha=0.35, linewidth=0
            )
        for curves, colour in ((view.u_curves, "tab:red"), (view.v_curves, "tab:blue")):
            if curves:
                xyz = _one_line(curves)
                axes.plot(xyz[:, 0], xyz[:, 1], xyz[:, 2], color=colour, lw=0.8)
        axes.set_title(view.title, fontsize=readable_points(width, 10.0))
    return png(figure)


def _one_line(curves: Sequence[np.ndarray]) -> np.ndarray:
    """Polylines (n_i, d) as one (sum n_i + count - 1, d), a NaN row between two: drawn
    as one line, the curves look as drawn one by one (about 60 lines a panel took 0.3 s
    of Fig. 3's 1.3 s surfaces picture)."""
    gap = np.full((1, curves[0].shape[1]), np.nan)
    return np.concatenate([part for xyz in curves for part in (gap, xyz)][1:])


def _equal_3d(axes, box, ticks: float, labels: float) -> None:
    """Equal scales: the same span on x, y and z; labelled axes with four ticks each
    (their labels ``ticks`` pt, the axes' names ``labels`` pt)."""
    from matplotlib.ticker import MaxNLocator

    if box is not None:
        centre, half = box
        for setter, c in zip((axes.set_xlim, axes.set_ylim, axes.set_zlim), centre, strict=True):
            setter(c - half, c + half)
    axes.set_box_aspect((1, 1, 1))
    for axis, name in ((axes.xaxis, "x"), (axes.yaxis, "y"), (axes.zaxis, "z")):
        axis.set_major_locator(MaxNLocator(4))
        axis.set_tick_params(labelsize=ticks)
        axis.set_label_text(f"{name} (design units)", fontsize=labels)


FLOOR = 1e-7
"""Residuals below this are drawn at it (the colour bar's bottom)."""


def residual_maps(scene: Scene) -> bytes:
    """Residual maps on the (u, v) grid: one column per surface, one row per residual.

    One log colour scale for every panel; its colour bar marks the check's tolerances
    (:class:`~fabkit.design.check.Tolerances`), and every panel's title gives its median
    and 95th percentile against the limits that apply to it.
    """
    design, maps, tolerances = scene.design, scene.maps, Tolerances()
    # a fixed grid (panels of one size, the colour bar beside them): constrained layout
    # took most of this picture's 2-4 s measuring every tick label. One column per
    # surface keeps the picture narrow enough for the report to show it near full size.
    width, height = PANEL_INCHES * len(maps) + 1.9, PANEL_INCHES * len(RESIDUALS) * 0.85
    text = readable_points(width)
    figure, axes = plt.subplots(
        len(RESIDUALS),
        len(maps),
        figsize=(width, height),
        squeeze=False,
        sharex=True,  # tick labels on the outer panels only: most of the drawing's time
        sharey=True,
        gridspec_kw={
            "left": 0.95 / width,
            "right": 1 - 1.75 / width,
            "bottom": 0.5 / height,
            "top": 1 - 0.75 / height,
            "wspace": 0.3,
            "hspace": 0.7,
        },
    )
    extent = [design.u[0], design.u[-1], design.v[0], design.v[-1]]
    finite = [np.isfinite(surface.maps[key]) for surface in maps for key in RESIDUALS]
    # every panel (axes shared), before the images: each image set all 16 panels' limits
    _zoom(axes[0, 0], design, np.logical_or.reduce(finite))  # again (0.1 s of 1.6 s)
    norm = LogNorm(vmin=FLOOR, vmax=1e-1)
    for column, surface in enumerate(maps):
        for row, key in enumerate(RESIDUALS):
            exact = surface.maps[key] < FLOOR  # round-off: the initial curves, given
            values = np.where(exact, np.nan, surface.maps[key])
            panel = axes[row, column]
            image = panel.imshow(
                values.T, origin="lower", extent=extent, norm=norm, cmap="magma", aspect="auto"
            )
            finite = surface.maps[key][np.isfinite(surface.maps[key])]
            median, p95 = np.percentile(finite, (50, 95)) if len(finite) else (np.nan,) * 2
            if key == "curvature":
                limits = f"limit {tolerances.curvature_median:.0e}"
            else:
                limits = f"limits {tolerances.isometry_median:.0e} / {tolerances.isometry_p95:.0e}"
            panel.set_title(
                f"{surface.name}: {RESIDUAL_TITLES[key]}\n"
                f"median {median:.1e}, p95 {p95:.1e}\n({limits})",
                fontsize=text,
                y=TITLE_Y,
            )
            panel.tick_params(labelsize=text)
            panel.set_xlabel("u" if row == len(RESIDUALS) - 1 else "", fontsize=text)
            panel.set_ylabel("v" if column == 0 else "", fontsize=text)
    bar = figure.colorbar(image, cax=figure.add_axes((1 - 1.45 / width, 0.12, 0.12 / width, 0.76)))
    bar.ax.tick_params(labelsize=text)
    bar.set_label(
        f"relative residual (log scale; blank: below {FLOOR:.0e}, exact to round-off, on "
        "the initial curves)\n"
        f"cyan: the check's limits, {tolerances.isometry_median:.0e} (isometry median), "
        f"{tolerances.isometry_p95:.0e} (isometry p95, curvature median)",
        fontsize=text,
    )
    for value in {tolerances.isometry_median, tolerances.isometry_p95, tolerances.curvature_median}:
        bar.ax.axhline(value, color="cyan", lw=2.5)
    return png(figure, tight=False)
