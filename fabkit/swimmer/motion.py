"""Net rigid motion of a free body that goes through a sequence of shapes in Stokes flow.

A stroke is a sequence of M + 1 shapes (M + 1, N, 3) of the same N material points. Each
shape is first placed rigidly in the body frame by a best fit to the first shape
(:func:`align`), so the body frame is a function of the shape alone: a closed cycle ends
where it began, and a path walked back retraces its frames. For each increment the
force- and torque-free rigid motion is solved at the midpoint shape (second order in the
increment), giving a body-frame twist (dU, dOmega); the poses are composed on SE(3) with
the exponential map. Nothing depends on how fast the shapes follow each other.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from fabkit.errors import FabkitError
from fabkit.swimmer.stokes import Stokes


@dataclass(frozen=True)
class Trajectory:
    """Poses of the body frame along a stroke; lab point = rotations[i] @ X + positions[i].

    ``shapes`` (M + 1, N, 3) the aligned body-frame shapes (centroid at the origin);
    ``twists`` (M, 6) body-frame (dU, dOmega) per increment (length, rad);
    ``rotations`` (M + 1, 3, 3) and ``positions`` (M + 1, 3) the lab poses, starting at
    the identity; ``positions`` is also the lab centroid of the points.
    """

    shapes: np.ndarray
    twists: np.ndarray
    rotations: np.ndarray
    positions: np.ndarray

    @property
    def displacement(self) -> np.ndarray:
        """Net displacement (3,) of the centroid from first to last shape, lab frame."""
        return self.positions[-1] - self.positions[0]

    @property
    def rotation(self) -> np.ndarray:
        """Net rotation vector (3,) from first to last shape (axis x angle, rad), lab frame."""
        return Rotation.from_matrix(self.rotations[-1]).as_rotvec()


def align(shape: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """``shape`` (N, 3) moved rigidly to fit ``reference`` (N, 3) best, centroid at origin.

    Least squares over rotations (Kabsch); ``reference`` is taken about its own centroid.
    """
    moved = shape - shape.mean(axis=0)
    target = reference - reference.mean(axis=0)
    u, _, vt = np.linalg.svd(moved.T @ target)
    flip = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    return moved @ (u @ flip @ vt)


def swim(
    shapes: Sequence[np.ndarray] | np.ndarray,
    epsilon: float,
    viscosity: float = 1.0,
    progress: Callable[[int, int], None] | None = None,
) -> Trajectory:
    """Sum the rigid motions over the increments of ``shapes`` (M + 1, N, 3).

    ``epsilon`` is the Stokeslet regularisation (length); ``progress(done, total)`` is
    called after each increment. Cost: one (3N)^3 / 3 factorisation per increment.
    """
    shapes = np.asarray(shapes, dtype=float)
    if shapes.ndim != 3 or shapes.shape[2] != 3 or len(shapes) < 2:
        raise FabkitError("swim: need at least two shapes of the same (N, 3) points")
    aligned = np.stack([align(shape, shapes[0]) for shape in shapes])
    count = len(aligned) - 1
    twists = np.empty((count, 6))
    rotations = np.empty((count + 1, 3, 3))
    positions = np.empty((count + 1, 3))
    rotations[0], positions[0] = np.eye(3), 0.0
    for i in range(count):
        middle = 0.5 * (aligned[i] + aligned[i + 1])
        twists[i] = Stokes.of(middle, epsilon, viscosity).rigid_motion(aligned[i + 1] - aligned[i])
        turn, shift = exponential(twists[i])
        rotations[i + 1] = rotations[i] @ turn
        positions[i + 1] = positions[i] + rotations[i] @ shift
        if progress is not None:
            progress(i + 1, count)
    return Trajectory(aligned, twists, rotations, positions)


def exponential(twist: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rigid motion (rotation (3, 3), translation (3,)) of a constant body twist (6,).

    ``twist`` = (U, Omega) held for unit parameter: the SE(3) exponential map.
    """
    velocity, spin = twist[:3], twist[3:]
    angle = float(np.linalg.norm(spin))
    cross = np.array([[0.0, -spin[2], spin[1]], [spin[2], 0.0, -spin[0]], [-spin[1], spin[0], 0.0]])
    if angle < 1e-6:
        first, second = 0.5 - angle**2 / 24.0, 1.0 / 6.0 - angle**2 / 120.0
    else:
        first = (1.0 - np.cos(angle)) / angle**2
        second = (angle - np.sin(angle)) / angle**3
    jacobian = np.eye(3) + first * cross + second * cross @ cross
    return Rotation.from_rotvec(spin).as_matrix(), jacobian @ velocity
