"""Which shape the sheet takes: every target simulated from flat, and a verdict on each.

The sheet (a design as designed, or a sheet as fabricated) is ramped from its flat state
to every embedded target's stimulus (:func:`~fabkit.mechanics.fabricated.simulate_sheet`)
and compared with that target (:func:`~fabkit.mechanics.compare.compare`). A target is
**formed** when the simulation converged, the sheet is not its mirror image and it ends
within ``tolerance`` RMS of the target (a share of the patch's diameter). Otherwise the
sheet forms something else, and the verdict says how far that is and whether it is the
mirror image.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from fabkit.design.design import Design
from fabkit.field.part import Part
from fabkit.mechanics.compare import FormedShape, compare, formed_shape
from fabkit.mechanics.fabricated import SheetFields, design_fields, simulate_sheet
from fabkit.mechanics.simulate import Settings, default_thickness

FORM_TOLERANCE = 0.03
"""Largest RMS distance to a target, as a share of its patch's diameter, of a sheet that
forms it."""
TARGET_TRIANGLES = 800
"""About how many triangles a verdict's simulation uses (the design's grid coarsened)."""


@dataclass(frozen=True)
class Shape:
    """What the sheet does under one target's stimulus: its RMS and max distance to the
    target (shares of the patch diameter), whether that is the mirror image, whether the
    simulation converged, the ``tolerance`` it is held to, and the wall time (s).
    ``diameter_mm`` is the patch diameter in mm and ``mesh`` the sheet beside its target
    (:class:`~fabkit.mechanics.compare.FormedShape`), both None where the sheet's scale is
    unknown."""

    target: str
    rms: float
    max: float
    mirrored: bool
    converged: bool
    tolerance: float
    seconds: float = 0.0
    diameter_mm: float | None = None
    mesh: FormedShape | None = field(default=None, repr=False, compare=False)

    @property
    def formed(self) -> bool:
        return self.converged and not self.mirrored and self.rms <= self.tolerance

    def line(self) -> str:
        """One line with every figure of the verdict on this target, e.g. ``sphere: formed,
        0.79 % RMS (0.41 mm), max 2.87 % (1.49 mm) of the patch diameter (52 mm); limit
        3 % RMS (1.56 mm); converged; not a mirror image`` (no mm where the scale is
        unknown)."""
        status = "formed" if self.formed else "NOT formed"
        diameter = f" ({self.diameter_mm:.3g} mm)" if self.diameter_mm is not None else ""
        mirror = "the target's mirror image" if self.mirrored else "not a mirror image"
        return (
            f"{self.target}: {status}, {self._pct(self.rms)} RMS, max {self._pct(self.max)} of "
            f"the patch diameter{diameter}; limit {self._pct(self.tolerance, '.3g')} RMS; "
            f"{'converged' if self.converged else 'NOT converged'}; {mirror}"
        )

    def _pct(self, share: float, spec: str = ".2f") -> str:
        """A share of the patch diameter as a percentage, and in mm when known."""
        text = f"{100 * share:{spec}} %"
        return text if self.diameter_mm is None else f"{text} ({share * self.diameter_mm:.3g} mm)"

    def miss(self) -> str:
        """A missed target in a few words: ``wavy (5.36 % RMS, mirror image)``."""
        return f"{self.target} ({', '.join([f'{100 * self.rms:.2f} % RMS', *self._reasons()])})"

    def _reasons(self) -> list[str]:
        reasons = [("mirror image", self.mirrored), ("not converged", not self.converged)]
        return [reason for reason, holds in reasons if holds]

    def to_dict(self) -> dict:
        """The figures; the ``_mm`` ones None where the scale is unknown."""

        def mm(share: float) -> float | None:
            return None if self.diameter_mm is None else share * self.diameter_mm

        return {
            "target": self.target,
            "formed": self.formed,
            "rms_pct": 100 * self.rms,
            "max_pct": 100 * self.max,
            "mirror_image": self.mirrored,
            "converged": self.converged,
            "limit_pct": 100 * self.tolerance,
            "seconds": self.seconds,
            "patch_diameter_mm": self.diameter_mm,
            "rms_mm": mm(self.rms),
            "max_mm": mm(self.max),
            "limit_mm": mm(self.tolerance),
            "line": self.line(),
        }


@dataclass(frozen=True)
class Verdict:
    """The shapes a sheet takes (``what``: "as designed" or "as fabricated"), ``layers``
    and ``thickness_mm`` (None where the scale is unknown) of the sheet simulated."""

    what: str
    shapes: tuple[Shape, ...]
    layers: int
    thickness_mm: float | None = None

    @property
    def formed(self) -> bool:
        """Every target formed."""
        return all(shape.formed for shape in self.shapes)

    def headline(self) -> str:
        """One line for the end of a run: which targets the sheet forms."""
        missed = [s for s in self.shapes if not s.formed]
        sheet = f"the sheet {self.what}"
        if not missed:
            names = ", ".join(s.target for s in self.shapes)
            return f"{sheet} forms every target ({names})"
        return f"{sheet} does NOT form " + "; ".join(s.miss() for s in missed)

    def lines(self) -> list[str]:
        return [shape.line() for shape in self.shapes]

    def to_dict(self) -> dict:
        return {
            "what": self.what,
            "headline": self.headline(),
            "formed": self.formed,
            "layers": self.layers,
            "thickness_mm": self.thickness_mm,
            "targets": [shape.to_dict() for shape in self.shapes],
        }


def embedded_targets(design: Design) -> list[int]:
    """The surfaces (indices > 0) embedded in 3D: the ones a shape can be compared with."""
    targets = design.problem.targets
    return [
        s for s in range(1, len(targets)) if targets[s].surface.embed(np.zeros((1, 2))) is not None
    ]


def sheet_verdict(
    design: Design,
    layers: Sequence[SheetFields],
    thickness: float,
    what: str,
    *,
    tolerance: float = FORM_TOLERANCE,
    part: Part | None = None,
    stride: int | None = None,
    settings: Settings | None = None,
    mm_per_unit: float | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> Verdict:
    """Simulate the sheet of ``layers`` (bottom first), ``thickness`` thick (design
    units), from flat to every embedded target's stimulus; the verdict on each."""
    stride = stride or grid_stride(design)
    surfaces = embedded_targets(design)
    shapes = []
    for k, surface in enumerate(surfaces):
        started = time.perf_counter()
        coarse, simulation = simulate_sheet(
            design,
            list(layers),
            surface,
            thickness,
            settings=settings,
            part=part,
            stride=stride,
            progress=_share(progress, k, len(surfaces)),
        )
        found = compare(coarse, simulation)
        shapes.append(
            Shape(
                found.name,
                found.rms,
                found.max,
                found.mirrored,
                found.converged,
                tolerance,
                time.perf_counter() - started,
                None if mm_per_unit is None else found.size * mm_per_unit,
                None if mm_per_unit is None else formed_shape(coarse, simulation, mm_per_unit),
            )
        )
    thickness_mm = thickness * mm_per_unit if mm_per_unit is not None else None
    return Verdict(what, tuple(shapes), len(layers), thickness_mm)


def _share(
    progress: Callable[[int, int], None] | None, k: int, count: int
) -> Callable[[int, int], None] | None:
    """The progress of the k-th of ``count`` simulations as a share of them all."""
    if progress is None:
        return None
    return lambda done, total: progress(k * total + done, count * total)


def design_verdict(
    design: Design,
    thickness: float | None = None,
    *,
    tolerance: float = FORM_TOLERANCE,
    part: Part | None = None,
    stride: int | None = None,
    mm_per_unit: float | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> Verdict:
    """The verdict on the sheet as designed: every layer's own director and features (one
    layer without a layering); ``thickness`` defaults to the layering's, else 1 % of the
    flat domain's diameter (as ``fabkit simulate``)."""
    if design.layering is not None:
        layers = [design_fields(design.layer(k)) for k in range(design.layers)]
        thickness = design.layering.thickness if thickness is None else thickness
    else:
        layers = [design_fields(design)]
    if thickness is None:
        thickness = default_thickness(design)
    return sheet_verdict(
        design,
        layers,
        thickness,
        "as designed",
        tolerance=tolerance,
        part=part,
        stride=stride,
        mm_per_unit=mm_per_unit,
        progress=progress,
    )


def grid_stride(design: Design) -> int:
    """The grid coarsening that leaves about :data:`TARGET_TRIANGLES` triangles."""
    valid = design.valid
    cells = int((valid[:-1, :-1] & valid[1:, :-1] & valid[:-1, 1:] & valid[1:, 1:]).sum())
    return max(1, round(math.sqrt(2 * cells / TARGET_TRIANGLES)))
