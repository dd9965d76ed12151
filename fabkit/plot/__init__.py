"""Pictures and the HTML report. ``render_design`` draws everything a design has.

Importing this package does not load matplotlib: :func:`draw_design` imports the
drawings (:mod:`fabkit.plot.design`) when it runs, so ``fabkit run``, which has them drawn
in its worker process, never loads them itself.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from fabkit.design.check import ResidualMaps
from fabkit.design.design import Design
from fabkit.field.part import Part
from fabkit.files.atomic import atomic_path
from fabkit.plot.scene import Scene, scene

DESIGN_PICTURES = (
    (
        "flat_sheet.png",
        "The flat sheet: director lines coloured by the first feature, "
        "v-curves grey, solved region grey, the part that is made black",
    ),
    ("eps.png", "Designable features on the flat sheet and on the material grid"),
    (
        "surfaces.png",
        "Every actuated surface in 3D (equal scales, design units) with the patch's "
        "u-curves (red) and v-curves (blue) drawn on the target",
    ),
    (
        "residuals.png",
        "Residual maps of fabkit check on the material grid (log scale); each panel's "
        "median and 95th percentile against the check's limits, marked on the colour bar",
    ),
)


@dataclass(frozen=True)
class Picture:
    """A drawn picture: its file ``name``, its ``caption`` and its ``png`` bytes."""

    name: str
    caption: str
    png: bytes


def draw_design(shown: Scene) -> tuple[Picture, ...]:
    """Every design picture of ``shown`` (:data:`DESIGN_PICTURES`), drawn in memory."""
    from fabkit.plot import design as drawings  # matplotlib: only where pictures are drawn

    drawing = {
        "flat_sheet.png": drawings.flat_sheet,
        "eps.png": drawings.eps_maps,
        "surfaces.png": drawings.actuated_surfaces,
        "residuals.png": drawings.residual_maps,
    }
    return tuple(Picture(name, caption, drawing[name](shown)) for name, caption in DESIGN_PICTURES)


def write_pictures(drawn: tuple[Picture, ...], folder: str | Path) -> list[tuple[str, Path]]:
    """Write ``drawn`` into ``folder`` (each file atomically); returns (caption, path)
    pairs."""
    written = []
    for picture in drawn:
        path = Path(folder) / picture.name
        with atomic_path(path) as tmp:
            tmp.write_bytes(picture.png)
        written.append((picture.caption, path))
    return written


def render_design(
    design: Design,
    folder: str | Path,
    part: Part | None = None,
    maps: tuple[ResidualMaps, ...] | None = None,
) -> list[tuple[str, Path]]:
    """Draw the design pictures into ``folder`` (``part`` and ``maps`` as in
    :func:`~fabkit.plot.scene.scene`); returns (caption, path) pairs."""
    return write_pictures(draw_design(scene(design, part, maps)), folder)
