"""What a swimmer run reports: figures per cycle, energy bounds per stage, plots, files.

* :func:`summary`: displacement per cycle (disc radii and mm), sideways drift, rotation,
  the same with half the stations and with a coarser Stokeslet point set (convergence),
  solver flags, closure, timing, and the work bound at every corner of the path;
* :func:`energy_bounds`: the frustrated energy of the bilayer held flat at every
  station (:mod:`fabkit.mechanics.energy`, per layer, summed), small-strain and
  neo-Hookean;
* :func:`plot_cycle`, :func:`plot_position`, :func:`plot_energy`: PNG figures (Agg);
* :func:`save_stroke`: the shapes and poses as ``stroke.npz``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from fabkit.files.atomic import atomic_path
from fabkit.mechanics.energy import DENSITIES
from fabkit.swimmer.cycle import POINT_ORDER, Convergence, Stroke, barycentric
from fabkit.swimmer.motion import align

DENSITY_NAMES = {"small_strain": "small-strain", "neo_hookean": "neo-Hookean"}
MM3_PA_TO_MJ = 1e-6
"""Pa x mm^3 in mJ."""


def energy_bounds(stroke: Stroke) -> dict[str, np.ndarray]:
    """Work bound (mJ) at every station (M + 1,) per density name.

    Each layer (thickness H / L, flat area pi R^2) held flat stores
    h A0 lambda1 lambda2 W(lambda1, lambda2); the layers' energies add.
    """
    spec = stroke.spec
    area = np.pi * spec.radius**2
    layer_thickness = spec.thickness / len(spec.layers)
    bounds = {}
    for name, density in DENSITIES.items():
        total = np.zeros(len(stroke.path.stimuli))
        for layer in spec.layers:
            stretches = np.array([layer.stretches(s) for s in stroke.path.stimuli])
            l1, l2 = stretches[:, 0], stretches[:, 1]
            w = density(l1, l2, spec.mechanics.young, spec.mechanics.poisson)
            total += layer_thickness * area * l1 * l2 * w
        bounds[name] = total * MM3_PA_TO_MJ
    return bounds


def summary(stroke: Stroke, checks: Convergence | None = None) -> dict[str, Any]:
    """The numbers of a run as a JSON-ready dict (see module docstring)."""
    spec = stroke.spec
    displacement = stroke.displacement
    corners = np.isclose(stroke.path.parameter, np.round(stroke.path.parameter))
    bounds = energy_bounds(stroke)
    return {
        "displacement_per_cycle_radii": float(displacement[2]),
        "displacement_per_cycle_mm": float(displacement[2] * spec.radius),
        "sideways_drift_radii": float(np.hypot(displacement[0], displacement[1])),
        "rotation_rad": float(np.linalg.norm(stroke.rotation)),
        "convergence": None if checks is None else _convergence(checks),
        "path": spec.path.tolist(),
        "stations": len(stroke.path.stimuli),
        "stokes_points": len(stroke.sheet.stokes),
        "epsilon_mm": stroke.epsilon,
        "mesh_vertices": len(stroke.sheet.points),
        "converged": [bool(c) for c in stroke.shapes.converged],
        "closure_radii": stroke.shapes.closure,
        "seconds": {"shapes": stroke.shapes.seconds, "hydrodynamics": stroke.seconds},
        "work_bound_mJ_at_corners": {
            name: values[corners].tolist() for name, values in bounds.items()
        },
        "elastic_energy_mJ": (stroke.shapes.energies * 1e3).tolist(),
    }


def _convergence(checks: Convergence) -> dict[str, Any]:
    rows = {"coarse Stokeslet points": checks.coarse, "half the stations": checks.half_stations}
    table = {
        label: {
            "displacement_per_cycle_radii": float(other.displacement[2]),
            "stokes_points": len(other.sheet.stokes),
            "stations": len(other.path.stimuli),
        }
        for label, other in rows.items()
        if other is not None
    }
    table["extrapolated to fine points"] = {
        "displacement_per_cycle_radii": float(checks.extrapolated[2]),
        "order": POINT_ORDER,
    }
    return table


def describe(data: dict[str, Any]) -> str:
    """A few lines for the terminal."""
    lines = [
        f"displacement per cycle: {data['displacement_per_cycle_radii']:+.5g} R "
        f"({data['displacement_per_cycle_mm']:+.4g} mm) along the axis (+ = towards the top layer)",
        f"sideways drift {data['sideways_drift_radii']:.2g} R, "
        f"rotation {data['rotation_rad']:.2g} rad",
        f"({data['stations']} shapes, {data['stokes_points']} Stokeslet points)",
    ]
    for label, item in (data["convergence"] or {}).items():
        where = (
            f"({item['stations']} shapes, {item['stokes_points']} Stokeslet points)"
            if "stations" in item
            else f"(Richardson, error ~ h^{item['order']:g})"
        )
        lines.append(f"  {label:28} {item['displacement_per_cycle_radii']:+.5g} R {where}")
    limit = (data["convergence"] or {}).get("extrapolated to fine points")
    if limit:
        best, computed = limit["displacement_per_cycle_radii"], data["displacement_per_cycle_radii"]
        short = abs(best - computed) / abs(best) if best else 0.0
        lines.append(
            f"  quote the extrapolated {best:+.3g} R: the computed value is {100 * short:.0f} % "
            "off it, the Stokeslet points' discretisation error (docs/swimmer.md)"
        )
    failed = data["converged"].count(False)
    if failed:
        lines.append(f"warning: {failed} of {len(data['converged'])} shapes did not converge")
    if data["closure_radii"] > 1e-3:
        lines.append(
            f"warning: a stimulus met twice gave shapes {data['closure_radii']:.2g} R apart "
            "(the sheet changed branch: hysteresis)"
        )
    seconds = data["seconds"]
    lines.append(
        f"time: shapes {seconds['shapes']:.1f} s, hydrodynamics {seconds['hydrodynamics']:.1f} s"
    )
    return "\n".join(lines)


def save_stroke(stroke: Stroke, path: Path) -> None:
    """Stations, mesh, vertex positions, Stokeslet points and poses as ``.npz`` (mm, rad)."""
    trajectory = stroke.trajectory
    with atomic_path(path) as tmp:
        np.savez_compressed(
            tmp,
            stimuli=stroke.path.stimuli,
            parameter=stroke.path.parameter,
            flat_points=stroke.sheet.points,
            triangles=stroke.sheet.triangles,
            positions=stroke.shapes.positions,
            stokes_flat=stroke.sheet.stokes,
            stokes_shapes=trajectory.shapes,
            rotations=trajectory.rotations,
            translations=trajectory.positions,
            twists=trajectory.twists,
        )


def _pyplot():
    """matplotlib.pyplot on the Agg backend (files only, no display)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(figure, path: Path) -> None:
    with atomic_path(path) as tmp:
        figure.savefig(tmp, dpi=110)
    _pyplot().close(figure)


def _plane(stimuli: np.ndarray) -> np.ndarray:
    """The first two stimulus components (n, 2) (zeros when there is one)."""
    if stimuli.shape[1] >= 2:
        return stimuli[:, :2]
    return np.column_stack([stimuli[:, 0], np.zeros(len(stimuli))])


def plot_cycle(stroke: Stroke, path: Path) -> None:
    """The path in stimulus space with the equilibrium shape at corners and mid-legs.

    Each shape is drawn in the body frame (best fit to the first), coloured by its height
    along the swimmer's axis on one colour scale for every shape (the colour bar, mm),
    with two material lines, the diameter y = 0 (red) and the circle r = R/2 (black), to
    show that the points correspond across shapes. A legend names every mark.
    """
    plt = _pyplot()
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize
    from matplotlib.lines import Line2D

    spec, sheet = stroke.spec, stroke.sheet
    plane = _plane(stroke.path.stimuli)
    figure = plt.figure(figsize=(10, 9))
    axes = figure.add_axes((0.34, 0.33, 0.32, 0.34))
    axes.plot(plane[:, 0], plane[:, 1], "o-", color="0.3", markersize=3)
    for start, end in zip(plane[:-1], plane[1:], strict=True):
        middle = 0.5 * (start + end)
        axes.annotate("", middle, start, arrowprops={"arrowstyle": "->", "color": "C0"})
    names = (*spec.stimuli, "")[:2]
    axes.set_xlabel(names[0] or "stimulus")
    axes.set_ylabel(names[1] or "(one stimulus)")
    low, high = plane.min(axis=0), plane.max(axis=0)
    pad = 0.1 * np.maximum(high - low, 1e-9)
    axes.set_xlim(low[0] - pad[0], high[0] + pad[0])
    axes.set_ylim(low[1] - pad[1], high[1] + pad[1])
    figure.suptitle(f"stimulus path and shapes: {stroke.displacement[2]:+.4g} R per cycle")
    figure.canvas.draw()
    markers = _material_lines(spec.radius)
    hosts = [barycentric(sheet.points, sheet.triangles, line) for line in markers]
    reference = stroke.shapes.positions[0]
    to_figure = axes.transData + figure.transFigure.inverted()
    middle = to_figure.transform(plane[:-1].mean(axis=0))
    shown = _shown_stations(stroke.path.parameter)
    shapes = {index: align(stroke.shapes.positions[index], reference) for index in shown}
    heights = np.concatenate([shape[:, 2] for shape in shapes.values()])
    norm = Normalize(float(heights.min()), float(max(heights.max(), heights.min() + 1e-9)))
    for index, shape in shapes.items():
        anchor = to_figure.transform(plane[index])
        outward = anchor - middle
        outward = outward / (np.linalg.norm(outward) or 1.0)
        x, y = 0.5 + 0.36 * outward
        figure.add_artist(Line2D([anchor[0], x], [anchor[1], y], color="0.75", linewidth=0.6))
        inset = figure.add_axes((x - 0.12, y - 0.12, 0.24, 0.24), projection="3d")
        inset.set_facecolor((1.0, 1.0, 1.0, 0.0))
        inset.plot_trisurf(
            *shape.T, triangles=sheet.triangles, cmap="viridis", norm=norm, linewidth=0,
            alpha=0.75,
        )  # fmt: skip
        for (host, weights), color in zip(hosts, ("red", "black"), strict=True):
            line = np.einsum("nc,ncd->nd", weights, shape[sheet.triangles[host]])
            inset.plot(*line.T, color=color, linewidth=1.5, zorder=10)
        limit = 0.75 * spec.radius
        inset.set(xlim=(-limit, limit), ylim=(-limit, limit), zlim=(-limit, limit))
        inset.set_axis_off()
        inset.view_init(elev=30, azim=-60)
        label = ", ".join(
            f"{name} {v:g}"
            for name, v in zip(spec.stimuli, np.round(stroke.path.stimuli[index], 3), strict=True)
        )
        inset.text2D(0.5, 0.82, label, transform=inset.transAxes, ha="center", fontsize=9)
    bar = figure.add_axes((0.93, 0.3, 0.015, 0.4))
    figure.colorbar(
        ScalarMappable(norm=norm, cmap="viridis"),
        cax=bar,
        label="height along the swimmer's axis (mm)",
    )
    figure.legend(
        handles=[
            Line2D([], [], color="0.3", marker="o", markersize=3, label="stations computed"),
            Line2D([], [], color="C0", marker=">", ls="none", label="direction of the cycle"),
            Line2D([], [], color="red", label="material diameter y = 0"),
            Line2D([], [], color="black", label="material circle r = R/2"),
        ],
        loc="lower center",
        ncol=4,
        frameon=False,
    )
    _save(figure, path)


def _shown_stations(parameter: np.ndarray) -> list[int]:
    """Stations nearest to every corner and mid-leg (the closing corner left out)."""
    legs = int(round(parameter[-1]))
    wanted = np.arange(0, legs, 0.5)
    return sorted({int(np.argmin(np.abs(parameter - t))) for t in wanted})


def _material_lines(radius: float) -> list[np.ndarray]:
    """Flat points (n, 2) of the diameter y = 0 and the circle r = R / 2."""
    t = np.linspace(-1.0, 1.0, 41)
    angle = np.linspace(0.0, 2 * np.pi, 81)
    diameter = np.column_stack([radius * t, np.zeros_like(t)])
    circle = 0.5 * radius * np.column_stack([np.cos(angle), np.sin(angle)])
    return [diameter, circle]


def plot_position(stroke: Stroke, path: Path) -> None:
    """Centroid position along the axis (and sideways) over the cycle, in disc radii."""
    plt = _pyplot()
    parameter = stroke.path.parameter
    position = stroke.trajectory.positions / stroke.spec.radius
    figure, axes = plt.subplots(figsize=(7, 4), layout="constrained")
    axes.plot(parameter, position[:, 2], "o-", label="z (axis)", markersize=3)
    axes.plot(parameter, position[:, 0], "--", label="x", linewidth=0.8)
    axes.plot(parameter, position[:, 1], ":", label="y", linewidth=0.8)
    _mark_corners(axes, parameter, stroke.path.stimuli)
    axes.set_xlabel("path coordinate (legs; corners at whole numbers)")
    axes.set_ylabel("centroid position / R")
    net = stroke.displacement[2]
    axes.set_title(f"net displacement per cycle {net:+.4g} R", pad=16)
    axes.legend()
    _save(figure, path)


def plot_energy(stroke: Stroke, path: Path) -> None:
    """Work bound (held flat) along the path, and the free equilibria's elastic energy.

    One colour and line style per bound, the corners of the path (whole path coordinates)
    marked and labelled with their stimulus, as in the position plot.
    """
    plt = _pyplot()
    parameter = stroke.path.parameter
    figure, axes = plt.subplots(figsize=(7, 4), layout="constrained")
    styles = {"small_strain": ("C0", "-"), "neo_hookean": ("C1", "--")}  # one per density
    for name, values in energy_bounds(stroke).items():
        colour, style = styles[name]
        label = f"work bound held flat, {DENSITY_NAMES[name]}"
        axes.plot(parameter, values, style, color=colour, label=label)
    axes.plot(
        parameter, stroke.shapes.energies * 1e3, "k.", label="elastic energy of the free shape"
    )
    _mark_corners(axes, parameter, stroke.path.stimuli)
    axes.set_xlabel("path coordinate (legs; corners at whole numbers)")
    axes.set_ylabel("energy (mJ)")
    axes.set_title("work bound along the cycle", pad=16)
    axes.legend(fontsize=8)
    _save(figure, path)


def _mark_corners(axes, parameter: np.ndarray, stimuli: np.ndarray) -> None:
    """A grey line at every corner of the path, labelled with its stimulus above the axes."""
    for corner, stimulus in zip(parameter, stimuli, strict=True):
        if np.isclose(corner, round(corner)):
            axes.axvline(corner, color="0.8", zorder=0)
            label = ",".join(f"{v:g}" for v in stimulus)
            axes.text(
                corner,
                1.01,
                f"({label})",
                ha="center",
                fontsize=8,
                transform=axes.get_xaxis_transform(),
            )
