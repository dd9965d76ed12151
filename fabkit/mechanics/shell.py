"""Thin-sheet energy of a triangle mesh with a reference metric per layer and face.

Continuum model (non-Euclidean plates, as in the paper's supplement): the sheet's
layers stack along the normal from z = -H/2 to H/2 (equal thicknesses, bottom layer
first); layer L has its own reference metric abar_L. With a the first and b the second
fundamental form of the mid-surface, the metric at height z is a - 2 z b and

    E = sum_L  int_layer  Q_L(a - abar_L - 2 z b) dz  sqrt(det abar_L) dx dy,
    Q_L(X) = Y / (8 (1 + nu)) [ nu / (1 - nu) tr(abar_L^-1 X)^2 + tr((abar_L^-1 X)^2) ],

which is h Q(a - abar) + h^3/3 Q(b) for a single layer (the supplement's w_S and w_B)
and couples stretching and bending for a bilayer. Coordinates (x, y) are the flat
sheet's; all tensors are 2 x 2 in those coordinates.

Discretisation: a is constant per triangle (constant strain, a = J^T J); b per
triangle is the mid-edge second fundamental form
``b = sum_i tan(phi_i / 2) sqrt(det abar) / (A_flat lbar_i) e_i^perp e_i^perp^T``
from the fold angles phi_i of its three edges (phi > 0 when the sheet bends towards
its normal), with rest-state lengths lbar_i in the mean reference metric. On a
boundary edge the mid-edge normal is free: its term is minimised out of each face's
energy (a free edge carries no moment). Per face the energy is then a quadratic form in
y = (a11, a12, a22, s0, s1, s2), s_i = tan(phi_i / 2):

    E_f = 1/2 (y - y0)^T K (y - y0) + c0,

with K (6 x 6), y0 and c0 precomputed from the reference metrics. Gradients and Hessians
are analytic (chain rule through a = J^T J and the fold-angle derivatives); everything
is vectorised over faces and hinges.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sparse

from fabkit.errors import FabkitError
from fabkit.mechanics.mesh import counter_clockwise, topology

VOIGT = np.array([[[1.0, 0.0], [0.0, 0.0]], [[0.0, 1.0], [1.0, 0.0]], [[0.0, 0.0], [0.0, 1.0]]])
"""Basis of symmetric 2 x 2 matrices: X = x11 V0 + x12 V1 + x22 V2."""

_EYE = np.eye(3)
_SELECT = np.zeros((4, 3, 12))
for _k in range(4):
    _SELECT[_k, :, 3 * _k : 3 * _k + 3] = _EYE
_DE, _DU, _DW = (_SELECT[k] - _SELECT[0] for k in (1, 2, 3))
"""d(x1 - x0), d(x2 - x0), d(x3 - x0) with respect to a hinge's 12 coordinates."""


def voigt(matrices: np.ndarray) -> np.ndarray:
    """(..., 2, 2) symmetric -> (..., 3) components (x11, x12, x22)."""
    return np.stack([matrices[..., 0, 0], matrices[..., 0, 1], matrices[..., 1, 1]], -1)


@dataclass(frozen=True)
class Sheet:
    """The flat sheet as made: mesh, hinge topology and per-face constants.

    ``points`` (V, 2), ``triangles`` (F, 3) counter-clockwise; ``hinges`` (H, 4) and
    ``face_hinges`` (F, 3) as in :class:`~fabkit.mechanics.mesh.Topology`;
    ``elements`` (F, 6): a face's vertices then its three flap vertices (the face's own
    opposite vertex stands in on a boundary edge); ``slots`` (F, 3, 4): where a hinge's
    four vertices sit among its face's six; ``shape`` (F, 3, 2): J = sum_a x_a shape[a]^T;
    ``area`` (F,) flat areas; ``edges`` (F, 3, 2) flat edge vectors (edge i opposite
    vertex i). ``pattern`` is the sparse pattern of the (3V, 3V) Hessian and
    ``hinge_entries`` (H, 144) where each entry of a hinge's (12, 12) block (its vertices
    p, q, a, b) goes in it.
    """

    points: np.ndarray
    triangles: np.ndarray
    hinges: np.ndarray
    face_hinges: np.ndarray
    elements: np.ndarray
    slots: np.ndarray
    shape: np.ndarray
    area: np.ndarray
    edges: np.ndarray
    pattern: _Pattern
    hinge_entries: np.ndarray

    @classmethod
    def build(cls, points: np.ndarray, triangles: np.ndarray) -> Sheet:
        """Precompute everything that depends only on the flat mesh."""
        points = np.asarray(points, dtype=float)
        triangles = counter_clockwise(points, triangles)
        corners = points[triangles]
        edges = corners[:, [2, 0, 1]] - corners[:, [1, 2, 0]]
        sides = np.stack([corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]], -1)
        area = 0.5 * np.linalg.det(sides)
        if np.any(area <= 1e-14 * np.max(area, initial=0.0)) or len(area) == 0:
            raise FabkitError("mesh: a triangle is degenerate on the flat sheet")
        inverse = np.linalg.inv(sides)  # rows: gradients of the barycentric coordinates 1, 2
        shape = np.concatenate([-inverse.sum(1, keepdims=True), inverse], 1)
        top = topology(triangles)
        elements = np.concatenate([triangles, np.where(top.flaps < 0, triangles, top.flaps)], 1)
        slots = _hinge_slots(triangles, top.hinges, top.face_hinges)
        pattern = _Pattern.build(elements, len(points))
        hinge_entries = pattern.entries(top.hinges)
        return cls(
            points,
            triangles,
            top.hinges,
            top.face_hinges,
            elements,
            slots,
            shape,
            area,
            edges,
            pattern,
            hinge_entries,
        )

    @property
    def vertex_count(self) -> int:
        return len(self.points)

    def edge_length(self) -> float:
        """Mean flat edge length (design units)."""
        return float(np.mean(np.linalg.norm(self.edges, axis=-1)))


@dataclass(frozen=True)
class _Pattern:
    """CSR pattern of the assembled Hessian and where each element entry goes in it
    (``keys``: row * size + column of every stored entry, sorted)."""

    indptr: np.ndarray
    indices: np.ndarray
    keys: np.ndarray
    scatter: np.ndarray
    size: int

    @classmethod
    def build(cls, elements: np.ndarray, vertices: int) -> _Pattern:
        size = 3 * vertices
        keys = _block_keys(elements, size).ravel()
        unique, scatter = np.unique(keys, return_inverse=True)
        rows, indices = np.divmod(unique, size)
        indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=size))])
        return cls(indptr, indices, unique, scatter.ravel(), size)

    def entries(self, vertices: np.ndarray) -> np.ndarray:
        """Where the entries of blocks over ``vertices`` (n, k) go: (n, 9 k^2) indices into
        the stored entries (every pair must be in the pattern)."""
        return np.searchsorted(self.keys, _block_keys(vertices, self.size))

    def assemble(
        self, blocks: np.ndarray, extra: tuple[np.ndarray, np.ndarray] | None = None
    ) -> sparse.csr_matrix:
        """Sum element matrices (F, 18, 18), and ``extra`` (blocks (n, m, m), their
        :meth:`entries` (n, m^2)), into a (3V, 3V) CSR matrix."""
        data = np.bincount(self.scatter, weights=blocks.ravel(), minlength=len(self.indices))
        if extra is not None:
            more, entries = extra
            data += np.bincount(entries.ravel(), weights=more.ravel(), minlength=len(data))
        return sparse.csr_matrix((data, self.indices, self.indptr), shape=(self.size, self.size))


def _block_keys(vertices: np.ndarray, size: int) -> np.ndarray:
    """row * size + column of every entry of blocks over ``vertices`` (n, k): (n, 9 k^2),
    rows and columns vertex-major (3 vertex + coordinate)."""
    dofs = (3 * vertices[:, :, None] + np.arange(3)).reshape(len(vertices), -1)
    return (dofs[:, :, None] * size + dofs[:, None, :]).reshape(len(vertices), -1)


def _hinge_slots(triangles: np.ndarray, hinges: np.ndarray, face_hinges: np.ndarray):
    """(F, 3, 4) positions (0..5) of each edge's hinge vertices among the face's six."""
    slots = np.zeros((*face_hinges.shape, 4), dtype=np.int64)
    for i in range(3):
        ends = [(i + 1) % 3, (i + 2) % 3]
        interior = face_hinges[:, i] >= 0
        hinge = hinges[np.maximum(face_hinges[:, i], 0)]
        is_a = hinge[:, 2] == triangles[:, i]  # the face is the hinge's face A
        p_slot = np.where(hinge[:, 0] == triangles[:, ends[0]], ends[0], ends[1])
        q_slot = np.where(hinge[:, 1] == triangles[:, ends[0]], ends[0], ends[1])
        slots[:, i] = np.stack(
            [p_slot, q_slot, np.where(is_a, i, 3 + i), np.where(is_a, 3 + i, i)], -1
        )
        slots[~interior, i] = 0
    return slots


def fold_angles(x: np.ndarray, hinges: np.ndarray, order: int = 1):
    """Fold angles phi (H,) of hinges (p, q, a, b) and their derivatives.

    phi is the angle between the two face normals, positive when the sheet bends towards
    its normal (a bowl opening along +n). Returns ``phi``, and with ``order`` >= 1 the
    gradient (H, 12) with respect to (x_p, x_q, x_a, x_b), with ``order`` 2 also the
    Hessian (H, 12, 12).
    """
    x0, x1, x2, x3 = (x[hinges[:, k]] for k in range(4))
    e, u, w = x1 - x0, x2 - x0, x3 - x0
    normal_a, normal_b = np.cross(e, u), np.cross(w, e)
    length2 = np.einsum("hi,hi->h", e, e)
    length = np.sqrt(length2)
    area2_a = np.einsum("hi,hi->h", normal_a, normal_a)
    area2_b = np.einsum("hi,hi->h", normal_b, normal_b)
    sine = np.einsum("hi,hi->h", np.cross(normal_b, normal_a), e) / length
    cosine = np.einsum("hi,hi->h", normal_a, normal_b)
    phi = np.arctan2(sine, cosine)
    if order == 0:
        return phi
    # grad phi: -(gA, gB) on the opposite vertices, cotangent-weighted on the edge ends.
    g_a = (length / area2_a)[:, None] * normal_a
    g_b = (length / area2_b)[:, None] * normal_b
    t_a = np.einsum("hi,hi->h", u, e) / length2
    t_b = np.einsum("hi,hi->h", w, e) / length2
    rows = [
        -((1 - t_a)[:, None] * g_a + (1 - t_b)[:, None] * g_b),
        -(t_a[:, None] * g_a + t_b[:, None] * g_b),
        g_a,
        g_b,
    ]
    gradient = np.concatenate(rows, -1)
    if order == 1:
        return phi, gradient
    d_g_a = _normal_gradient(normal_a, area2_a, e, length, _cross_jacobian(e, u, _DE, _DU))
    d_g_b = _normal_gradient(normal_b, area2_b, e, length, _cross_jacobian(w, e, _DW, _DE))
    d_t_a = _projection_gradient(u, e, length2, _DU)
    d_t_b = _projection_gradient(w, e, length2, _DW)
    outer_a = g_a[:, :, None] * d_t_a[:, None, :]
    outer_b = g_b[:, :, None] * d_t_b[:, None, :]
    blocks = [
        outer_a - (1 - t_a)[:, None, None] * d_g_a + outer_b - (1 - t_b)[:, None, None] * d_g_b,
        -outer_a - t_a[:, None, None] * d_g_a - outer_b - t_b[:, None, None] * d_g_b,
        d_g_a,
        d_g_b,
    ]
    hessian = np.concatenate(blocks, 1)
    return phi, gradient, 0.5 * (hessian + hessian.transpose(0, 2, 1))


def _skew(v: np.ndarray) -> np.ndarray:
    """[v]x (..., 3, 3) such that [v]x w = v x w."""
    zero = np.zeros_like(v[..., 0])
    return np.stack(
        [
            np.stack([zero, -v[..., 2], v[..., 1]], -1),
            np.stack([v[..., 2], zero, -v[..., 0]], -1),
            np.stack([-v[..., 1], v[..., 0], zero], -1),
        ],
        -2,
    )


def _cross_jacobian(left, right, d_left, d_right):
    """Jacobian (H, 3, 12) of left x right given the constant Jacobians of both factors."""
    return _skew(left) @ d_right - _skew(right) @ d_left


def _normal_gradient(normal, area2, e, length, d_normal):
    """Jacobian (H, 3, 12) of g = |e| N / |N|^2."""
    unit = normal / np.sqrt(area2)[:, None]
    project = _EYE - 2 * unit[:, :, None] * unit[:, None, :]
    d_length = np.einsum("hi,ij->hj", e / length[:, None], _DE)
    return (normal / area2[:, None])[:, :, None] * d_length[:, None, :] + (length / area2)[
        :, None, None
    ] * (project @ d_normal)


def _projection_gradient(v, e, length2, d_v):
    """Gradient (H, 12) of t = (v . e) / |e|^2."""
    dot = np.einsum("hi,hi->h", v, e)
    d_dot = np.einsum("hi,ij->hj", e, d_v) + np.einsum("hi,ij->hj", v, _DE)
    d_length2 = 2 * np.einsum("hi,ij->hj", e, _DE)
    return d_dot / length2[:, None] - (dot / length2**2)[:, None] * d_length2


@dataclass(frozen=True)
class Shell:
    """Energy of a :class:`Sheet` under given reference metrics (see the module docstring).

    ``stiffness`` (F, 6, 6), ``rest`` (F, 6) and ``offset`` (F,) define each face's
    quadratic form in y = (a11, a12, a22, s0, s1, s2); energies are in units of
    Young's modulus x length^3 (design units).
    """

    sheet: Sheet
    stiffness: np.ndarray
    rest: np.ndarray
    offset: np.ndarray

    def coordinates(self, x: np.ndarray, order: int = 1):
        """y (F, 6) at positions x (V, 3); with order >= 1 also the parts of dy/dx.

        Returns ``y`` and, for order >= 1, ``(J, hinge)`` where J (F, 3, 2) is the
        deformation gradient and ``hinge`` the output of :func:`fold_angles` at ``order``.
        """
        sheet = self.sheet
        jac = np.einsum("fac,fak->fck", x[sheet.triangles], sheet.shape)
        metric = np.einsum("fck,fcl->fkl", jac, jac)
        hinge = fold_angles(x, sheet.hinges, order)
        phi = hinge if order == 0 else hinge[0]
        tangent = np.append(np.tan(0.5 * phi), 0.0)[sheet.face_hinges]
        y = np.concatenate([voigt(metric), tangent], -1)
        return (y, None) if order == 0 else (y, (jac, hinge))

    def energy(self, x: np.ndarray) -> float:
        """Total energy at positions x (V, 3)."""
        delta = self.coordinates(x, 0)[0] - self.rest
        return float(
            0.5 * np.einsum("fi,fij,fj->", delta, self.stiffness, delta) + self.offset.sum()
        )

    def face_energy(self, x: np.ndarray) -> np.ndarray:
        """Energy of every face (F,) at positions x (V, 3)."""
        delta = self.coordinates(x, 0)[0] - self.rest
        return 0.5 * np.einsum("fi,fij,fj->f", delta, self.stiffness, delta) + self.offset

    def gradient(self, x: np.ndarray) -> np.ndarray:
        """dE/dx (V, 3)."""
        y, (jac, (phi, d_phi)) = self.coordinates(x, 1)
        stress = np.einsum("fij,fj->fi", self.stiffness, y - self.rest)
        sheet = self.sheet
        face = 2 * np.einsum("fak,fkl,fcl->fac", sheet.shape, _symmetric(stress[:, :3]), jac)
        gradient = _scatter(sheet.triangles, face, len(sheet.points))
        moment = _hinge_sum(sheet, stress[:, 3:]) * _tan_slope(phi)
        hinge = (moment[:, None] * d_phi).reshape(-1, 4, 3)
        return gradient + _scatter(sheet.hinges, hinge, len(sheet.points))

    def hessian(self, x: np.ndarray, projected: bool = True) -> sparse.csr_matrix:
        """d^2E/dx^2 (3V, 3V), vertex-major (3 k + coordinate).

        ``projected=False``: the exact Hessian. ``projected=True``: the positive
        semi-definite model used by the Newton solver: the exact Gauss-Newton part
        dy^T K dy (K is positive semi-definite), plus the membrane-stress part projected
        onto its non-negative eigenvalues; the fold-angle curvature term is left out.
        """
        order = 1 if projected else 2
        y, (jac, hinge) = self.coordinates(x, order)
        sheet = self.sheet
        stress = np.einsum("fij,fj->fi", self.stiffness, y - self.rest)
        slope = _tan_slope(hinge[0])
        dy = _coordinate_jacobian(sheet, jac, slope[:, None] * hinge[1])
        blocks = np.einsum("fki,fkl,flj->fij", dy, self.stiffness, dy, optimize=True)
        membrane = _symmetric(stress[:, :3])
        if projected:
            membrane = _positive_part(membrane, sheet.shape)
        geometric = 2 * np.einsum("fak,fkl,fbl->fab", sheet.shape, membrane, sheet.shape)
        blocks[:, :9, :9] += np.kron(geometric, np.eye(3)[None]).reshape(-1, 9, 9)
        if not projected:
            _, d_phi, dd_phi = hinge
            moment = _hinge_sum(sheet, stress[:, 3:])
            curvature = moment[:, None, None] * (
                (slope * np.tan(0.5 * hinge[0]))[:, None, None]
                * d_phi[:, :, None]
                * d_phi[:, None, :]
                + slope[:, None, None] * dd_phi
            )
            return sheet.pattern.assemble(blocks, (curvature, sheet.hinge_entries))
        return sheet.pattern.assemble(blocks)


def _symmetric(components: np.ndarray) -> np.ndarray:
    """dE/dy for (a11, a12, a22) -> the symmetric S with dE = tr(S da) (F, 2, 2)."""
    half = 0.5 * components[:, 1]
    return np.stack(
        [np.stack([components[:, 0], half], -1), np.stack([half, components[:, 2]], -1)], -2
    )


def _tan_slope(phi: np.ndarray) -> np.ndarray:
    """d tan(phi/2) / d phi."""
    return 0.5 / np.cos(0.5 * phi) ** 2


def _hinge_sum(sheet: Sheet, per_face_edge: np.ndarray) -> np.ndarray:
    """Sum (F, 3) face-edge values onto their hinges (H,)."""
    interior = sheet.face_hinges >= 0
    return np.bincount(
        sheet.face_hinges[interior], weights=per_face_edge[interior], minlength=len(sheet.hinges)
    )


def _scatter(indices: np.ndarray, values: np.ndarray, count: int) -> np.ndarray:
    """Sum per-element vertex vectors (E, k, 3) into (count, 3)."""
    flat = indices.ravel()
    return np.stack(
        [np.bincount(flat, weights=values[..., c].ravel(), minlength=count) for c in range(3)], -1
    )


def _coordinate_jacobian(sheet: Sheet, jac: np.ndarray, d_tangent: np.ndarray) -> np.ndarray:
    """dy/dx (F, 6, 18) over each face's element coordinates (6 vertices x 3)."""
    faces = len(sheet.triangles)
    dy = np.zeros((faces, 6, 18))
    shape = sheet.shape
    d_metric = np.zeros((faces, 3, 3, 3))  # (component, vertex, coordinate)
    d_metric[:, 0] = 2 * shape[:, :, 0, None] * jac[:, None, :, 0]
    d_metric[:, 1] = (
        shape[:, :, 0, None] * jac[:, None, :, 1] + shape[:, :, 1, None] * jac[:, None, :, 0]
    )
    d_metric[:, 2] = 2 * shape[:, :, 1, None] * jac[:, None, :, 1]
    dy[:, :3, :9] = d_metric.reshape(faces, 3, 9)
    rows, columns = _hinge_columns(sheet)
    interior = sheet.face_hinges >= 0
    values = np.where(interior[:, :, None], d_tangent[np.maximum(sheet.face_hinges, 0)], 0.0)
    face = np.arange(faces)[:, None, None]
    dy[face, 3 + rows, columns] = values
    return dy


def _hinge_columns(sheet: Sheet) -> tuple[np.ndarray, np.ndarray]:
    """(F, 3, 12) row offsets and element columns of each edge's hinge coordinates."""
    columns = (3 * sheet.slots[:, :, :, None] + np.arange(3)).reshape(*sheet.slots.shape[:2], 12)
    rows = np.broadcast_to(np.arange(3)[None, :, None], columns.shape)
    return rows, columns


def _positive_part(stress: np.ndarray, shape: np.ndarray) -> np.ndarray:
    """The S+ with shape S+ shape^T the positive part of shape S shape^T (F, 2, 2)."""
    gram = np.einsum("fak,fal->fkl", shape, shape)
    root = np.linalg.cholesky(gram)  # gram = root root^T
    inner = np.einsum("fki,fkl,flj->fij", root, stress, root)
    values, vectors = np.linalg.eigh(inner)
    clipped = np.einsum("fik,fk,fjk->fij", vectors, np.maximum(values, 0.0), vectors)
    inverse = np.linalg.inv(root)
    return np.einsum("fki,fkl,flj->fij", inverse, clipped, inverse)


def build_shell(
    sheet: Sheet,
    metrics: np.ndarray,
    thickness: float,
    poisson: float = 0.5,
    youngs: float = 1.0,
) -> Shell:
    """The quadratic forms of every face for reference metrics ``metrics``.

    ``metrics`` (F, 2, 2) for a single layer, or (L, F, 2, 2) for L equal layers
    stacked bottom (-normal side) to top; ``thickness`` H in design units; ``poisson``
    in [0, 0.5]; ``youngs`` scales every energy.
    """
    metrics = np.asarray(metrics, dtype=float)
    if metrics.ndim == 3:
        metrics = metrics[None]
    faces = len(sheet.triangles)
    if metrics.shape[1:] != (faces, 2, 2):
        raise FabkitError(f"metrics: expected shape (layers, {faces}, 2, 2), got {metrics.shape}")
    if not np.all(np.linalg.eigvalsh(metrics) > 0):
        raise FabkitError("metrics: every reference metric must be positive definite")
    if not thickness > 0:
        raise FabkitError("thickness must be positive")
    if not 0 <= poisson <= 0.5:
        raise FabkitError("poisson ratio must lie in [0, 0.5]")
    bend = _bending_basis(sheet, metrics.mean(0))
    stiffness, linear, constant = _layer_forms(
        metrics, bend, sheet.area, thickness, poisson, youngs
    )
    stiffness, linear, constant = _free_boundary(stiffness, linear, constant, sheet.face_hinges < 0)
    regular = stiffness.copy()
    boundary = np.nonzero(sheet.face_hinges < 0)
    regular[boundary[0], 3 + boundary[1], 3 + boundary[1]] = 1.0
    rest = -np.linalg.solve(regular, linear[:, :, None])[:, :, 0]
    offset = constant + 0.5 * np.einsum("fi,fi->f", linear, rest)
    return Shell(sheet, stiffness, rest, offset)


def _bending_basis(sheet: Sheet, metric: np.ndarray) -> np.ndarray:
    """(F, 3, 3): column i is the Voigt form of sqrt(det a)/(A lbar_i) e_i^perp e_i^perp^T."""
    edges = sheet.edges
    perp = np.stack([edges[..., 1], -edges[..., 0]], -1)
    length = np.sqrt(np.einsum("fik,fkl,fil->fi", edges, metric, edges))
    scale = np.sqrt(np.linalg.det(metric))[:, None] / (sheet.area[:, None] * length)
    outer = perp[..., :, None] * perp[..., None, :] * scale[..., None, None]
    return np.swapaxes(voigt(outer), 1, 2)


def _norm_matrix(metric: np.ndarray, poisson: float, youngs: float) -> np.ndarray:
    """Q as a (F, 3, 3) matrix on Voigt components: Q(X, Y) = x^T C y."""
    inverse = np.linalg.inv(metric)
    products = np.einsum("fij,vjk->fvik", inverse, VOIGT)  # abar^-1 V_v
    traces = np.trace(products, axis1=2, axis2=3)
    pairs = np.einsum("fvij,fwji->fvw", products, products)
    ratio = poisson / (1 - poisson)
    factor = youngs / (8 * (1 + poisson))
    return factor * (ratio * traces[:, :, None] * traces[:, None, :] + pairs)


def _layer_forms(metrics, bend, area, thickness, poisson, youngs):
    """Stiffness (F, 6, 6), linear (F, 6) and constant (F,) terms of sum over layers."""
    faces = metrics.shape[1]
    stiffness, linear, constant = np.zeros((faces, 6, 6)), np.zeros((faces, 6)), np.zeros(faces)
    heights = np.linspace(-thickness / 2, thickness / 2, len(metrics) + 1)
    for metric, low, high in zip(metrics, heights[:-1], heights[1:], strict=True):
        norm = (
            _norm_matrix(metric, poisson, youngs)
            * (np.sqrt(np.linalg.det(metric)) * area)[:, None, None]
        )
        width, first, second = high - low, high**2 - low**2, 4 * (high**3 - low**3) / 3
        rest = voigt(metric)
        coupled = norm @ bend
        stiffness[:, :3, :3] += 2 * width * norm
        stiffness[:, :3, 3:] -= 2 * first * coupled
        stiffness[:, 3:, :3] -= 2 * first * np.swapaxes(coupled, 1, 2)
        stiffness[:, 3:, 3:] += 2 * second * np.swapaxes(bend, 1, 2) @ coupled
        norm_rest = np.einsum("fij,fj->fi", norm, rest)
        linear[:, :3] -= 2 * width * norm_rest
        linear[:, 3:] += 2 * first * np.einsum("fji,fj->fi", bend, norm_rest)
        constant += width * np.einsum("fi,fi->f", rest, norm_rest)
    return stiffness, linear, constant


def _free_boundary(stiffness, linear, constant, boundary):
    """Minimise each face's form over the s_i of its boundary edges (``boundary`` (F, 3))."""
    stiffness, linear, constant = stiffness.copy(), linear.copy(), constant.copy()
    for i in range(3):
        free = boundary[:, i]
        k = 3 + i
        pivot = np.where(free, stiffness[:, k, k], 1.0)
        column = np.where(free[:, None], stiffness[:, :, k], 0.0)
        load = np.where(free, linear[:, k], 0.0)
        constant -= 0.5 * load**2 / pivot
        linear -= column * (load / pivot)[:, None]
        stiffness -= column[:, :, None] * column[:, None, :] / pivot[:, None, None]
        stiffness[free, k, :] = 0.0
        stiffness[free, :, k] = 0.0
        linear[free, k] = 0.0
    return stiffness, linear, constant
