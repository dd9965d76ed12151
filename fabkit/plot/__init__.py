"""Pictures and the HTML report. ``render_design`` draws everything a design has."""

from __future__ import annotations

from pathlib import Path

from fabkit.design.check import ResidualMaps, residual_maps
from fabkit.design.design import Design
from fabkit.field.part import Part
from fabkit.plot import design as pictures

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


def render_design(
    design: Design,
    folder: str | Path,
    part: Part | None = None,
    maps: tuple[ResidualMaps, ...] | None = None,
) -> list[tuple[str, Path]]:
    """Draw the design pictures into ``folder`` (the flat sheet with its ``part``, default:
    the part of :class:`fabkit.field.part.PartRules`' defaults; ``maps``: the check's
    residual maps, computed here if not given); returns (caption, path) pairs."""
    folder = Path(folder)
    paths = {name: folder / name for name, _ in DESIGN_PICTURES}
    pictures.flat_sheet(design, paths["flat_sheet.png"], part)
    pictures.eps_maps(design, paths["eps.png"])
    pictures.actuated_surfaces(design, paths["surfaces.png"])
    maps = residual_maps(design) if maps is None else maps
    pictures.residual_maps(design, maps, paths["residuals.png"])
    return [(caption, paths[name]) for name, caption in DESIGN_PICTURES]
