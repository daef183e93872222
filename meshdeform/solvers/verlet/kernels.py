"""Numba kernels of the `verlet` solver: the substep (one source, a serial and a parallel build)."""

from __future__ import annotations

import numba as nb
import numpy as np

from meshdeform.solvers.jit import SWEEP, serial_and_parallel
from meshdeform.solvers.sweep_kernels import (
    apply_tethers,
    load_vertices,
    predict_vertices,
    pull,
    release_tethers,
    span,
    store_vertices,
)

#: verlet spring: ends (kernel numbering), rest length, k w_a / w and k w_b / w under tension and compression
RELAX_SPRING = np.dtype(
    [("a", "u4"), ("b", "u4"), ("rest", "f8"), ("at", "f8"), ("bt", "f8"), ("ac", "f8"), ("bc", "f8")], align=True
)


@nb.njit(**SWEEP)
def _relax_spring(X, P, s):  # pragma: no cover - compiled
    """One Jakobsen relaxation (P[s]: see RELAX_SPRING)."""
    c = P[s]
    va = X[c.a]
    vb = X[c.b]
    at = c.at  # loaded before the test (see `_xpbd_spring`)
    bt = c.bt
    ac = c.ac
    bc = c.bc
    dx, dy, dz, length, inv_d2 = span(va, vb)
    rest = c.rest
    tension = length > rest
    ka = at if tension else ac
    kb = bt if tension else bc
    f = 1.0 - rest * length * inv_d2
    pull(va, vb, dx, dy, dz, f * ka, f * kb)


@nb.njit(**SWEEP)
def _relax_range(X, P, lo, hi, backward):  # pragma: no cover - compiled
    one = np.uint64(1)
    if backward:
        for j in range(hi - lo):
            _relax_spring(X, P, hi - one - j)
    else:
        for s in range(lo, hi):
            _relax_spring(X, P, s)


def verlet_substep(
    x, prev, v, inv_mass, accel, retention, dt, X, rank, order, P, offsets, parts, iterations, tethers,
    vchunks, tchunks, base, release_state, release, count,
):  # pragma: no cover - compiled
    """`count` Verlet substeps: predict, tethers, relaxation sweeps, tethers; then the State.

    Arguments, order of the work and the two builds (`verlet_substep`, `verlet_substep_parallel`)
    as for `xpbd.kernels.xpbd_substep` (tethers: the limits in force, base: the tethers' own
    records, release / release_state: `release_tethers` first, with the vertices the colliders
    moved after the last substep as its contacts).
    """
    dt2 = dt * dt
    for p in nb.prange(parts):
        load_vertices(X, x, prev, inv_mass, accel, rank, retention, dt2, vchunks[p], vchunks[p + 1])
    if release:
        release_tethers(X, base, tethers, *release_state)
    for p in nb.prange(parts):
        apply_tethers(X, tethers, tchunks[p], tchunks[p + 1])
    for step in range(count):
        for it in range(iterations):
            backward = (it % 2) == 1
            for p in nb.prange(parts):
                _relax_range(X, P, offsets[p], offsets[p + 1], backward)
            _relax_range(X, P, offsets[parts], offsets[parts + 1], backward)
        if step + 1 < count:
            for p in nb.prange(parts):
                apply_tethers(X, tethers, tchunks[p], tchunks[p + 1])
                predict_vertices(X, accel, order, retention, dt2, vchunks[p], vchunks[p + 1])
                apply_tethers(X, tethers, tchunks[p], tchunks[p + 1])
        else:
            for p in nb.prange(parts):
                apply_tethers(X, tethers, tchunks[p], tchunks[p + 1])
    inv_dt = 1.0 / dt
    for p in nb.prange(parts):
        store_vertices(X, x, prev, v, rank, inv_dt, vchunks[p], vchunks[p + 1])


verlet_substep, verlet_substep_parallel = serial_and_parallel(verlet_substep, **SWEEP)
