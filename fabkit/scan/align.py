"""Aligning a scan to a surface without correspondences: a global start, then ICP.

The surface (a triangle mesh, mm) is sampled densely and evenly (:class:`Surface`); its
distances are measured to the triangles themselves. A scan's points are aligned for the
proper fit (a rotation and a translation) and for the mirrored one (the scan's mirror
image first, then a rotation and a translation) apart, in three stages:

1. the global start: both point sets centred and turned onto their principal axes,
   their least spread axis (a sheet's normal) either way up and turned by every
   :data:`TURNS`-th of a turn about it (the principal axes of a partial scan, or of a
   rotationally symmetric target, say nothing about the turn); from each of these starts
   :data:`COARSE_ITERATIONS` of point-to-point ICP on :data:`COARSE_POINTS` points
   against :data:`COARSE_SAMPLES` samples, fitting the nearest :data:`TRIM` of the
   pairs (so that what the target lacks and its holes do not pull), all starts at once;
2. the best :data:`REFINED` starts tried further by ICP (point-to-plane over the surface,
   point-to-point beyond its edge, where a plane would let the scan slide off) on
   :data:`TRY_POINTS` points; each distinct pose they reach refined on
   :data:`FINE_POINTS` points (a nearly symmetric target has several, nearly as good),
   the best kept;
3. that fit polished on :data:`POLISH_POINTS` points;
4. then finished by Gauss-Newton on the exact distances of those points to the
   triangles (:func:`finish`): ICP's nearest samples stop short along the directions a
   surface barely holds (a cap sliding on its sphere), where the exact distance still
   has a slope.

Stages 2 and 3 fit every pair (:data:`FINE_TRIM`): a scan's points beyond the edge of a
rotationally symmetric target are what hold the fit in place, so a scan must be cropped
to the sheet (no base plate, no turntable).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

MIRROR = np.array([1.0, 1.0, -1.0])
"""The mirror image: z negated (then a rotation and translation: every mirror image)."""
SURFACE_SAMPLES = 20_000
"""Points sampled on a surface to find its nearest points quickly."""
COARSE_POINTS = 400
TRY_POINTS = 1_000
FINE_POINTS = 2_000
TURNS = 8
"""Turns about the normal tried as global starts (each way up)."""
POLISH_POINTS = 10_000
"""Points the best refined fit is polished with (a rotationally symmetric target holds
the fit in place by its edge only: a few points there move it)."""
COARSE_ITERATIONS = 10
TRY_ITERATIONS = 10
FINE_ITERATIONS = 30
POLISH_ITERATIONS = 10
FINISH_ITERATIONS = 20
STRETCH = 3.0
STRETCHES = 4
"""A finishing step is tried :data:`STRETCH` times longer, at most this many times."""
REFINED = 4
"""Global starts tried further (:data:`TRY_ITERATIONS` on :data:`TRY_POINTS` points), of
each of the proper and the mirrored fits; the best is refined."""
SAME_POSE = 5.0
"""Sample spacings (RMS over the points) within which two tried fits are one pose."""
TRIM = 0.9
"""Share of the nearest pairs an iteration from a global start fits."""
FINE_TRIM = 1.0
"""Share of the nearest pairs a refining iteration fits (a scan's points beyond the
target's edge are what holds a fit on a rotationally symmetric target in place)."""
CANDIDATES = 1
"""Nearest samples whose triangles are searched for a point's nearest point."""
EDGE_SPACINGS = 3.0
"""A point is beyond a surface's edge when its nearest sample is farther sideways than
this many sample spacings."""
COARSE_SAMPLES = 3_000
"""Samples of the surface the global starts are fitted to (a tree of far fewer points is
quick to search from far away)."""
FAR = 3.0
"""Coarse sample spacings beyond which a point's nearest samples are sought among the
coarse ones only (:meth:`Surface.nearest`)."""
CHUNK = 50_000
"""Points whose exact distances are measured at once (bounds the memory)."""
SEED = 0


def area_samples(
    corners: np.ndarray, areas: np.ndarray, count: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """``count`` points (count, 3) spread evenly by area over the triangles ``corners``
    (F, 3, 3) of ``areas`` (F,; any common scale), and the triangle each lies on
    (count,)."""
    faces = rng.choice(len(corners), size=count, p=areas / areas.sum())
    a, b = rng.random((2, count))
    flip = a + b > 1
    a[flip], b[flip] = 1 - a[flip], 1 - b[flip]
    c = corners[faces]
    return c[:, 0] + a[:, None] * (c[:, 1] - c[:, 0]) + b[:, None] * (c[:, 2] - c[:, 0]), faces


@dataclass(frozen=True, eq=False)
class Surface:
    """A triangle mesh: ``vertices`` (V, 3), ``triangles`` (F, 3); ``samples`` (S, 3)
    spread evenly over it (by area), each on the triangle ``sample_faces`` (S,) with that
    triangle's unit normal ``normals`` (S, 3); ``tree`` finds the nearest samples,
    ``coarse_tree`` the nearest of the first :data:`COARSE_SAMPLES`, ``vertex_tree`` the
    nearest vertex, whose triangles are the rows of ``vertex_faces`` (V, most triangles
    at a vertex; a row's first repeated where it has fewer)."""

    vertices: np.ndarray
    triangles: np.ndarray
    samples: np.ndarray
    sample_faces: np.ndarray
    normals: np.ndarray
    tree: cKDTree
    coarse_tree: cKDTree
    vertex_tree: cKDTree
    vertex_faces: np.ndarray

    @classmethod
    def of(cls, vertices: np.ndarray, triangles: np.ndarray, count: int = SURFACE_SAMPLES):
        """The surface of the mesh, sampled at ``count`` points (seeded)."""
        vertices = np.asarray(vertices, dtype=float)
        triangles = np.asarray(triangles, dtype=np.int64)
        corners = vertices[triangles]
        cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        areas = np.linalg.norm(cross, axis=1)
        samples, faces = area_samples(corners, areas, count, np.random.default_rng(SEED))
        normals = cross[faces] / np.maximum(areas[faces], 1e-300)[:, None]
        coarse = cKDTree(samples[:COARSE_SAMPLES])  # a random choice too: samples are iid
        return cls(
            vertices,
            triangles,
            samples,
            faces,
            normals,
            cKDTree(samples),
            coarse,
            cKDTree(vertices),
            _vertex_faces(triangles, len(vertices)),
        )

    @property
    def area(self) -> float:
        """The surface's area (its units squared)."""
        corners = self.vertices[self.triangles]
        cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        return float(0.5 * np.linalg.norm(cross, axis=1).sum())

    @property
    def spacing(self) -> float:
        """The typical distance between neighbouring samples (its units)."""
        return float(np.sqrt(self.area / len(self.samples)))

    def nearest(self, points: np.ndarray, k: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """The distances and indices ((n,), or (n, k)) of the ``k`` nearest samples to
        each of ``points`` (n, 3) within :data:`FAR` coarse sample spacings (fewer
        found: the nearest repeated); for a point with none so near, the ``k`` nearest
        coarse samples (a search from afar in the large tree is slow, and its answer
        hardly better)."""
        reach = FAR * np.sqrt(self.area / COARSE_SAMPLES)
        distances, indices = self.tree.query(points, k=k, distance_upper_bound=reach)
        if k > 1:
            missing = ~np.isfinite(distances)
            distances = np.where(missing, distances[:, :1], distances)
            indices = np.where(missing, indices[:, :1], indices)
        far = ~np.isfinite(distances if k == 1 else distances[:, 0])
        if far.any():
            distances[far], indices[far] = self.coarse_tree.query(points[far], k=k)
        return distances, indices

    def distances(self, points: np.ndarray) -> np.ndarray:
        """The exact distance (n,) from every one of ``points`` (n, 3) to the surface."""
        return np.linalg.norm(self.closest(points) - points, axis=1)

    def closest(self, points: np.ndarray) -> np.ndarray:
        """The nearest point (n, 3) of the surface to every one of ``points`` (n, 3): on
        the triangles of its :data:`CANDIDATES` nearest samples and of its nearest
        vertex, :data:`CHUNK` points at a time."""
        return np.concatenate(
            [self._closest(points[k : k + CHUNK]) for k in range(0, len(points), CHUNK)]
            or [np.zeros((0, 3))]
        )

    def _closest(self, points: np.ndarray) -> np.ndarray:
        _, nearest = self.nearest(points, k=CANDIDATES)
        _, vertex = self.vertex_tree.query(points)
        faces = np.hstack(
            [self.sample_faces[nearest].reshape(len(points), -1), self.vertex_faces[vertex]]
        )
        corners = self.vertices[self.triangles[faces.ravel()]]
        repeated = np.repeat(points, faces.shape[1], axis=0)
        found = closest_on_triangles(corners[:, 0], corners[:, 1], corners[:, 2], repeated)
        found = found.reshape(len(points), faces.shape[1], 3)
        gaps = np.einsum("nkd,nkd->nk", found - points[:, None], found - points[:, None])
        return found[np.arange(len(points)), np.argmin(gaps, axis=1)]

    def plane_distances(self, points: np.ndarray) -> np.ndarray:
        """The distance (n,) from every one of ``points`` (n, 3) to the plane of its
        nearest sample's triangle, or to that sample where the point lies beyond the
        surface's edge (:data:`EDGE_SPACINGS`): quick, and within the sampling of
        :meth:`distances`."""
        distances, nearest = self.nearest(points)
        offsets = points - self.samples[nearest]
        normal = np.abs(np.einsum("ij,ij->i", offsets, self.normals[nearest]))
        sideways = np.sqrt(np.maximum(distances**2 - normal**2, 0.0))
        return np.where(sideways <= EDGE_SPACINGS * self.spacing, normal, distances)


@dataclass(frozen=True)
class Motion:
    """A rigid motion, mirrored first when ``mirrored``: x -> ``rotation`` (3, 3, proper)
    applied to x (or its mirror image, :data:`MIRROR`), plus ``translation`` (3,)."""

    rotation: np.ndarray
    translation: np.ndarray
    mirrored: bool

    def apply(self, points: np.ndarray) -> np.ndarray:
        """``points`` (n, 3) moved."""
        points = points * MIRROR if self.mirrored else points
        return points @ self.rotation.T + self.translation

    def then(self, rotation: np.ndarray, translation: np.ndarray) -> Motion:
        """This motion followed by the proper one ``rotation``, ``translation``."""
        return Motion(
            rotation @ self.rotation, self.translation @ rotation.T + translation, self.mirrored
        )


@dataclass(frozen=True)
class Fit:
    """The best ``motion`` of a scan onto a surface found, and its trimmed RMS distance
    (the points' units) on the points it was refined with."""

    motion: Motion
    trimmed_rms: float


def fit(points: np.ndarray, surface: Surface, mirrored: bool) -> Fit:
    """The best proper (``mirrored`` False) or mirrored motion of ``points`` (n, 3) onto
    ``surface`` (module docstring)."""
    rng = np.random.default_rng(SEED)
    coarse = _subset(points, COARSE_POINTS, rng)
    starts = _global_starts(coarse, surface, mirrored)
    scores = [_trimmed_rms(surface.coarse_tree.query(s.apply(coarse))[0]) for s in starts]
    tried = _subset(points, TRY_POINTS, rng)
    fits = [refine(tried, surface, starts[k], TRY_ITERATIONS) for k in np.argsort(scores)[:REFINED]]
    fine = _subset(points, FINE_POINTS, rng)
    fits = [refine(fine, surface, found.motion) for found in _distinct(fits, coarse, surface)]
    found = min(fits, key=lambda found: found.trimmed_rms)
    polish = _subset(points, POLISH_POINTS, rng)
    found = refine(polish, surface, found.motion, POLISH_ITERATIONS)
    return finish(polish, surface, found.motion)


def _distinct(fits: list[Fit], points: np.ndarray, surface: Surface) -> list[Fit]:
    """``fits`` without those that place ``points`` within :data:`SAME_POSE` sample
    spacings (RMS) of a better one: the poses worth refining."""
    kept: list[Fit] = []
    for found in sorted(fits, key=lambda found: found.trimmed_rms):
        moved = found.motion.apply(points)
        gaps = [np.sqrt(np.mean(np.sum((moved - k.motion.apply(points)) ** 2, 1))) for k in kept]
        if all(gap > SAME_POSE * surface.spacing for gap in gaps):
            kept.append(found)
    return kept


def refine(
    points: np.ndarray, surface: Surface, start: Motion, iterations: int = FINE_ITERATIONS
) -> Fit:
    """``start`` refined by trimmed ICP of ``points`` onto ``surface``: point-to-plane
    where a point lies over the surface, point-to-point where it lies beyond its edge (a
    plane would let it slide off freely)."""
    motion = start
    edge = EDGE_SPACINGS * surface.spacing
    for _ in range(iterations):
        moved = motion.apply(points)
        step = _icp_step(moved, surface, edge)
        motion = motion.then(_rotation(step[:3]), step[3:])
        if np.linalg.norm(step[:3]) < 1e-6 and np.linalg.norm(step[3:]) < 1e-3 * surface.spacing:
            break
    return Fit(motion, _trimmed_rms(surface.plane_distances(motion.apply(points))))


def finish(
    points: np.ndarray, surface: Surface, start: Motion, iterations: int = FINISH_ITERATIONS
) -> Fit:
    """``start`` finished by Gauss-Newton on the exact distances of ``points`` (n, 3)
    to ``surface``'s triangles: a distance's slope is the unit vector from the point's
    nearest point to it (over a triangle its normal, beyond an edge away from that edge),
    so this is point-to-plane ICP with no sampling in it. Each step is lengthened by
    :data:`STRETCH` while that lowers the RMS distance (along a direction the surface
    barely holds, the linear model's steps are short), and the finish ends when a step
    does not lower it."""
    motion = start
    moved = motion.apply(points)
    nearest = surface.closest(moved)
    best = rms(np.linalg.norm(nearest - moved, axis=1))
    for _ in range(iterations):
        offsets = moved - nearest
        distances = np.linalg.norm(offsets, axis=1)
        on = distances > 1e-9 * surface.spacing  # a point on the surface has no slope
        slopes = offsets[on] / distances[on, None]
        centre = moved.mean(0)
        system = np.hstack([np.cross(moved[on] - centre, slopes), slopes])
        step, *_ = np.linalg.lstsq(system, -distances[on], rcond=None)
        taken = None
        for length in STRETCH ** np.arange(STRETCHES):
            turn = _rotation(length * step[:3])
            tried = motion.then(turn, centre - turn @ centre + length * step[3:])
            tried_moved = tried.apply(points)
            tried_nearest = surface.closest(tried_moved)
            tried_rms = rms(np.linalg.norm(tried_nearest - tried_moved, axis=1))
            if tried_rms >= best:
                break
            taken, best = (tried, tried_moved, tried_nearest), tried_rms
        if taken is None:
            break
        motion, moved, nearest = taken  # the step taken's nearest points serve the next
    return Fit(motion, _trimmed_rms(np.linalg.norm(nearest - moved, axis=1)))


def _icp_step(moved: np.ndarray, surface: Surface, edge: float) -> np.ndarray:
    """The small motion (rotation vector, translation: (6,)) that best moves ``moved``
    (n, 3) onto ``surface``, linearised, over its :data:`TRIM` nearest pairs."""
    distances, nearest = surface.nearest(moved)
    kept = distances <= np.quantile(distances, FINE_TRIM)
    moved, nearest = moved[kept], nearest[kept]
    offsets = moved - surface.samples[nearest]
    normals = surface.normals[nearest]
    normal = np.einsum("ij,ij->i", offsets, normals)
    over = np.linalg.norm(offsets - normal[:, None] * normals, axis=1) <= edge
    plane = np.hstack([np.cross(moved[over], normals[over]), normals[over]])
    beyond = moved[~over]
    skew = np.zeros((len(beyond), 3, 3))
    skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = beyond[:, 2], -beyond[:, 1], beyond[:, 0]
    skew -= np.transpose(skew, (0, 2, 1))  # -[p]x: the rotation vector's rows of w x p
    point = np.concatenate([skew, np.tile(np.eye(3), (len(beyond), 1, 1))], axis=2)
    system = np.vstack([plane, point.reshape(-1, 6)])
    rhs = np.concatenate([-normal[over], -offsets[~over].ravel()])
    step, *_ = np.linalg.lstsq(system.T @ system, system.T @ rhs, rcond=None)
    return step


def _global_starts(points: np.ndarray, surface: Surface, mirrored: bool) -> list[Motion]:
    """Every global start (module docstring), each after :data:`COARSE_ITERATIONS` of
    trimmed point-to-point ICP, all at once."""
    source = points * MIRROR if mirrored else points
    source_axes, target_axes = _axes(source), _axes(surface.samples)
    source_mean, target_mean = source.mean(0), surface.samples.mean(0)
    rotations = []
    for flip in (np.diag([1.0, 1.0, 1.0]), np.diag([1.0, -1.0, -1.0])):
        for angle in np.arange(TURNS) * 2 * np.pi / TURNS:
            turn = _rotation(np.array([0.0, 0.0, angle]))
            rotations.append(target_axes @ turn @ flip @ source_axes.T)
    rotations = np.array(rotations)  # (K, 3, 3)
    translations = target_mean - np.einsum("kij,j->ki", rotations, source_mean)
    for _ in range(COARSE_ITERATIONS):
        moved = np.einsum("kij,nj->kni", rotations, source) + translations[:, None, :]
        _, nearest = surface.coarse_tree.query(moved.reshape(-1, 3))
        matched = surface.samples[nearest].reshape(moved.shape)
        step_rotations, step_translations = _kabsch_trimmed(moved, matched)
        rotations = step_rotations @ rotations
        translations = np.einsum("kij,kj->ki", step_rotations, translations) + step_translations
    return [Motion(r, t, mirrored) for r, t in zip(rotations, translations, strict=True)]


def _kabsch_trimmed(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per set k, the proper rotation (K, 3, 3) and translation (K, 3) moving ``source``
    (K, n, 3) closest to ``target`` (K, n, 3) over its :data:`TRIM` nearest pairs."""
    distances = np.linalg.norm(source - target, axis=2)
    weights = (distances <= np.quantile(distances, TRIM, axis=1, keepdims=True)).astype(float)
    weights /= weights.sum(axis=1, keepdims=True)
    source_mean = np.einsum("kn,kni->ki", weights, source)
    target_mean = np.einsum("kn,kni->ki", weights, target)
    covariance = np.einsum(
        "kn,kni,knj->kij", weights, source - source_mean[:, None], target - target_mean[:, None]
    )
    left, _, right = np.linalg.svd(covariance)
    signs = np.sign(np.linalg.det(left @ right))
    signs[signs == 0] = 1.0
    fix = np.tile(np.eye(3), (len(signs), 1, 1))
    fix[:, 2, 2] = signs
    rotations = np.transpose(left @ fix @ right, (0, 2, 1))
    translations = target_mean - np.einsum("kij,kj->ki", rotations, source_mean)
    return rotations, translations


def _axes(points: np.ndarray) -> np.ndarray:
    """The principal axes of ``points`` (n, 3) as the columns of a proper rotation, the
    most spread first."""
    _, _, rows = np.linalg.svd(points - points.mean(0), full_matrices=False)
    axes = rows.T.copy()
    if np.linalg.det(axes) < 0:
        axes[:, 2] *= -1
    return axes


def closest_on_triangles(
    a: np.ndarray, b: np.ndarray, c: np.ndarray, points: np.ndarray
) -> np.ndarray:
    """The nearest point (n, 3) of each triangle (``a``, ``b``, ``c``: its corners, (n,
    3) each) to the point of ``points`` (n, 3) in the same row (Ericson, Real-Time
    Collision Detection, 5.1.5: the vertex regions win over the edge regions, these over
    the inside)."""
    ab, ac = b - a, c - a

    def dots(offset: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.einsum("ij,ij->i", ab, offset), np.einsum("ij,ij->i", ac, offset)

    (d1, d2), (d3, d4), (d5, d6) = dots(points - a), dots(points - b), dots(points - c)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        total = va + vb + vc
        found = a + ab * (vb / total)[:, None] + ac * (vc / total)[:, None]
        edges = (
            ((vc <= 0) & (d1 >= 0) & (d3 <= 0), a, ab, d1 / (d1 - d3)),
            ((vb <= 0) & (d2 >= 0) & (d6 <= 0), a, ac, d2 / (d2 - d6)),
            ((va <= 0) & (d4 >= d3) & (d5 >= d6), b, c - b, (d4 - d3) / (d4 - d3 + d5 - d6)),
        )
        for on, start, side, share in reversed(edges):
            found[on] = start[on] + share[on, None] * side[on]
    for on, corner in (((d6 >= 0) & (d5 <= d6), c), ((d3 >= 0) & (d4 <= d3), b)):
        found[on] = corner[on]
    at_a = (d1 <= 0) & (d2 <= 0)
    found[at_a] = a[at_a]
    return found


def _vertex_faces(triangles: np.ndarray, count: int) -> np.ndarray:
    """The triangles at every vertex (count, most at one), a row's first repeated where it
    has fewer (a vertex in no triangle: triangle 0)."""
    corners = triangles.ravel()
    order = np.argsort(corners, kind="stable")
    at = corners[order]
    faces = order // 3
    starts = np.searchsorted(at, np.arange(count))
    valence = np.bincount(corners, minlength=count)
    rank = np.arange(len(at)) - starts[at]
    table = np.zeros((count, max(1, int(valence.max()))), dtype=np.int64)
    table[at, rank] = faces
    first = np.where(valence > 0, table[:, 0], 0)
    filled = np.arange(table.shape[1])[None, :] < valence[:, None]
    return np.where(filled, table, first[:, None])


def _rotation(vector: np.ndarray) -> np.ndarray:
    """The rotation (3, 3) by |vector| radians about ``vector`` (Rodrigues)."""
    angle = float(np.linalg.norm(vector))
    if angle < 1e-15:
        return np.eye(3)
    x, y, z = vector / angle
    cross = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + np.sin(angle) * cross + (1 - np.cos(angle)) * cross @ cross


def _subset(points: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """At most ``count`` of ``points``, a seeded random choice."""
    if len(points) <= count:
        return points
    return points[np.sort(rng.choice(len(points), size=count, replace=False))]


def rms(values: np.ndarray) -> float:
    """The root mean square of ``values`` (their units)."""
    return float(np.sqrt(np.mean(values**2)))


def _trimmed_rms(distances: np.ndarray) -> float:
    """The RMS of the :data:`TRIM` smallest of ``distances``."""
    kept = distances[distances <= np.quantile(distances, TRIM)]
    return float(np.sqrt(np.mean(kept**2)))
