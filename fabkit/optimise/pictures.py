"""Pictures of a search: the objective over the evaluations, and the flat sheet of the
spec as given beside the best one (PNG, matplotlib)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402
from matplotlib.tri import Triangulation  # noqa: E402

from fabkit.design.design import Design  # noqa: E402
from fabkit.design.patches import grid_triangles  # noqa: E402
from fabkit.files.atomic import atomic_path  # noqa: E402
from fabkit.optimise.search import Result  # noqa: E402


def _save(figure: plt.Figure, path: str | Path) -> None:
    with atomic_path(path) as tmp:
        figure.savefig(tmp, dpi=110, bbox_inches="tight", format="png")
    plt.close(figure)


def search_picture(result: Result, start: float, objective: str, path: str | Path) -> None:
    """Every evaluation's objective in the order the search asked for it (dots; refused or
    failing candidates at 0), the best so far (line) and the spec as given (dashed)."""
    values = np.array([e.value for _, e in result.history])
    number = np.arange(1, len(values) + 1)
    figure, axes = plt.subplots(figsize=(7.5, 4.2))
    axes.scatter(number, values, s=4, color="0.55", alpha=0.6, label="evaluation", lw=0)
    axes.plot(number, np.maximum.accumulate(values), color="C3", lw=1.8, label="best so far")
    axes.axhline(start, color="C0", ls="--", lw=1.2, label=f"spec as given ({start:.3g})")
    axes.set_xlabel("evaluation")
    label = "covered flat area" if objective == "flat" else "smallest covered target area"
    axes.set_ylabel(f"{label} (design units²)")
    best = values.max(initial=0.0)
    ratio = f", {best / start:.2f}x" if start > 0 else ""
    axes.set_title(f"search: best {best:.3g}{ratio} after {len(values)} evaluations")
    axes.legend(loc="lower right")
    axes.grid(alpha=0.3)
    _save(figure, path)


def sheets_picture(given: Design, best: Design, summary: dict[str, Any], path: str | Path) -> None:
    """The flat sheets of the spec as given and of the best spec, side by side on one
    scale: the solved domain coloured by the first feature, its outline, director lines."""
    figure, axes = plt.subplots(1, 2, figsize=(12, 5.6))
    eps = np.concatenate([d.eps[0][d.valid] for d in (given, best)])
    limits = (float(eps.min()), float(eps.max()))
    names = ("spec as given", "best")
    values = (summary["start"]["value"], summary["best_solved_again"]["value"])
    mappable = None
    for ax, design, name, value in zip(axes, (given, best), names, values, strict=True):
        mappable = _flat_sheet(ax, design, limits) or mappable
        ax.set_title(f"{name}: {design.valid.sum()} points, objective {value:.3g}")
    extent = np.concatenate([d.r[0][d.valid] for d in (given, best)])
    low, high = extent.min(0), extent.max(0)
    pad = 0.05 * float((high - low).max())
    for ax in axes:
        ax.set_xlim(low[0] - pad, high[0] + pad)
        ax.set_ylim(low[1] - pad, high[1] + pad)
        ax.set_aspect("equal")
        ax.set_xlabel("x (design units)")
        ax.set_ylabel("y (design units)")
    feature = best.problem.material.features[0]
    if mappable is not None:
        figure.colorbar(mappable, ax=list(axes), label=feature, shrink=0.85)
    _save(figure, path)


def _flat_sheet(axes, design: Design, limits: tuple[float, float]):
    """Draw one flat sheet; returns the colour mapping of its eps (None: no cell)."""
    points, triangles = grid_triangles(design.valid)
    if not len(triangles):  # no solved cell: nothing to draw but the note
        axes.text(0.5, 0.5, "no solved cell", transform=axes.transAxes, ha="center")
        return None
    xy = design.r[0][points[:, 0], points[:, 1]]
    colour = design.eps[0][points[:, 0], points[:, 1]]
    mesh = Triangulation(xy[:, 0], xy[:, 1], triangles)
    mappable = axes.tripcolor(mesh, colour, shading="gouraud", vmin=limits[0], vmax=limits[1])
    sides = (triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]])
    edges = np.sort(np.concatenate(sides), 1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    axes.add_collection(LineCollection(xy[unique[counts == 1]], colors="black", lw=0.8))
    flat = design.r[0]
    stride = max(1, int(np.ptp(np.nonzero(design.valid.any(1))[0]) // 20))
    for k in range(0, flat.shape[1], stride):  # director lines: the u-curves, v fixed
        rows = np.nonzero(design.valid[:, k])[0]
        for run in np.split(rows, np.nonzero(np.diff(rows) > 1)[0] + 1):
            if len(run) > 1:
                axes.plot(flat[run, k, 0], flat[run, k, 1], color="white", lw=0.5, alpha=0.7)
    return mappable
