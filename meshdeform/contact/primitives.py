"""Closest points between contact primitives, as compiled scalar functions (Numba).

Every cloth contact, against itself or a collider, reduces to two exact queries (Ericson,
Real-Time Collision Detection, 5.1.5 and 5.1.9): the closest point of a triangle to a point
and the closest points of two segments. Both take the coordinates of a few 3-vectors (rows of
(V, 3) float64 arrays passed by index, so kernels call them without slicing) and return the
barycentric weights of the closest points, from which callers form distances, normals and
mass-weighted corrections. Degenerate primitives (zero-area triangles, zero-length segments)
give a valid nearest point, never NaN.
"""

from __future__ import annotations

import numba
import numpy as np

_JIT = {"cache": True, "error_model": "numpy", "inline": "always"}


@numba.njit(**_JIT)
def point_triangle_weights(
    px: float, py: float, pz: float, x: np.ndarray, a: int, b: int, c: int
) -> tuple[float, float, float]:
    """Barycentric weights (wa, wb, wc), summing to 1, of the point of triangle (x[a], x[b], x[c])
    nearest to p (Ericson 5.1.5, by Voronoi regions)."""
    abx = x[b, 0] - x[a, 0]
    aby = x[b, 1] - x[a, 1]
    abz = x[b, 2] - x[a, 2]
    acx = x[c, 0] - x[a, 0]
    acy = x[c, 1] - x[a, 1]
    acz = x[c, 2] - x[a, 2]
    apx = px - x[a, 0]
    apy = py - x[a, 1]
    apz = pz - x[a, 2]
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return 1.0, 0.0, 0.0
    bpx = px - x[b, 0]
    bpy = py - x[b, 1]
    bpz = pz - x[b, 2]
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return 0.0, 1.0, 0.0
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3) if d1 - d3 != 0.0 else 0.0
        return 1.0 - v, v, 0.0
    cpx = px - x[c, 0]
    cpy = py - x[c, 1]
    cpz = pz - x[c, 2]
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        return 0.0, 0.0, 1.0
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        w = d2 / (d2 - d6) if d2 - d6 != 0.0 else 0.0
        return 1.0 - w, 0.0, w
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        den = (d4 - d3) + (d5 - d6)
        w = (d4 - d3) / den if den != 0.0 else 0.0
        return 0.0, 1.0 - w, w
    total = va + vb + vc
    if total == 0.0:  # a degenerate triangle whose regions all failed: take its first corner
        return 1.0, 0.0, 0.0
    v = vb / total
    w = vc / total
    return 1.0 - v - w, v, w


@numba.njit(**_JIT)
def segment_segment_params(
    xp: np.ndarray, p0: int, p1: int, xq: np.ndarray, q0: int, q1: int
) -> tuple[float, float]:
    """Parameters (s, t) in [0, 1] of the closest points p0 + s (p1 - p0) and q0 + t (q1 - q0) of
    two segments, rows p0, p1 of xp and q0, q1 of xq (Ericson 5.1.9; parallel segments take
    s = 0 or the clamp)."""
    d1x = xp[p1, 0] - xp[p0, 0]
    d1y = xp[p1, 1] - xp[p0, 1]
    d1z = xp[p1, 2] - xp[p0, 2]
    d2x = xq[q1, 0] - xq[q0, 0]
    d2y = xq[q1, 1] - xq[q0, 1]
    d2z = xq[q1, 2] - xq[q0, 2]
    rx = xp[p0, 0] - xq[q0, 0]
    ry = xp[p0, 1] - xq[q0, 1]
    rz = xp[p0, 2] - xq[q0, 2]
    a = d1x * d1x + d1y * d1y + d1z * d1z
    e = d2x * d2x + d2y * d2y + d2z * d2z
    f = d2x * rx + d2y * ry + d2z * rz
    eps = 1e-300
    if a <= eps and e <= eps:
        return 0.0, 0.0
    if a <= eps:
        return 0.0, min(max(f / e, 0.0), 1.0)
    c = d1x * rx + d1y * ry + d1z * rz
    if e <= eps:
        return min(max(-c / a, 0.0), 1.0), 0.0
    b = d1x * d2x + d1y * d2y + d1z * d2z
    denom = a * e - b * b
    s = min(max((b * f - c * e) / denom, 0.0), 1.0) if denom > 1e-12 * a * e else 0.0
    t = (b * s + f) / e
    if t < 0.0:
        t = 0.0
        s = min(max(-c / a, 0.0), 1.0)
    elif t > 1.0:
        t = 1.0
        s = min(max((b - c) / a, 0.0), 1.0)
    return s, t
