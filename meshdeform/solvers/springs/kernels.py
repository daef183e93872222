"""Numba kernels of the explicit solvers (`springs`, and `anchor` which runs the same step)."""

from __future__ import annotations

import numba as nb
import numpy as np

from meshdeform.solvers.jit import FAST, JIT


@nb.njit(inline="always", **FAST)
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


@nb.njit(**FAST)
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


@nb.njit(**FAST)
def _hold_planes(x, v, inv_mass, pv, pw, pn, poff, pvel, pfric, tau, dt, was):  # pragma: no cover - compiled
    """Keeps each contact point on its plane (`ContactPlanes` as arrays: vertices pv (C, 3),
    weights pw, normals pn, surface velocities pvel (C, 3), offsets poff and friction pfric (C,))
    after a step of dt ending tau (s) into the substep: a point behind its plane is moved onto it
    along the normal, spread over its vertices by weight and inverse mass as the colliders do
    (`collider_kernels`), and the way it slid along the plane in the step (its velocity relative
    to the surface times dt) is taken back by Coulomb friction, up to pfric times the push (all of
    it within the cone: static friction, so a sheet on a slope does not creep). Each change of
    position changes the velocity by itself over dt (position-based dynamics' velocity update),
    so a vertex that pressed contacts hold still ends the step still, however many faces share
    it (docs/performance.md, "springs: contact planes in every explicit step"). Gauss-Seidel in
    row order; a point in front of its plane is left alone (a contact only pushes). Then each
    vertex of a plane leaves it no faster than it did before the planes (was (V, 3): scratch,
    their velocities before, by row): pressed faces that share a corner push it out further
    than it came in, and that move as velocity sent a corner standing still off at up to
    0.27 m/s, so a sheet draped on a ball never came to rest (docs/performance.md, "springs: a
    held vertex leaves its planes no faster than it came")."""
    for k in range(poff.shape[0]):
        for j in range(3):
            i = pv[k, j]
            was[i, 0] = v[i, 0]
            was[i, 1] = v[i, 1]
            was[i, 2] = v[i, 2]
    for k in range(poff.shape[0]):
        i0, i1, i2 = pv[k, 0], pv[k, 1], pv[k, 2]
        w0, w1, w2 = pw[k, 0], pw[k, 1], pw[k, 2]
        denom = w0 * w0 * inv_mass[i0] + w1 * w1 * inv_mass[i1] + w2 * w2 * inv_mass[i2]
        if not denom > 1e-300:
            continue
        nx, ny, nz = pn[k, 0], pn[k, 1], pn[k, 2]
        ux, uy, uz = pvel[k, 0], pvel[k, 1], pvel[k, 2]
        px = w0 * x[i0, 0] + w1 * x[i1, 0] + w2 * x[i2, 0]
        py = w0 * x[i0, 1] + w1 * x[i1, 1] + w2 * x[i2, 1]
        pz = w0 * x[i0, 2] + w1 * x[i1, 2] + w2 * x[i2, 2]
        depth = poff[k] + (nx * ux + ny * uy + nz * uz) * tau - (nx * px + ny * py + nz * pz)
        if not depth > 0.0:
            continue
        rx = w0 * v[i0, 0] + w1 * v[i1, 0] + w2 * v[i2, 0] - ux
        ry = w0 * v[i0, 1] + w1 * v[i1, 1] + w2 * v[i2, 1] - uy
        rz = w0 * v[i0, 2] + w1 * v[i1, 2] + w2 * v[i2, 2] - uz
        vn = rx * nx + ry * ny + rz * nz
        tx, ty, tz = rx - vn * nx, ry - vn * ny, rz - vn * nz
        slide = np.sqrt(tx * tx + ty * ty + tz * tz)
        # friction bounded by the normal velocity the push stands for, depth / dt
        held = min(pfric[k] * depth / (dt * slide), 1.0) if slide > 1e-300 else 0.0
        cx = depth * nx - held * tx * dt
        cy = depth * ny - held * ty * dt
        cz = depth * nz - held * tz * dt
        for i, wk in ((i0, w0), (i1, w1), (i2, w2)):
            f = wk * inv_mass[i] / denom
            if f != 0.0:
                x[i, 0] += f * cx
                x[i, 1] += f * cy
                x[i, 2] += f * cz
                v[i, 0] += f * cx / dt
                v[i, 1] += f * cy / dt
                v[i, 2] += f * cz / dt
    # each held vertex leaves its planes no faster than it did before them
    for k in range(poff.shape[0]):
        nx, ny, nz = pn[k, 0], pn[k, 1], pn[k, 2]
        ux, uy, uz = pvel[k, 0], pvel[k, 1], pvel[k, 2]
        for j in range(3):
            i = pv[k, j]
            if not (pw[k, j] > 0.0 and inv_mass[i] > 0.0):
                continue
            vn = (v[i, 0] - ux) * nx + (v[i, 1] - uy) * ny + (v[i, 2] - uz) * nz
            vn_was = (was[i, 0] - ux) * nx + (was[i, 1] - uy) * ny + (was[i, 2] - uz) * nz
            cap = max(vn_was, 0.0)
            if vn > cap:
                v[i, 0] -= (vn - cap) * nx
                v[i, 1] -= (vn - cap) * ny
                v[i, 2] -= (vn - cap) * nz


@nb.njit(inline="always", **FAST)
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


@nb.njit(**FAST)
def explicit_advance(
    x, v, prev, inv_mass, mass, accel, retention, dt, steps,
    a, b, rest, kt, kc, cd, offsets, parts, f,
    anchor_k, anchors, anchor_follow, rest_center, anchor_keep,
    la, lb, lrest, ratio, max_passes,
    pv, pw, pn, poff, pvel, pfric,
):  # pragma: no cover - compiled
    """`steps` semi-implicit Euler steps of length dt: springs (Hooke + damping), anchors, air damping.

    Serial: the many short steps would pay a parallel launch each.

    anchor_k > 0 adds -anchor_k (x - anchor) per unit mass, anchor = anchors + (centre of mass
    - rest_center) when anchor_follow else anchors, and multiplies each velocity relative to
    the anchors' (the centre of mass's when anchor_follow, else zero) by anchor_keep per step.
    ratio > 0 applies the strain limit on the (la, lb, lrest) springs after each step. Then the
    contact planes (pv .. pfric, `_hold_planes`; none: C = 0) keep their contacts. Pinned
    vertices (inv_mass 0) are not moved.
    """
    nv = x.shape[0]
    use_springs = a.shape[0] > 0
    inv_dt = 1.0 / dt
    for step in range(steps):
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
        if poff.shape[0] > 0:
            _hold_planes(x, v, inv_mass, pv, pw, pn, poff, pvel, pfric, (step + 1) * dt, dt, f)


@nb.njit(**JIT)
def start_step(x, prev, v, inv_mass, inv_dt):  # pragma: no cover - compiled
    """Before a velocity-based step: pinned v = (x - prev) / dt (their motion), free prev = x."""
    for i in range(x.shape[0]):
        if inv_mass[i] == 0.0:
            for k in range(3):
                v[i, k] = (x[i, k] - prev[i, k]) * inv_dt
        else:
            for k in range(3):
                prev[i, k] = x[i, k]
