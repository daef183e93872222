"""Numba kernels of the `implicit` solver (projective dynamics): local step and right-hand side, scatter."""

from __future__ import annotations

import numba as nb
import numpy as np

from meshdeform.solvers.jit import FAST, JIT


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
            r = max(stiff_t[s] if c > 0.0 else stiff_c[s], 0.0) * modulus / w
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
