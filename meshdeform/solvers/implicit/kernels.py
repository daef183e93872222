"""Numba kernels of the `implicit` solver (projective dynamics): local step and right-hand side, scatter."""

from __future__ import annotations

import numba as nb
import numpy as np

from meshdeform.solvers.jit import FAST, JIT

#: metres: a constraint's move of a vertex up to this is rounding, not a push (`constrained_rows`)
MOVE_TOLERANCE = 1e-12


@nb.njit(inline="always", **JIT)
def spring_constant(stretch, stiff_t, stiff_c, modulus):  # pragma: no cover - compiled
    """k (N/m) of a spring stretched by `stretch` = l - L (m): its tension stiffness while longer
    than rest, its compression stiffness while shorter, times the material's modulus (never < 0)."""
    return max(stiff_t if stretch > 0.0 else stiff_c, 0.0) * modulus


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
            r = spring_constant(c, stiff_t[s], stiff_c[s], modulus) / w
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


@nb.njit(**FAST)
def step_energy(  # pragma: no cover - compiled
    x, a, b, rest, stiff_t, stiff_c, modulus, free, free_vertices, rows, inertia, y, grad
):
    """The energy (J) the implicit step minimises at positions x (V, 3), and its gradient, over
    the free rows `rows` and the springs a, b.

    E(x) = sum_free inertia_i / 2 |x_i - y_i|^2 + sum_s k_s / 2 (|x_a - x_b| - L_s)^2 with
    k_s = max(stiffness, 0) * modulus under tension or compression (the sign of l - L), so the
    energy is continuous where a spring passes its rest length. grad (F, 3) receives dE/dx of
    the free vertices (F = free_vertices.shape[0], `free` maps a vertex to its row, -1 pinned):
    the rows in `rows` are set to their inertia term, then each spring adds to its ends' rows;
    pinned vertices enter at their current positions. One call over every row and spring is the
    whole energy; calls over slabs that share no vertex, then one over the springs between them
    (with no rows), give their parts (`ImplicitSolver._energy`). Serial and in a fixed order:
    the same bytes on any thread count (the line search compares energies).
    """
    energy = 0.0
    for r in range(rows.shape[0]):
        j = rows[r]
        i = free_vertices[j]
        m = inertia[j]
        dx = x[i, 0] - y[i, 0]
        dy = x[i, 1] - y[i, 1]
        dz = x[i, 2] - y[i, 2]
        energy += 0.5 * m * (dx * dx + dy * dy + dz * dz)
        grad[j, 0] = m * dx
        grad[j, 1] = m * dy
        grad[j, 2] = m * dz
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
        c = length - rest[s]
        k = spring_constant(c, stiff_t[s], stiff_c[s], modulus)
        energy += 0.5 * k * c * c
        if length < 1e-12:
            continue
        f = k * c / length
        if fa >= 0:
            grad[fa, 0] += f * dx
            grad[fa, 1] += f * dy
            grad[fa, 2] += f * dz
        if fb >= 0:
            grad[fb, 0] -= f * dx
            grad[fb, 1] -= f * dy
            grad[fb, 2] -= f * dz
    return energy


@nb.njit(**JIT)
def dot(u, v):  # pragma: no cover - compiled
    """sum(u * v) of two (F, 3) arrays, serial in a fixed order (BLAS may thread and reorder)."""
    total = 0.0
    for j in range(u.shape[0]):
        total += u[j, 0] * v[j, 0] + u[j, 1] * v[j, 1] + u[j, 2] * v[j, 2]
    return total


@nb.njit(**JIT)
def add_scaled(out, u, scale):  # pragma: no cover - compiled
    """out += scale * u, (F, 3) arrays."""
    for j in range(out.shape[0]):
        out[j, 0] += scale * u[j, 0]
        out[j, 1] += scale * u[j, 1]
        out[j, 2] += scale * u[j, 2]


@nb.njit(**JIT)
def place(x, free_vertices, base, direction, step):  # pragma: no cover - compiled
    """x[free_vertices] = base + step * direction (base, direction (F, 3))."""
    for j in range(free_vertices.shape[0]):
        i = free_vertices[j]
        x[i, 0] = base[j, 0] + step * direction[j, 0]
        x[i, 1] = base[j, 1] + step * direction[j, 1]
        x[i, 2] = base[j, 2] + step * direction[j, 2]


@nb.njit(**JIT)
def constrained_rows(  # pragma: no cover - compiled
    x, v, x_was, v_was, free, speed_tolerance, normal, depth, moved, pushed
):
    """The vertices a constraint changed since the last step, and which way it pushed them.

    x, v (V, 3): positions and velocities now; x_was, v_was: what the last step left. Fills
    moved (V,) bool, the rows whose position moved by more than `MOVE_TOLERANCE` (m) or whose
    velocity changed by more than `speed_tolerance` (m/s), and pushed (V,) bool, the free
    vertices (free >= 0) whose position moved so; normal (V, 3) receives the unit direction of that
    move (x - x_was) on the pushed rows (a collider's contact normal, or the way back along a
    crossing path) and depth (V,) its length (m). Changes within the tolerances are rounding (a
    constraint that projects a pair back to the distance it already has): they restart nothing.
    The caller's arrays: an array made in a kernel costs every process with an empty compile
    cache the compiling of its allocator.
    """
    n = x.shape[0]
    for i in range(n):
        moved[i] = False
        pushed[i] = False
        dx = x[i, 0] - x_was[i, 0]
        dy = x[i, 1] - x_was[i, 1]
        dz = x[i, 2] - x_was[i, 2]
        length = np.sqrt(dx * dx + dy * dy + dz * dz)
        if length > MOVE_TOLERANCE:
            moved[i] = True
            if free[i] >= 0:
                pushed[i] = True
                depth[i] = length
                normal[i, 0] = dx / length
                normal[i, 1] = dy / length
                normal[i, 2] = dz / length
        else:
            du = v[i, 0] - v_was[i, 0]
            dv = v[i, 1] - v_was[i, 1]
            dw = v[i, 2] - v_was[i, 2]
            if du * du + dv * dv + dw * dw > speed_tolerance * speed_tolerance:
                moved[i] = True


@nb.njit(**JIT)
def remove_normal(arr, rows, normals):  # pragma: no cover - compiled
    """arr[rows[k]] -= (arr[rows[k]] . normals[k]) normals[k]: (F, 3) rows made tangent to a contact."""
    for k in range(rows.shape[0]):
        j = rows[k]
        along = arr[j, 0] * normals[k, 0] + arr[j, 1] * normals[k, 1] + arr[j, 2] * normals[k, 2]
        arr[j, 0] -= along * normals[k, 0]
        arr[j, 1] -= along * normals[k, 1]
        arr[j, 2] -= along * normals[k, 2]


@nb.njit(**JIT)
def longest_row(arr):  # pragma: no cover - compiled
    """The largest row length of an (F, 3) array."""
    longest = 0.0
    for j in range(arr.shape[0]):
        longest = max(longest, arr[j, 0] * arr[j, 0] + arr[j, 1] * arr[j, 1] + arr[j, 2] * arr[j, 2])
    return np.sqrt(longest)


@nb.njit(**JIT)
def pressing(grad, x, y, free_vertices, rows, normals, impacts, out):  # pragma: no cover - compiled
    """out (K,) bool: whether each contact row (rows (K,) of grad (F, 3)) is pressed into its obstacle,
    against its unit normal (K, 3): by the whole force -grad, or, on the rows of an impact
    (impacts (K,) bool), by the vertex's own momentum alone, the gradient's inertia term
    inertia (x - y), whose sign is that of x - y (x, y (V, 3); free_vertices (F,) maps a row to
    its vertex)."""
    for k in range(rows.shape[0]):
        j = rows[k]
        if impacts[k]:
            i = free_vertices[j]
            along = (
                (x[i, 0] - y[i, 0]) * normals[k, 0] + (x[i, 1] - y[i, 1]) * normals[k, 1]
                + (x[i, 2] - y[i, 2]) * normals[k, 2]
            )
            out[k] = along > 0.0
        else:
            out[k] = grad[j, 0] * normals[k, 0] + grad[j, 1] * normals[k, 1] + grad[j, 2] * normals[k, 2] > 0.0


@nb.njit(**JIT)
def bdf2_start(  # pragma: no cover - compiled
    x, v, x_prev, v_prev, accel, dt, beta2, drag_factor, free_vertices, x_n, v_n, x_hat, y
):
    """A BDF2 step's start, all (V, 3): x_n, v_n = x, v (the step's start, kept); x_hat =
    4/3 x_n - 1/3 x_prev; the inertial target y = (2 dt / 9 (4 v_n - v_prev) + beta2 accel) /
    drag_factor + x_hat; and x on the free vertices set to y - beta2 / drag_factor accel (the
    iterations' start: the springs already balance most of the external acceleration). One pass
    over the vertices."""
    damped = drag_factor != 1.0
    for i in range(x.shape[0]):
        for d in range(3):
            xn = x[i, d]
            vn = v[i, d]
            x_n[i, d] = xn
            v_n[i, d] = vn
            hat = (4.0 / 3.0) * xn - (1.0 / 3.0) * x_prev[i, d]
            x_hat[i, d] = hat
            target = (2.0 * dt / 9.0) * (4.0 * vn - v_prev[i, d])
            target += beta2 * accel[i, d]
            if damped:
                target /= drag_factor
            y[i, d] = target + hat
    lead = beta2 / drag_factor
    for j in range(free_vertices.shape[0]):
        i = free_vertices[j]
        for d in range(3):
            x[i, d] = y[i, d] - lead * accel[i, d]


@nb.njit(**JIT)
def bdf2_finish(x, v, x_hat, x_n, previous, free, dt, x_out):  # pragma: no cover - compiled
    """A BDF2 step's end, all (V, 3): v = 3 / (2 dt) (x - x_hat) on free vertices, (x -
    previous) / dt on pinned ones (free < 0: their scripted motion); previous = x_n on free
    vertices; x_out = x (what the step left, to tell a constraint's later change)."""
    rate = 1.5 / dt
    for i in range(x.shape[0]):
        pinned = free[i] < 0
        for d in range(3):
            if pinned:
                v[i, d] = (x[i, d] - previous[i, d]) / dt
            else:
                v[i, d] = rate * (x[i, d] - x_hat[i, d])
                previous[i, d] = x_n[i, d]
            x_out[i, d] = x[i, d]


@nb.njit(**JIT)
def lbfgs_first_loop(  # pragma: no cover - compiled
    grad, rows, normals, slots, rho, step_history, gradient_history, alpha, residual
):
    """The first loop of L-BFGS's two-loop recursion: residual (F, 3) = grad made tangent to the
    held contacts (rows (K,), unit normals (K, 3): `remove_normal`), then for each history slot
    in `slots` (newest first) alpha[slot] = rho[slot] s . residual and residual -= alpha[slot] y
    (s, y the slot's step and gradient change in step_history, gradient_history (H, F, 3))."""
    for j in range(grad.shape[0]):  # a loop, not residual[:] = grad: its shape check compiles
        residual[j, 0] = grad[j, 0]  # string formatting (seconds in a process with an empty cache)
        residual[j, 1] = grad[j, 1]
        residual[j, 2] = grad[j, 2]
    remove_normal(residual, rows, normals)
    for k in range(slots.shape[0]):
        slot = slots[k]
        alpha[slot] = rho[slot] * dot(step_history[slot], residual)
        add_scaled(residual, gradient_history[slot], -alpha[slot])


@nb.njit(**JIT)
def lbfgs_second_loop(  # pragma: no cover - compiled
    direction, rows, normals, slots, rho, step_history, gradient_history, alpha, grad
):
    """The second loop of the recursion on direction (F, 3) (the preconditioned residual): for
    each slot oldest first, beta = rho[slot] y . direction and direction += (alpha[slot] - beta)
    s; then direction made tangent to the held contacts. Returns the slope -grad . direction of
    the step -direction (negative for a descent direction)."""
    for k in range(slots.shape[0] - 1, -1, -1):
        slot = slots[k]
        beta = rho[slot] * dot(gradient_history[slot], direction)
        add_scaled(direction, step_history[slot], alpha[slot] - beta)
    remove_normal(direction, rows, normals)
    return -dot(grad, direction)


@nb.njit(**JIT)
def lbfgs_remember(direction, step, trial_grad, grad, rows, normals, s_k, y_k):  # pragma: no cover - compiled
    """An L-BFGS history pair after a step of length `step` along -direction (F, 3): s_k =
    -step direction, y_k = trial_grad - grad made tangent to the held contacts. Returns the
    curvature s_k . y_k."""
    for j in range(direction.shape[0]):
        for d in range(3):
            s_k[j, d] = direction[j, d] * -step
            y_k[j, d] = trial_grad[j, d] - grad[j, d]
    remove_normal(y_k, rows, normals)
    return dot(s_k, y_k)


@nb.njit(**JIT)
def gather_rows(x, free_vertices, out):  # pragma: no cover - compiled
    """out (F, 3) = x[free_vertices], in place (a step gathers x several times: NumPy's fancy
    indexing or `take` cost several times as much at this size)."""
    for j in range(free_vertices.shape[0]):
        i = free_vertices[j]
        out[j, 0] = x[i, 0]
        out[j, 1] = x[i, 1]
        out[j, 2] = x[i, 2]
