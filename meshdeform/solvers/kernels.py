"""Numba kernels shared by the solvers, on the general spring list (no grid assumption).

All take structure-of-arrays spring data in a `SpringLayout` order: slabs 0..P-1 are swept
in parallel (`prange` over slabs, they share no vertex), the separator after them.
Positions and velocities are the State's (W, 3) float64 arrays, updated in place.
Compiled with `cache=True` and `error_model="numpy"` (no divide-by-zero checks in the loops).
"""

from __future__ import annotations

import numba as nb
import numpy as np

_JIT = {"cache": True, "error_model": "numpy", "nogil": True}
_FAST = {**_JIT, "fastmath": True}


# --------------------------------------------------------------------------- integration


@nb.njit(**_JIT)
def predict_verlet(x, prev, inv_mass, accel, retention, dt2):  # pragma: no cover - compiled
    """Verlet prediction x' = x + (x - prev) * retention + a dt^2 for free vertices; prev = x."""
    for i in range(x.shape[0]):
        if inv_mass[i] == 0.0:
            continue
        for k in range(3):
            xi = x[i, k]
            x[i, k] = xi + (xi - prev[i, k]) * retention + accel[i, k] * dt2
            prev[i, k] = xi


@nb.njit(**_JIT)
def velocities_from_positions(x, prev, v, inv_dt):  # pragma: no cover - compiled
    """v = (x - prev) / dt for every vertex."""
    for i in range(x.shape[0]):
        for k in range(3):
            v[i, k] = (x[i, k] - prev[i, k]) * inv_dt


# --------------------------------------------------------------------------- verlet


@nb.njit(inline="always", **_FAST)
def _relax_range(x, a, b, rest, inv_mass, kt, kc, lo, hi, backward):  # pragma: no cover - compiled
    n = hi - lo
    for j in range(n):
        s = hi - 1 - j if backward else lo + j
        ia = a[s]
        ib = b[s]
        wa = inv_mass[ia]
        wb = inv_mass[ib]
        w = wa + wb
        if w == 0.0:
            continue
        dx = x[ib, 0] - x[ia, 0]
        dy = x[ib, 1] - x[ia, 1]
        dz = x[ib, 2] - x[ia, 2]
        length = np.sqrt(dx * dx + dy * dy + dz * dz)
        if length < 1e-12:
            continue
        c = length - rest[s]
        k = kt[s] if c > 0.0 else kc[s]
        f = k * c / (length * w)
        fa = f * wa
        fb = f * wb
        x[ia, 0] += dx * fa
        x[ia, 1] += dy * fa
        x[ia, 2] += dz * fa
        x[ib, 0] -= dx * fb
        x[ib, 1] -= dy * fb
        x[ib, 2] -= dz * fb


@nb.njit(parallel=True, **_FAST)
def relax_springs(x, a, b, rest, inv_mass, kt, kc, offsets, parts, iterations, start):  # pragma: no cover
    """Jakobsen relaxation, `iterations` Gauss-Seidel sweeps alternating direction (from `start`)."""
    for it in range(iterations):
        backward = ((it + start) % 2) == 1
        for p in nb.prange(parts):
            _relax_range(x, a, b, rest, inv_mass, kt, kc, offsets[p], offsets[p + 1], backward)
        _relax_range(x, a, b, rest, inv_mass, kt, kc, offsets[parts], offsets[parts + 1], backward)


@nb.njit(**_FAST)
def relax_springs_serial(x, a, b, rest, inv_mass, kt, kc, offsets, parts, iterations, start):  # pragma: no cover
    """`relax_springs` on one thread (no parallel runtime started)."""
    for it in range(iterations):
        backward = ((it + start) % 2) == 1
        for p in range(parts + 1):
            _relax_range(x, a, b, rest, inv_mass, kt, kc, offsets[p], offsets[p + 1], backward)


# --------------------------------------------------------------------------- xpbd


@nb.njit(inline="always", **_FAST)
def _xpbd_range(x, prev, a, b, rest, inv_mass, at, ac, gamma, lam, lo, hi, backward):  # pragma: no cover - compiled
    n = hi - lo
    for j in range(n):
        s = hi - 1 - j if backward else lo + j
        ia = a[s]
        ib = b[s]
        wa = inv_mass[ia]
        wb = inv_mass[ib]
        w = wa + wb
        if w == 0.0:
            continue
        dx = x[ib, 0] - x[ia, 0]
        dy = x[ib, 1] - x[ia, 1]
        dz = x[ib, 2] - x[ia, 2]
        length = np.sqrt(dx * dx + dy * dy + dz * dz)
        if length < 1e-12:
            continue
        c = length - rest[s]
        alpha = at[s] if c > 0.0 else ac[s]
        if alpha < 0.0:
            continue
        inv_l = 1.0 / length
        nx = dx * inv_l
        ny = dy * inv_l
        nz = dz * inv_l
        g = gamma[s]
        # damping: gamma * grad C . (x - x_prev)
        rel = 0.0
        if g > 0.0:
            rel = (
                nx * ((x[ib, 0] - prev[ib, 0]) - (x[ia, 0] - prev[ia, 0]))
                + ny * ((x[ib, 1] - prev[ib, 1]) - (x[ia, 1] - prev[ia, 1]))
                + nz * ((x[ib, 2] - prev[ib, 2]) - (x[ia, 2] - prev[ia, 2]))
            )
        dlam = (-c - alpha * lam[s] - g * rel) / ((1.0 + g) * w + alpha)
        lam[s] += dlam
        pa = dlam * wa
        pb = dlam * wb
        x[ia, 0] -= nx * pa
        x[ia, 1] -= ny * pa
        x[ia, 2] -= nz * pa
        x[ib, 0] += nx * pb
        x[ib, 1] += ny * pb
        x[ib, 2] += nz * pb


@nb.njit(parallel=True, **_FAST)
def xpbd_solve(x, prev, a, b, rest, inv_mass, at, ac, gamma, lam, offsets, parts, iterations, start):
    """XPBD distance constraints (Macklin et al. 2016): lam reset, then Gauss-Seidel sweeps.

    at / ac: compliance / dt^2 under tension / compression (negative: no constraint);
    gamma: damping factor alpha~ * beta~ per constraint (eq. 26 of the paper).
    """
    lam[:] = 0.0
    for it in range(iterations):
        backward = ((it + start) % 2) == 1
        for p in nb.prange(parts):
            _xpbd_range(x, prev, a, b, rest, inv_mass, at, ac, gamma, lam, offsets[p], offsets[p + 1], backward)
        _xpbd_range(x, prev, a, b, rest, inv_mass, at, ac, gamma, lam, offsets[parts], offsets[parts + 1], backward)


@nb.njit(**_FAST)
def xpbd_solve_serial(
    x, prev, a, b, rest, inv_mass, at, ac, gamma, lam, offsets, parts, iterations, start
):  # pragma: no cover
    """`xpbd_solve` on one thread (no parallel runtime started)."""
    lam[:] = 0.0
    for it in range(iterations):
        backward = ((it + start) % 2) == 1
        for p in range(parts + 1):
            _xpbd_range(x, prev, a, b, rest, inv_mass, at, ac, gamma, lam, offsets[p], offsets[p + 1], backward)


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


@nb.njit(**_FAST)
def explicit_advance(
    x, v, prev, inv_mass, mass, accel, retention, dt, steps,
    a, b, rest, kt, kc, cd, offsets, parts, f,
    anchor_k, anchors, anchor_follow, rest_center,
    la, lb, lrest, ratio, max_passes,
):  # pragma: no cover - compiled
    """`steps` semi-implicit Euler steps of length dt: springs (Hooke + damping), anchors, air damping.

    Serial: the many short steps would pay a parallel launch each.

    anchor_k > 0 adds -anchor_k (x - anchor) per unit mass, anchor = anchors + (centre of mass
    - rest_center) when anchor_follow else anchors. ratio > 0 applies the strain limit on the
    (la, lb, lrest) springs after each step. Pinned vertices (inv_mass 0) are not moved.
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
            total = 0.0
            for i in range(nv):
                m = mass[i]
                ox += m * x[i, 0]
                oy += m * x[i, 1]
                oz += m * x[i, 2]
                total += m
            ox = ox / total - rest_center[0]
            oy = oy / total - rest_center[1]
            oz = oz / total - rest_center[2]
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
                vi = (v[i, k] + acc * dt) * retention
                v[i, k] = vi
                x[i, k] += vi * dt
        if ratio > 0.0:
            _limit_strain(x, v, la, lb, lrest, inv_mass, ratio, inv_dt, max_passes)


# --------------------------------------------------------------------------- projective dynamics


@nb.njit(**_FAST)
def pd_rhs(x, a, b, rest, weight, ratio_t, ratio_c, free, inertia, y, out):  # pragma: no cover - compiled
    """Local step + right-hand side of projective dynamics (Liu et al. 2013) for free vertices.

    For each spring the projection d (length l_d along the current direction) of x_a - x_b;
    out = inertia * y + sum_s weight_s (e_a - e_b) d_s, with pinned ends moved to the right.
    l_d = l - ratio (l - L): ratio k / weight makes a spring of stiffness k (tension or
    compression) inside a system matrix built with one weight per spring.
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
            r = ratio_t[s] if c > 0.0 else ratio_c[s]
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


@nb.njit(**_FAST)
def apply_tethers(x, vertex, pin, limit):  # pragma: no cover - compiled
    """Pull each tethered vertex back to within `limit` of its pin (the pin does not move)."""
    for t in range(vertex.shape[0]):
        _tether(x, vertex, pin, limit, t)


@nb.njit(inline="always", **_FAST)
def _tether(x, vertex, pin, limit, t):  # pragma: no cover - compiled
    i = vertex[t]
    p = pin[t]
    dx = x[i, 0] - x[p, 0]
    dy = x[i, 1] - x[p, 1]
    dz = x[i, 2] - x[p, 2]
    length = np.sqrt(dx * dx + dy * dy + dz * dz)
    if length > limit[t]:
        s = limit[t] / length
        x[i, 0] = x[p, 0] + dx * s
        x[i, 1] = x[p, 1] + dy * s
        x[i, 2] = x[p, 2] + dz * s
