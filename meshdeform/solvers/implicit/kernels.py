"""Numba kernels of the `implicit` solver (projective dynamics): local step and right-hand side, scatter."""

from __future__ import annotations

import numba as nb
import numpy as np

from meshdeform.solvers.jit import FAST, JIT


@nb.njit(inline="always", **JIT)
def spring_constant(stretch, stiff_t, stiff_c, modulus):  # pragma: no cover - compiled
    """k (N/m) of a spring stretched by `stretch` = l - L (m): its tension stiffness while longer
    than rest, its compression stiffness while shorter, times the material's modulus (never < 0)."""
    return max(stiff_t if stretch > 0.0 else stiff_c, 0.0) * modulus


@nb.njit(**FAST)
def pd_rhs(x, a, b, rest, weight, stiff_t, stiff_c, modulus, free, inertia, y, out):  # pragma: no cover - compiled
    """Local step + right-hand side of projective dynamics (Liu et al. 2013) for free vertices.

    For each spring the projection d (length l_d along the current direction) of x_a - x_b;
    out = inertia * y + sum_s weight_s (e_a - e_b) d_s, with pinned ends moved to the right.
    l_d = l - ratio (l - L): ratio k / weight, with k = max(stiffness, 0) * modulus under
    tension or compression (the model's per-spring arrays, not copied), makes a spring of
    stiffness k inside a system matrix built with one weight per spring.
    """
    nf = out.shape[0]
    vid = np.empty(nf, dtype=np.int64)
    for i in range(free.shape[0]):
        fi = free[i]
        if fi >= 0:
            vid[fi] = i
    for fi in range(nf):
        i = vid[fi]
        m = inertia[fi]
        out[fi, 0] = m * y[i, 0]
        out[fi, 1] = m * y[i, 1]
        out[fi, 2] = m * y[i, 2]
    for s in range(a.shape[0]):
        ia = a[s]
        ib = b[s]
        fa = free[ia]
        fb = free[ib]
        if fa < 0 and fb < 0:
            continue
        dx = x[ia, 0] - x[ib, 0]
        dy = x[ia, 1] - x[ib, 1]
        dz = x[ia, 2] - x[ib, 2]
        length = np.sqrt(dx * dx + dy * dy + dz * dz)
        w = weight[s]
        if length < 1e-12:
            tx = 0.0
            ty = 0.0
            tz = 0.0
        else:
            c = length - rest[s]
            r = spring_constant(c, stiff_t[s], stiff_c[s], modulus) / w
            scale = (length - r * c) / length
            tx = dx * scale
            ty = dy * scale
            tz = dz * scale
        if fa >= 0:
            out[fa, 0] += w * tx
            out[fa, 1] += w * ty
            out[fa, 2] += w * tz
            if fb < 0:
                out[fa, 0] += w * x[ib, 0]
                out[fa, 1] += w * x[ib, 1]
                out[fa, 2] += w * x[ib, 2]
        if fb >= 0:
            out[fb, 0] -= w * tx
            out[fb, 1] -= w * ty
            out[fb, 2] -= w * tz
            if fa < 0:
                out[fb, 0] += w * x[ia, 0]
                out[fb, 1] += w * x[ia, 1]
                out[fb, 2] += w * x[ia, 2]


@nb.njit(**JIT)
def scatter_free(x, free_vertices, solution):  # pragma: no cover - compiled
    """x[free_vertices] = solution."""
    for j in range(free_vertices.shape[0]):
        i = free_vertices[j]
        x[i, 0] = solution[j, 0]
        x[i, 1] = solution[j, 1]
        x[i, 2] = solution[j, 2]


@nb.njit(**FAST)
def step_energy(  # pragma: no cover - compiled
    x, a, b, rest, stiff_t, stiff_c, modulus, free, free_vertices, inertia, y, grad
):
    """The energy (J) the implicit step minimises at positions x (V, 3), and its gradient.

    E(x) = sum_free inertia_i / 2 |x_i - y_i|^2 + sum_s k_s / 2 (|x_a - x_b| - L_s)^2 with
    k_s = max(stiffness, 0) * modulus under tension or compression (the sign of l - L), so the
    energy is continuous where a spring passes its rest length. grad (F, 3) receives dE/dx of
    the free vertices (F = free_vertices.shape[0], `free` maps a vertex to its row, -1 pinned);
    pinned vertices enter at their current positions. Serial and in a fixed order: the same
    bytes on any thread count (the line search compares energies).
    """
    energy = 0.0
    for j in range(free_vertices.shape[0]):
        i = free_vertices[j]
        m = inertia[j]
        dx = x[i, 0] - y[i, 0]
        dy = x[i, 1] - y[i, 1]
        dz = x[i, 2] - y[i, 2]
        energy += 0.5 * m * (dx * dx + dy * dy + dz * dz)
        grad[j, 0] = m * dx
        grad[j, 1] = m * dy
        grad[j, 2] = m * dz
    for s in range(a.shape[0]):
        ia = a[s]
        ib = b[s]
        fa = free[ia]
        fb = free[ib]
        if fa < 0 and fb < 0:
            continue
        dx = x[ia, 0] - x[ib, 0]
        dy = x[ia, 1] - x[ib, 1]
        dz = x[ia, 2] - x[ib, 2]
        length = np.sqrt(dx * dx + dy * dy + dz * dz)
        c = length - rest[s]
        k = spring_constant(c, stiff_t[s], stiff_c[s], modulus)
        energy += 0.5 * k * c * c
        if length < 1e-12:
            continue
        f = k * c / length
        if fa >= 0:
            grad[fa, 0] += f * dx
            grad[fa, 1] += f * dy
            grad[fa, 2] += f * dz
        if fb >= 0:
            grad[fb, 0] -= f * dx
            grad[fb, 1] -= f * dy
            grad[fb, 2] -= f * dz
    return energy


@nb.njit(**JIT)
def dot(u, v):  # pragma: no cover - compiled
    """sum(u * v) of two (F, 3) arrays, serial in a fixed order (BLAS may thread and reorder)."""
    total = 0.0
    for j in range(u.shape[0]):
        total += u[j, 0] * v[j, 0] + u[j, 1] * v[j, 1] + u[j, 2] * v[j, 2]
    return total


@nb.njit(**JIT)
def add_scaled(out, u, scale):  # pragma: no cover - compiled
    """out += scale * u, (F, 3) arrays."""
    for j in range(out.shape[0]):
        out[j, 0] += scale * u[j, 0]
        out[j, 1] += scale * u[j, 1]
        out[j, 2] += scale * u[j, 2]


@nb.njit(**JIT)
def place(x, free_vertices, base, direction, step):  # pragma: no cover - compiled
    """x[free_vertices] = base + step * direction (base, direction (F, 3))."""
    for j in range(free_vertices.shape[0]):
        i = free_vertices[j]
        x[i, 0] = base[j, 0] + step * direction[j, 0]
        x[i, 1] = base[j, 1] + step * direction[j, 1]
        x[i, 2] = base[j, 2] + step * direction[j, 2]


@nb.njit(**JIT)
def rows_changed(x, v, x_was, v_was):  # pragma: no cover - compiled
    """(V,) bool: the rows where positions x or velocities v (V, 3) differ from x_was, v_was."""
    out = np.zeros(x.shape[0], dtype=np.bool_)
    for i in range(x.shape[0]):
        for k in range(3):
            if x[i, k] != x_was[i, k] or v[i, k] != v_was[i, k]:
                out[i] = True
                break
    return out
