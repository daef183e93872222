"""Numba kernels shared by the solvers, on the general spring list (no grid assumption).

All take spring data in a `SpringLayout` order: slabs 0..P-1 are swept in parallel (`prange`
over slabs, they share no vertex), the separator after them. Positions and velocities are the
State's (W, 3) float64 arrays, updated in place. Compiled with `cache=True` and
`error_model="numpy"` (no divide-by-zero checks in the loops).
"""

from __future__ import annotations

import numba as nb
import numpy as np

_JIT = {"cache": True, "error_model": "numpy", "nogil": True}
_FAST = {**_JIT, "fastmath": True}


# --------------------------------------------------------------------------- layout


@nb.njit(**_JIT)
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


@nb.njit(**_JIT)
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


@nb.njit(**_JIT)
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


# --------------------------------------------------------------------------- position-based substeps
#
# verlet and xpbd run a whole substep in one compiled call on a scratch copy of the vertices in
# the layout's kernel numbering, one 64-byte record (a cache line) per vertex: position,
# inverse mass and previous position, so the two positions a spring reads arrive together.
# Per spring one record of precomputed constants (see the solvers), so a projection does one
# square root and one division and no gather of masses. Record fields compile to constant
# offsets and unsigned indices need no negative-index wraparound, which keeps the loop short.
# Only free vertices are written back: pinned positions stay bit-identical.
# Sweep kernels use fast-math flags without reassociation, so the serial and the parallel
# build compute every spring bit for bit alike.

_SWEEP = {**_JIT, "fastmath": {"nnan", "ninf", "nsz", "arcp", "contract", "afn"}}

#: squared distance ratio past which a tether no longer pulls a vertex back (see `_tethers`)
_RUNAWAY2 = 1e30
#: squared length below which a spring's direction is taken as undefined (no division by zero)
_TINY2 = 1e-24

#: scratch vertex: position, inverse mass, previous position (64 bytes)
VERTEX = np.dtype(
    [("x", "f8"), ("y", "f8"), ("z", "f8"), ("w", "f8"), ("px", "f8"), ("py", "f8"), ("pz", "f8"), ("pad", "f8")],
    align=True,
)
#: verlet scratch vertex: position and inverse mass (32 bytes; the relaxation needs no previous
#: position, and the write-back takes it from the State's positions before overwriting them)
POINT = np.dtype([("x", "f8"), ("y", "f8"), ("z", "f8"), ("w", "f8")], align=True)
#: spring ends in kernel vertex numbering
ENDS = np.dtype([("a", "u4"), ("b", "u4")], align=True)
#: xpbd spring: ends (kernel numbering), rest length, compliance / dt^2 and 1 / denominator
#: under tension and compression, damping factor gamma (56 bytes, one stream per sweep; the
#: inverse masses come from the vertex records)
XPBD_SPRING = np.dtype(
    [("a", "u4"), ("b", "u4"), ("rest", "f8"), ("at", "f8"), ("ac", "f8"), ("it", "f8"), ("ic", "f8"), ("g", "f8")],
    align=True,
)
#: verlet spring: ends (kernel numbering), rest length, k w_a / w and k w_b / w under tension and compression
RELAX_SPRING = np.dtype(
    [("a", "u4"), ("b", "u4"), ("rest", "f8"), ("at", "f8"), ("bt", "f8"), ("ac", "f8"), ("bc", "f8")], align=True
)
#: tether: kernel vertex, kernel pin vertex, largest distance
TETHER = np.dtype([("v", "u4"), ("p", "u4"), ("lim", "f8")], align=True)


@nb.njit(inline="always", **_JIT)
def _verlet(x0, p0, a0, retention, dt2):  # pragma: no cover - compiled
    """One coordinate's Verlet prediction x + (x - prev) retention + a dt^2 (every substep kernel's)."""
    return x0 + (x0 - p0) * retention + a0 * dt2


@nb.njit(inline="always", **_JIT)
def _load(X, x, prev, inv_mass, accel, rank, retention, dt2, lo, hi):  # pragma: no cover - compiled
    """Scratch copy with the Verlet prediction x' = x + (x - prev) retention + a dt^2 of free vertices.

    Model vertices lo..hi-1. Walks the State's arrays in order (rank: model vertex -> scratch
    record), so only the scratch is written out of order, one cache line per vertex.
    """
    for i in range(lo, hi):
        r = X[rank[i]]
        w = inv_mass[i]
        x0 = x[i, 0]
        x1 = x[i, 1]
        x2 = x[i, 2]
        r.w = w
        r.pad = 0.0
        if w == 0.0:
            r.x = x0
            r.y = x1
            r.z = x2
            r.px = prev[i, 0]
            r.py = prev[i, 1]
            r.pz = prev[i, 2]
        else:
            r.x = _verlet(x0, prev[i, 0], accel[i, 0], retention, dt2)
            r.y = _verlet(x1, prev[i, 1], accel[i, 1], retention, dt2)
            r.z = _verlet(x2, prev[i, 2], accel[i, 2], retention, dt2)
            r.px = x0
            r.py = x1
            r.pz = x2


@nb.njit(inline="always", **_JIT)
def _load_points(X, XP, x, prev, inv_mass, accel, rank, retention, dt2, lo, hi, keep):  # pragma: no cover - compiled
    """`_load` for `POINT` records: predicted positions of free vertices, pinned ones as they are.

    keep: also keep each free vertex's position before the prediction in XP (kernel numbering),
    for a call that runs more than one substep (`_predict_points`, `_store_points`).
    """
    for i in range(lo, hi):
        k = rank[i]
        r = X[k]
        w = inv_mass[i]
        x0 = x[i, 0]
        x1 = x[i, 1]
        x2 = x[i, 2]
        r.w = w
        if w == 0.0:
            r.x = x0
            r.y = x1
            r.z = x2
        else:
            r.x = _verlet(x0, prev[i, 0], accel[i, 0], retention, dt2)
            r.y = _verlet(x1, prev[i, 1], accel[i, 1], retention, dt2)
            r.z = _verlet(x2, prev[i, 2], accel[i, 2], retention, dt2)
            if keep:
                XP[k, 0] = x0
                XP[k, 1] = x1
                XP[k, 2] = x2


@nb.njit(inline="always", **_JIT)
def _predict(X, accel, order, retention, dt2, lo, hi):  # pragma: no cover - compiled
    """The next substep's prediction inside `VERTEX` records, kernel vertices lo..hi-1 (a call
    running several substeps): x' = x + (x - px) retention + a dt^2, px = x, as in `_load`.
    order: kernel vertex -> model vertex (for its acceleration)."""
    for k in range(lo, hi):
        r = X[k]
        if r.w != 0.0:
            i = order[k]
            x0 = r.x
            x1 = r.y
            x2 = r.z
            r.x = _verlet(x0, r.px, accel[i, 0], retention, dt2)
            r.y = _verlet(x1, r.py, accel[i, 1], retention, dt2)
            r.z = _verlet(x2, r.pz, accel[i, 2], retention, dt2)
            r.px = x0
            r.py = x1
            r.pz = x2


@nb.njit(inline="always", **_JIT)
def _predict_points(X, XP, accel, order, retention, dt2, lo, hi):  # pragma: no cover - compiled
    """`_predict` for `POINT` records, the previous positions in XP (kernel numbering)."""
    for k in range(lo, hi):
        r = X[k]
        if r.w != 0.0:
            i = order[k]
            x0 = r.x
            x1 = r.y
            x2 = r.z
            r.x = _verlet(x0, XP[k, 0], accel[i, 0], retention, dt2)
            r.y = _verlet(x1, XP[k, 1], accel[i, 1], retention, dt2)
            r.z = _verlet(x2, XP[k, 2], accel[i, 2], retention, dt2)
            XP[k, 0] = x0
            XP[k, 1] = x1
            XP[k, 2] = x2


@nb.njit(inline="always", **_JIT)
def _put(x, prev, v, i, x0, x1, x2, p0, p1, p2, inv_dt):  # pragma: no cover - compiled
    """x[i] = (x0, x1, x2), prev[i] = (p0, p1, p2), v[i] = (x - prev) / dt."""
    x[i, 0] = x0
    x[i, 1] = x1
    x[i, 2] = x2
    prev[i, 0] = p0
    prev[i, 1] = p1
    prev[i, 2] = p2
    v[i, 0] = (x0 - p0) * inv_dt
    v[i, 1] = (x1 - p1) * inv_dt
    v[i, 2] = (x2 - p2) * inv_dt


@nb.njit(inline="always", **_JIT)
def _put_pinned(x, prev, v, i, inv_dt):  # pragma: no cover - compiled
    """A pinned vertex keeps x and prev bit for bit; v = (x - prev) / dt."""
    v[i, 0] = (x[i, 0] - prev[i, 0]) * inv_dt
    v[i, 1] = (x[i, 1] - prev[i, 1]) * inv_dt
    v[i, 2] = (x[i, 2] - prev[i, 2]) * inv_dt


@nb.njit(inline="always", **_JIT)
def _store(X, x, prev, v, rank, inv_dt, lo, hi):  # pragma: no cover - compiled
    """Model vertices lo..hi-1 back from `VERTEX` records: x = the record, prev = its position
    before the last substep (px), v = (x - prev) / dt; pinned ones keep x and prev."""
    for i in range(lo, hi):
        r = X[rank[i]]
        if r.w != 0.0:
            _put(x, prev, v, i, r.x, r.y, r.z, r.px, r.py, r.pz, inv_dt)
        else:
            _put_pinned(x, prev, v, i, inv_dt)


@nb.njit(inline="always", **_JIT)
def _store_points(X, XP, x, prev, v, rank, inv_dt, lo, hi, kept):  # pragma: no cover - compiled
    """`_store` for `POINT` records: prev from XP when `kept` (several substeps), else the State's
    positions before they are overwritten (one substep: they are the positions it started from)."""
    for i in range(lo, hi):
        k = rank[i]
        r = X[k]
        if r.w == 0.0:
            _put_pinned(x, prev, v, i, inv_dt)
        elif kept:
            _put(x, prev, v, i, r.x, r.y, r.z, XP[k, 0], XP[k, 1], XP[k, 2], inv_dt)
        else:
            _put(x, prev, v, i, r.x, r.y, r.z, x[i, 0], x[i, 1], x[i, 2], inv_dt)


@nb.njit(inline="always", **_SWEEP)
def _tethers(X, tethers, lo, hi):  # pragma: no cover - compiled
    """Pull vertices of tethers lo..hi-1 back to within their limit of their pin (pins do not move)."""
    for t in range(lo, hi):
        te = tethers[t]
        vi = X[te.v]
        pin = X[te.p]
        dx = vi.x - pin.x
        dy = vi.y - pin.y
        dz = vi.z - pin.z
        d2 = dx * dx + dy * dy + dz * dz
        lim2 = te.lim * te.lim
        # a vertex 1e15 times past its limit (or overflowed) has blown up: left where it is for
        # the divergence guard to report, not quietly pulled back onto its pin
        if lim2 < d2 < lim2 * _RUNAWAY2:
            s = te.lim / np.sqrt(d2)
            vi.x = pin.x + dx * s
            vi.y = pin.y + dy * s
            vi.z = pin.z + dz * s


@nb.njit(inline="always", **_SWEEP)
def _span(va, vb):  # pragma: no cover - compiled
    """d = x_b - x_a, |d| and 1 / |d|^2 (the division runs beside the square root, not after it:
    a shorter dependency chain per spring)."""
    dx = vb.x - va.x
    dy = vb.y - va.y
    dz = vb.z - va.z
    d2 = max(dx * dx + dy * dy + dz * dz, _TINY2)
    inv_d2 = 1.0 / d2
    return dx, dy, dz, np.sqrt(d2), inv_d2


@nb.njit(inline="always", **_SWEEP)
def _pull(va, vb, dx, dy, dz, fa, fb):  # pragma: no cover - compiled
    """x_a += d fa, x_b -= d fb."""
    va.x += dx * fa
    va.y += dy * fa
    va.z += dz * fa
    vb.x -= dx * fb
    vb.y -= dy * fb
    vb.z -= dz * fb


@nb.njit(inline="always", **_SWEEP)
def _xpbd_spring(X, P, lam, s, damped, first):  # pragma: no cover - compiled
    """One XPBD distance constraint (P[s]: see XPBD_SPRING).

    dlam = (-C - a~ lam - gamma n . (dx - dx_prev)) / ((1 + gamma) w + a~), written as
    (L - l - gamma (l - d . dp / l) - a~ lam) / den with d = x_b - x_a, dp = prev_b - prev_a.
    """
    c = P[s]
    va = X[c.a]
    vb = X[c.b]
    # both constants of each pair are loaded before the test: a select, not a load that waits for it
    at = c.at
    ac = c.ac
    it = c.it
    ic = c.ic
    dx, dy, dz, length, inv_d2 = _span(va, vb)
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
    lam[s] = lam_s + dlam
    q = -dlam * inv_l
    _pull(va, vb, dx, dy, dz, q * va.w, q * vb.w)


@nb.njit(inline="always", **_SWEEP)
def _xpbd_range(X, P, lam, lo, hi, backward, damped, first):  # pragma: no cover - compiled
    """Springs lo..hi-1 (unsigned offsets: no wraparound code), forward or backward.

    first: the substep's first sweep (forward), whose multipliers start at zero: written, not read.
    """
    one = np.uint64(1)
    if first:
        if damped:
            for s in range(lo, hi):
                _xpbd_spring(X, P, lam, s, True, True)
        else:
            for s in range(lo, hi):
                _xpbd_spring(X, P, lam, s, False, True)
    elif damped:
        if backward:
            for j in range(hi - lo):
                _xpbd_spring(X, P, lam, hi - one - j, True, False)
        else:
            for s in range(lo, hi):
                _xpbd_spring(X, P, lam, s, True, False)
    elif backward:
        for j in range(hi - lo):
            _xpbd_spring(X, P, lam, hi - one - j, False, False)
    else:
        for s in range(lo, hi):
            _xpbd_spring(X, P, lam, s, False, False)


@nb.njit(inline="always", **_SWEEP)
def _relax_spring(X, P, s):  # pragma: no cover - compiled
    """One Jakobsen relaxation (P[s]: see RELAX_SPRING)."""
    c = P[s]
    va = X[c.a]
    vb = X[c.b]
    at = c.at  # loaded before the test (see `_xpbd_spring`)
    bt = c.bt
    ac = c.ac
    bc = c.bc
    dx, dy, dz, length, inv_d2 = _span(va, vb)
    rest = c.rest
    tension = length > rest
    ka = at if tension else ac
    kb = bt if tension else bc
    f = 1.0 - rest * length * inv_d2
    _pull(va, vb, dx, dy, dz, f * ka, f * kb)


@nb.njit(inline="always", **_SWEEP)
def _relax_range(X, P, lo, hi, backward):  # pragma: no cover - compiled
    one = np.uint64(1)
    if backward:
        for j in range(hi - lo):
            _relax_spring(X, P, hi - one - j)
    else:
        for s in range(lo, hi):
            _relax_spring(X, P, s)


@nb.njit(**_SWEEP)
def xpbd_substep(
    x, prev, v, inv_mass, accel, retention, dt, X, rank, order, P, lam, offsets, parts, iterations, damped,
    tethers, vchunks, tchunks, count,
):  # pragma: no cover - compiled
    """`count` XPBD substeps on one thread: predict, tethers, `iterations` sweeps, tethers; then
    positions, previous positions and velocities back to the State.

    The vertices stay in the scratch from one substep to the next (`_predict`), so a frame with
    nothing between its substeps is one call. Sweeps alternate direction, the first forward (from
    the pins outward); slabs then the separator, in layout order. rank / order: model vertex ->
    kernel vertex and back; offsets: (parts + 2,) uint64 (see `SpringLayout`); vchunks, tchunks:
    the vertex and tether chunks of the parallel build (unused here).
    """
    n = np.uint64(rank.shape[0])
    nt = np.uint64(tethers.shape[0])
    zero = np.uint64(0)
    dt2 = dt * dt
    _load(X, x, prev, inv_mass, accel, rank, retention, dt2, zero, n)
    _tethers(X, tethers, zero, nt)
    for step in range(count):
        for it in range(iterations):
            backward = (it % 2) == 1
            for p in range(parts + 1):
                _xpbd_range(X, P, lam, offsets[p], offsets[p + 1], backward, damped, it == 0)
        _tethers(X, tethers, zero, nt)
        if step + 1 < count:
            _predict(X, accel, order, retention, dt2, zero, n)
            _tethers(X, tethers, zero, nt)
    _store(X, x, prev, v, rank, 1.0 / dt, zero, n)


@nb.njit(parallel=True, **_SWEEP)
def xpbd_substep_parallel(
    x, prev, v, inv_mass, accel, retention, dt, X, rank, order, P, lam, offsets, parts, iterations, damped,
    tethers, vchunks, tchunks, count,
):  # pragma: no cover - compiled
    """`xpbd_substep` with every phase split over `parts` threads (bit for bit the same result).

    Load and write-back run over vertex chunks (vchunks) of the State; between two substeps one
    pass per kernel vertex chunk applies the last substep's tethers, predicts and applies the
    next one's (tchunks: the tethers of each chunk); sweeps run over the slabs, the separator
    follows serially. Every vertex sees the same operations in the same order as in the serial
    build.
    """
    dt2 = dt * dt
    for p in nb.prange(parts):
        _load(X, x, prev, inv_mass, accel, rank, retention, dt2, vchunks[p], vchunks[p + 1])
    for p in nb.prange(parts):
        _tethers(X, tethers, tchunks[p], tchunks[p + 1])
    for step in range(count):
        for it in range(iterations):
            backward = (it % 2) == 1
            for p in nb.prange(parts):
                _xpbd_range(X, P, lam, offsets[p], offsets[p + 1], backward, damped, it == 0)
            _xpbd_range(X, P, lam, offsets[parts], offsets[parts + 1], backward, damped, it == 0)
        if step + 1 < count:
            for p in nb.prange(parts):
                _tethers(X, tethers, tchunks[p], tchunks[p + 1])
                _predict(X, accel, order, retention, dt2, vchunks[p], vchunks[p + 1])
                _tethers(X, tethers, tchunks[p], tchunks[p + 1])
        else:
            for p in nb.prange(parts):
                _tethers(X, tethers, tchunks[p], tchunks[p + 1])
    inv_dt = 1.0 / dt
    for p in nb.prange(parts):
        _store(X, x, prev, v, rank, inv_dt, vchunks[p], vchunks[p + 1])


@nb.njit(**_SWEEP)
def verlet_substep(
    x, prev, v, inv_mass, accel, retention, dt, X, XP, rank, order, P, offsets, parts, iterations, tethers,
    vchunks, tchunks, count,
):  # pragma: no cover - compiled
    """`count` Verlet substeps on one thread: predict, tethers, relaxation sweeps, tethers; then
    the State. XP: (W, 3) previous positions in kernel numbering, used when count > 1."""
    n = np.uint64(rank.shape[0])
    nt = np.uint64(tethers.shape[0])
    zero = np.uint64(0)
    dt2 = dt * dt
    keep = count > 1
    _load_points(X, XP, x, prev, inv_mass, accel, rank, retention, dt2, zero, n, keep)
    _tethers(X, tethers, zero, nt)
    for step in range(count):
        for it in range(iterations):
            backward = (it % 2) == 1
            for p in range(parts + 1):
                _relax_range(X, P, offsets[p], offsets[p + 1], backward)
        _tethers(X, tethers, zero, nt)
        if step + 1 < count:
            _predict_points(X, XP, accel, order, retention, dt2, zero, n)
            _tethers(X, tethers, zero, nt)
    _store_points(X, XP, x, prev, v, rank, 1.0 / dt, zero, n, keep)


@nb.njit(parallel=True, **_SWEEP)
def verlet_substep_parallel(
    x, prev, v, inv_mass, accel, retention, dt, X, XP, rank, order, P, offsets, parts, iterations, tethers,
    vchunks, tchunks, count,
):  # pragma: no cover - compiled
    """`verlet_substep` with every phase split over `parts` threads (see `xpbd_substep_parallel`)."""
    dt2 = dt * dt
    keep = count > 1
    for p in nb.prange(parts):
        _load_points(X, XP, x, prev, inv_mass, accel, rank, retention, dt2, vchunks[p], vchunks[p + 1], keep)
    for p in nb.prange(parts):
        _tethers(X, tethers, tchunks[p], tchunks[p + 1])
    for step in range(count):
        for it in range(iterations):
            backward = (it % 2) == 1
            for p in nb.prange(parts):
                _relax_range(X, P, offsets[p], offsets[p + 1], backward)
            _relax_range(X, P, offsets[parts], offsets[parts + 1], backward)
        if step + 1 < count:
            for p in nb.prange(parts):
                _tethers(X, tethers, tchunks[p], tchunks[p + 1])
                _predict_points(X, XP, accel, order, retention, dt2, vchunks[p], vchunks[p + 1])
                _tethers(X, tethers, tchunks[p], tchunks[p + 1])
        else:
            for p in nb.prange(parts):
                _tethers(X, tethers, tchunks[p], tchunks[p + 1])
    inv_dt = 1.0 / dt
    for p in nb.prange(parts):
        _store_points(X, XP, x, prev, v, rank, inv_dt, vchunks[p], vchunks[p + 1], keep)


# --------------------------------------------------------------------------- explicit springs


@nb.njit(inline="always", **_FAST)
def _force_range(x, v, a, b, rest, kt, kc, cd, f, lo, hi):  # pragma: no cover - compiled
    for s in range(lo, hi):
        ia = a[s]
        ib = b[s]
        dx = x[ib, 0] - x[ia, 0]
        dy = x[ib, 1] - x[ia, 1]
        dz = x[ib, 2] - x[ia, 2]
        length = np.sqrt(dx * dx + dy * dy + dz * dz)
        if length < 1e-12:
            continue
        inv_l = 1.0 / length
        nx = dx * inv_l
        ny = dy * inv_l
        nz = dz * inv_l
        c = length - rest[s]
        k = kt[s] if c > 0.0 else kc[s]
        rv = nx * (v[ib, 0] - v[ia, 0]) + ny * (v[ib, 1] - v[ia, 1]) + nz * (v[ib, 2] - v[ia, 2])
        t = k * c + cd[s] * rv
        f[ia, 0] += t * nx
        f[ia, 1] += t * ny
        f[ia, 2] += t * nz
        f[ib, 0] -= t * nx
        f[ib, 1] -= t * ny
        f[ib, 2] -= t * nz


@nb.njit(**_FAST)
def _limit_strain(x, v, la, lb, lrest, inv_mass, ratio, inv_dt, max_passes):  # pragma: no cover - compiled
    """Provot's deformation constraint: pull structural springs longer than ratio * rest back.

    Gauss-Seidel passes until none exceeds the ratio (or max_passes); the position changes
    are added to the velocities (divided by dt). Returns the passes used.
    """
    for p in range(max_passes):
        worst = 0.0
        for s in range(la.shape[0]):
            ia = la[s]
            ib = lb[s]
            wa = inv_mass[ia]
            wb = inv_mass[ib]
            w = wa + wb
            if w == 0.0:
                continue
            dx = x[ib, 0] - x[ia, 0]
            dy = x[ib, 1] - x[ia, 1]
            dz = x[ib, 2] - x[ia, 2]
            length = np.sqrt(dx * dx + dy * dy + dz * dz)
            limit = ratio * lrest[s]
            if length <= limit:
                continue
            over = (length - limit) / limit
            if over > worst:
                worst = over
            f = (length - limit) / (length * w)
            fa = f * wa
            fb = f * wb
            x[ia, 0] += dx * fa
            x[ia, 1] += dy * fa
            x[ia, 2] += dz * fa
            x[ib, 0] -= dx * fb
            x[ib, 1] -= dy * fb
            x[ib, 2] -= dz * fb
            v[ia, 0] += dx * fa * inv_dt
            v[ia, 1] += dy * fa * inv_dt
            v[ia, 2] += dz * fa * inv_dt
            v[ib, 0] -= dx * fb * inv_dt
            v[ib, 1] -= dy * fb * inv_dt
            v[ib, 2] -= dz * fb * inv_dt
        if worst <= 1e-9:
            return p
    return max_passes


@nb.njit(inline="always", **_FAST)
def _mass_mean(mass, values):  # pragma: no cover - compiled
    """Mass-weighted mean of the rows of values (W, 3), as three numbers."""
    total = 0.0
    mx = 0.0
    my = 0.0
    mz = 0.0
    for i in range(values.shape[0]):
        m = mass[i]
        mx += m * values[i, 0]
        my += m * values[i, 1]
        mz += m * values[i, 2]
        total += m
    return mx / total, my / total, mz / total


@nb.njit(**_FAST)
def explicit_advance(
    x, v, prev, inv_mass, mass, accel, retention, dt, steps,
    a, b, rest, kt, kc, cd, offsets, parts, f,
    anchor_k, anchors, anchor_follow, rest_center, anchor_keep,
    la, lb, lrest, ratio, max_passes,
):  # pragma: no cover - compiled
    """`steps` semi-implicit Euler steps of length dt: springs (Hooke + damping), anchors, air damping.

    Serial: the many short steps would pay a parallel launch each.

    anchor_k > 0 adds -anchor_k (x - anchor) per unit mass, anchor = anchors + (centre of mass
    - rest_center) when anchor_follow else anchors, and multiplies each velocity relative to
    the anchors' (the centre of mass's when anchor_follow, else zero) by anchor_keep per step.
    ratio > 0 applies the strain limit on the (la, lb, lrest) springs after each step. Pinned
    vertices (inv_mass 0) are not moved.
    """
    nv = x.shape[0]
    use_springs = a.shape[0] > 0
    inv_dt = 1.0 / dt
    for _ in range(steps):
        if use_springs:
            for i in range(nv):
                f[i, 0] = 0.0
                f[i, 1] = 0.0
                f[i, 2] = 0.0
            _force_range(x, v, a, b, rest, kt, kc, cd, f, offsets[0], offsets[parts + 1])
        ox = 0.0
        oy = 0.0
        oz = 0.0
        if anchor_k > 0.0 and anchor_follow:
            ox, oy, oz = _mass_mean(mass, x)
            ox -= rest_center[0]
            oy -= rest_center[1]
            oz -= rest_center[2]
        for i in range(nv):
            w = inv_mass[i]
            if w == 0.0:
                continue
            for k in range(3):
                acc = accel[i, k]
                if use_springs:
                    acc += f[i, k] * w
                if anchor_k > 0.0:
                    off = ox if k == 0 else (oy if k == 1 else oz)
                    acc -= anchor_k * (x[i, k] - anchors[i, k] - off)
                v[i, k] += acc * dt
        # the velocity relative to the anchors' (the centre of mass's after this step, which the
        # internal forces do not change; zero for world anchors) keeps anchor_keep of itself
        keep = anchor_keep if anchor_k > 0.0 else 1.0
        ux = 0.0
        uy = 0.0
        uz = 0.0
        if keep < 1.0 and anchor_follow:
            ux, uy, uz = _mass_mean(mass, v)
        for i in range(nv):
            if inv_mass[i] == 0.0:
                continue
            for k in range(3):
                frame_v = ux if k == 0 else (uy if k == 1 else uz)
                vi = (frame_v + (v[i, k] - frame_v) * keep) * retention
                v[i, k] = vi
                x[i, k] += vi * dt
        if ratio > 0.0:
            _limit_strain(x, v, la, lb, lrest, inv_mass, ratio, inv_dt, max_passes)


# --------------------------------------------------------------------------- projective dynamics


@nb.njit(**_FAST)
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


@nb.njit(**_JIT)
def scatter_free(x, free_vertices, solution):  # pragma: no cover - compiled
    """x[free_vertices] = solution."""
    for j in range(free_vertices.shape[0]):
        i = free_vertices[j]
        x[i, 0] = solution[j, 0]
        x[i, 1] = solution[j, 1]
        x[i, 2] = solution[j, 2]


# --------------------------------------------------------------------------- figures


@nb.njit(**_FAST)
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


@nb.njit(**_JIT)
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


@nb.njit(**_JIT)
def start_step(x, prev, v, inv_mass, inv_dt):  # pragma: no cover - compiled
    """Before a velocity-based step: pinned v = (x - prev) / dt (their motion), free prev = x."""
    for i in range(x.shape[0]):
        if inv_mass[i] == 0.0:
            for k in range(3):
                v[i, k] = (x[i, k] - prev[i, k]) * inv_dt
        else:
            for k in range(3):
                prev[i, k] = x[i, k]


@nb.njit(**_JIT)
def xpbd_constants(
    order, springs, rest_lengths, stiffness, compression, damping, inv_mass, modulus, dt, P
):  # pragma: no cover - compiled
    """Fill the constants of `XPBD_SPRING` records P (layout order: P[k] is model spring order[k])
    for step dt in one pass; True when any spring is damped. Serial: it runs in every job, also
    where two jobs share a process (Dask threads), which the parallel runtime does not allow.

    k = max(stiffness, 0) modulus under tension (compression alike), c = 2 z sqrt(k m_reduced),
    alpha~ = 1 / (k dt^2), gamma = c / (k dt), 1 / ((1 + gamma) (w_a + w_b) + alpha~); 0 where
    k = 0 (no constraint that way). The same operations in the same order as the NumPy
    expressions they replace (no fast-math), so the records are bit for bit those values.
    """
    inv_dt2 = 1.0 / (dt * dt)
    damped = False
    for k in range(order.shape[0]):
        s = order[k]
        w = inv_mass[springs[s, 0]] + inv_mass[springs[s, 1]]
        reduced = 1.0 / w if w > 0.0 else 0.0
        kt = max(stiffness[s], 0.0) * modulus
        kc = max(compression[s], 0.0) * modulus
        c = 2.0 * max(damping[s], 0.0) * np.sqrt(kt * reduced)
        r = P[k]
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
    return damped
