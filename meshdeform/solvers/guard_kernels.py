"""Numba kernels of the divergence guard and the frame figures of `meshdeform.simulate`."""

from __future__ import annotations

import numba as nb
import numpy as np

from meshdeform.solvers.jit import FAST, JIT


@nb.njit(**FAST)
def max_ratio(x, a, b, rest):  # pragma: no cover - compiled
    """Largest length / rest over the given springs (1.0 when there are none)."""
    m = 1.0
    for s in range(a.shape[0]):
        ia = a[s]
        ib = b[s]
        dx = x[ib, 0] - x[ia, 0]
        dy = x[ib, 1] - x[ia, 1]
        dz = x[ib, 2] - x[ia, 2]
        r = np.sqrt(dx * dx + dy * dy + dz * dz) / rest[s]
        if r > m:
            m = r
    return m


@nb.njit(**JIT)
def guard_figures(x, v, center):  # pragma: no cover - compiled
    """(finite, largest |x - center| component, largest speed) in one pass."""
    reach = 0.0
    speed2 = 0.0
    finite = True
    for i in range(x.shape[0]):
        s = 0.0
        for k in range(3):
            xi = x[i, k]
            if not np.isfinite(xi):
                finite = False
            d = abs(xi - center[k])
            if d > reach:
                reach = d
            s += v[i, k] * v[i, k]
        if not np.isfinite(s):
            finite = False
        elif s > speed2:
            speed2 = s
    return finite, reach, np.sqrt(speed2)


@nb.njit(**JIT)
def force_residual(  # pragma: no cover - compiled
    x, a, b, rest, kt, kc, mass, inv_mass, accel, cell, f, load, mag, magnitudes
):
    """The free vertices' force imbalance at positions x (W, 3), in cells: (|R|^2, |L|^2, |M|^2).

    Per free vertex (inv_mass > 0) r_i = the sum of its springs' Hooke forces (k = kt under
    tension, kc under compression, N/m; a, b, rest: (S,) ends and rest lengths) plus m_i accel_i
    (N). The r_i and the loads m_i accel_i are summed over the vertices of each cell (cell: (W,)
    int64 in 0..cells-1), so that forces between vertices of one cell cancel: what is left is the
    imbalance on the scale of the cells (the cloth's shape), not the jitter of single springs
    (which the stiff springs of a fine mesh make large against a vertex's small weight); a caller
    may therefore leave out the springs whose forces cancel so (`simulate._Balance`). Returns
    the squared Euclidean norms over every cell's three components of R (the cells' sums) and of
    L (their loads), and where `magnitudes` that of M, the cells' sums of spring force magnitudes
    (else 0). f, load (C, 3) and mag (C,): the caller's zeroed arrays, one row per cell (C
    cells) (an array made in a kernel costs a process with an empty compile cache the compiling
    of its allocator).
    """
    cells = mag.shape[0]
    for s in range(a.shape[0]):
        ia = a[s]
        ib = b[s]
        dx = x[ib, 0] - x[ia, 0]
        dy = x[ib, 1] - x[ia, 1]
        dz = x[ib, 2] - x[ia, 2]
        length = np.sqrt(dx * dx + dy * dy + dz * dz)
        if length < 1e-300:
            continue
        c = length - rest[s]
        t = (kt[s] if c > 0.0 else kc[s]) * c / length
        m = abs(t) * length if magnitudes else 0.0
        if inv_mass[ia] != 0.0:
            ca = cell[ia]
            f[ca, 0] += t * dx
            f[ca, 1] += t * dy
            f[ca, 2] += t * dz
            mag[ca] += m
        if inv_mass[ib] != 0.0:
            cb = cell[ib]
            f[cb, 0] -= t * dx
            f[cb, 1] -= t * dy
            f[cb, 2] -= t * dz
            mag[cb] += m
    for i in range(x.shape[0]):
        if inv_mass[i] != 0.0:
            ci = cell[i]
            for k in range(3):
                load[ci, k] += mass[i] * accel[i, k]
    r2 = 0.0
    load2 = 0.0
    mag2 = 0.0
    for c in range(cells):
        for k in range(3):
            r = f[c, k] + load[c, k]
            r2 += r * r
            load2 += load[c, k] * load[c, k]
        mag2 += mag[c] * mag[c]
    return r2, load2, mag2
