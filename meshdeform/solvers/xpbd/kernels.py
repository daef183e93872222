"""Numba kernels of the `xpbd` solver: the substep (one source, serial and parallel builds), the spring constants."""

from __future__ import annotations

import numba as nb
import numpy as np

from meshdeform.solvers.jit import JIT, SWEEP, serial_and_parallel
from meshdeform.solvers.sweep_kernels import (
    apply_tethers,
    hold_planes,
    load_vertices,
    predict_vertices,
    pull,
    release_tethers,
    span,
    store_vertices,
)

#: xpbd spring: ends (kernel numbering) and the index of its `XPBD_CONSTANTS` record (12 bytes,
#: one stream per sweep; the inverse masses come from the vertex records)
XPBD_SPRING = np.dtype([("a", "u4"), ("b", "u4"), ("k", "u4")], align=True)
#: the constants of one or more springs: rest length, compliance / dt^2 and 1 / denominator under
#: tension and compression, damping factor gamma (48 bytes). Springs with bit for bit the same six
#: values share one record (`xpbd_constants`): on a cloth of uniform material and vertex masses a
#: few dozen records serve every spring and stay in the L1 cache, so a sweep streams 12 bytes per
#: spring, not 56 (docs/performance.md); with all-different values it is one record per spring.
XPBD_CONSTANTS = np.dtype(
    [("rest", "f8"), ("at", "f8"), ("ac", "f8"), ("it", "f8"), ("ic", "f8"), ("g", "f8")], align=True
)
#: float64 words of an `XPBD_CONSTANTS` record (compared bit for bit by `xpbd_constants`)
_WORDS = 6


@nb.njit(**SWEEP)
def _xpbd_spring(X, P, T, lam, s, damped, first, keep):  # pragma: no cover - compiled
    """One XPBD distance constraint (P[s], its constants T[P[s].k]: see XPBD_SPRING).

    dlam = (-C - a~ lam - gamma n . (dx - dx_prev)) / ((1 + gamma) w + a~), written as
    (L - l - gamma (l - d . dp / l) - a~ lam) / den with d = x_b - x_a, dp = prev_b - prev_a.
    first: lam starts at zero (not read); keep: the new lam is stored (not after the last sweep).
    """
    e = P[s]
    va = X[e.a]
    vb = X[e.b]
    c = T[e.k]
    # both constants of each pair are loaded before the test: a select, not a load that waits for it
    at = c.at
    ac = c.ac
    it = c.it
    ic = c.ic
    dx, dy, dz, length, inv_d2 = span(va, vb)
    inv_l = length * inv_d2
    rest = c.rest
    tension = length > rest
    alpha = at if tension else ac
    inv_den = it if tension else ic
    lam_s = 0.0 if first else lam[s]
    num = rest - length - alpha * lam_s
    if damped:
        px = vb.px - va.px
        py = vb.py - va.py
        pz = vb.pz - va.pz
        num -= c.g * (length - (dx * px + dy * py + dz * pz) * inv_l)
    dlam = num * inv_den
    if keep:
        lam[s] = lam_s + dlam
    q = -dlam * inv_l
    pull(va, vb, dx, dy, dz, q * va.w, q * vb.w)


@nb.njit(**SWEEP)
def _xpbd_forward(X, P, T, lam, lo, hi, damped, first, keep):  # pragma: no cover - compiled
    """Springs lo..hi-1 forward; every flag a constant in each loop (see `_xpbd_range`)."""
    if damped:
        if first:
            if keep:
                for s in range(lo, hi):
                    _xpbd_spring(X, P, T, lam, s, True, True, True)
            else:
                for s in range(lo, hi):
                    _xpbd_spring(X, P, T, lam, s, True, True, False)
        elif keep:
            for s in range(lo, hi):
                _xpbd_spring(X, P, T, lam, s, True, False, True)
        else:
            for s in range(lo, hi):
                _xpbd_spring(X, P, T, lam, s, True, False, False)
    elif first:
        if keep:
            for s in range(lo, hi):
                _xpbd_spring(X, P, T, lam, s, False, True, True)
        else:
            for s in range(lo, hi):
                _xpbd_spring(X, P, T, lam, s, False, True, False)
    elif keep:
        for s in range(lo, hi):
            _xpbd_spring(X, P, T, lam, s, False, False, True)
    else:
        for s in range(lo, hi):
            _xpbd_spring(X, P, T, lam, s, False, False, False)


@nb.njit(**SWEEP)
def _xpbd_backward(X, P, T, lam, lo, hi, damped, keep):  # pragma: no cover - compiled
    """Springs hi-1 down to lo (unsigned offsets: no wraparound code); never a first sweep."""
    one = np.uint64(1)
    if damped:
        if keep:
            for j in range(hi - lo):
                _xpbd_spring(X, P, T, lam, hi - one - j, True, False, True)
        else:
            for j in range(hi - lo):
                _xpbd_spring(X, P, T, lam, hi - one - j, True, False, False)
    elif keep:
        for j in range(hi - lo):
            _xpbd_spring(X, P, T, lam, hi - one - j, False, False, True)
    else:
        for j in range(hi - lo):
            _xpbd_spring(X, P, T, lam, hi - one - j, False, False, False)


@nb.njit(**SWEEP)
def _xpbd_range(X, P, T, lam, lo, hi, backward, damped, first, last):  # pragma: no cover - compiled
    """Springs lo..hi-1, forward or backward.

    first: the substep's first sweep (forward), whose multipliers start at zero: written, not read.
    last: its last sweep, whose multipliers nothing reads (the next substep starts from zero, unless
    warm started): read, not written, which spares the sweep the write-back of the multiplier array.
    """
    if backward:
        _xpbd_backward(X, P, T, lam, lo, hi, damped, not last)
    else:
        _xpbd_forward(X, P, T, lam, lo, hi, damped, first, not last)


@nb.njit(inline="always", **SWEEP)
def _warm_range(X, P, lam, lo, hi, warm):  # pragma: no cover - compiled
    """Springs lo..hi-1: the multipliers left from the last substep, times `warm`, applied to the
    positions (the iteration's starting guess), and kept as the multipliers the sweeps start from."""
    for s in range(lo, hi):
        c = P[s]
        va = X[c.a]
        vb = X[c.b]
        lam_s = lam[s] * warm
        lam[s] = lam_s
        dx, dy, dz, length, inv_d2 = span(va, vb)
        q = -lam_s * length * inv_d2
        pull(va, vb, dx, dy, dz, q * va.w, q * vb.w)


def xpbd_substep(
    x, prev, v, inv_mass, accel, retention, dt, X, rank, order, P, T, lam, offsets, parts, iterations, damped,
    tethers, vchunks, tchunks, warm, planes, base, release_state, release, count,
):  # pragma: no cover - compiled
    """`count` XPBD substeps: predict, tethers, `iterations` sweeps, tethers; then positions,
    previous positions and velocities back to the State.

    The vertices stay in the scratch from one substep to the next (`predict_vertices`), so a frame with
    nothing between its substeps is one call. Sweeps alternate direction, the first forward (from
    the pins outward); the slabs, then the separator. rank / order: model vertex -> kernel vertex
    and back; P, T: the springs and their constants (`XPBD_SPRING`, `XPBD_CONSTANTS`); offsets:
    (parts + 2,) uint64 (see `SpringLayout`); vchunks, tchunks: the vertex
    chunks and their tethers (`layout.KernelChunks`), one per slab. planes: the contact planes
    (`sweep_kernels.PLANE`, held after the sweeps: `hold_planes`). tethers: the limits in force,
    base: the tethers' own records; release: whether to compute the limits in force first
    (`release_tethers`, with release_state = (offsets, links, gaps, contact, limits and scaled
    limits scratch, released count), as `SweepSolver._release` gives them).

    Every `prange` loop runs over slabs or chunks that share no vertex: the serial build
    (`xpbd_substep`) runs them in order, the parallel one (`xpbd_substep_parallel`) one thread
    each, and every vertex sees the same operations in the same order in both.
    """
    dt2 = dt * dt
    last = iterations - 1
    for p in nb.prange(parts):
        load_vertices(X, x, prev, inv_mass, accel, rank, retention, dt2, vchunks[p], vchunks[p + 1])
    if release:
        release_tethers(X, base, tethers, *release_state)
    for p in nb.prange(parts):
        apply_tethers(X, tethers, tchunks[p], tchunks[p + 1])
    cold = warm == 0.0
    for step in range(count):
        if not cold:
            for p in nb.prange(parts):
                _warm_range(X, P, lam, offsets[p], offsets[p + 1], warm)
            _warm_range(X, P, lam, offsets[parts], offsets[parts + 1], warm)
        for it in range(iterations):
            backward = (it % 2) == 1
            first = cold and it == 0
            for p in nb.prange(parts):
                _xpbd_range(X, P, T, lam, offsets[p], offsets[p + 1], backward, damped, first, cold and it == last)
            _xpbd_range(X, P, T, lam, offsets[parts], offsets[parts + 1], backward, damped, first, cold and it == last)
        hold_planes(X, planes)
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


xpbd_substep, xpbd_substep_parallel = serial_and_parallel(xpbd_substep, **SWEEP)


@nb.njit(**JIT)
def _mix(bits, base):  # pragma: no cover - compiled
    """A 64-bit hash of the `_WORDS` words bits[base:base + _WORDS]."""
    h = np.uint64(0x9E3779B97F4A7C15)
    for j in range(_WORDS):
        h = (h ^ bits[base + j]) * np.uint64(0xBF58476D1CE4E5B9)
        h ^= h >> np.uint64(29)
    return h


@nb.njit(**JIT)
def xpbd_constants(
    order, springs, rest_lengths, stiffness, compression, damping, inv_mass, modulus, dt, P, T, bits
):  # pragma: no cover - compiled
    """Fill the constants index P[k].k of `XPBD_SPRING` records P (layout order: P[k] is model
    spring order[k]) and the `XPBD_CONSTANTS` records T they index, for step dt, in one pass.
    Returns (damped: any spring damped, the records used: T[:count]).

    T: (S,) records, bits: T viewed as (6 S,) uint64. A spring whose six values are bit for bit
    those of an earlier spring's record shares it (open addressing on a hash of the bits), so
    records are numbered in order of first use: the same model and dt give the same arrays.
    Serial: it runs in every job, also where two jobs share a process (Dask threads), which the
    parallel runtime does not allow.

    k = max(stiffness, 0) modulus under tension (compression alike), c = 2 z sqrt(k m_reduced),
    alpha~ = 1 / (k dt^2), gamma = c / (k dt), 1 / ((1 + gamma) (w_a + w_b) + alpha~); 0 where
    k = 0 (no constraint that way). The same operations in the same order as the NumPy
    expressions they replace (no fast-math), so the records are bit for bit those values.
    """
    inv_dt2 = 1.0 / (dt * dt)
    damped = False
    size = 1
    while size < 2 * order.shape[0]:
        size *= 2
    mask = np.uint64(size - 1)
    slots = np.full(size, -1, dtype=np.int64)
    count = 0
    for k in range(order.shape[0]):
        s = order[k]
        w = inv_mass[springs[s, 0]] + inv_mass[springs[s, 1]]
        reduced = 1.0 / w if w > 0.0 else 0.0
        kt = max(stiffness[s], 0.0) * modulus
        kc = max(compression[s], 0.0) * modulus
        c = 2.0 * max(damping[s], 0.0) * np.sqrt(kt * reduced)
        r = T[count]  # a candidate: kept when no earlier record holds the same bits
        r.rest = rest_lengths[s]
        at = inv_dt2 / kt if kt > 0.0 else 0.0
        ac = inv_dt2 / kc if kc > 0.0 else 0.0
        g = c / (kt * dt) if kt > 0.0 else 0.0
        base = (1.0 + g) * w
        den = base + at
        r.at = at
        r.ac = ac
        r.g = g
        r.it = 1.0 / den if kt > 0.0 and den > 0.0 else 0.0
        den = base + ac
        r.ic = 1.0 / den if kc > 0.0 and den > 0.0 else 0.0
        if g > 0.0:
            damped = True
        new = count * _WORDS
        h = _mix(bits, new) & mask
        while True:
            held = slots[h]
            if held < 0:
                slots[h] = count
                P[k].k = count
                count += 1
                break
            old = held * _WORDS
            same = True
            for j in range(_WORDS):
                if bits[old + j] != bits[new + j]:
                    same = False
                    break
            if same:
                P[k].k = held
                break
            h = (h + np.uint64(1)) & mask
    return damped, count
