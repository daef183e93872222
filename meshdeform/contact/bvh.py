"""A bounding-volume hierarchy over a static triangle mesh, and its exact closest-point queries.

Built once per mesh (`build_bvh`): top-down, each node's triangles split at the median of their
centroids along the longest axis of the centroid bounds (a stable sort, so the tree depends on
the input only), leaves of at most `LEAF_SIZE` triangles. A mesh that deforms (a cache-driven collider) keeps its
tree and has its boxes refitted to the new vertex positions (`refit_bvh`): the queries stay exact,
only slower where the motion has stretched the boxes. The tree is a `TriangleBVH` of flat
arrays: node bounds, children (-1 at a leaf), each leaf's run of `order` (triangle ids).

Queries (compiled; kernels call them per point or per cloth triangle): depth-first, the nearer
child first, a node skipped when its box is no nearer than the best found so far or than the
caller's `limit2` (squared distance beyond which nothing is wanted). The answer is the exact
nearest triangle whatever the sizes of the triangles (no centroid heuristic); ties keep the
first triangle met in the fixed traversal order, so results are deterministic.
"""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np

from meshdeform.contact.triangle_distance import point_triangle_d2, triangle_triangle_closest
from meshdeform.solvers.jit import JIT

#: triangles per leaf at most
LEAF_SIZE = 4
#: traversal stack entries: the median split keeps the depth near log2(T / LEAF_SIZE) (25 for
#: 100 million triangles), and a depth-first walk holds at most depth + 1 entries
STACK = 96


class TriangleBVH(NamedTuple):
    """The hierarchy as flat arrays (kernels take them one by one: Numba passes a tuple of
    arrays to a compiled call at a cost far above a sphere's query). bounds: (N, 6) float64
    node boxes (lo xyz, hi xyz); nodes: (N, 4) int64 (left, right, start, count): children (-1
    at a leaf), a leaf's run of `order`; order: (T,) int64 triangle ids; tri_bounds: (T, 6)
    each triangle's box (leaves skip triangles by them); depth: levels."""

    bounds: np.ndarray
    nodes: np.ndarray
    order: np.ndarray
    tri_bounds: np.ndarray
    depth: int


@numba.njit(**JIT)
def _build(tlo: np.ndarray, thi: np.ndarray, centroids: np.ndarray, leaf_size: int):  # pragma: no cover - compiled
    t_count = centroids.shape[0]
    capacity = max(2 * t_count, 1)
    lo = np.empty((capacity, 3))
    hi = np.empty((capacity, 3))
    left = np.full(capacity, -1, dtype=np.int64)
    right = np.full(capacity, -1, dtype=np.int64)
    start = np.zeros(capacity, dtype=np.int64)
    count = np.zeros(capacity, dtype=np.int64)
    level = np.zeros(capacity, dtype=np.int64)
    order = np.arange(t_count).astype(np.int64)
    stack = np.empty(capacity, dtype=np.int64)
    begin = np.zeros(capacity, dtype=np.int64)
    end = np.zeros(capacity, dtype=np.int64)
    begin[0], end[0] = 0, t_count
    stack[0] = 0
    top = 1
    nodes = 1
    depth = 1
    while top > 0:
        top -= 1
        node = stack[top]
        b, e = begin[node], end[node]
        clo = np.full(3, np.inf)
        chi = np.full(3, -np.inf)
        for k in range(3):
            lo[node, k] = np.inf
            hi[node, k] = -np.inf
        for i in range(b, e):
            t = order[i]
            for k in range(3):
                lo[node, k] = min(lo[node, k], tlo[t, k])
                hi[node, k] = max(hi[node, k], thi[t, k])
                clo[k] = min(clo[k], centroids[t, k])
                chi[k] = max(chi[k], centroids[t, k])
        depth = max(depth, level[node] + 1)
        if e - b <= leaf_size:
            start[node], count[node] = b, e - b
            continue
        axis = 0
        for k in range(1, 3):
            if chi[k] - clo[k] > chi[axis] - clo[axis]:
                axis = k
        run = order[b:e].copy()
        keys = np.empty(e - b)
        for i in range(e - b):
            keys[i] = centroids[run[i], axis]
        perm = np.argsort(keys, kind="mergesort")
        for i in range(e - b):
            order[b + i] = run[perm[i]]
        mid = (b + e) // 2
        for child, cb, ce in ((nodes, b, mid), (nodes + 1, mid, e)):
            begin[child], end[child] = cb, ce
            level[child] = level[node] + 1
            stack[top] = child
            top += 1
        left[node], right[node] = nodes, nodes + 1
        nodes += 2
    return lo[:nodes], hi[:nodes], left[:nodes], right[:nodes], start[:nodes], count[:nodes], order, depth


def build_bvh(vertices: np.ndarray, triangles: np.ndarray, leaf_size: int = LEAF_SIZE) -> TriangleBVH:
    """The hierarchy over triangles (T, 3) int of vertices (V, 3) float64 (T >= 1)."""
    corners = np.asarray(vertices, dtype=np.float64)[np.asarray(triangles, dtype=np.int64)]
    tlo = np.ascontiguousarray(corners.min(axis=1))
    thi = np.ascontiguousarray(corners.max(axis=1))
    centroids = np.ascontiguousarray(corners.mean(axis=1))
    lo, hi, left, right, start, count, order, depth = _build(tlo, thi, centroids, int(leaf_size))
    if depth + 1 >= STACK:
        raise ValueError(f"collider mesh too deep for the BVH stack ({depth} levels)")
    return TriangleBVH(
        bounds=np.ascontiguousarray(np.concatenate([lo, hi], axis=1)),
        nodes=np.ascontiguousarray(np.stack([left, right, start, count], axis=1)),
        order=order,
        tri_bounds=np.ascontiguousarray(np.concatenate([tlo, thi], axis=1)),
        depth=int(depth),
    )


@numba.njit(**JIT)
def _refit(bounds: np.ndarray, nodes: np.ndarray, order: np.ndarray, tri_bounds: np.ndarray) -> None:
    """Node boxes (N, 6) from the triangle boxes (T, 6), children before parents: `_build`
    numbers every child after its parent, so a walk from the last node to the first sees both
    children of a node before the node."""
    for node in range(nodes.shape[0] - 1, -1, -1):
        for k in range(3):
            bounds[node, k] = np.inf
            bounds[node, 3 + k] = -np.inf
        if nodes[node, 0] < 0:
            for i in range(nodes[node, 2], nodes[node, 2] + nodes[node, 3]):
                t = order[i]
                for k in range(3):
                    bounds[node, k] = min(bounds[node, k], tri_bounds[t, k])
                    bounds[node, 3 + k] = max(bounds[node, 3 + k], tri_bounds[t, 3 + k])
        else:
            for child in (nodes[node, 0], nodes[node, 1]):
                for k in range(3):
                    bounds[node, k] = min(bounds[node, k], bounds[child, k])
                    bounds[node, 3 + k] = max(bounds[node, 3 + k], bounds[child, 3 + k])


def refit_bvh(bvh: TriangleBVH, vertices: np.ndarray, triangles: np.ndarray) -> TriangleBVH:
    """The same tree over the triangles (T, 3) at new vertex positions (V, 3) float64: new
    boxes, the same nodes and triangle order (the arrays of `bvh` are not changed)."""
    corners = np.asarray(vertices, dtype=np.float64)[np.asarray(triangles, dtype=np.int64)]
    tri_bounds = np.ascontiguousarray(np.concatenate([corners.min(axis=1), corners.max(axis=1)], axis=1))
    bounds = np.empty_like(bvh.bounds)
    _refit(bounds, bvh.nodes, bvh.order, tri_bounds)
    return bvh._replace(bounds=bounds, tri_bounds=tri_bounds)


@numba.njit(**JIT)
def _box_point_d2(boxes: np.ndarray, i: int, px: float, py: float, pz: float) -> float:
    """Squared distance of p to box i of boxes (B, 6)."""
    dx = max(boxes[i, 0] - px, 0.0, px - boxes[i, 3])
    dy = max(boxes[i, 1] - py, 0.0, py - boxes[i, 4])
    dz = max(boxes[i, 2] - pz, 0.0, pz - boxes[i, 5])
    return dx * dx + dy * dy + dz * dz


@numba.njit(**JIT)
def _box_box_d2(boxes: np.ndarray, i: int, q: tuple[float, float, float, float, float, float]) -> float:
    """Squared distance between box i of boxes (B, 6) and the box q = (x0, y0, z0, x1, y1, z1)."""
    dx = max(boxes[i, 0] - q[3], 0.0, q[0] - boxes[i, 3])
    dy = max(boxes[i, 1] - q[4], 0.0, q[1] - boxes[i, 4])
    dz = max(boxes[i, 2] - q[5], 0.0, q[2] - boxes[i, 5])
    return dx * dx + dy * dy + dz * dz


@numba.njit(**JIT)
def _plane_gap2(
    vertices: np.ndarray, triangles: np.ndarray, face_normals: np.ndarray, t: int, xq: np.ndarray, q0: int, q1: int,
    q2: int,
) -> float:  # fmt: skip
    """Squared distance from the plane of triangle t to the query triangle when the query lies
    strictly on one side of it (a lower bound of their distance), else 0."""
    nx, ny, nz = face_normals[t, 0], face_normals[t, 1], face_normals[t, 2]
    a = triangles[t, 0]
    lo = np.inf
    hi = -np.inf
    for r in range(3):
        q = q0 if r == 0 else (q1 if r == 1 else q2)
        d = (xq[q, 0] - vertices[a, 0]) * nx + (xq[q, 1] - vertices[a, 1]) * ny + (xq[q, 2] - vertices[a, 2]) * nz
        lo = min(lo, d)
        hi = max(hi, d)
    if lo > 0.0:
        return lo * lo
    if hi < 0.0:
        return hi * hi
    return 0.0


@numba.njit(**JIT)
def new_stack() -> np.ndarray:
    """A traversal stack for the queries (a kernel makes one and passes it to every query)."""
    return np.empty(STACK, dtype=np.int64)


@numba.njit(**JIT)
def closest_to_point(
    bounds: np.ndarray,
    nodes: np.ndarray,
    order: np.ndarray,
    tri_bounds: np.ndarray,
    vertices: np.ndarray,
    triangles: np.ndarray,
    px: float,
    py: float,
    pz: float,
    limit2: float,
    stack: np.ndarray,
) -> tuple[float, int, float, float, float]:
    """(squared distance, triangle, wa, wb, wc) of the mesh point nearest to p, or (limit2, -1,
    ...) when no triangle is nearer than sqrt(limit2) (np.inf: no limit). The first four
    arguments are a `TriangleBVH`'s arrays; stack: `new_stack()`."""
    stack[0] = 0
    top = 1
    best, tri, wa, wb, wc = limit2, -1, 1.0, 0.0, 0.0
    while top > 0:
        top -= 1
        node = stack[top]
        if _box_point_d2(bounds, node, px, py, pz) >= best:
            continue
        if nodes[node, 0] < 0:
            for i in range(nodes[node, 2], nodes[node, 2] + nodes[node, 3]):
                t = order[i]
                if _box_point_d2(tri_bounds, t, px, py, pz) >= best:
                    continue
                d2, a, b, c = point_triangle_d2(px, py, pz, vertices, triangles[t, 0], triangles[t, 1], triangles[t, 2])
                if d2 < best:
                    best, tri, wa, wb, wc = d2, t, a, b, c
            continue
        near, far = nodes[node, 0], nodes[node, 1]
        dn = _box_point_d2(bounds, near, px, py, pz)
        df = _box_point_d2(bounds, far, px, py, pz)
        if df < dn:
            near, far, dn, df = far, near, df, dn
        if df < best:
            stack[top] = far
            top += 1
        if dn < best:
            stack[top] = near
            top += 1
    return best, tri, wa, wb, wc


@numba.njit(**JIT)
def closest_to_triangle(
    bounds: np.ndarray,
    nodes: np.ndarray,
    order: np.ndarray,
    tri_bounds: np.ndarray,
    vertices: np.ndarray,
    triangles: np.ndarray,
    face_normals: np.ndarray,
    xq: np.ndarray,
    q0: int,
    q1: int,
    q2: int,
    limit2: float,
    stack: np.ndarray,
) -> tuple[float, int, float, float, float, float, float, float]:
    """(squared distance, triangle, wq0, wq1, wq2, wm0, wm1, wm2): the closest points of the query
    triangle (rows q0, q1, q2 of xq; a segment (a, b, b) or a point (a, a, a) works) and the mesh,
    as weights on the query (wq) and on the mesh triangle (wm); triangle -1 (and limit2) when
    nothing is nearer than sqrt(limit2). Arguments as for `closest_to_point`, and face_normals
    (K, 3) unit (zero for zero-area triangles): a mesh triangle whose plane the query lies
    wholly in front of (or behind), no nearer than the best so far, is skipped."""
    qb = (
        min(xq[q0, 0], xq[q1, 0], xq[q2, 0]),
        min(xq[q0, 1], xq[q1, 1], xq[q2, 1]),
        min(xq[q0, 2], xq[q1, 2], xq[q2, 2]),
        max(xq[q0, 0], xq[q1, 0], xq[q2, 0]),
        max(xq[q0, 1], xq[q1, 1], xq[q2, 1]),
        max(xq[q0, 2], xq[q1, 2], xq[q2, 2]),
    )
    stack[0] = 0
    top = 1
    best, tri = limit2, -1
    w0, w1, w2, m0, m1, m2 = 1.0, 0.0, 0.0, 1.0, 0.0, 0.0
    while top > 0:
        top -= 1
        node = stack[top]
        if _box_box_d2(bounds, node, qb) >= best:
            continue
        if nodes[node, 0] < 0:
            for i in range(nodes[node, 2], nodes[node, 2] + nodes[node, 3]):
                t = order[i]
                if _box_box_d2(tri_bounds, t, qb) >= best:
                    continue
                if _plane_gap2(vertices, triangles, face_normals, t, xq, q0, q1, q2) >= best:
                    continue
                d2, a0, a1, a2, b0, b1, b2 = triangle_triangle_closest(
                    xq, q0, q1, q2, vertices, triangles[t, 0], triangles[t, 1], triangles[t, 2]
                )
                if d2 < best:
                    best, tri, w0, w1, w2, m0, m1, m2 = d2, t, a0, a1, a2, b0, b1, b2
            continue
        near, far = nodes[node, 0], nodes[node, 1]
        dn = _box_box_d2(bounds, near, qb)
        df = _box_box_d2(bounds, far, qb)
        if df < dn:
            near, far, dn, df = far, near, df, dn
        if df < best:
            stack[top] = far
            top += 1
        if dn < best:
            stack[top] = near
            top += 1
    return best, tri, w0, w1, w2, m0, m1, m2
