"""Preview images of a toolpath: PNG and SVG, one panel per layer (at most four).

Print moves are drawn to scale at 60 % of their road width (so that neighbouring lines stay
distinguishable and gaps show), over the domain outline in grey; travels are thin dark
lines. The roads are coloured by the first encoded channel (one colour when nothing is
encoded); the colour bar names it and the feature it encodes.
"""

from __future__ import annotations

import io
from pathlib import Path

import matplotlib
import numpy as np
import shapely
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.cm import ScalarMappable
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Circle, Patch, PathPatch
from matplotlib.path import Path as MplPath
from matplotlib.transforms import Bbox

from fabkit.calibration import LABELS
from fabkit.files.atomic import atomic_path
from fabkit.toolpath.model import PRINT, Toolpath

PANEL_INCHES = 6.0
ROAD_SCALE = 0.6
MAX_PANELS = 4
PAD_INCHES = 0.05
"""White margin around what is drawn (inches), as savefig's ``pad_inches`` had it."""
COLOUR_LEVELS = 64
"""Colour steps of the roads' channel (more than the eye tells apart on viridis)."""
WIDTH_STEP = 0.02
"""Relative width step at which a drawn road run is cut."""


def preview_images(
    toolpath: Toolpath,
    outlines: list[shapely.Geometry],
    formats: tuple[str, ...] = ("png", "svg"),
    dpi: int = 200,
) -> dict[str, bytes]:
    """``toolpath`` drawn over the per-layer ``outlines`` (mm), as the bytes of each image
    format (``"png"``, ``"svg"``, ``"pdf"``)."""
    shown = _shown_layers(len(toolpath.layers))
    channel = next(iter(toolpath.channels), None)
    figure = Figure(figsize=(PANEL_INCHES * len(shown), PANEL_INCHES), dpi=dpi)
    FigureCanvasAgg(figure)  # one renderer lays the figure out and draws the PNG
    axes = figure.subplots(1, len(shown), squeeze=False)[0]
    low, high = toolpath.bounds()
    span = np.maximum(np.asarray(high[:2] - low[:2], float), 1e-9) * 1.04
    extent = float(span.max())
    norm = _norm(toolpath, channel)
    middle = 0.5 * (low + high)
    for ax, index in zip(axes, shown, strict=True):
        _draw_layer(ax, toolpath, index, outlines[index % len(outlines)], channel, norm, extent)
        ax.set_xlim(middle[0] - span[0] / 2, middle[0] + span[0] / 2)  # the part, no more:
        ax.set_ylim(middle[1] - span[1] / 2, middle[1] + span[1] / 2)  # the box fits it
    if norm is not None:
        label = f"{LABELS.get(channel, channel)}: {toolpath.channels[channel] or 'eps'}"
        mappable = ScalarMappable(norm=norm, cmap="viridis")
        figure.colorbar(mappable, ax=axes.tolist(), shrink=0.8, label=label)
    box = _tight_box(figure)
    images = {}
    for fmt in formats:
        buffer = io.BytesIO()
        figure.savefig(buffer, dpi=dpi, format=fmt, bbox_inches=box)
        images[fmt] = buffer.getvalue()
    return images


def _tight_box(figure: Figure) -> Bbox:
    """What ``bbox_inches="tight"`` crops ``figure`` to (inches, :data:`PAD_INCHES`
    around it), laid out once for every format: savefig's "tight" lays the figure out
    again for each (1.76 s -> 1.59 s for PNG and SVG on Fig. 3 at 20 mm)."""
    figure.draw_without_rendering()
    return figure.get_tightbbox().padded(PAD_INCHES)


def save_preview(
    toolpath: Toolpath,
    outlines: list[shapely.Geometry],
    paths: list[str | Path],
    dpi: int = 200,
) -> None:
    """Draw ``toolpath`` over the per-layer ``outlines`` (mm) and save to each of ``paths``
    (the suffix picks the format: .png, .svg, .pdf)."""
    formats = tuple(Path(path).suffix.lstrip(".") for path in paths)
    images = preview_images(toolpath, outlines, formats, dpi)
    for path, fmt in zip(paths, formats, strict=True):
        with atomic_path(path) as tmp:
            tmp.write_bytes(images[fmt])


def _norm(toolpath: Toolpath, channel: str | None) -> Normalize | None:
    """The colour scale of a channel over every print vertex (None: no channel)."""
    if channel is None:
        return None
    values = np.concatenate(
        [m.channels[channel][1:] for _, m in toolpath.moves() if m.kind == PRINT]
    )
    finite = values[np.isfinite(values)]
    if not len(finite):
        return None
    if finite.min() == finite.max():
        return Normalize(finite.min() - 1, finite.max() + 1)
    return Normalize(finite.min(), finite.max())


def _shown_layers(count: int) -> list[int]:
    if count <= MAX_PANELS:
        return list(range(count))
    return sorted({0, 1, count - 2, count - 1})


def _draw_layer(
    ax, toolpath: Toolpath, index: int, outline, channel: str | None, norm, extent: float
) -> None:
    layer = toolpath.layers[index]
    ax.set_aspect("equal", adjustable="box")
    # y given: matplotlib does not look for tick labels above the panel (there are none)
    # at each draw, 0.08 s of a preview
    ax.set_title(f"layer {index + 1}  z = {layer.z_mm:g} mm", y=1.0)
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    for polygon in shapely.get_parts(outline):  # as add_patch, not measured for the
        # limits, set afterwards (0.08 s of a preview, walking every curve of the outline)
        ax.add_artist(PathPatch(_polygon_path(polygon), facecolor="0.88", edgecolor="0.5", lw=0.5))
    points_per_mm = PANEL_INCHES * 0.75 * 72 / extent  # axes span about 3/4 of the panel
    prints = [m for m in layer.moves if m.kind == PRINT]
    lines, widths, values = _road_runs(prints, channel, norm)
    roads = LineCollection(
        lines,
        linewidths=widths * points_per_mm * ROAD_SCALE,
        capstyle="round",
        joinstyle="round",
    )
    if norm is not None:
        roads.set_array(values)
        roads.set_cmap("viridis")
        roads.set_norm(norm)
    else:
        roads.set_color("tab:blue")
    ax.add_collection(roads)
    travels = [m.xyz[:, :2] for m in layer.moves if m.kind != PRINT]
    if travels:
        ax.add_collection(LineCollection(travels, linewidths=0.3, colors="0.15", alpha=0.7))


def _road_runs(
    prints: list, channel: str | None, norm: Normalize | None
) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """The print moves as polylines of one colour and width each: a move is cut where its
    segments' value moves to another of COLOUR_LEVELS colour steps or its width by more
    than WIDTH_STEP (relative). Returns the polylines ((k, 2) mm each), their widths (mm)
    and values (the channel's, mid-step). Drawn per segment, a sheet is ~20,000 paths;
    as runs, a few thousand (the SVG's size and drawing time follow)."""
    width = np.concatenate([m.width[1:] for m in prints])
    value = (
        np.concatenate([m.channels[channel][1:] for m in prints])
        if norm is not None
        else np.zeros_like(width)
    )
    move = np.repeat(np.arange(len(prints)), [len(m.xyz) - 1 for m in prints])
    colour = np.zeros(len(value), np.int64)
    if norm is not None:  # a value that is not finite (a layer not encoded): its own step, -1
        scaled = np.clip(np.asarray(norm(value), float), 0, 1) * (COLOUR_LEVELS - 1) + 0.5
        finite = np.isfinite(scaled)
        colour[finite] = np.floor(scaled[finite]).astype(np.int64)
        colour[~finite] = -1
    size = np.round(np.log(np.maximum(width, 1e-9)) / np.log1p(WIDTH_STEP)).astype(np.int64)
    cut = np.ones(len(move), bool)
    cut[1:] = (move[1:] != move[:-1]) | (colour[1:] != colour[:-1]) | (size[1:] != size[:-1])
    starts = np.flatnonzero(cut)
    ends = np.append(starts[1:], len(move))
    xy = np.concatenate([m.xyz[:, :2] for m in prints])  # segment k starts at k + move[k]
    lines = [xy[a + move[a] : b + move[a] + 1] for a, b in zip(starts, ends, strict=True)]
    if norm is not None:
        steps = colour[starts] / (COLOUR_LEVELS - 1)
        value = np.where(colour[starts] >= 0, norm.inverse(steps), np.nan)
    else:
        value = value[starts]
    return lines, width[starts], np.asarray(value, float)


def _width_quads(line: np.ndarray, widths: np.ndarray) -> np.ndarray:
    """(n - 1, 4, 2) quadrilaterals covering a centreline (n, 2) at its per-vertex widths
    (mm): each segment's piece of the channel, to be coloured by its width."""
    tangent = np.gradient(line, axis=0) if len(line) > 1 else np.zeros_like(line)
    length = np.linalg.norm(tangent, axis=1, keepdims=True)
    normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1) / np.where(length > 0, length, 1)
    left, right = line + normal * widths[:, None] / 2, line - normal * widths[:, None] / 2
    return np.stack([left[:-1], left[1:], right[1:], right[:-1]], axis=1)


def _polygon_path(polygon: shapely.Polygon) -> MplPath:
    rings = [np.asarray(polygon.exterior.coords)] + [
        np.asarray(r.coords) for r in polygon.interiors
    ]
    vertices = np.concatenate(rings)
    codes = np.concatenate(
        [[MplPath.MOVETO] + [MplPath.LINETO] * (len(r) - 2) + [MplPath.CLOSEPOLY] for r in rings]
    )
    return MplPath(vertices, codes)


def save_channel_preview(layout, paths: list[str | Path], dpi: int = 200) -> None:
    """Draw a baromorph :class:`~fabkit.toolpath.baromorph.ChannelLayout`: the sheet (its
    walls) light grey, every channel coloured along its length by its local width (the
    colour bar spans every width drawn), the manifold dark grey, the inlet as a red dot."""
    low_x, low_y, high_x, high_y = shapely.union_all([layout.outline, layout.network]).bounds
    margin = 0.03 * max(high_x - low_x, high_y - low_y)
    aspect = (high_x - low_x + 2 * margin) / (high_y - low_y + 2 * margin)
    width = float(np.clip(PANEL_INCHES * aspect, 2.5, 2 * PANEL_INCHES))
    figure = Figure(figsize=(width + 1.8, PANEL_INCHES), layout="constrained")
    ax = figure.subplots()
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_title("baromorph channels by local width")
    for polygon in shapely.get_parts(layout.outline):
        ax.add_patch(PathPatch(_polygon_path(polygon), facecolor="0.85", edgecolor="0.4", lw=0.5))
    for polygon in shapely.get_parts(layout.manifold):
        ax.add_patch(PathPatch(_polygon_path(polygon), facecolor="0.25", edgecolor="none"))
    widths = np.concatenate(layout.widths) if layout.widths else np.ones(1)
    low, high = float(widths.min()), float(widths.max())
    norm = Normalize(low, high if high > low else low + 1e-3)
    cmap = matplotlib.colormaps["viridis"]
    for line, line_widths in zip(layout.centrelines, layout.widths, strict=True):
        line, line_widths = np.asarray(line, float), np.asarray(line_widths, float)
        quads = _width_quads(line, line_widths)
        ax.add_collection(
            PolyCollection(
                quads, array=0.5 * (line_widths[:-1] + line_widths[1:]), cmap=cmap, norm=norm,
                edgecolors="face", linewidths=0.4,
            )
        )  # fmt: skip
        for end in (0, -1):  # the round ends, at their own width
            ax.add_patch(
                Circle(line[end], line_widths[end] / 2, color=cmap(norm(line_widths[end])), lw=0)
            )
    ax.plot(*layout.inlet, "o", color="tab:red")
    ax.legend(
        handles=[
            Patch(facecolor="0.85", edgecolor="0.4", label="sheet (walls)"),
            Patch(facecolor="0.25", label="manifold"),
            Line2D([], [], marker="o", color="tab:red", ls="none", label="inlet"),
        ],
        loc="upper center",
        bbox_to_anchor=(0.5, -0.09),
        ncol=3,
        fontsize="small",
    )
    ax.set_xlim(low_x - margin, high_x + margin)
    ax.set_ylim(low_y - margin, high_y + margin)
    figure.colorbar(ScalarMappable(norm=norm, cmap=cmap), ax=ax, label="local channel width (mm)")
    for path in paths:
        with atomic_path(path) as tmp:
            figure.savefig(tmp, dpi=dpi, format=Path(path).suffix.lstrip("."))
