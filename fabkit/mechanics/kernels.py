"""Compiled (numba) kernels of the shell energy: fold angles and the Hessian's blocks.

The shell's Hessian is a sum of small dense blocks, an (18, 18) one per face and a
(12, 12) one per hinge; written as numpy operations over all faces at once it made about
forty array passes per Hessian, each a few microseconds per face, and the Hessian was a
third of a simulation's time. Here each block is computed in registers and added
straight into the sparse matrix's stored entries. The arithmetic is that of the numpy
formulation it replaces (fabkit.mechanics.shell's docstring); the tests check the
gradient and the exact Hessian against finite differences (tests/test_mechanics_shell.py).
Compiled on first use and cached beside the package (``cache=True``).
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True, error_model="numpy", inline="always")
def _cross(a, b, out):
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


@numba.njit(cache=True, error_model="numpy", inline="always")
def _dot(a, b) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@numba.njit(cache=True, error_model="numpy", inline="always")
def _skew_times_difference(v, sign, plus, minus, out):
    """out (3, 12) += sign [v]x (S_plus - S_minus), S_k selecting vertex k's coordinates."""
    skew = ((0.0, -v[2], v[1]), (v[2], 0.0, -v[0]), (-v[1], v[0], 0.0))
    for i in range(3):
        for j in range(3):
            out[i, 3 * plus + j] += sign * skew[i][j]
            out[i, 3 * minus + j] -= sign * skew[i][j]


@numba.njit(cache=True, error_model="numpy", inline="always")
def _normal_gradient(normal, area2, e, length, d_normal, out):
    """out (3, 12) = Jacobian of g = |e| N / |N|^2 given dN (3, 12)."""
    root = math.sqrt(area2)
    d_length = np.zeros(12)
    for j in range(3):
        d_length[3 + j] += e[j] / length
        d_length[j] -= e[j] / length
    for i in range(3):
        for k in range(12):
            projected = d_normal[i, k]
            for j in range(3):
                projected -= 2.0 * (normal[i] / root) * (normal[j] / root) * d_normal[j, k]
            out[i, k] = normal[i] / area2 * d_length[k] + length / area2 * projected


@numba.njit(cache=True, error_model="numpy", inline="always")
def _projection_gradient(v, e, length2, vertex, out):
    """out (12,) = gradient of t = (v . e) / |e|^2, v = x_vertex - x_0, e = x_1 - x_0."""
    dot = _dot(v, e)
    for j in range(3):
        out[j] = 0.0
        out[3 + j] = 0.0
        out[6 + j] = 0.0
        out[9 + j] = 0.0
    for j in range(3):
        d_dot_v, d_dot_e = e[j] / length2, v[j] / length2
        d_length2 = 2.0 * e[j] * dot / length2**2
        out[3 * vertex + j] += d_dot_v
        out[j] -= d_dot_v
        out[3 + j] += d_dot_e - d_length2
        out[j] -= d_dot_e - d_length2


@numba.njit(cache=True, error_model="numpy")
def fold_angles(x, hinges, order):
    """Fold angles phi (H,) of hinges (p, q, a, b) at positions x (V, 3); with ``order``
    >= 1 their gradients (H, 12) over (x_p, x_q, x_a, x_b), with ``order`` 2 their
    Hessians (H, 12, 12) (zeros (H, 0) or (H, 0, 0) when not asked for)."""
    count = hinges.shape[0]
    phi = np.empty(count)
    gradient = np.zeros((count, 12 if order >= 1 else 0))
    hessian = np.zeros((count, 12 if order == 2 else 0, 12 if order == 2 else 0))
    e, u, w = np.empty(3), np.empty(3), np.empty(3)
    normal_a, normal_b, cross = np.empty(3), np.empty(3), np.empty(3)
    g_a, g_b = np.empty(3), np.empty(3)
    d_normal_a, d_normal_b = np.empty((3, 12)), np.empty((3, 12))
    d_g_a, d_g_b = np.empty((3, 12)), np.empty((3, 12))
    d_t_a, d_t_b = np.empty(12), np.empty(12)
    block = np.empty((12, 12))
    for h in range(count):
        p, q, a, b = hinges[h, 0], hinges[h, 1], hinges[h, 2], hinges[h, 3]
        for j in range(3):
            e[j] = x[q, j] - x[p, j]
            u[j] = x[a, j] - x[p, j]
            w[j] = x[b, j] - x[p, j]
        _cross(e, u, normal_a)
        _cross(w, e, normal_b)
        length2 = _dot(e, e)
        length = math.sqrt(length2)
        area2_a, area2_b = _dot(normal_a, normal_a), _dot(normal_b, normal_b)
        _cross(normal_b, normal_a, cross)
        phi[h] = math.atan2(_dot(cross, e) / length, _dot(normal_a, normal_b))
        if order == 0:
            continue
        t_a, t_b = _dot(u, e) / length2, _dot(w, e) / length2
        for j in range(3):
            g_a[j] = length / area2_a * normal_a[j]
            g_b[j] = length / area2_b * normal_b[j]
            gradient[h, j] = -((1 - t_a) * g_a[j] + (1 - t_b) * g_b[j])
            gradient[h, 3 + j] = -(t_a * g_a[j] + t_b * g_b[j])
            gradient[h, 6 + j] = g_a[j]
            gradient[h, 9 + j] = g_b[j]
        if order == 1:
            continue
        d_normal_a[:] = 0.0
        d_normal_b[:] = 0.0
        _skew_times_difference(e, 1.0, 2, 0, d_normal_a)  # [e]x du - [u]x de
        _skew_times_difference(u, -1.0, 1, 0, d_normal_a)
        _skew_times_difference(w, 1.0, 1, 0, d_normal_b)  # [w]x de - [e]x dw
        _skew_times_difference(e, -1.0, 3, 0, d_normal_b)
        _normal_gradient(normal_a, area2_a, e, length, d_normal_a, d_g_a)
        _normal_gradient(normal_b, area2_b, e, length, d_normal_b, d_g_b)
        _projection_gradient(u, e, length2, 2, d_t_a)
        _projection_gradient(w, e, length2, 3, d_t_b)
        for i in range(3):
            for k in range(12):
                outer_a, outer_b = g_a[i] * d_t_a[k], g_b[i] * d_t_b[k]
                block[i, k] = outer_a - (1 - t_a) * d_g_a[i, k] + outer_b - (1 - t_b) * d_g_b[i, k]
                block[3 + i, k] = -outer_a - t_a * d_g_a[i, k] - outer_b - t_b * d_g_b[i, k]
                block[6 + i, k] = d_g_a[i, k]
                block[9 + i, k] = d_g_b[i, k]
        for i in range(12):
            for k in range(12):
                hessian[h, i, k] = 0.5 * (block[i, k] + block[k, i])
    return phi, gradient, hessian


@numba.njit(cache=True, error_model="numpy")
def add_face_blocks(data, scatter, jac, shape, stiffness, d_tangent, face_hinges, slots, membrane):
    """Add every face's (18, 18) block dy^T K dy + (2 shape S shape^T) x I3 into ``data``
    (the Hessian's stored entries; ``scatter`` (F * 324,) says where each block entry
    goes). dy (6, 18) is dy/dx over the face's six vertices: the metric's components from
    the deformation gradient ``jac`` (F, 3, 2) and ``shape`` (F, 3, 2), the edges'
    tan(phi/2) from ``d_tangent`` (H, 12) through ``face_hinges`` (F, 3) and ``slots``
    (F, 3, 4); K is ``stiffness`` (F, 6, 6) and S ``membrane`` (F, 2, 2)."""
    dy, product = np.zeros((6, 18)), np.empty((6, 18))
    geometric = np.empty((3, 3))
    for f in range(jac.shape[0]):
        dy[:] = 0.0
        for a in range(3):
            for c in range(3):
                column = 3 * a + c
                dy[0, column] = 2 * shape[f, a, 0] * jac[f, c, 0]
                dy[1, column] = shape[f, a, 0] * jac[f, c, 1] + shape[f, a, 1] * jac[f, c, 0]
                dy[2, column] = 2 * shape[f, a, 1] * jac[f, c, 1]
        for i in range(3):
            h = face_hinges[f, i]
            if h >= 0:
                for k in range(4):
                    for c in range(3):
                        dy[3 + i, 3 * slots[f, i, k] + c] = d_tangent[h, 3 * k + c]
        for r in range(6):
            for column in range(18):
                total = 0.0
                for s in range(6):
                    total += stiffness[f, r, s] * dy[s, column]
                product[r, column] = total
        for a in range(3):
            for b in range(3):
                total = 0.0
                for k in range(2):
                    for m in range(2):
                        total += shape[f, a, k] * membrane[f, k, m] * shape[f, b, m]
                geometric[a, b] = 2 * total
        base = f * 324
        for i in range(18):
            for j in range(18):
                total = 0.0
                for r in range(6):
                    total += dy[r, i] * product[r, j]
                if i < 9 and j < 9 and i % 3 == j % 3:
                    total += geometric[i // 3, j // 3]
                data[scatter[base + 18 * i + j]] += total


@numba.njit(cache=True, error_model="numpy")
def add_hinge_blocks(data, entries, moment, slope, tangent, d_phi, dd_phi):
    """Add every hinge's (12, 12) fold-angle curvature block into ``data``: the moment
    (H,) times the second derivative of tan(phi/2), slope (H,) d tan(phi/2)/d phi and
    tangent (H,) tan(phi/2), from phi's gradient (H, 12) and Hessian (H, 12, 12);
    ``entries`` (H, 144) says where each block entry goes."""
    for h in range(entries.shape[0]):
        curvature = slope[h] * tangent[h]
        for i in range(12):
            for j in range(12):
                value = curvature * d_phi[h, i] * d_phi[h, j] + slope[h] * dd_phi[h, i, j]
                data[entries[h, 12 * i + j]] += moment[h] * value


@numba.njit(cache=True, error_model="numpy")
def positive_part(stress, shape):
    """The S+ (F, 2, 2) with shape S+ shape^T the positive part of shape S shape^T, for
    symmetric ``stress`` S (F, 2, 2) and ``shape`` (F, 3, 2): with shape^T shape = R R^T
    (Cholesky), S+ = R^-T P(R^T S R) R^-1, P clipping the eigenvalues at zero (closed
    form for 2 x 2)."""
    result = np.zeros_like(stress)
    for f in range(stress.shape[0]):
        g00, g01, g11 = 0.0, 0.0, 0.0
        for a in range(3):
            g00 += shape[f, a, 0] * shape[f, a, 0]
            g01 += shape[f, a, 0] * shape[f, a, 1]
            g11 += shape[f, a, 1] * shape[f, a, 1]
        r00 = math.sqrt(g00)
        r10 = g01 / r00
        r11 = math.sqrt(g11 - r10 * r10)
        s00, s01, s11 = stress[f, 0, 0], stress[f, 0, 1], stress[f, 1, 1]
        # inner = R^T S R, R = [[r00, 0], [r10, r11]]
        a = r00 * r00 * s00 + 2 * r00 * r10 * s01 + r10 * r10 * s11
        b = r00 * r11 * s01 + r10 * r11 * s11
        c = r11 * r11 * s11
        mean, spread = 0.5 * (a + c), math.sqrt(0.25 * (a - c) ** 2 + b * b)
        low, high = mean - spread, mean + spread
        if low >= 0.0:
            p00, p01, p11 = a, b, c
        elif high <= 0.0:
            continue
        else:  # high times the projector onto its eigenvector
            scale = high / (2 * spread)
            p00, p01, p11 = scale * (a - low), scale * b, scale * (c - low)
        i00, i10, i11 = 1.0 / r00, -r10 / (r00 * r11), 1.0 / r11  # R^-1, lower triangular
        # S+ = R^-T P R^-1
        result[f, 0, 0] = i00 * (i00 * p00 + i10 * p01) + i10 * (i00 * p01 + i10 * p11)
        result[f, 0, 1] = i11 * (i00 * p01 + i10 * p11)
        result[f, 1, 0] = result[f, 0, 1]
        result[f, 1, 1] = i11 * i11 * p11
    return result


@numba.njit(cache=True, error_model="numpy")
def face_state(x, triangles, shape, phi, face_hinges):
    """The deformation gradient J (F, 3, 2) of every face at positions x (V, 3), and its
    coordinates y (F, 6): the metric J^T J (a11, a12, a22) and tan(phi / 2) of its three
    edges (0 on a boundary edge) from the hinges' fold angles ``phi`` (H,)."""
    faces = triangles.shape[0]
    jac, y = np.zeros((faces, 3, 2)), np.zeros((faces, 6))
    for f in range(faces):
        for a in range(3):
            v = triangles[f, a]
            for c in range(3):
                jac[f, c, 0] += x[v, c] * shape[f, a, 0]
                jac[f, c, 1] += x[v, c] * shape[f, a, 1]
        for c in range(3):
            y[f, 0] += jac[f, c, 0] * jac[f, c, 0]
            y[f, 1] += jac[f, c, 0] * jac[f, c, 1]
            y[f, 2] += jac[f, c, 1] * jac[f, c, 1]
        for i in range(3):
            h = face_hinges[f, i]
            if h >= 0:
                y[f, 3 + i] = math.tan(0.5 * phi[h])
    return jac, y


@numba.njit(cache=True, error_model="numpy")
def face_energies(y, rest, stiffness, offset):
    """Every face's energy (F,): 1/2 (y - y0)^T K (y - y0) + c0."""
    energies = np.empty(y.shape[0])
    delta = np.empty(6)
    for f in range(y.shape[0]):
        for i in range(6):
            delta[i] = y[f, i] - rest[f, i]
        total = 0.0
        for i in range(6):
            row = 0.0
            for j in range(6):
                row += stiffness[f, i, j] * delta[j]
            total += delta[i] * row
        energies[f] = 0.5 * total + offset[f]
    return energies


@numba.njit(cache=True, error_model="numpy")
def gradient(vertices, triangles, shape, jac, stress, hinges, hinge_force):
    """dE/dx (V, 3): every face's membrane part 2 shape S J^T, S the symmetric matrix of
    dE/da (``stress`` (F, 6) columns 0-2: a11, 2 a12, a22), plus every hinge's
    ``hinge_force`` (H, 12) over its four vertices."""
    result = np.zeros((vertices, 3))
    for f in range(triangles.shape[0]):
        s00, s01, s11 = stress[f, 0], 0.5 * stress[f, 1], stress[f, 2]
        for a in range(3):
            left0 = shape[f, a, 0] * s00 + shape[f, a, 1] * s01
            left1 = shape[f, a, 0] * s01 + shape[f, a, 1] * s11
            v = triangles[f, a]
            for c in range(3):
                result[v, c] += 2 * (left0 * jac[f, c, 0] + left1 * jac[f, c, 1])
    for h in range(hinges.shape[0]):
        for k in range(4):
            for c in range(3):
                result[hinges[h, k], c] += hinge_force[h, 3 * k + c]
    return result
