"""Numba pieces shared by the position-based solvers (`verlet`, `xpbd`): scratch records, tethers.

verlet and xpbd run whole substeps in one compiled call on a scratch copy of the vertices in
the layout's kernel numbering, one `VERTEX` record per vertex: position, inverse mass and
previous position in one 64-byte cache line, so the two positions a spring reads arrive
together (xpbd's damping reads both ends' previous positions; verlet's relaxation does not, and
the previous position rides along to the next substep's prediction and the write-back). Per
spring precomputed constants (see each solver's kernels), so a projection does one
square root and one division and no gather of masses. Record fields compile to constant offsets
and unsigned indices need no negative-index wraparound, which keeps the loops short. Only free
vertices are written back: pinned positions stay bit-identical.

All take spring data in a `SpringLayout` order: slabs 0..P-1 (swept one after the other, or in
parallel by a solver's parallel build: they share no vertex), the separator after them.
Positions and velocities are the State's (W, 3) float64 arrays, updated in place. These are
plain compiled functions that LLVM inlines into the solvers' substep kernels: Numba's own IR
inlining (`inline="always"`) gives the same machine code speed but types every call site anew,
which doubled the substep kernels' compile time (the figures: docs/performance.md).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from meshdeform.solvers.jit import JIT, SWEEP

#: squared distance ratio past which a tether no longer pulls a vertex back (see `apply_tethers`)
_RUNAWAY2 = 1e30
#: squared length below which a spring's direction is taken as undefined (no division by zero)
_TINY2 = 1e-24

#: scratch vertex: position, inverse mass, previous position (64 bytes)
VERTEX = np.dtype(
    [("x", "f8"), ("y", "f8"), ("z", "f8"), ("w", "f8"), ("px", "f8"), ("py", "f8"), ("pz", "f8"), ("pad", "f8")],
    align=True,
)
#: tether: kernel vertex, kernel pin vertex, largest distance
TETHER = np.dtype([("v", "u4"), ("p", "u4"), ("lim", "f8")], align=True)
#: a contact plane (`meshdeform.model.ContactPlanes` row) in kernel numbering: the cloth point
#: p = w0 x[v0] + w1 x[v1] + w2 x[v2] keeps n . p >= level at the end of the substep (level: the
#: plane's offset moved on with its surface over the substep), slides relative to the surface's
#: move (ux, uy, uz) over the substep (m) under Coulomb friction mu; push: the kernel's scratch,
#: how far `hold_planes` moved the point onto its plane (m)
PLANE = np.dtype(
    [("v0", "u4"), ("v1", "u4"), ("v2", "u4"), ("w0", "f8"), ("w1", "f8"), ("w2", "f8"),
     ("nx", "f8"), ("ny", "f8"), ("nz", "f8"), ("level", "f8"), ("ux", "f8"), ("uy", "f8"), ("uz", "f8"),
     ("mu", "f8"), ("push", "f8")],
    align=True,
)  # fmt: skip


@nb.njit(**JIT)
def _verlet(x0, p0, a0, retention, dt2):  # pragma: no cover - compiled
    """One coordinate's Verlet prediction x + (x - prev) retention + a dt^2 (every substep kernel's)."""
    return x0 + (x0 - p0) * retention + a0 * dt2


@nb.njit(**JIT)
def load_vertices(X, x, prev, inv_mass, accel, rank, retention, dt2, lo, hi):  # pragma: no cover - compiled
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


@nb.njit(**JIT)
def predict_vertices(X, accel, order, retention, dt2, lo, hi):  # pragma: no cover - compiled
    """The next substep's prediction inside `VERTEX` records, kernel vertices lo..hi-1 (a call
    running several substeps): x' = x + (x - px) retention + a dt^2, px = x, as in `load_vertices`.
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


@nb.njit(**JIT)
def store_vertices(X, x, prev, v, rank, inv_dt, lo, hi):  # pragma: no cover - compiled
    """Model vertices lo..hi-1 back from `VERTEX` records: x = the record, prev = its position
    before the last substep (px), v = (x - prev) / dt; pinned ones keep x and prev bit for bit."""
    for i in range(lo, hi):
        r = X[rank[i]]
        if r.w != 0.0:
            x0 = r.x
            x1 = r.y
            x2 = r.z
            p0 = r.px
            p1 = r.py
            p2 = r.pz
            x[i, 0] = x0
            x[i, 1] = x1
            x[i, 2] = x2
            prev[i, 0] = p0
            prev[i, 1] = p1
            prev[i, 2] = p2
            v[i, 0] = (x0 - p0) * inv_dt
            v[i, 1] = (x1 - p1) * inv_dt
            v[i, 2] = (x2 - p2) * inv_dt
        else:
            v[i, 0] = (x[i, 0] - prev[i, 0]) * inv_dt
            v[i, 1] = (x[i, 1] - prev[i, 1]) * inv_dt
            v[i, 2] = (x[i, 2] - prev[i, 2]) * inv_dt


@nb.njit(**SWEEP)
def apply_tethers(X, tethers, lo, hi):  # pragma: no cover - compiled
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


@nb.njit(**SWEEP)
def span(va, vb):  # pragma: no cover - compiled
    """d = x_b - x_a, |d| and 1 / |d|^2 (the division runs beside the square root, not after it:
    a shorter dependency chain per spring)."""
    dx = vb.x - va.x
    dy = vb.y - va.y
    dz = vb.z - va.z
    d2 = max(dx * dx + dy * dy + dz * dz, _TINY2)
    inv_d2 = 1.0 / d2
    return dx, dy, dz, np.sqrt(d2), inv_d2


@nb.njit(**SWEEP)
def pull(va, vb, dx, dy, dz, fa, fb):  # pragma: no cover - compiled
    """x_a += d fa, x_b -= d fb."""
    va.x += dx * fa
    va.y += dy * fa
    va.z += dz * fa
    vb.x -= dx * fb
    vb.y -= dy * fb
    vb.z -= dz * fb


@nb.njit(**SWEEP)
def _shift(r, f, cx, cy, cz):  # pragma: no cover - compiled
    """x_r += f c."""
    r.x += f * cx
    r.y += f * cy
    r.z += f * cz


@nb.njit(**SWEEP)
def hold_planes(X, planes):  # pragma: no cover - compiled
    """The contact planes (`PLANE` records) at the end of a substep's sweeps: first each point
    behind its plane is moved onto it along the normal (Gauss-Seidel in row order; a point in
    front of its plane is left alone: a contact only pushes), then the way each pushed point slid
    along its plane over the substep (its move since the substep's start, less the surface's) is
    taken back by Coulomb friction, up to mu times the push (all of it within the cone: static
    friction); each correction spread over the point's vertices by weight and inverse mass, as
    the colliders spread theirs (`collider_kernels`). Each row's push is kept in its `push`.

    Held here, before the velocities are taken from the positions, the springs' pull on a resting
    contact ends the substep on the obstacle: left to the colliders after the substep, the pull
    sank it by a quarter millimetre a substep and their push-back of the surface (vertices, edges,
    faces) cycled on it, so a sheet draped on a ball never came to rest (docs/performance.md,
    "xpbd: contact planes after the sweeps")."""
    for k in range(planes.shape[0]):
        c = planes[k]
        c.push = 0.0
        a = X[c.v0]
        b = X[c.v1]
        d = X[c.v2]
        w0 = c.w0
        w1 = c.w1
        w2 = c.w2
        denom = w0 * w0 * a.w + w1 * w1 * b.w + w2 * w2 * d.w
        if not denom > 1e-300:
            continue
        nx = c.nx
        ny = c.ny
        nz = c.nz
        depth = c.level - (nx * (w0 * a.x + w1 * b.x + w2 * d.x) + ny * (w0 * a.y + w1 * b.y + w2 * d.y)
                           + nz * (w0 * a.z + w1 * b.z + w2 * d.z))
        if not depth > 0.0:
            continue
        c.push = depth
        s = depth / denom
        _shift(a, w0 * a.w * s, nx, ny, nz)
        _shift(b, w1 * b.w * s, nx, ny, nz)
        _shift(d, w2 * d.w * s, nx, ny, nz)
    for k in range(planes.shape[0]):
        c = planes[k]
        push = c.push
        if not push > 0.0:
            continue
        a = X[c.v0]
        b = X[c.v1]
        d = X[c.v2]
        w0 = c.w0
        w1 = c.w1
        w2 = c.w2
        denom = w0 * w0 * a.w + w1 * w1 * b.w + w2 * w2 * d.w
        nx = c.nx
        ny = c.ny
        nz = c.nz
        rx = w0 * (a.x - a.px) + w1 * (b.x - b.px) + w2 * (d.x - d.px) - c.ux
        ry = w0 * (a.y - a.py) + w1 * (b.y - b.py) + w2 * (d.y - d.py) - c.uy
        rz = w0 * (a.z - a.pz) + w1 * (b.z - b.pz) + w2 * (d.z - d.pz) - c.uz
        rn = rx * nx + ry * ny + rz * nz
        tx = rx - rn * nx
        ty = ry - rn * ny
        tz = rz - rn * nz
        slide = np.sqrt(tx * tx + ty * ty + tz * tz)
        if not slide > 1e-300:
            continue
        s = -min(c.mu * push / slide, 1.0) / denom
        _shift(a, w0 * a.w * s, tx, ty, tz)
        _shift(b, w1 * b.w * s, tx, ty, tz)
        _shift(d, w2 * d.w * s, tx, ty, tz)


@nb.njit(**SWEEP)
def _from_pin(v, pin):  # pragma: no cover - compiled
    """|x_v - x_pin| (m) from where vertex record v started the substep (px) to where pin is now."""
    dx = v.px - pin.x
    dy = v.py - pin.y
    dz = v.pz - pin.z
    return np.sqrt(dx * dx + dy * dy + dz * dz)


@nb.njit(**SWEEP)
def _pin_gap(X, a, b):  # pragma: no cover - compiled
    """|x_a - x_b| (m) between the vertex records a and b (two pins)."""
    dx = X[a].x - X[b].x
    dy = X[a].y - X[b].y
    dz = X[a].z - X[b].z
    return np.sqrt(dx * dx + dy * dy + dz * dz)


@nb.njit(**SWEEP)
def _scale_by_pins(X, base, scaled):  # pragma: no cover - compiled
    """scaled (R,) m: each tether record's limit times the most any pair of its vertex's pins
    asks for (their distance over the pair's limits together, at least 1; a vertex's records
    are consecutive: sorted by vertex), `release_tethers`' pins."""
    n = base.shape[0]
    first = 0
    while first < n:
        end = first + 1
        while end < n and base[end].v == base[first].v:
            end += 1
        scale = 1.0
        for a in range(first, end):
            for b in range(a + 1, end):
                room = base[a].lim + base[b].lim
                apart = _pin_gap(X, base[a].p, base[b].p)
                if apart > scale * room:
                    scale = apart / room
        for a in range(first, end):
            scaled[a] = base[a].lim * scale
        first = end


@nb.njit(**SWEEP)
def release_tethers(  # pragma: no cover - compiled
    X, base, work, offsets, links, gaps, contact, limits, scaled, released
):
    """The tethers' limits for a substep (`work`, from the records `base` and the limits `work`
    held in the last one), where the pins or a collider force the cloth further from its pins
    than they allow.

    Pins: a vertex tethered to pins of two groups (records sorted by vertex, so its records are
    consecutive) can keep both limits only while those pins are no further apart than the two
    limits together; grips that pull a cloth apart move them further, and the tethers then held
    every vertex but the row next to a grip, whose springs took the whole stretch (9.4x where
    the cloth as a whole stretched 1.3x). So each vertex's limits are scaled alike by the most
    any pair of its pins asks for (`_scale_by_pins`): `scaled` (R,) m. In a cloth whose pins are
    no further apart than the limits allow this is 1 (the paths' triangle inequality). Scaled
    so, a vertex's limits to two grips meet where the cloth between them stretches evenly: they
    hold it there as they hold an unstretched cloth within them, against sweeps that do not
    carry a grip's pull across the cloth within a substep (with the limits' slack kept on top,
    1.79x instead of 1.55x on `pulled_banner` under xpbd; the scene effect `NearestPinTethers`
    keeps it, for solvers that converge).

    A collider: a vertex it touches (contact (W,) uint8 in kernel numbering, or empty) may stay
    as far from its pin as it started the substep, and a vertex next to a released one (links,
    gaps: `common.TetherLinks`) as far as that one less the gap between them. That never releases
    a tether in a cloth within its (scaled) tethers (the gaps' triangle inequality), spreads one
    neighbour a substep and ends as the push does. Distances from where each vertex started the
    substep (px) to where its pin is. released: (1,) int64, the count of tethers released past
    their scaled limit.

    Held by a collider's push, the vertices next to those a plate punched 0.4 m through a pinned
    cloth were kept back and the spring between took the whole difference (10.7-12.7x: the
    guard stopped the run; docs/performance.md, "Tethers against a collider that forces
    stretch")."""
    _scale_by_pins(X, base, scaled)
    count = 0
    n = base.shape[0]
    touched = contact.shape[0] > 0
    for r in range(n):
        te = base[r]
        lim = scaled[r]
        if touched and contact[te.v] != 0:
            lim = max(lim, _from_pin(X[te.v], X[te.p]))
        for k in range(offsets[r], offsets[r + 1]):
            q = links[k]
            if work[q].lim > scaled[q]:
                tq = base[q]
                lim = max(lim, _from_pin(X[tq.v], X[tq.p]) - gaps[k])
        limits[r] = lim
        if lim > scaled[r]:
            count += 1
    for r in range(n):
        work[r].lim = limits[r]
    released[0] = count
