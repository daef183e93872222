"""Exact signed closest points of a point, a segment or a triangle and an axis-aligned box (Numba).

A box is convex, so outside it the distance between it and a triangle (segment, point) is reached
at a corner of the triangle against the box or at an edge of the box against the triangle: the
nearest features of two disjoint convex polytopes include a vertex of one (Ericson 5.1.9 / GJK's
features), and a box vertex is an end of a box edge. So the clearance is
min(corners vs box: clamping, 12 box edges vs triangle: `segment_triangle_closest`), the box
edges skipped when a lower bound (the edge against the triangle's bounding box) already loses.

That min is only the distance when they do not meet. They meet when a corner is inside, when an
edge of the triangle crosses the box (slab test) or when an edge of the box pierces the triangle
(the triangle's plane cuts the box in a polygon whose corners lie on box edges). Then the signed
answer says how to get out: the deepest corner inside pushed out through its nearest face; else
the middle of the part of a crossing triangle edge inside the box, through its nearest face; else
(a box edge through the triangle) along the triangle's normal facing away from the box's centre,
by the depth of the box's farthest corner beyond the triangle's plane. In every case
d = n . (p - q) with p the cloth point, q the box point and n the unit direction out.

Corners (8, 3) are indexed by bits: bit 0 picks hi in x, bit 1 in y, bit 2 in z
(`meshdeform.scene.colliders.Box.corners`). Ties keep the first candidate in the order above.
"""

from __future__ import annotations

import numba
import numpy as np

from meshdeform.contact.triangle_distance import segment_triangle_closest
from meshdeform.solvers.jit import JIT, opaque


@numba.njit(**JIT)
def point_box(
    px: float, py: float, pz: float, lo: np.ndarray, hi: np.ndarray
) -> tuple[float, float, float, float, float, float, float]:
    """(d, qx, qy, qz, nx, ny, nz): signed distance of p to the box lo, hi (3,) (negative
    inside), the nearest point q of its surface and the outward unit normal there (inside or on
    the surface: of the nearest face, the first of -x, +x, -y, +y, -z, +z on a tie)."""
    qx = min(max(px, lo[0]), hi[0])
    qy = min(max(py, lo[1]), hi[1])
    qz = min(max(pz, lo[2]), hi[2])
    dx, dy, dz = px - qx, py - qy, pz - qz
    d2 = dx * dx + dy * dy + dz * dz
    if d2 > 0.0:
        d = np.sqrt(d2)
        return d, qx, qy, qz, dx / d, dy / d, dz / d
    best = np.inf
    axis = 0
    sign = -1.0
    for k in range(3):
        p = px if k == 0 else (py if k == 1 else pz)
        below = p - lo[k]
        above = hi[k] - p
        if below < best:
            best, axis, sign = below, k, -1.0
        if above < best:
            best, axis, sign = above, k, 1.0
    face = hi[axis] if sign > 0.0 else lo[axis]
    if axis == 0:
        return -best, face, py, pz, sign, 0.0, 0.0
    if axis == 1:
        return -best, px, face, pz, 0.0, sign, 0.0
    return -best, px, py, face, 0.0, 0.0, sign


@numba.njit(**JIT)
def segment_box_overlap(x: np.ndarray, a: int, b: int, lo: np.ndarray, hi: np.ndarray) -> tuple[bool, float, float]:
    """(hit, t0, t1): the parameters (0 <= t0 <= t1 <= 1) of the part of segment x[a]-x[b] inside
    the closed box lo, hi (slab test); hit False when the segment misses it."""
    t0 = 0.0
    t1 = 1.0
    for k in range(3):
        start = x[a, k]
        step = x[b, k] - start
        if step == 0.0:
            if start < lo[k] or start > hi[k]:
                return False, 0.0, 0.0
            continue
        ta = (lo[k] - start) / step
        tb = (hi[k] - start) / step
        if ta > tb:
            ta, tb = tb, ta
        t0 = max(t0, ta)
        t1 = min(t1, tb)
        if t0 > t1:
            return False, 0.0, 0.0
    return True, t0, t1


@numba.njit(**JIT)
def primitive_box_closest(
    tri: np.ndarray, corners: int, box: np.ndarray, lo: np.ndarray, hi: np.ndarray
) -> tuple[float, float, float, float, float, float, float, float, float, float]:
    """(d, w0, w1, w2, qx, qy, qz, nx, ny, nz) of the primitive whose corners are the first
    `corners` rows of tri (3, 3) (1: a point, 2: a segment, 3: a triangle) against the box with
    corners box (8, 3) and bounds lo, hi (3,): the signed clearance d (module docstring), the
    cloth point as weights w on tri's rows, the box point q and the unit normal n out of the box."""
    # 1. the corners: the clearance outside, the deepest inside
    best = np.inf
    w0 = w1 = w2 = 0.0
    qx = qy = qz = nx = ny = nz = 0.0
    for k in range(corners):
        d, ax, ay, az, bx, by, bz = point_box(tri[k, 0], tri[k, 1], tri[k, 2], lo, hi)
        if d < best:
            best, qx, qy, qz, nx, ny, nz = d, ax, ay, az, bx, by, bz
            w0, w1, w2 = (1.0 if k == 0 else 0.0), (1.0 if k == 1 else 0.0), (1.0 if k == 2 else 0.0)
    if best <= 0.0 or corners == 1:
        return best, w0, w1, w2, qx, qy, qz, nx, ny, nz
    # 2. an edge of the primitive through the box: the middle of its part inside
    deepest = np.inf
    for e in range(corners if corners == 3 else 1):
        a, b = e, (e + 1) % corners
        hit, t0, t1 = segment_box_overlap(tri, a, b, lo, hi)
        if not hit:
            continue
        t = 0.5 * (t0 + t1)
        mx = tri[a, 0] + t * (tri[b, 0] - tri[a, 0])
        my = tri[a, 1] + t * (tri[b, 1] - tri[a, 1])
        mz = tri[a, 2] + t * (tri[b, 2] - tri[a, 2])
        d, ax, ay, az, bx, by, bz = point_box(mx, my, mz, lo, hi)
        if d < deepest:
            deepest, qx, qy, qz, nx, ny, nz = d, ax, ay, az, bx, by, bz
            w0, w1, w2 = 0.0, 0.0, 0.0
            if a == 0:
                w0 = 1.0 - t
            elif a == 1:
                w1 = 1.0 - t
            else:
                w2 = 1.0 - t
            if b == 0:
                w0 += t
            elif b == 1:
                w1 += t
            else:
                w2 += t
    if deepest < np.inf:
        return deepest, w0, w1, w2, qx, qy, qz, nx, ny, nz
    # 3. the box's edges against the primitive, where its bounding box lets them come nearer
    last = corners - 1
    tlo0 = min(tri[0, 0], tri[1 if corners > 1 else 0, 0], tri[last, 0])
    tlo1 = min(tri[0, 1], tri[1 if corners > 1 else 0, 1], tri[last, 1])
    tlo2 = min(tri[0, 2], tri[1 if corners > 1 else 0, 2], tri[last, 2])
    thi0 = max(tri[0, 0], tri[1 if corners > 1 else 0, 0], tri[last, 0])
    thi1 = max(tri[0, 1], tri[1 if corners > 1 else 0, 1], tri[last, 1])
    thi2 = max(tri[0, 2], tri[1 if corners > 1 else 0, 2], tri[last, 2])
    best2 = best * best
    pierced = False
    t2 = last if corners == 3 else 1  # a segment is passed as the triangle (a, b, b)
    t0, t1 = opaque(0), opaque(1)  # rows as runtime values: the callee compiles once (`opaque`)
    for a in range(8):
        for axis in range(3):
            bit = 1 << axis
            if a & bit:
                continue
            b = a | bit
            bound = 0.0
            for k in range(3):
                tl = tlo0 if k == 0 else (tlo1 if k == 1 else tlo2)
                th = thi0 if k == 0 else (thi1 if k == 1 else thi2)
                el = box[a, k]
                eh = box[b, k]
                gap = max(tl - eh, el - th, 0.0)
                bound += gap * gap
            if bound >= best2:
                continue
            d2, u, a0, a1, a2 = segment_triangle_closest(box, a, b, tri, t0, t1, t2)
            if d2 < best2:
                best2 = d2
                w0, w1, w2 = a0, a1, a2
                if corners == 2:  # the triangle (a, b, b): its third weight is b's
                    w1 += w2
                    w2 = 0.0
                qx = box[a, 0] + u * (box[b, 0] - box[a, 0])
                qy = box[a, 1] + u * (box[b, 1] - box[a, 1])
                qz = box[a, 2] + u * (box[b, 2] - box[a, 2])
                pierced = d2 == 0.0
    if best2 == best * best:
        return best, w0, w1, w2, qx, qy, qz, nx, ny, nz
    px = w0 * tri[0, 0] + w1 * tri[1, 0] + w2 * tri[2, 0]
    py = w0 * tri[0, 1] + w1 * tri[1, 1] + w2 * tri[2, 1]
    pz = w0 * tri[0, 2] + w1 * tri[1, 2] + w2 * tri[2, 2]
    if not pierced:
        d = np.sqrt(best2)
        return d, w0, w1, w2, qx, qy, qz, (px - qx) / d, (py - qy) / d, (pz - qz) / d
    # 4. a box edge through the triangle: out along its normal, away from the box's centre
    ux, uy, uz = tri[1, 0] - tri[0, 0], tri[1, 1] - tri[0, 1], tri[1, 2] - tri[0, 2]
    vx, vy, vz = tri[2, 0] - tri[0, 0], tri[2, 1] - tri[0, 1], tri[2, 2] - tri[0, 2]
    nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    length = np.sqrt(nx * nx + ny * ny + nz * nz)
    if not length > 0.0:  # not reached: a zero-area triangle is never pierced (step 2 finds its edges)
        return 0.0, w0, w1, w2, qx, qy, qz, 0.0, 1.0, 0.0
    nx, ny, nz = nx / length, ny / length, nz / length
    cx, cy, cz = 0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), 0.5 * (lo[2] + hi[2])
    if nx * (px - cx) + ny * (py - cy) + nz * (pz - cz) < 0.0:
        nx, ny, nz = -nx, -ny, -nz
    beyond = -np.inf
    for c in range(8):
        depth = nx * (box[c, 0] - px) + ny * (box[c, 1] - py) + nz * (box[c, 2] - pz)
        if depth > beyond:
            beyond, qx, qy, qz = depth, box[c, 0], box[c, 1], box[c, 2]
    return -beyond, w0, w1, w2, qx, qy, qz, nx, ny, nz
