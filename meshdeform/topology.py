"""Spring topology: structural, shear and bending springs derived from a polygon mesh.

Everything is built on *welded* positions (vertices at identical coordinates merged, as OBJ
files split vertices at UV seams) so the cloth does not fall apart at seams. All steps are
vectorised NumPy; the one per-vertex search (straightest continuation for bending springs)
is a Numba kernel.

Definitions (DESIGN.md section 2):
- structural: every unique edge of the polygons (and of polylines);
- shear: every diagonal of polygons with 4 to 8 corners (of larger polygons the diagonals of
  their fan triangulation, so the count stays linear). Triangles get none: their edges already
  hold them rigid in their plane;
- bending, two rules whose springs are merged (each pair once):
  - across triangles: for every interior manifold edge (used by exactly two polygons, both
    triangles) the pair of vertices opposite it, i.e. the pairs trimesh's
    `face_adjacency_unshared` gives; the spring's length changes with the fold angle at that
    edge, so it resists folding on any triangle mesh, regular or not;
  - straight lines: for a vertex v whose neighbours a and b continue each other most straightly
    (each is the other's best continuation through v, angle >= 150 degrees at rest), the spring
    a-b. Only edges of polygons with 4 or more corners and polyline segments count as
    neighbours here, so a pure triangle mesh is bent by the first rule alone, not twice, and a
    quad mesh keeps exactly the springs it always had;
  either way not where a-b already is a structural or shear spring (a tetrahedron gets no
  bending spring: every pair of its vertices is an edge).
  On a mixed mesh each region is bent by its own rule: triangles by the pairs across their
  shared edges, quads and larger polygons by straight lines over their own edges (a line
  through a quad region ends where it meets triangles). An edge between a triangle and a
  larger polygon gets no bending spring from either rule.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from meshdeform.arrays import argsort_int, isin_int, run_lengths, unique_int
from meshdeform.mesh import Mesh


class SpringKind(IntEnum):
    """The three kinds of spring; the value is stored in `SpringModel.kinds`."""

    STRUCTURAL = 0
    SHEAR = 1
    BENDING = 2


KIND_NAMES: tuple[str, ...] = ("structural", "shear", "bending")

#: cosine of the smallest rest angle a-v-b that still counts as a straight continuation (150 degrees)
STRAIGHT_COS = float(np.cos(np.deg2rad(150.0)))


@dataclass(frozen=True, eq=False)
class Welding:
    """Input vertices merged by identical position.

    vertex_map: (V,) input vertex -> welded vertex; welded vertices are numbered in order of
    their first input occurrence, so a mesh without duplicates maps to itself.
    representative: (W,) the first input vertex of each welded vertex.
    """

    vertex_map: np.ndarray
    representative: np.ndarray

    @property
    def count(self) -> int:
        return int(self.representative.shape[0])


@dataclass(frozen=True, eq=False)
class Springs:
    """Springs over welded vertices: pairs (S, 2) int32 sorted (a < b), kind (S,) int8."""

    pairs: np.ndarray
    kinds: np.ndarray

    def count(self, kind: SpringKind) -> int:
        return int(np.count_nonzero(self.kinds == kind))

    def counts(self) -> dict[str, int]:
        return {name: self.count(SpringKind(i)) for i, name in enumerate(KIND_NAMES)}


def weld(positions: np.ndarray) -> Welding:
    """Merge vertices with bit-identical coordinates (-0.0 equals 0.0), keeping first-seen order."""
    pos = np.ascontiguousarray(np.asarray(positions, dtype=np.float64) + 0.0)
    if pos.shape[0] == 0:
        empty = np.zeros(0, dtype=np.int64)
        return Welding(empty, empty)
    rows = pos.view(np.dtype((np.void, pos.dtype.itemsize * 3))).ravel()
    _, first, inverse = np.unique(rows, return_index=True, return_inverse=True)
    # renumber unique rows by first occurrence so welded order follows input order
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(order.shape[0])
    return Welding(vertex_map=rank[inverse.ravel()].astype(np.int64), representative=first[order].astype(np.int64))


def _unique_pairs(a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    """Unique unordered pairs (a, b) with a != b, as (K, 2) int64 sorted by (min, max)."""
    lo = np.minimum(a, b).astype(np.int64)
    hi = np.maximum(a, b).astype(np.int64)
    keep = lo != hi
    keys = unique_int(lo[keep] * n + hi[keep])
    return np.stack([keys // n, keys % n], axis=1)


def _pair_keys(pairs: np.ndarray, n: int) -> np.ndarray:
    return pairs[:, 0].astype(np.int64) * n + pairs[:, 1].astype(np.int64)


def edge_incidence(start: np.ndarray, end: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The distinct undirected edges among the directed edges start -> end and how often each occurs.

    start, end: (E,) vertex indices below n. Returns the edges (K, 2) int64 as pairs (lo, hi) in
    lexicographic order and the number of directed edges giving each (K,) int64: 1 on an open
    boundary (a hole, the outline of a sheet, the lips of a tear), 2 inside a manifold surface,
    more at non-manifold edges. Self-edges (start == end, a collapsed edge of a degenerate
    polygon) count like any other; callers that must not count them drop them first.
    """
    n = max(int(n), 1)
    lo = np.minimum(start, end).astype(np.int64)
    hi = np.maximum(start, end).astype(np.int64)
    keys = np.sort(lo * n + hi)
    starts, counts = run_lengths(keys)
    distinct = keys[starts]
    return np.stack([distinct // n, distinct % n], axis=1), counts


def boundary_edges(start: np.ndarray, end: np.ndarray, n: int) -> np.ndarray:
    """The edges (B, 2) int64 that exactly one of the directed edges start -> end gives (see
    `edge_incidence`): the open boundary of a surface, as sorted pairs in lexicographic order."""
    edges, counts = edge_incidence(start, end, n)
    return edges[counts == 1]


def triangle_edge_counts(triangles: np.ndarray) -> np.ndarray:
    """How many triangles (T, 3) use each of their distinct edges (K,) (`edge_incidence`)."""
    if triangles.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    start = triangles.ravel()
    end = triangles[:, [1, 2, 0]].ravel()
    return edge_incidence(start, end, int(triangles.max()) + 1)[1]


def boundary_edge_count(triangles: np.ndarray) -> int:
    """Number of edges used by exactly one triangle (0 for a closed surface)."""
    return int(np.count_nonzero(triangle_edge_counts(triangles) == 1))


def is_closed(triangles: np.ndarray) -> bool:
    """True when every edge is shared by exactly two triangles (a watertight surface)."""
    counts = triangle_edge_counts(triangles)
    return bool(counts.shape[0]) and bool(np.all(counts == 2))


def polygon_edges(mesh: Mesh, vertex_map: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Directed edge of every polygon corner on welded indices: (start, end), each (C,)."""
    start = vertex_map[mesh.face_indices]
    end = vertex_map[mesh.face_indices[mesh.corner_next]]
    return start, end


def line_edges(mesh: Mesh, vertex_map: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Consecutive vertex pairs of every polyline on welded indices."""
    if mesh.line_count == 0:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty
    idx = mesh.line_indices
    last = np.zeros(idx.shape[0], dtype=bool)
    last[mesh.line_offsets[1:] - 1] = True
    starts = np.flatnonzero(~last)
    return vertex_map[idx[starts]], vertex_map[idx[starts + 1]]


def structural_pairs(mesh: Mesh, vertex_map: np.ndarray, n: int) -> np.ndarray:
    s, e = polygon_edges(mesh, vertex_map)
    ls, le = line_edges(mesh, vertex_map)
    return _unique_pairs(np.concatenate([s, ls]), np.concatenate([e, le]), n)


#: polygons with up to this many corners get every diagonal as a shear spring (at most 20 each);
#: larger ones get the diagonals of their fan triangulation, so the work stays linear in the corners
FULL_DIAGONAL_CORNERS = 8


def _polygon_diagonals(mesh: Mesh, vertex_map: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Shear diagonals of polygons with 4+ corners, as (start, end) welded vertices.

    A polygon of k <= FULL_DIAGONAL_CORNERS corners gets all k (k - 3) / 2 diagonals (a quad its
    two, a hexagon nine), grouped by size (at most five sizes). A larger polygon gets the k - 3
    diagonals of the fan triangulation `Mesh.triangles` uses, corner 0 to corners 2 .. k - 2:
    that still triangulates (and so braces) the polygon in its plane, in O(k) springs and time,
    where all diagonals would be quadratic (200 million springs for a 20,000-corner cap).
    """
    sizes = mesh.face_sizes
    out_a: list[np.ndarray] = []
    out_b: list[np.ndarray] = []
    small = sizes[(sizes >= 4) & (sizes <= FULL_DIAGONAL_CORNERS)]
    for k in np.unique(small).tolist():
        polys = np.flatnonzero(sizes == k)
        corners = mesh.face_offsets[polys][:, None] + np.arange(k)[None, :]
        verts = vertex_map[mesh.face_indices[corners]]  # (P, k)
        i, j = np.triu_indices(k, 1)
        diag = (j - i != 1) & (j - i != k - 1)
        out_a.append(verts[:, i[diag]].ravel())
        out_b.append(verts[:, j[diag]].ravel())
    large = np.flatnonzero(sizes > FULL_DIAGONAL_CORNERS)
    if large.shape[0]:
        per_polygon = sizes[large] - 3
        first = mesh.face_offsets[large]
        before = np.cumsum(per_polygon) - per_polygon
        local = np.arange(int(per_polygon.sum()), dtype=np.int64) - np.repeat(before, per_polygon)
        out_a.append(vertex_map[mesh.face_indices[np.repeat(first, per_polygon)]])
        out_b.append(vertex_map[mesh.face_indices[np.repeat(first, per_polygon) + 2 + local]])
    if not out_a:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty
    return np.concatenate(out_a), np.concatenate(out_b)


def dihedral_pairs(mesh: Mesh, vertex_map: np.ndarray, n: int) -> np.ndarray:
    """The two vertices opposite each interior manifold edge between triangles, (K, 2) int64.

    An edge qualifies when exactly two polygon corners give it (either direction), both of
    triangles; edges also used by a larger polygon or by three or more polygons do not. Those
    are the pairs of trimesh's `face_adjacency_unshared` on a triangle mesh. Returned as
    unique sorted pairs (lo, hi) in lexicographic order (self pairs of degenerate triangles
    dropped), structural ones included: the caller drops those.
    """
    if not np.any(mesh.face_sizes == 3):
        return np.zeros((0, 2), dtype=np.int64)
    s, e = polygon_edges(mesh, vertex_map)
    corner_nxt = mesh.corner_next
    triangle = np.repeat(mesh.face_sizes == 3, mesh.face_sizes)
    # corner c's edge c -> next(c) of a triangle is opposite the third corner, next(next(c))
    opposite = vertex_map[mesh.face_indices[corner_nxt[corner_nxt]]]
    real = np.flatnonzero(s != e)
    keys = np.minimum(s[real], e[real]).astype(np.int64) * n + np.maximum(s[real], e[real])
    order = argsort_int(keys)
    starts, counts = run_lengths(keys[order])
    twice = starts[counts == 2]
    first = real[order[twice]]
    second = real[order[twice + 1]]
    both = triangle[first] & triangle[second]
    return _unique_pairs(opposite[first[both]], opposite[second[both]], n)


def shear_pairs(mesh: Mesh, vertex_map: np.ndarray, n: int, structural: np.ndarray) -> np.ndarray:
    """Polygon diagonals (`_polygon_diagonals`) that are not structural, (K, 2) sorted pairs."""
    da, db = _polygon_diagonals(mesh, vertex_map)
    pairs = _unique_pairs(da, db, n)
    return pairs[~isin_int(_pair_keys(pairs, n), _pair_keys(structural, n))]


def line_graph_pairs(mesh: Mesh, vertex_map: np.ndarray, n: int, structural: np.ndarray) -> np.ndarray:
    """The structural edges the straight-line bending rule walks along, (K, 2) sorted pairs:
    edges of polygons with 4 or more corners and polyline segments (not triangle edges).

    structural: (S, 2) `structural_pairs` of the same mesh, returned as it is when the mesh
    has no triangle (a quad mesh walks along all its edges).
    """
    if not np.any(mesh.face_sizes == 3):
        return structural
    s, e = polygon_edges(mesh, vertex_map)
    larger = np.repeat(mesh.face_sizes >= 4, mesh.face_sizes)
    ls, le = line_edges(mesh, vertex_map)
    return _unique_pairs(np.concatenate([s[larger], ls]), np.concatenate([e[larger], le]), n)


def _straightest_continuations(
    positions: np.ndarray, indptr: np.ndarray, neighbours: np.ndarray, straight_cos: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each vertex v and each neighbour a, the neighbour b of v most opposite to a.

    Returns (v, a, b) triples where b is a's best continuation through v, a is b's best
    continuation too (mutual) and the rest angle a-v-b is at least the straightness threshold;
    each accepted pair is reported once (a < b), ordered by v then by a's place among v's
    neighbours; among equally opposite neighbours the last in order wins. NumPy, one pass over
    all neighbour slots per place in the longest neighbour list, not a compiled loop: it runs once
    per model, and compiling the loop cost every fresh process 0.7 s.
    """
    slots = np.arange(indptr[-1], dtype=np.int64)
    degree = np.diff(indptr)
    owner = np.repeat(np.arange(degree.shape[0], dtype=np.int64), degree)  # each slot's vertex
    centre = positions[owner]
    to_a = positions[neighbours] - centre  # (slots, 3): each slot's edge, as a and as b alike
    length = np.sqrt(to_a[:, 0] * to_a[:, 0] + to_a[:, 1] * to_a[:, 1] + to_a[:, 2] * to_a[:, 2])
    best = np.full(slots.shape[0], -1, dtype=np.int64)
    best_cos = np.full(slots.shape[0], straight_cos)
    first = indptr[owner]
    for place in range(int(degree.max(initial=0))):  # b = the place-th neighbour of a's vertex
        sb = first + place
        live = (place < degree[owner]) & (sb != slots)
        sb = np.where(live, sb, 0)
        denom = length * length[sb]
        live &= denom > 0.0
        dot = to_a[:, 0] * to_a[sb, 0] + to_a[:, 1] * to_a[sb, 1] + to_a[:, 2] * to_a[sb, 2]
        cos = np.divide(dot, denom, out=np.full(slots.shape[0], np.inf), where=live)
        better = live & (cos <= best_cos)
        best_cos[better] = cos[better]
        best[better] = sb[better]
    partner = np.maximum(best, 0)
    mutual = (best >= 0) & (best[partner] == slots) & (neighbours < neighbours[partner])
    accepted = slots[mutual]
    return owner[accepted], neighbours[accepted], neighbours[best[accepted]]


def adjacency(pairs: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """CSR adjacency (indptr, neighbours) of an undirected pair list, neighbours sorted."""
    src = np.concatenate([pairs[:, 0], pairs[:, 1]]).astype(np.int64)
    dst = np.concatenate([pairs[:, 1], pairs[:, 0]]).astype(np.int64)
    order = argsort_int(src * n + dst)
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(src, minlength=n), out=indptr[1:])
    return indptr, dst[order]


def bending_pairs(
    positions: np.ndarray, line_graph: np.ndarray, dihedral: np.ndarray, existing: np.ndarray, n: int
) -> np.ndarray:
    """Bending springs, (K, 2) sorted pairs in lexicographic order: the straightest
    continuations through every vertex over `line_graph` ((E, 2) pairs, `line_graph_pairs`)
    merged with the `dihedral` pairs ((D, 2), `dihedral_pairs`), less the `existing` springs.

    positions: (n, 3) rest positions (m), for the straightness test.
    """
    indptr, neighbours = adjacency(line_graph, n)
    points = np.ascontiguousarray(positions, dtype=np.float64)
    _, a, b = _straightest_continuations(points, indptr, neighbours, STRAIGHT_COS)
    pairs = _unique_pairs(np.concatenate([a, dihedral[:, 0]]), np.concatenate([b, dihedral[:, 1]]), n)
    return pairs[~isin_int(_pair_keys(pairs, n), _pair_keys(existing, n))]


def derive_springs(mesh: Mesh, vertex_map: np.ndarray, positions: np.ndarray) -> Springs:
    """Structural, shear and bending springs over the vertices `vertex_map` maps the mesh's onto.

    positions: (n, 3) rest positions of those n vertices (welded ones, or the mesh's own when
    the map is the identity, as tearing uses it on already-split vertices).
    """
    n = max(int(positions.shape[0]), 1)
    structural = structural_pairs(mesh, vertex_map, n)
    shear = shear_pairs(mesh, vertex_map, n, structural)
    existing = np.concatenate([structural, shear])
    dihedral = dihedral_pairs(mesh, vertex_map, n)
    bending = bending_pairs(positions, line_graph_pairs(mesh, vertex_map, n, structural), dihedral, existing, n)
    pairs = np.concatenate([structural, shear, bending]).astype(np.int32)
    kinds = np.concatenate(
        [
            np.full(structural.shape[0], SpringKind.STRUCTURAL, np.int8),
            np.full(shear.shape[0], SpringKind.SHEAR, np.int8),
            np.full(bending.shape[0], SpringKind.BENDING, np.int8),
        ]
    )
    return Springs(pairs=pairs.reshape(-1, 2), kinds=kinds)


def build_springs(mesh: Mesh, welding: Welding | None = None) -> tuple[Welding, Springs]:
    """Weld the mesh and derive its structural, shear and bending springs (welded indices)."""
    welding = welding or weld(mesh.positions)
    return welding, derive_springs(mesh, welding.vertex_map, mesh.positions[welding.representative])


@dataclass(frozen=True)
class TopologyStats:
    """Counts `meshdeform inspect` reports."""

    welded_vertices: int
    referenced_vertices: int
    pieces: int
    boundary_edges: int
    non_manifold_edges: int


def topology_stats(mesh: Mesh, welding: Welding, springs: Springs) -> TopologyStats:
    """Edge-incidence and connectivity figures over welded vertices."""
    n = max(welding.count, 1)
    s, e = polygon_edges(mesh, welding.vertex_map)
    keep = s != e
    # an edge used twice by the same polygon direction still counts per incidence
    _, per_edge = edge_incidence(s[keep], e[keep], n)
    referenced = np.zeros(welding.count, dtype=bool)
    referenced[welding.vertex_map[mesh.face_indices]] = True
    if mesh.line_count:
        referenced[welding.vertex_map[mesh.line_indices]] = True
    structural = springs.pairs[springs.kinds == SpringKind.STRUCTURAL]
    graph = coo_matrix(
        (np.ones(structural.shape[0]), (structural[:, 0], structural[:, 1])), shape=(welding.count, welding.count)
    )
    _, labels = connected_components(graph, directed=False)
    pieces = int(unique_int(labels[referenced]).shape[0]) if referenced.any() else 0
    return TopologyStats(
        welded_vertices=welding.count,
        referenced_vertices=int(referenced.sum()),
        pieces=pieces,
        boundary_edges=int(np.count_nonzero(per_edge == 1)),
        non_manifold_edges=int(np.count_nonzero(per_edge > 2)),
    )
