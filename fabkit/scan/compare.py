"""A scan of a printed sheet against its target: the verdict, in the words of ``run``'s.

The scan is fitted to the target surface both as it is and as its mirror image
(:func:`~fabkit.scan.align.fit`); the better fit is the scan's. Its figures are those of
``run``'s verdict: the RMS and largest distance from the scan's measured points to the
target surface, as shares of the patch diameter and in mm, held to the same limit
(:data:`~fabkit.mechanics.verdict.FORM_TOLERANCE` by default). Three things a scan adds:

* the mirror image: a scan knows no face of the sheet, so a target congruent to its own
  mirror image (a sphere cap, a symmetric bump: a rotation turns one into the other)
  cannot tell which way the sheet bent. The target's mirror image is fitted to the
  target; when it lies within :data:`SAME_SHAPE` of the limit the verdict says so instead
  of guessing, and uses the better fit. Otherwise a scan that fits the mirror image better
  is named the target's mirror image, and is not formed.
* the coverage: the share of the target's area with the nearest target point of a scan
  point within :func:`cover_radius` (:func:`coverage`: the scan's holes); a scan covering
  less than :data:`MIN_COVERAGE` is not judged formed (a small piece of any curved
  surface fits somewhere).
* another part: a scan farther than :data:`NOT_THIS` times the limit does not look like
  this target.

Where the run simulated the sheet, the scan is also fitted to that sheet (as it is and as
its mirror image, the better kept): where print and simulation differ.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from fabkit.mechanics.verdict import FORM_TOLERANCE, distance_words
from fabkit.scan.align import MIRROR, Motion, Surface, fit
from fabkit.scan.align import rms as rms_of
from fabkit.scan.read import Scan
from fabkit.scan.targets import Target

MIN_COVERAGE = 0.6
"""Least share of the target's area a scan must cover to be judged formed."""
COVER_MM = 1.0
"""A target point is covered by a scan point within this (mm), or within
:data:`COVER_SPACINGS` of the scan's point spacing when that is larger."""
COVER_SPACINGS = 3.0
SAME_SHAPE = 0.1
"""A target whose mirror image fits it within this share of the limit (RMS) has the same
shape as its mirror image."""
NOT_THIS = 3.0
"""A scan farther than this many times the limit (RMS) does not look like the target."""
SELF_POINTS = 3_000
"""Points of the target's mirror image fitted to the target."""


@dataclass(frozen=True)
class ScanVerdict:
    """The verdict on a scan of target ``target``: distances in mm from the scan's
    measured points (``points`` of them, chosen as ``sampling`` says) to the target after
    the better fit (``rms_mm``, ``max_mm``; ``mirrored``: that fit is the mirrored one),
    both fits' RMS, the RMS of the target's own mirror image fitted to it
    (``self_mirror_mm``), the share of the target covered (``coverage``, within
    ``cover_mm``), the patch diameter and the limit (a share of it, ``tolerance``); the
    scan against the simulated sheet ``sheet_what`` (mm), None without one."""

    target: str
    scan: str
    units: str
    sampling: str
    points: int
    diameter_mm: float
    tolerance: float
    rms_mm: float
    max_mm: float
    mirrored: bool
    proper_rms_mm: float
    mirrored_rms_mm: float
    self_mirror_mm: float
    coverage: float
    cover_mm: float
    sheet_what: str = ""
    sheet_rms_mm: float | None = None
    sheet_max_mm: float | None = None
    seconds: float = 0.0

    @property
    def limit_mm(self) -> float:
        return self.tolerance * self.diameter_mm

    @property
    def mirror_tells(self) -> bool:
        """The target differs from its own mirror image: a scan can tell them apart."""
        return self.self_mirror_mm > SAME_SHAPE * self.limit_mm

    @property
    def mirror_image(self) -> bool:
        """The scan is the target's mirror image (one it can tell from the target)."""
        return self.mirrored and self.mirror_tells

    @property
    def covered(self) -> bool:
        return self.coverage >= MIN_COVERAGE

    @property
    def this_target(self) -> bool:
        """The scan looks like this target: within :data:`NOT_THIS` times the limit."""
        return self.rms_mm <= NOT_THIS * self.limit_mm

    @property
    def formed(self) -> bool:
        """Within the limit, covering enough of the target, not its mirror image."""
        return self.covered and self.rms_mm <= self.limit_mm and not self.mirror_image

    def line(self) -> str:
        """The verdict in ``run``'s words, e.g. ``sphere: formed, 0.41 % (0.3 mm) RMS, max
        1.9 % (1.4 mm) of the patch diameter (73.6 mm); limit 3 % (2.21 mm) RMS; not a
        mirror image (...); the scan covers 80 % of the target (within 1 mm of where a scan
        point lies nearest it)``."""
        status = self.status()
        if not self.formed:
            status += f" ({'; '.join(self.why())})"
        elif not self.mirror_tells:
            status += " (which way it bends: unknown, see the first line)"
        figures = f"{self._pct(self.rms_mm)} RMS, max {self._pct(self.max_mm)} of the patch "
        figures += f"diameter ({self.diameter_mm:.3g} mm)"
        return (
            f"{self.target}: {status}, {figures}; limit {self._pct(self.limit_mm, '.3g')} RMS; "
            f"{self.mirror_words()}; the scan covers {100 * self.coverage:.0f} % of the target "
            f"(within {self.cover_mm:.2g} mm of where a scan point lies nearest it)"
        )

    def status(self) -> str:
        """``formed``, ``formed in shape`` (a side a scan cannot tell) or ``NOT formed``."""
        if not self.formed:
            return "NOT formed"
        return "formed" if self.mirror_tells else "formed in shape"

    def why(self) -> list[str]:
        """Why the scan is not formed, in a few words each."""
        reasons = []
        if self.mirror_image:
            reasons.append("it is the target's mirror image")
        if not self.this_target:
            reasons.append("it does not look like this target: is it a scan of another part?")
        elif self.rms_mm > self.limit_mm:
            reasons.append("farther than the limit")
        if not self.covered:
            reasons.append(
                f"the scan covers only {100 * self.coverage:.0f} % of the target, at least "
                f"{100 * MIN_COVERAGE:.0f} % is needed"
            )
        return reasons

    def mirror_words(self) -> str:
        other = self._pct(self.proper_rms_mm if self.mirrored else self.mirrored_rms_mm)
        if not self.mirror_tells:
            return "the mirror image or not: a scan cannot tell (see the first line)"
        if self.mirror_image:
            return f"the target's mirror image ({other} RMS from the target itself)"
        return f"not a mirror image (its mirror image fits at {other} RMS)"

    def caveat(self) -> str | None:
        """What the verdict cannot say, for its first line: which way a target congruent
        to its own mirror image bends (None: nothing)."""
        if self.mirror_tells:
            return None
        return (
            f"caveat: {self.target}'s mirror image has the same shape (within "
            f"{self._pct(self.self_mirror_mm)} RMS), so a scan cannot tell which way the sheet "
            "bends: the verdict is on its shape; mark the sheet's top face and look which "
            "side it bulges to"
        )

    def lines(self) -> list[str]:
        """The caveat (if any) first, the scan against the simulated sheet, what was
        measured, and the verdict last."""
        lines = [] if self.caveat() is None else [self.caveat()]
        if self.sheet_rms_mm is not None:
            lines.append(
                f"scan vs the simulated sheet {self.sheet_what}: {self._pct(self.sheet_rms_mm)} "
                f"RMS, max {self._pct(self.sheet_max_mm)} of the patch diameter"
            )
        lines.append(
            f"measured at {self.sampling} (its lengths read in {self.units}), "
            f"in {self.seconds:.1f} s"
        )
        return [*lines, self.line()]

    def _pct(self, mm: float, spec: str = ".2f") -> str:
        """A length as a percentage of the patch diameter, and in mm (``run``'s form)."""
        return distance_words(100 * mm / self.diameter_mm, mm, spec)

    def to_dict(self) -> dict:
        """The figures (docs/compare.schema.json's ``verdict``)."""
        pct = 100 / self.diameter_mm
        sheet = None
        if self.sheet_rms_mm is not None:
            sheet = {
                "what": self.sheet_what,
                "rms_mm": self.sheet_rms_mm,
                "max_mm": self.sheet_max_mm,
                "rms_pct": pct * self.sheet_rms_mm,
                "max_pct": pct * self.sheet_max_mm,
            }
        return {
            "target": self.target,
            "scan": self.scan,
            "units": self.units,
            "formed": self.formed,
            "this_target": self.this_target,
            "mirror_image": self.mirror_image,
            "mirror_distinguishable": self.mirror_tells,
            "rms_pct": pct * self.rms_mm,
            "max_pct": pct * self.max_mm,
            "rms_mm": self.rms_mm,
            "max_mm": self.max_mm,
            "limit_pct": 100 * self.tolerance,
            "limit_mm": self.limit_mm,
            "patch_diameter_mm": self.diameter_mm,
            "proper_fit_rms_mm": self.proper_rms_mm,
            "mirrored_fit_rms_mm": self.mirrored_rms_mm,
            "self_mirror_rms_mm": self.self_mirror_mm,
            "coverage_pct": 100 * self.coverage,
            "coverage_radius_mm": self.cover_mm,
            "min_coverage_pct": 100 * MIN_COVERAGE,
            "points": self.points,
            "sampling": self.sampling,
            "sheet": sheet,
            "seconds": self.seconds,
            "lines": self.lines(),
        }


@dataclass(frozen=True, eq=False)
class Compared:
    """A scan compared: the ``verdict``, the ``motion`` fitting it to the target, the
    scan's vertices moved so (``aligned_mm`` (V, 3), ``faces`` (F, 3)) with each one's
    distance to the target (``distance_mm`` (V,)) and, after the fit to the simulated
    sheet (``sheet_motion``), to that sheet (``sheet_distance_mm`` (V,); both None
    without one); the measured points moved (``points_mm`` (n, 3)) with their distances
    (``point_distance_mm``)."""

    verdict: ScanVerdict
    motion: Motion
    aligned_mm: np.ndarray
    faces: np.ndarray
    distance_mm: np.ndarray
    sheet_distance_mm: np.ndarray | None
    points_mm: np.ndarray
    point_distance_mm: np.ndarray
    sheet_motion: Motion | None = None


def compare_scan(scan: Scan, target: Target, tolerance: float = FORM_TOLERANCE) -> Compared:
    """``scan`` against ``target`` (module docstring)."""
    start = time.perf_counter()
    surface = Surface.of(target.mesh.vertices_mm, target.mesh.triangles)
    proper, mirrored = (_Measured.of(scan, surface, side) for side in (False, True))
    best = mirrored if mirrored.rms < proper.rms else proper
    sheet = _SheetFit.of(scan, target)
    cover_mm = cover_radius(scan.points_mm)
    verdict = ScanVerdict(
        target.name,
        scan.name,
        scan.units,
        scan.sampling,
        len(scan.points_mm),
        target.diameter_mm,
        tolerance,
        best.rms,
        float(best.distances.max()),
        best is mirrored,
        proper.rms,
        mirrored.rms,
        self_mirror(surface),
        coverage(surface, best.feet, cover_mm),
        cover_mm,
        target.sheet_what if sheet else "",
        sheet.rms if sheet else None,
        float(sheet.point_distances.max()) if sheet else None,
        time.perf_counter() - start,
    )
    motion = best.motion
    aligned = motion.apply(scan.vertices_mm)
    return Compared(
        verdict,
        motion,
        aligned,
        scan.faces[:, ::-1] if motion.mirrored else scan.faces,  # outward stays outward
        surface.distances(aligned),
        sheet.vertex_distances if sheet else None,
        best.points,
        best.distances,
        sheet.motion if sheet else None,
    )


@dataclass(frozen=True, eq=False)
class _Measured:
    """One fit (``motion``) of a scan's measured points: moved (``points`` (n, 3)), their
    nearest points of the surface (``feet`` (n, 3)) and distances to it (``distances``)."""

    motion: Motion
    points: np.ndarray
    feet: np.ndarray
    distances: np.ndarray

    @classmethod
    def of(cls, scan: Scan, surface: Surface, mirrored: bool) -> _Measured:
        motion = fit(scan.points_mm, surface, mirrored).motion
        points = motion.apply(scan.points_mm)
        feet = surface.closest(points)
        return cls(motion, points, feet, np.linalg.norm(feet - points, axis=1))

    @property
    def rms(self) -> float:
        return rms_of(self.distances)


@dataclass(frozen=True, eq=False)
class _SheetFit:
    """A scan fitted to the simulated sheet, proper or mirrored, the better kept
    (``motion``): the distances (mm) of its measured points and of its vertices."""

    motion: Motion
    point_distances: np.ndarray
    vertex_distances: np.ndarray

    @classmethod
    def of(cls, scan: Scan, target: Target) -> _SheetFit | None:
        """None without a simulated sheet."""
        if target.sheet is None:
            return None
        surface = Surface.of(target.sheet.vertices_mm, target.sheet.triangles)
        fits = [fit(scan.points_mm, surface, mirrored) for mirrored in (False, True)]
        motion = min(fits, key=lambda found: found.trimmed_rms).motion
        return cls(
            motion,
            surface.distances(motion.apply(scan.points_mm)),
            surface.distances(motion.apply(scan.vertices_mm)),
        )

    @property
    def rms(self) -> float:
        return rms_of(self.point_distances)


def self_mirror(surface: Surface) -> float:
    """The RMS distance (the surface's units) of the surface's mirror image, fitted to the
    surface by a rotation and translation: 0 for a surface congruent to its mirror."""
    mirror = surface.samples[:SELF_POINTS] * MIRROR
    found = fit(mirror, surface, mirrored=False)
    return rms_of(surface.distances(found.motion.apply(mirror)))


def cover_radius(points: np.ndarray) -> float:
    """How near a scan point must be to cover a target point (mm): :data:`COVER_MM`, or
    :data:`COVER_SPACINGS` times the scan's median point spacing if larger."""
    spacing, _ = cKDTree(points).query(points, k=2)
    return max(COVER_MM, COVER_SPACINGS * float(np.median(spacing[:, 1])))


def coverage(surface: Surface, feet: np.ndarray, radius: float) -> float:
    """The share of the surface's area (of its samples) with one of ``feet`` (n, 3), the
    nearest points of the surface to a scan's points, within ``radius``: where the scan
    has holes (not where it lies off the surface, which its distances say)."""
    distances, _ = cKDTree(feet).query(surface.samples, distance_upper_bound=radius)
    return float(np.mean(np.isfinite(distances)))
