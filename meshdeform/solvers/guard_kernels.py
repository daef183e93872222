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
