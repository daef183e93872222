"""A collider's triangle surface as the contact kernels read it: vertices, triangles, normals, BVH.

Closed surfaces are solids: a point is inside when it lies behind its nearest surface point, as
told by the angle-weighted pseudo-normal of the feature that point lies on (Baerentzen and
Aanaes, "Signed distance computation using the angle weighted pseudonormal", 2005): the face
normal inside a face, the sum of the two face normals on an edge, the angle-weighted sum of the
face normals around a vertex. That test is exact at edges and vertices, where the normal of
whichever face the search returned is not. Open surfaces use the same normals for the side a
point is on (they are two-sided: no inside).
"""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np

from meshdeform.contact.bvh import STACK, TriangleBVH, build_bvh, closest_to_point, refit_bvh
from meshdeform.solvers.jit import JIT
from meshdeform.topology import is_closed

#: a barycentric weight at most this is taken as 0 when choosing the feature (face, edge, vertex)
FEATURE_EPS = 1e-9


class Surface(NamedTuple):
    """vertices (M, 3) float64; triangles (K, 3) int64; normals (K, 7, 3) per triangle: its unit
    face normal (zero for a zero-area triangle), the pseudo-normals of the edges opposite its
    corners 0, 1, 2 and the angle-weighted pseudo-normals of its corners 0, 1, 2 (copied per
    triangle, so a kernel reads one array); bvh over the triangles; closed: every edge shared by
    exactly two triangles (a solid)."""

    vertices: np.ndarray
    triangles: np.ndarray
    normals: np.ndarray
    bvh: TriangleBVH
    closed: bool


def edge_index(triangles: np.ndarray, vertex_count: int) -> np.ndarray:
    """(K, 3) int64: for each triangle the index of the undirected edge opposite each of its
    corners, edges numbered 0..E-1 in the order of their sorted (low, high) vertex pair."""
    tri = np.asarray(triangles, dtype=np.int64)
    ends = tri[:, [[1, 2], [2, 0], [0, 1]]]  # the edge opposite each corner (K, 3, 2)
    keys = (ends.min(axis=2) * vertex_count + ends.max(axis=2)).ravel()
    _, inverse = np.unique(keys, return_inverse=True)
    return inverse.reshape(tri.shape)


def surface_normals(vertices: np.ndarray, triangles: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """`Surface.normals` (K, 7, 3) of triangles (K, 3) over vertices (M, 3) float64, with their
    `edge_index` edges (K, 3). Compiled: a deforming collider recomputes them every substep."""
    tri = np.ascontiguousarray(triangles, dtype=np.int64)
    edge = np.ascontiguousarray(edges, dtype=np.int64)
    count = int(edge.max(initial=-1)) + 1
    return _surface_normals(np.ascontiguousarray(vertices, dtype=np.float64), tri, edge, count)


@numba.njit(**JIT)
def _surface_normals(v: np.ndarray, tri: np.ndarray, edges: np.ndarray, edge_count: int) -> np.ndarray:
    """`surface_normals`, in fixed order over the triangles (the same bytes on every run): unit face
    normals; per edge the sum of its faces' normals; per vertex the angle-weighted sum."""
    k_count = tri.shape[0]
    out = np.zeros((k_count, 7, 3))
    edge_sum = np.zeros((edge_count, 3))
    vertex_sum = np.zeros((v.shape[0], 3))
    for t in range(k_count):
        a, b, c = tri[t, 0], tri[t, 1], tri[t, 2]
        ux, uy, uz = v[b, 0] - v[a, 0], v[b, 1] - v[a, 1], v[b, 2] - v[a, 2]
        wx, wy, wz = v[c, 0] - v[a, 0], v[c, 1] - v[a, 1], v[c, 2] - v[a, 2]
        nx, ny, nz = uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx
        length = np.sqrt(nx * nx + ny * ny + nz * nz)
        if length > 0.0:
            out[t, 0, 0], out[t, 0, 1], out[t, 0, 2] = nx / length, ny / length, nz / length
        for corner in range(3):
            e = edges[t, corner]
            for k in range(3):
                edge_sum[e, k] += out[t, 0, k]
        for corner in range(3):
            i, j, q = tri[t, corner], tri[t, (corner + 1) % 3], tri[t, (corner + 2) % 3]
            e1x, e1y, e1z = v[j, 0] - v[i, 0], v[j, 1] - v[i, 1], v[j, 2] - v[i, 2]
            e2x, e2y, e2z = v[q, 0] - v[i, 0], v[q, 1] - v[i, 1], v[q, 2] - v[i, 2]
            cx, cy, cz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
            angle = np.arctan2(np.sqrt(cx * cx + cy * cy + cz * cz), e1x * e2x + e1y * e2y + e1z * e2z)
            for k in range(3):
                vertex_sum[i, k] += angle * out[t, 0, k]
    for t in range(k_count):
        for corner in range(3):
            for k in range(3):
                out[t, 1 + corner, k] = edge_sum[edges[t, corner], k]
                out[t, 4 + corner, k] = vertex_sum[tri[t, corner], k]
    return out


def surface_of(vertices: np.ndarray, triangles: np.ndarray) -> Surface:
    """The surface of triangles (K >= 1, 3) over vertices (M, 3), with its normals and BVH."""
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    tri = np.ascontiguousarray(triangles, dtype=np.int64)
    return Surface(
        vertices=v,
        triangles=tri,
        normals=surface_normals(v, tri, edge_index(tri, v.shape[0])),
        bvh=build_bvh(v, tri),
        closed=is_closed(tri),
    )


def moved_surface(surface: Surface, vertices: np.ndarray, edges: np.ndarray) -> Surface:
    """`surface` with its vertices moved to `vertices` (M, 3) (same triangles; `edges`: their
    `edge_index`): normals computed anew, the BVH refitted (`bvh.refit_bvh`), not rebuilt."""
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    return surface._replace(
        vertices=v,
        normals=surface_normals(v, surface.triangles, edges),
        bvh=refit_bvh(surface.bvh, v, surface.triangles),
    )


@numba.njit(**JIT)
def pseudo_normal(normals: np.ndarray, t: int, w0: float, w1: float, w2: float) -> tuple[float, float, float]:
    """The (unnormalised) pseudo-normal at the point of triangle t with weights (w0, w1, w2):
    of the corner, edge or face the point lies on (normals: `Surface.normals`)."""
    z0 = w0 <= FEATURE_EPS
    z1 = w1 <= FEATURE_EPS
    z2 = w2 <= FEATURE_EPS
    zeros = int(z0) + int(z1) + int(z2)
    row = 0
    if zeros >= 2:
        row = 4 + (0 if not z0 else (1 if not z1 else 2))
    elif zeros == 1:
        row = 1 + (0 if z0 else (1 if z1 else 2))
    return normals[t, row, 0], normals[t, row, 1], normals[t, row, 2]


@numba.njit(**JIT)
def signed_closest(
    surface: Surface, points: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover
    """For points (N, 3): nearest surface points (N, 3), pseudo-normals there (N, 3, unit, zero
    where they vanish) and unsigned distances (N,)."""
    n = points.shape[0]
    closest = np.empty((n, 3))
    normals = np.zeros((n, 3))
    dist = np.empty(n)
    tris = surface.triangles
    x = surface.vertices
    bvh = surface.bvh
    bounds, nodes, order, tri_bounds = bvh.bounds, bvh.nodes, bvh.order, bvh.tri_bounds
    pseudo = surface.normals
    stack = np.empty(STACK, dtype=np.int64)
    for i in range(n):
        d2, t, wa, wb, wc = closest_to_point(
            bounds, nodes, order, tri_bounds, x, tris, points[i, 0], points[i, 1], points[i, 2], np.inf, stack
        )
        for k in range(3):
            closest[i, k] = wa * x[tris[t, 0], k] + wb * x[tris[t, 1], k] + wc * x[tris[t, 2], k]
        nx, ny, nz = pseudo_normal(pseudo, t, wa, wb, wc)
        length = np.sqrt(nx * nx + ny * ny + nz * nz)
        if length > 0.0:
            normals[i, 0], normals[i, 1], normals[i, 2] = nx / length, ny / length, nz / length
        dist[i] = np.sqrt(d2)
    return closest, normals, dist


@numba.njit(**JIT)
def surface_motion(
    surface: Surface, start: np.ndarray, end: np.ndarray, points: np.ndarray, limit: float
) -> np.ndarray:  # pragma: no cover
    """(N, 3) how far the surface point nearest to each of points (N, 3) moves when the surface's
    vertices go from start (M, 3) to end (M, 3): sum_k w_k (end - start)[corner k] at the nearest
    point's weights w on `surface` (which holds one of the two configurations); zero for points
    farther than `limit` from it. A deforming collider carries the cloth near it by this."""
    n = points.shape[0]
    out = np.zeros((n, 3))
    tris = surface.triangles
    bvh = surface.bvh
    stack = np.empty(STACK, dtype=np.int64)
    limit2 = limit * limit
    for i in range(n):
        _, t, wa, wb, wc = closest_to_point(
            bvh.bounds, bvh.nodes, bvh.order, bvh.tri_bounds, surface.vertices, tris,
            points[i, 0], points[i, 1], points[i, 2], limit2, stack,
        )  # fmt: skip
        if t < 0:
            continue
        a, b, c = tris[t, 0], tris[t, 1], tris[t, 2]
        for k in range(3):
            out[i, k] = wa * (end[a, k] - start[a, k]) + wb * (end[b, k] - start[b, k]) + wc * (end[c, k] - start[c, k])
    return out


@numba.njit(**JIT)
def closest_triangles(surface: Surface, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover
    """For points (N, 3): the triangle (N,) int64 holding the nearest surface point and that
    point's barycentric weights (N, 3) on it."""
    n = points.shape[0]
    tri = np.empty(n, dtype=np.int64)
    weights = np.empty((n, 3))
    bvh = surface.bvh
    stack = np.empty(STACK, dtype=np.int64)
    for i in range(n):
        _, t, wa, wb, wc = closest_to_point(
            bvh.bounds, bvh.nodes, bvh.order, bvh.tri_bounds, surface.vertices, surface.triangles,
            points[i, 0], points[i, 1], points[i, 2], np.inf, stack,
        )  # fmt: skip
        tri[i] = t
        weights[i, 0], weights[i, 1], weights[i, 2] = wa, wb, wc
    return tri, weights
