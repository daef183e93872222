"""Exact closest points of a segment and a triangle, and of two triangles (compiled, Numba).

Built on the two primitives of `meshdeform.contact.primitives` (point-triangle and
segment-segment, Ericson 5.1.5 and 5.1.9): two convex sets that do not intersect are nearest
at a vertex of one against the other or at an edge against an edge, and a segment that
pierces a triangle meets it at distance 0 (Moller-Trumbore). So
- segment-triangle = min(2 ends vs the triangle, the segment vs 3 edges, the piercing point);
- triangle-triangle = min(3 corners of each vs the other, 9 edge pairs, the edges of either
  piercing the other; the piercing tests skipped when one lies strictly on one side of the
  other's plane).
Arguments are rows of (N, 3) float64 arrays given by index, as in `primitives`, so kernels call
them without slicing. Degenerate inputs work: a segment (a, b, b) or a point (a, a, a) passed
as a triangle, a zero-length segment. Results are squared distances and weights: barycentric
weights (summing to 1) for triangles, the parameter u in [0, 1] (point = s0 + u (s1 - s0)) for
segments. Ties keep the first candidate in the order above, so results are deterministic.
"""

from __future__ import annotations

import numba
import numpy as np

from meshdeform.contact.primitives import point_triangle_weights, segment_segment_params
from meshdeform.solvers.jit import JIT


@numba.njit(**JIT)
def segment_pierces_triangle(
    xs: np.ndarray, s0: int, s1: int, xt: np.ndarray, t0: int, t1: int, t2: int
) -> tuple[bool, float, float, float, float]:
    """(hit, u, wa, wb, wc): where segment xs[s0]-xs[s1] crosses triangle (xt[t0], xt[t1], xt[t2])
    (Moller-Trumbore); no hit for a segment parallel to the plane or a zero-area triangle (their
    contacts are found by the edge and vertex queries)."""
    dx = xs[s1, 0] - xs[s0, 0]
    dy = xs[s1, 1] - xs[s0, 1]
    dz = xs[s1, 2] - xs[s0, 2]
    e1x = xt[t1, 0] - xt[t0, 0]
    e1y = xt[t1, 1] - xt[t0, 1]
    e1z = xt[t1, 2] - xt[t0, 2]
    e2x = xt[t2, 0] - xt[t0, 0]
    e2y = xt[t2, 1] - xt[t0, 1]
    e2z = xt[t2, 2] - xt[t0, 2]
    hx = dy * e2z - dz * e2y
    hy = dz * e2x - dx * e2z
    hz = dx * e2y - dy * e2x
    det = e1x * hx + e1y * hy + e1z * hz
    scale = np.sqrt(
        (dx * dx + dy * dy + dz * dz) * (e1x * e1x + e1y * e1y + e1z * e1z) * (e2x * e2x + e2y * e2y + e2z * e2z)
    )
    if not abs(det) > 1e-12 * scale or scale == 0.0:
        return False, 0.0, 0.0, 0.0, 0.0
    f = 1.0 / det
    rx = xs[s0, 0] - xt[t0, 0]
    ry = xs[s0, 1] - xt[t0, 1]
    rz = xs[s0, 2] - xt[t0, 2]
    beta = f * (rx * hx + ry * hy + rz * hz)
    if beta < 0.0 or beta > 1.0:
        return False, 0.0, 0.0, 0.0, 0.0
    qx = ry * e1z - rz * e1y
    qy = rz * e1x - rx * e1z
    qz = rx * e1y - ry * e1x
    gamma = f * (dx * qx + dy * qy + dz * qz)
    if gamma < 0.0 or beta + gamma > 1.0:
        return False, 0.0, 0.0, 0.0, 0.0
    u = f * (e2x * qx + e2y * qy + e2z * qz)
    if u < 0.0 or u > 1.0:
        return False, 0.0, 0.0, 0.0, 0.0
    return True, u, 1.0 - beta - gamma, beta, gamma


@numba.njit(**JIT)
def point_triangle_d2(
    px: float, py: float, pz: float, xt: np.ndarray, t0: int, t1: int, t2: int
) -> tuple[float, float, float, float]:
    """(squared distance, wa, wb, wc) of p to the triangle."""
    wa, wb, wc = point_triangle_weights(px, py, pz, xt, t0, t1, t2)
    dx = px - (wa * xt[t0, 0] + wb * xt[t1, 0] + wc * xt[t2, 0])
    dy = py - (wa * xt[t0, 1] + wb * xt[t1, 1] + wc * xt[t2, 1])
    dz = pz - (wa * xt[t0, 2] + wb * xt[t1, 2] + wc * xt[t2, 2])
    return dx * dx + dy * dy + dz * dz, wa, wb, wc


@numba.njit(**JIT)
def segment_edge_d2(xs: np.ndarray, s0: int, s1: int, xt: np.ndarray, e0: int, e1: int) -> tuple[float, float, float]:
    """(squared distance, u on the segment, t on the edge e0-e1)."""
    u, t = segment_segment_params(xs, s0, s1, xt, e0, e1)
    dx = xs[s0, 0] + u * (xs[s1, 0] - xs[s0, 0]) - xt[e0, 0] - t * (xt[e1, 0] - xt[e0, 0])
    dy = xs[s0, 1] + u * (xs[s1, 1] - xs[s0, 1]) - xt[e0, 1] - t * (xt[e1, 1] - xt[e0, 1])
    dz = xs[s0, 2] + u * (xs[s1, 2] - xs[s0, 2]) - xt[e0, 2] - t * (xt[e1, 2] - xt[e0, 2])
    return dx * dx + dy * dy + dz * dz, u, t


@numba.njit(**JIT)
def segment_triangle_closest(
    xs: np.ndarray, s0: int, s1: int, xt: np.ndarray, t0: int, t1: int, t2: int
) -> tuple[float, float, float, float, float]:
    """(squared distance, u, wa, wb, wc) of the closest points of segment xs[s0]-xs[s1] (at
    parameter u) and triangle (xt[t0], xt[t1], xt[t2]) (at weights wa, wb, wc)."""
    hit, u, wa, wb, wc = segment_pierces_triangle(xs, s0, s1, xt, t0, t1, t2)
    if hit:
        return 0.0, u, wa, wb, wc
    best, wa, wb, wc = point_triangle_d2(xs[s0, 0], xs[s0, 1], xs[s0, 2], xt, t0, t1, t2)
    bu = 0.0
    d2, a, b, c = point_triangle_d2(xs[s1, 0], xs[s1, 1], xs[s1, 2], xt, t0, t1, t2)
    if d2 < best:
        best, bu, wa, wb, wc = d2, 1.0, a, b, c
    d2, u, t = segment_edge_d2(xs, s0, s1, xt, t0, t1)
    if d2 < best:
        best, bu, wa, wb, wc = d2, u, 1.0 - t, t, 0.0
    d2, u, t = segment_edge_d2(xs, s0, s1, xt, t1, t2)
    if d2 < best:
        best, bu, wa, wb, wc = d2, u, 0.0, 1.0 - t, t
    d2, u, t = segment_edge_d2(xs, s0, s1, xt, t2, t0)
    if d2 < best:
        best, bu, wa, wb, wc = d2, u, t, 0.0, 1.0 - t
    return best, bu, wa, wb, wc


@numba.njit(**JIT)
def _plane_sides(xp: np.ndarray, p0: int, p1: int, p2: int, xq: np.ndarray, q0: int, q1: int, q2: int) -> bool:
    """True when triangle Q lies strictly on one side of the plane of triangle P (then the two
    cannot intersect); False when it touches or straddles it, or P has no plane (zero area)."""
    ux, uy, uz = xp[p1, 0] - xp[p0, 0], xp[p1, 1] - xp[p0, 1], xp[p1, 2] - xp[p0, 2]
    vx, vy, vz = xp[p2, 0] - xp[p0, 0], xp[p2, 1] - xp[p0, 1], xp[p2, 2] - xp[p0, 2]
    nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    lo = np.inf
    hi = -np.inf
    for q in (q0, q1, q2):
        d = (xq[q, 0] - xp[p0, 0]) * nx + (xq[q, 1] - xp[p0, 1]) * ny + (xq[q, 2] - xp[p0, 2]) * nz
        lo = min(lo, d)
        hi = max(hi, d)
    return lo > 0.0 or hi < 0.0


@numba.njit(**JIT)
def _over_face(
    xp: np.ndarray, p0: int, p1: int, p2: int, xq: np.ndarray, q0: int, q1: int, q2: int
) -> tuple[bool, float, int, float, float, float]:
    """When every corner of triangle Q lies strictly on one side of triangle P's plane and
    projects inside P, Q's nearest point to P is its corner nearest that plane (the projection
    of Q lies in P, and the distance to a plane is linear over Q): (True, squared distance,
    that corner (0, 1, 2), its projection's weights on P). Otherwise (False, ...)."""
    ux, uy, uz = xp[p1, 0] - xp[p0, 0], xp[p1, 1] - xp[p0, 1], xp[p1, 2] - xp[p0, 2]
    vx, vy, vz = xp[p2, 0] - xp[p0, 0], xp[p2, 1] - xp[p0, 1], xp[p2, 2] - xp[p0, 2]
    nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    nn = nx * nx + ny * ny + nz * nz
    uu = ux * ux + uy * uy + uz * uz
    uv = ux * vx + uy * vy + uz * vz
    vv = vx * vx + vy * vy + vz * vz
    det = uu * vv - uv * uv
    if not (nn > 0.0 and det > 0.0):
        return False, 0.0, 0, 0.0, 0.0, 0.0
    best = np.inf
    corner = 0
    sign = 0.0
    bb = 0.0
    bc = 0.0
    for r in range(3):
        q = q0 if r == 0 else (q1 if r == 1 else q2)
        wx, wy, wz = xq[q, 0] - xp[p0, 0], xq[q, 1] - xp[p0, 1], xq[q, 2] - xp[p0, 2]
        h = wx * nx + wy * ny + wz * nz
        if h == 0.0 or (sign != 0.0 and (h > 0.0) != (sign > 0.0)):
            return False, 0.0, 0, 0.0, 0.0, 0.0
        sign = h
        wu = wx * ux + wy * uy + wz * uz
        wv = wx * vx + wy * vy + wz * vz
        b = (vv * wu - uv * wv) / det
        c = (uu * wv - uv * wu) / det
        if b < 0.0 or c < 0.0 or b + c > 1.0:
            return False, 0.0, 0, 0.0, 0.0, 0.0
        d2 = h * h / nn
        if d2 < best:
            best, corner, bb, bc = d2, r, b, c
    return True, best, corner, 1.0 - bb - bc, bb, bc


@numba.njit(**JIT)
def triangle_triangle_closest(
    xa: np.ndarray, a0: int, a1: int, a2: int, xb: np.ndarray, b0: int, b1: int, b2: int
) -> tuple[float, float, float, float, float, float, float]:
    """(squared distance, wa0, wa1, wa2, wb0, wb1, wb2): the closest points of triangles A
    (rows a0, a1, a2 of xa) and B (rows b0, b1, b2 of xb) as barycentric weights on each.

    Candidates in order: A's corners against B, B's corners against A, the 9 edge pairs, then
    (unless one triangle lies strictly on one side of the other's plane, so they cannot
    intersect) the edges of each piercing the other. First the common case of cloth on a face:
    one triangle lying over the other's face (`_over_face`), exact without the edge pairs."""
    over, d2, corner, c0, c1, c2 = _over_face(xb, b0, b1, b2, xa, a0, a1, a2)
    if over:
        return d2, 1.0 if corner == 0 else 0.0, 1.0 if corner == 1 else 0.0, 1.0 if corner == 2 else 0.0, c0, c1, c2
    over, d2, corner, c0, c1, c2 = _over_face(xa, a0, a1, a2, xb, b0, b1, b2)
    if over:
        return d2, c0, c1, c2, 1.0 if corner == 0 else 0.0, 1.0 if corner == 1 else 0.0, 1.0 if corner == 2 else 0.0
    best, b_0, b_1, b_2 = point_triangle_d2(xa[a0, 0], xa[a0, 1], xa[a0, 2], xb, b0, b1, b2)
    w0, w1, w2 = 1.0, 0.0, 0.0
    d2, c0, c1, c2 = point_triangle_d2(xa[a1, 0], xa[a1, 1], xa[a1, 2], xb, b0, b1, b2)
    if d2 < best:
        best, w0, w1, w2, b_0, b_1, b_2 = d2, 0.0, 1.0, 0.0, c0, c1, c2
    d2, c0, c1, c2 = point_triangle_d2(xa[a2, 0], xa[a2, 1], xa[a2, 2], xb, b0, b1, b2)
    if d2 < best:
        best, w0, w1, w2, b_0, b_1, b_2 = d2, 0.0, 0.0, 1.0, c0, c1, c2
    d2, c0, c1, c2 = point_triangle_d2(xb[b0, 0], xb[b0, 1], xb[b0, 2], xa, a0, a1, a2)
    if d2 < best:
        best, w0, w1, w2, b_0, b_1, b_2 = d2, c0, c1, c2, 1.0, 0.0, 0.0
    d2, c0, c1, c2 = point_triangle_d2(xb[b1, 0], xb[b1, 1], xb[b1, 2], xa, a0, a1, a2)
    if d2 < best:
        best, w0, w1, w2, b_0, b_1, b_2 = d2, c0, c1, c2, 0.0, 1.0, 0.0
    d2, c0, c1, c2 = point_triangle_d2(xb[b2, 0], xb[b2, 1], xb[b2, 2], xa, a0, a1, a2)
    if d2 < best:
        best, w0, w1, w2, b_0, b_1, b_2 = d2, c0, c1, c2, 0.0, 0.0, 1.0
    for ea in range(3):
        e0 = a0 if ea == 0 else (a1 if ea == 1 else a2)
        e1 = a1 if ea == 0 else (a2 if ea == 1 else a0)
        for eb in range(3):
            f0 = b0 if eb == 0 else (b1 if eb == 1 else b2)
            f1 = b1 if eb == 0 else (b2 if eb == 1 else b0)
            d2, u, t = segment_edge_d2(xa, e0, e1, xb, f0, f1)
            if d2 < best:
                best = d2
                w0 = (1.0 - u) if ea == 0 else (0.0 if ea == 1 else u)
                w1 = u if ea == 0 else ((1.0 - u) if ea == 1 else 0.0)
                w2 = 0.0 if ea == 0 else (u if ea == 1 else (1.0 - u))
                b_0 = (1.0 - t) if eb == 0 else (0.0 if eb == 1 else t)
                b_1 = t if eb == 0 else ((1.0 - t) if eb == 1 else 0.0)
                b_2 = 0.0 if eb == 0 else (t if eb == 1 else (1.0 - t))
    if best == 0.0 or _plane_sides(xb, b0, b1, b2, xa, a0, a1, a2) or _plane_sides(xa, a0, a1, a2, xb, b0, b1, b2):
        return best, w0, w1, w2, b_0, b_1, b_2
    for ea in range(3):
        e0 = a0 if ea == 0 else (a1 if ea == 1 else a2)
        e1 = a1 if ea == 0 else (a2 if ea == 1 else a0)
        hit, u, c0, c1, c2 = segment_pierces_triangle(xa, e0, e1, xb, b0, b1, b2)
        if hit:
            w0 = (1.0 - u) if ea == 0 else (0.0 if ea == 1 else u)
            w1 = u if ea == 0 else ((1.0 - u) if ea == 1 else 0.0)
            w2 = 0.0 if ea == 0 else (u if ea == 1 else (1.0 - u))
            return 0.0, w0, w1, w2, c0, c1, c2
    for eb in range(3):
        f0 = b0 if eb == 0 else (b1 if eb == 1 else b2)
        f1 = b1 if eb == 0 else (b2 if eb == 1 else b0)
        hit, t, c0, c1, c2 = segment_pierces_triangle(xb, f0, f1, xa, a0, a1, a2)
        if hit:
            b_0 = (1.0 - t) if eb == 0 else (0.0 if eb == 1 else t)
            b_1 = t if eb == 0 else ((1.0 - t) if eb == 1 else 0.0)
            b_2 = 0.0 if eb == 0 else (t if eb == 1 else (1.0 - t))
            return 0.0, c0, c1, c2, b_0, b_1, b_2
    return best, w0, w1, w2, b_0, b_1, b_2


@numba.njit(**JIT)
def triangles_cross(x: np.ndarray, triangles: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """(K,) bool: whether the triangles of each pair (K, 2) (rows of `triangles` (T, 3), corners in
    x (V, 3)) intersect: an edge of either piercing the other (`segment_pierces_triangle`); a
    coplanar overlap is not seen (it needs exactly coplanar triangles)."""
    crossing = np.zeros(pairs.shape[0], dtype=np.bool_)
    for k in range(pairs.shape[0]):
        for first, second in ((pairs[k, 0], pairs[k, 1]), (pairs[k, 1], pairs[k, 0])):
            a, b, c = triangles[second, 0], triangles[second, 1], triangles[second, 2]
            for j in range(3):
                s0, s1 = triangles[first, j], triangles[first, (j + 1) % 3]
                if not crossing[k] and segment_pierces_triangle(x, s0, s1, x, a, b, c)[0]:
                    crossing[k] = True
    return crossing
