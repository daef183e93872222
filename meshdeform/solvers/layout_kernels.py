"""Numba kernels of the spring layout (`meshdeform.solvers.layout`): levels, first touch, inherited order."""

from __future__ import annotations

import numba as nb
import numpy as np

from meshdeform.solvers.jit import JIT


@nb.njit(**JIT)
def sweep_levels(a, b, n, block):  # pragma: no cover - compiled
    """Level of each spring in list order: 1 + the highest level of earlier springs sharing an
    end, and above every level of the earlier blocks of `block` consecutive springs (0: no blocks)."""
    last = np.zeros(n, dtype=np.int64)
    level = np.empty(a.shape[0], dtype=np.int64)
    base = 0
    top = 0
    for s in range(a.shape[0]):
        if block > 0 and s % block == 0:
            base = top
        ia = a[s]
        ib = b[s]
        lv = max(last[ia], last[ib], base) + 1
        level[s] = lv
        last[ia] = lv
        last[ib] = lv
        top = max(top, lv)
    return level


@nb.njit(**JIT)
def first_touch(a, b, n):  # pragma: no cover - compiled
    """Vertices 0..n-1 in the order springs (a, b) first reach them, untouched ones after (ascending)."""
    seen = np.zeros(n, dtype=np.bool_)
    order = np.empty(n, dtype=np.int64)
    k = 0
    for s in range(a.shape[0]):
        for v in (a[s], b[s]):
            if not seen[v]:
                seen[v] = True
                order[k] = v
                k += 1
    for v in range(n):
        if not seen[v]:
            order[k] = v
            k += 1
    return order


@nb.njit(**JIT)
def inherit_order(previous_order, previous_a, previous_b, parent, springs, index_map):  # pragma: no cover - compiled
    """Springs of a torn model in their parents' places of the previous layout order.

    Returns (order, key): order (S',) new springs sorted stably by key, key (S',) the place of
    each new spring's parent in previous_order. Both empty when a spring does not join its
    parent's two vertices or their copies (index_map: new vertex -> previous vertex), which
    `layout.inherited_layout` needs. A counting sort: O(S + S').
    """
    m = previous_order.shape[0]
    count = parent.shape[0]
    position = np.empty(m, dtype=np.int64)
    for k in range(m):
        position[previous_order[k]] = k
    key = np.empty(count, dtype=np.int64)
    start = np.zeros(m + 1, dtype=np.int64)
    for j in range(count):
        p = parent[j]
        if p < 0 or p >= m:
            return np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int64)
        k = position[p]
        ia = index_map[springs[j, 0]]
        ib = index_map[springs[j, 1]]
        pa = previous_a[k]
        pb = previous_b[k]
        if not ((ia == pa and ib == pb) or (ia == pb and ib == pa)):
            return np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int64)
        key[j] = k
        start[k + 1] += 1
    for k in range(m):
        start[k + 1] += start[k]
    order = np.empty(count, dtype=np.int64)
    for j in range(count):
        k = key[j]
        order[start[k]] = j
        start[k] += 1
    return order, key
