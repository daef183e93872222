"""Independent check of a triangle mesh against itself: which pairs of its triangles intersect.

The oracle for self-collision (issue 15): it counts the pairs of triangles that share no vertex
(topological neighbours excluded) and meet. Its decisions come from the IPC Toolkit (`ipctk`, a
test dependency written elsewhere), not from meshdeform: the broad phase is ipctk's
(`LBVH.detect_edge_face_candidates`, boxes inflated by the tolerance) and every reported hit is
decided by ipctk's own predicates:

- an edge that crosses a triangle's plane (or touches it at one end) hits the triangle when
  `ipctk.is_edge_intersecting_triangle` says so (exact orientation tests, then the crossing
  point's barycentric coordinates; boundary hits count);
- an edge lying in the triangle's plane (both ends within `tolerance` of it) hits the triangle
  when ipctk's squared distances (`point_triangle_distance` of both ends, `edge_edge_distance`
  to the triangle's three edges) put it within `tolerance`: two layers of cloth pressed into one
  plane, overlapping, do count. `is_edge_intersecting_triangle` alone is unreliable there (it
  solves a singular system).

Two triangles that share no vertex intersect exactly when an edge of one hits the other (the ends
of their common segment lie on their boundaries; coplanar overlaps have crossing or contained
edges), so each hit (edge e, triangle g) marks the pairs (f, g) for the triangles f around e that
share no vertex with g, and the pairs are counted once each.

Between the broad phase and ipctk a vectorised NumPy filter drops the candidates that cannot hit:
both ends farther than `tolerance` on one side of the plane, or (crossing point, or in-plane
segment) farther than `tolerance` outside the triangle along one of the in-plane axes of a
separating-axis test. It only ever drops candidates that ipctk would reject, so that a 40 x 40
grid (3,042 triangles) takes milliseconds per frame; `prefilter=False` sends every candidate to
ipctk, and the tests check that both give the same pairs.

Arrays: vertices (V, 3) float in metres, triangles (F, 3) int vertex indices. The tolerance is
absolute (metres); its default is `RELATIVE_TOLERANCE` times the diagonal of the vertices'
bounding box (1 nm on a 1 m sheet).
"""

from __future__ import annotations

import ipctk
import numpy as np

#: default tolerance, as a fraction of the diagonal of the vertices' bounding box
RELATIVE_TOLERANCE = 1e-9


def intersecting_pairs(
    vertices: np.ndarray, triangles: np.ndarray, *, tolerance: float | None = None, prefilter: bool = True
) -> int:
    """How many pairs of triangles that share no vertex intersect (see the module docstring)."""
    return len(intersecting_pair_array(vertices, triangles, tolerance=tolerance, prefilter=prefilter))


def intersecting_pair_array(
    vertices: np.ndarray, triangles: np.ndarray, *, tolerance: float | None = None, prefilter: bool = True
) -> np.ndarray:
    """The intersecting pairs (K, 2) int64 of triangle indices, each pair (f, g) with f < g, sorted."""
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    t = np.ascontiguousarray(triangles, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or t.ndim != 2 or t.shape[1] != 3:
        raise ValueError(f"expected vertices (V, 3) and triangles (F, 3), got {v.shape} and {t.shape}")
    if t.size and (t.min() < 0 or t.max() >= len(v)):
        raise ValueError("triangle vertex index out of range")
    if not np.isfinite(v).all():
        raise ValueError("vertices must be finite")
    if len(t) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    if tolerance is None:
        tolerance = RELATIVE_TOLERANCE * float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
    edges, edge_faces, edge_face_offsets = _edges(t, len(v))
    edge_ids, face_ids = _candidates(v, edges, t, tolerance)
    # an edge that shares a vertex with the triangle: every triangle around it shares that vertex too
    shared = (edges[edge_ids, :, None] == t[face_ids, None, :]).any(axis=(1, 2))
    edge_ids, face_ids = edge_ids[~shared], face_ids[~shared]
    hit = _hits(v, edges[edge_ids], t[face_ids], tolerance, prefilter)
    return _pairs(t, edge_ids[hit], face_ids[hit], edge_faces, edge_face_offsets)


def _edges(triangles: np.ndarray, vertex_count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The mesh's unique edges (E, 2) (lower index first) and, in CSR, the triangles around each."""
    half = triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    half = np.sort(half, axis=1)
    keys = half[:, 0] * vertex_count + half[:, 1]
    unique, inverse = np.unique(keys, return_inverse=True)
    edges = np.stack([unique // vertex_count, unique % vertex_count], axis=1)
    order = np.argsort(inverse, kind="stable")
    edge_faces = (order // 3).astype(np.int64)
    offsets = np.zeros(len(edges) + 1, dtype=np.int64)
    np.cumsum(np.bincount(inverse, minlength=len(edges)), out=offsets[1:])
    return edges, edge_faces, offsets


def _candidates(v: np.ndarray, edges: np.ndarray, t: np.ndarray, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """ipctk's broad phase: (edge, triangle) pairs whose boxes, inflated by `tolerance`, overlap."""
    broad = ipctk.LBVH()
    broad.build(
        np.asfortranarray(v), np.asfortranarray(edges, dtype=np.int32), np.asfortranarray(t, dtype=np.int32), tolerance
    )
    found = broad.detect_edge_face_candidates()
    ids = np.fromiter((i for c in found for i in (c.edge_id, c.face_id)), dtype=np.int64, count=2 * len(found))
    return ids[0::2], ids[1::2]


def _hits(v: np.ndarray, e: np.ndarray, f: np.ndarray, tolerance: float, prefilter: bool) -> np.ndarray:
    """(C,) bool: does edge e[c] (C, 2) hit triangle f[c] (C, 3)? Decided by ipctk (module docstring)."""
    a, b = v[e[:, 0]], v[e[:, 1]]
    t0, t1, t2 = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    normal = np.cross(t1 - t0, t2 - t0)
    length = np.linalg.norm(normal, axis=1)
    flat = length > 0.0  # degenerate triangles have no plane: ipctk alone decides
    unit = np.divide(normal, length[:, None], out=np.zeros_like(normal), where=flat[:, None])
    da = np.einsum("ij,ij->i", a - t0, unit)
    db = np.einsum("ij,ij->i", b - t0, unit)
    in_plane = flat & (np.abs(da) <= tolerance) & (np.abs(db) <= tolerance)
    if prefilter:
        possible = ~flat | in_plane | ~(((da > tolerance) & (db > tolerance)) | ((da < -tolerance) & (db < -tolerance)))
        crossing = possible & flat & ~in_plane
        s = np.divide(da, da - db, out=np.zeros_like(da), where=crossing)
        point = a + np.clip(s, 0.0, 1.0)[:, None] * (b - a)
        apart = _outside(point, point, t0, t1, t2, unit, tolerance) & crossing
        apart |= _outside(a, b, t0, t1, t2, unit, tolerance) & in_plane
        possible &= ~apart
    else:
        possible = np.ones(len(e), dtype=bool)
    hit = np.zeros(len(e), dtype=bool)
    squared = tolerance * tolerance
    for c in np.flatnonzero(possible):
        p, q, r0, r1, r2 = a[c], b[c], t0[c], t1[c], t2[c]
        if in_plane[c]:
            hit[c] = (
                min(
                    ipctk.point_triangle_distance(p, r0, r1, r2),
                    ipctk.point_triangle_distance(q, r0, r1, r2),
                    ipctk.edge_edge_distance(p, q, r0, r1),
                    ipctk.edge_edge_distance(p, q, r1, r2),
                    ipctk.edge_edge_distance(p, q, r2, r0),
                )
                <= squared
            )
        else:
            hit[c] = ipctk.is_edge_intersecting_triangle(p, q, r0, r1, r2)
    return hit


def _outside(
    p: np.ndarray,
    q: np.ndarray,
    t0: np.ndarray,
    t1: np.ndarray,
    t2: np.ndarray,
    unit: np.ndarray,
    tolerance: float,
) -> np.ndarray:
    """(C,) bool: the segments p-q (C, 3) lie farther than `tolerance` outside their triangles, in the
    triangles' planes (unit normals (C, 3)): a separating axis among the triangle's three in-plane edge
    normals and the segment's in-plane normal (a point when p == q)."""
    apart = np.zeros(len(p), dtype=bool)
    for start, end in ((t0, t1), (t1, t2), (t2, t0)):
        outward = np.cross(end - start, unit)  # in the plane, away from the triangle (it winds about unit)
        outward /= np.maximum(np.linalg.norm(outward, axis=1), 1e-300)[:, None]
        near = np.minimum(np.einsum("ij,ij->i", p - start, outward), np.einsum("ij,ij->i", q - start, outward))
        apart |= near > tolerance
    side = np.cross(q - p, unit)
    size = np.linalg.norm(side, axis=1)
    segment = size > 0.0
    side = np.divide(side, size[:, None], out=np.zeros_like(side), where=segment[:, None])
    offsets = np.stack([np.einsum("ij,ij->i", corner - p, side) for corner in (t0, t1, t2)], axis=1)
    apart |= segment & ((offsets.min(axis=1) > tolerance) | (offsets.max(axis=1) < -tolerance))
    return apart


def _pairs(
    t: np.ndarray, edge_ids: np.ndarray, face_ids: np.ndarray, edge_faces: np.ndarray, offsets: np.ndarray
) -> np.ndarray:
    """The pairs (f, g), f < g, for each hit of edge edge_ids[k] on triangle face_ids[k]: f runs over the
    triangles around the edge that share no vertex with g."""
    counts = offsets[edge_ids + 1] - offsets[edge_ids]
    g = np.repeat(face_ids, counts)
    start = np.repeat(offsets[edge_ids], counts)
    within = np.arange(len(g)) - np.repeat(np.cumsum(counts) - counts, counts)
    f = edge_faces[start + within]
    apart = ~(t[f, :, None] == t[g, None, :]).any(axis=(1, 2))
    f, g = f[apart], g[apart]
    pairs = np.stack([np.minimum(f, g), np.maximum(f, g)], axis=1)
    if len(pairs) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    return np.unique(pairs, axis=0)
