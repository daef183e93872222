"""Compiled narrow phase of self-collision: pair filters, proximity projection, the conservative
continuous check and impact zones (see `self_collision` for the method and why it holds).

Pairs come in two kinds, each an (P, 2) int64 array from the broad phase:
- vertex-triangle (VF): (vertex, triangle), the vertex not a corner of the triangle;
- edge-edge (EE): (edge, edge), the edges sharing no vertex.
The continuous check judges every pair but one that touches where the substep starts (within
`TOUCHING`; none does: the substeps keep the pairs apart, and the sides of a tear start parted,
`SelfCollision.part_seams`).
Positions are (V, 3) float64 metres; x0 the start of the substep (intersection free), x the
end. `origin` (V,) maps each vertex to the vertex of the untorn rest mesh it came from, so the
copies a tear makes still count as the same vertex (they start where their original is).
`ring_start`, `ring` are the rest mesh's vertex adjacency (CSR, sorted neighbours, on origins).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from meshdeform.contact.broad_phase import cell_index, dense_cell, query_grown
from meshdeform.contact.primitives import point_triangle_weights, segment_segment_params
from meshdeform.solvers.jit import JIT, opaque

#: pairs whose distance falls to this fraction of its start value within the substep count as
#: colliding (the conservative advancement's stopping rule, Li et al. 2021 "additive CCD")
SEPARATION = 0.1
#: advancement steps per pair before it counts as colliding (conservative: a zone, never a miss)
MAX_ADVANCE_STEPS = 64
#: a pair closer than this (m) where the substep starts touches: it is not judged (two copies of
#: a vertex a tear made lie at one place, their distances rounded to a few 1e-17 m)
TOUCHING = 1e-12


@nb.njit(**JIT)
def _adjacent(ring_start: np.ndarray, ring: np.ndarray, a: int, b: int) -> bool:
    """Whether origin vertices a and b are equal or neighbours in the rest mesh (binary search)."""
    if a == b:
        return True
    lo = ring_start[a]
    hi = ring_start[a + 1]
    while lo < hi:
        mid = (lo + hi) // 2
        if ring[mid] < b:
            lo = mid + 1
        else:
            hi = mid
    return lo < ring_start[a + 1] and ring[lo] == b


@nb.njit(**JIT)
def _vf_gap(x: np.ndarray, v: int, a: int, b: int, c: int) -> tuple[float, float, float, float, float, float, float]:
    """Distance from vertex v to triangle (a, b, c) in x, the closest point's weights and the
    unit direction from that point to v (the face normal towards v when they touch)."""
    wa, wb, wc = point_triangle_weights(x[v, 0], x[v, 1], x[v, 2], x, a, b, c)
    dx = x[v, 0] - (wa * x[a, 0] + wb * x[b, 0] + wc * x[c, 0])
    dy = x[v, 1] - (wa * x[a, 1] + wb * x[b, 1] + wc * x[c, 1])
    dz = x[v, 2] - (wa * x[a, 2] + wb * x[b, 2] + wc * x[c, 2])
    dist = np.sqrt(dx * dx + dy * dy + dz * dz)
    if dist > 1e-300:
        return dist, wa, wb, wc, dx / dist, dy / dist, dz / dist
    return 0.0, wa, wb, wc, 0.0, 0.0, 0.0


@nb.njit(**JIT)
def _face_normal(x: np.ndarray, a: int, b: int, c: int) -> tuple[float, float, float]:
    ux = x[b, 0] - x[a, 0]
    uy = x[b, 1] - x[a, 1]
    uz = x[b, 2] - x[a, 2]
    vx = x[c, 0] - x[a, 0]
    vy = x[c, 1] - x[a, 1]
    vz = x[c, 2] - x[a, 2]
    nx = uy * vz - uz * vy
    ny = uz * vx - ux * vz
    nz = ux * vy - uy * vx
    length = np.sqrt(nx * nx + ny * ny + nz * nz)
    if length > 1e-300:
        return nx / length, ny / length, nz / length
    return 0.0, 0.0, 0.0


@nb.njit(**JIT)
def _ee_gap(x: np.ndarray, p0: int, p1: int, q0: int, q1: int) -> tuple[float, float, float, float, float, float]:
    """Distance between edges (p0, p1) and (q0, q1) in x, the closest points' parameters and the
    unit direction from the q point to the p point."""
    s, t = segment_segment_params(x, p0, p1, x, q0, q1)
    dx = x[p0, 0] + s * (x[p1, 0] - x[p0, 0]) - x[q0, 0] - t * (x[q1, 0] - x[q0, 0])
    dy = x[p0, 1] + s * (x[p1, 1] - x[p0, 1]) - x[q0, 1] - t * (x[q1, 1] - x[q0, 1])
    dz = x[p0, 2] + s * (x[p1, 2] - x[p0, 2]) - x[q0, 2] - t * (x[q1, 2] - x[q0, 2])
    dist = np.sqrt(dx * dx + dy * dy + dz * dz)
    if dist > 1e-300:
        return dist, s, t, dx / dist, dy / dist, dz / dist
    return 0.0, s, t, 0.0, 0.0, 0.0


@nb.njit(**JIT)
def _ball(x: np.ndarray, a: int, b: int, c: int) -> tuple[float, float, float, float]:
    """A ball around the points a, b, c of x: the centre of their bounding box and the largest
    distance of a point from it (m)."""
    cx = 0.5 * (min(x[a, 0], min(x[b, 0], x[c, 0])) + max(x[a, 0], max(x[b, 0], x[c, 0])))
    cy = 0.5 * (min(x[a, 1], min(x[b, 1], x[c, 1])) + max(x[a, 1], max(x[b, 1], x[c, 1])))
    cz = 0.5 * (min(x[a, 2], min(x[b, 2], x[c, 2])) + max(x[a, 2], max(x[b, 2], x[c, 2])))
    radius = 0.0
    for p in (a, b, c):
        dx, dy, dz = x[p, 0] - cx, x[p, 1] - cy, x[p, 2] - cz
        radius = max(radius, np.sqrt(dx * dx + dy * dy + dz * dz))
    return cx, cy, cz, radius


@nb.njit(**JIT)
def _vf_far(x: np.ndarray, v: int, a: int, b: int, c: int, reach: float) -> bool:
    """Whether vertex v is surely further than `reach` (m) from triangle (a, b, c) of x: its
    distance from a ball holding the triangle is (a lower bound of the exact distance, far
    cheaper; kept a hair short of `reach` so that rounding never drops a pair the exact
    distance keeps)."""
    cx, cy, cz, radius = _ball(x, a, b, c)
    dx, dy, dz = x[v, 0] - cx, x[v, 1] - cy, x[v, 2] - cz
    return np.sqrt(dx * dx + dy * dy + dz * dz) - radius > reach * (1.0 + 1e-9) + 1e-12


@nb.njit(**JIT)
def _ee_far(x: np.ndarray, p0: int, p1: int, q0: int, q1: int, reach: float) -> bool:
    """Whether edges (p0, p1) and (q0, q1) of x are surely further apart than `reach` (m): the
    distance of their midpoints less their half lengths is (a lower bound, as `_vf_far`)."""
    dx = 0.5 * (x[p0, 0] + x[p1, 0] - x[q0, 0] - x[q1, 0])
    dy = 0.5 * (x[p0, 1] + x[p1, 1] - x[q0, 1] - x[q1, 1])
    dz = 0.5 * (x[p0, 2] + x[p1, 2] - x[q0, 2] - x[q1, 2])
    ux, uy, uz = x[p1, 0] - x[p0, 0], x[p1, 1] - x[p0, 1], x[p1, 2] - x[p0, 2]
    wx, wy, wz = x[q1, 0] - x[q0, 0], x[q1, 1] - x[q0, 1], x[q1, 2] - x[q0, 2]
    half = 0.5 * (np.sqrt(ux * ux + uy * uy + uz * uz) + np.sqrt(wx * wx + wy * wy + wz * wz))
    return np.sqrt(dx * dx + dy * dy + dz * dz) - half > reach * (1.0 + 1e-9) + 1e-12


@nb.njit(**JIT)
def _apart2(motion: np.ndarray, p: int, q: int) -> float:
    """|motion[p] - motion[q]|^2: how fast (m per substep, squared) points p and q move relative to
    each other (callers take the root of the largest: the same bits as the largest root)."""
    dx = motion[p, 0] - motion[q, 0]
    dy = motion[p, 1] - motion[q, 1]
    dz = motion[p, 2] - motion[q, 2]
    return dx * dx + dy * dy + dz * dz


@nb.njit(**JIT)
def _pair_buffers(size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Room for `size` candidate pairs: the pairs (size, 2) int64, their proximity flags (size,)
    and their rest distances (size,)."""
    return np.empty((size, 2), dtype=np.int64), np.empty(size, dtype=np.bool_), np.empty(size)


@nb.njit(**JIT)
def _grow(
    pairs: np.ndarray, apart: np.ndarray, rest: np.ndarray, count: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The first `count` rows of the three output arrays, in arrays twice as long. Copied element
    by element: a slice assignment compiles Numba's shape-mismatch message (docs/performance.md,
    "Start-up with an empty compile cache")."""
    grown_pairs, grown_apart, grown_rest = _pair_buffers(2 * max(count, 16))
    for k in range(count):
        grown_pairs[k, 0] = pairs[k, 0]
        grown_pairs[k, 1] = pairs[k, 1]
        grown_apart[k] = apart[k]
        grown_rest[k] = rest[k]
    return grown_pairs, grown_apart, grown_rest


@nb.njit(**JIT)
def vf_candidates(
    x: np.ndarray, rest: np.ndarray, queries: np.ndarray, skip: np.ndarray,
    qlo: np.ndarray, qhi: np.ndarray, tlo: np.ndarray, thi: np.ndarray, by_triangle: bool,
    inv_cell: float, start: np.ndarray, element: np.ndarray, cell: np.ndarray, box: np.ndarray,
    triangles: np.ndarray, origin: np.ndarray, ring_start: np.ndarray, ring: np.ndarray,
    motion: np.ndarray, span: float, reach: float, capacity: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The VF pairs to keep for the coming substeps, straight from a grid (`broad_phase.grid_for`)
    of the vertex boxes qlo, qhi (V, 3) or the triangle boxes tlo, thi (T, 3): each of `queries`
    (vertices, or triangles when `by_triangle`) asks the grid of the other kind, and a found
    vertex flagged in `skip` (V,) is passed over (its pairs come from a query of its own). A pair
    is kept when the vertex is no corner of the triangle and their distance in x (V, 3) is within
    `reach` (m) plus `span` substeps of the vertex's motion relative to the triangle's corners
    (`motion` (V, 3), m per substep: how much closer the pair may come while the list holds).
    Returns the pairs (P, 2) (vertex, triangle) by query, then in the grid's order; whether it is
    apart in the rest mesh (its origin neither a corner's origin nor a rest neighbour of one;
    False: rest neighbours, or copies of one vertex that a tear split), (P,) bool; and its
    distance (m) in the rest positions (P,)."""
    pairs, apart, rest_gap = _pair_buffers(max(capacity, 16))
    found = np.empty(64, dtype=np.int64)
    count = opaque(0)  # constants through `opaque`: the callees compile once, for runtime values
    anyone = opaque(-1)
    for k in range(queries.shape[0]):
        q = queries[k]
        if by_triangle:
            n, found = query_grown(tlo, thi, q, qlo, qhi, inv_cell, start, element, cell, box, anyone, found)
        else:
            n, found = query_grown(qlo, qhi, q, tlo, thi, inv_cell, start, element, cell, box, anyone, found)
        for j in range(n):
            v, t = (found[j], q) if by_triangle else (q, found[j])
            a, b, c = triangles[t, 0], triangles[t, 1], triangles[t, 2]
            if skip[v] or v in (a, b, c):
                continue
            # written out here, not in a helper returning the buffers: Numba counts the references
            # of returned arrays on every call (docs/performance.md, "The VF search written out")
            closing = np.sqrt(max(_apart2(motion, v, a), max(_apart2(motion, v, b), _apart2(motion, v, c))))
            limit = reach + span * closing
            if _vf_far(x, v, a, b, c, limit) or _vf_gap(x, v, a, b, c)[0] > limit:
                continue
            if count == pairs.shape[0]:
                pairs, apart, rest_gap = _grow(pairs, apart, rest_gap, count)
            ov = origin[v]
            pairs[count, 0] = v
            pairs[count, 1] = t
            apart[count] = not (
                _adjacent(ring_start, ring, ov, origin[a]) or _adjacent(ring_start, ring, ov, origin[b])
                or _adjacent(ring_start, ring, ov, origin[c])
            )
            rest_gap[count] = _vf_gap(rest, v, a, b, c)[0]
            count += 1
    return pairs[:count], apart[:count], rest_gap[:count]


@nb.njit(**JIT)
def ee_candidates(
    x: np.ndarray, rest: np.ndarray, queries: np.ndarray, fresh: np.ndarray, elo: np.ndarray, ehi: np.ndarray,
    inv_cell: float, start: np.ndarray, element: np.ndarray, cell: np.ndarray, box: np.ndarray,
    edges: np.ndarray, origin: np.ndarray, ring_start: np.ndarray, ring: np.ndarray,
    motion: np.ndarray, span: float, reach: float, every: bool, capacity: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The EE pairs to keep, from the grid of edge boxes elo, ehi (E, 3) asked by each edge of
    `queries`, each pair once (lower edge first): a found edge that is `fresh` (E,) too (itself
    among the queries) pairs only with the lower of the two. `every`: every edge is fresh (some
    query asks for each: the grid then reports the higher edges only). Kept when the edges share no vertex
    and their distance in x is within `reach` plus `span` substeps of the ends' relative motion
    (as `vf_candidates`). Returns the pairs (Q, 2), whether they are apart in the rest mesh
    (no end's origin equal to or a rest neighbour of an end's origin of the other), (Q,) bool, and
    the distance (m) in the rest positions (Q,)."""
    pairs, apart, rest_gap = _pair_buffers(max(capacity, 16))
    found = np.empty(64, dtype=np.int64)
    count = opaque(0)  # a runtime value: `_grow` compiles once (`opaque`)
    for k in range(queries.shape[0]):
        e = queries[k]
        n, found = query_grown(elo, ehi, e, elo, ehi, inv_cell, start, element, cell, box, e if every else -1, found)
        p0, p1 = edges[e, 0], edges[e, 1]
        for j in range(n):
            f = found[j]
            if f == e or (fresh[f] and f < e):
                continue
            q0, q1 = edges[f, 0], edges[f, 1]
            if p0 in (q0, q1) or p1 in (q0, q1):
                continue
            closing = np.sqrt(
                max(
                    max(_apart2(motion, p0, q0), _apart2(motion, p0, q1)),
                    max(_apart2(motion, p1, q0), _apart2(motion, p1, q1)),
                )
            )
            limit = reach + span * closing
            if _ee_far(x, p0, p1, q0, q1, limit) or _ee_gap(x, p0, p1, q0, q1)[0] > limit:
                continue
            if count == pairs.shape[0]:
                pairs, apart, rest_gap = _grow(pairs, apart, rest_gap, count)
            pairs[count, 0] = min(e, f)
            pairs[count, 1] = max(e, f)
            a, b, c, d = origin[p0], origin[p1], origin[q0], origin[q1]
            apart[count] = not (
                _adjacent(ring_start, ring, a, c) or _adjacent(ring_start, ring, a, d)
                or _adjacent(ring_start, ring, b, c) or _adjacent(ring_start, ring, b, d)
            )
            rest_gap[count] = _ee_gap(rest, p0, p1, q0, q1)[0]
            count += 1
    return pairs[:count], apart[:count], rest_gap[:count]


@nb.njit(**JIT)
def ee_candidates_in_cells(
    x: np.ndarray, rest: np.ndarray, buckets: np.ndarray, elo: np.ndarray, ehi: np.ndarray,
    inv_cell: float, start: np.ndarray, element: np.ndarray, cell: np.ndarray, box: np.ndarray,
    edges: np.ndarray, origin: np.ndarray, ring_start: np.ndarray, ring: np.ndarray,
    motion: np.ndarray, span: float, reach: float, capacity: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The EE pairs to keep among all edges, as `ee_candidates` with every edge fresh finds them
    (the same pairs, flags and rest distances), but cell by cell: in each of the grid's `buckets`
    (ascending; `broad_phase.build_grid` of the edge boxes elo, ehi (E, 3)), every two entries of one
    cell whose boxes overlap, each pair once, in the cell holding the lower corner of the boxes'
    overlap. A cell holds a few edges, so pairs of entries are far fewer than the entries each
    query of all edges visits (2x faster on the 40 x 40 sheets of benchmarks/contact.py).
    The buckets' entries are first copied in their order with what the tests of a pair read (box,
    ends, the cell of the box's lower corner), so that the pairs of a cell, 200 000 a search on
    those sheets for a few hundred kept, read consecutive memory (1.2x faster).
    Returns the pairs (Q, 2) (lower edge first) by bucket, then by the entries' order, whether
    they are apart in the rest mesh, (Q,) bool, and its distance (m) in the rest positions (Q,)."""
    pairs, apart, rest_gap = _pair_buffers(max(capacity, 16))
    count = opaque(0)  # a runtime value: `_grow` compiles once (`opaque`)
    dense = box[3] > 0
    # the entries of these buckets, in order: box (lo, hi), ends and the lower corner's cell
    offset = start[buckets[0]] if buckets.shape[0] else 0
    entries = start[buckets[-1] + 1] - offset if buckets.shape[0] else 0
    entry_box = np.empty((entries, 6))
    entry_ends = np.empty((entries, 5), dtype=np.int64)
    for j in range(entries):
        e = element[offset + j]
        for k in range(3):
            entry_box[j, k] = elo[e, k]
            entry_box[j, 3 + k] = ehi[e, k]
            entry_ends[j, 2 + k] = cell_index(elo[e, k], inv_cell)
        entry_ends[j, 0], entry_ends[j, 1] = edges[e, 0], edges[e, 1]
    ix, iy, iz = 0, 0, 0
    for k in range(buckets.shape[0]):
        h = buckets[k]
        first, last = start[h] - offset, start[h + 1] - offset
        if last - first < 2:
            continue
        if dense:  # the bucket's cell, from its place in the dense range
            ix, iy, iz = dense_cell(h, box)
        for s1 in range(first, last):
            e = element[offset + s1]
            if not dense:  # a hashed bucket may hold several cells: pairs within one only
                ix, iy, iz = cell[offset + s1, 0], cell[offset + s1, 1], cell[offset + s1, 2]
            p0, p1 = entry_ends[s1, 0], entry_ends[s1, 1]
            lx, ly, lz = entry_box[s1, 0], entry_box[s1, 1], entry_box[s1, 2]
            hx, hy, hz = entry_box[s1, 3], entry_box[s1, 4], entry_box[s1, 5]
            cx, cy, cz = entry_ends[s1, 2], entry_ends[s1, 3], entry_ends[s1, 4]
            for s2 in range(s1 + 1, last):
                q0, q1 = entry_ends[s2, 0], entry_ends[s2, 1]
                if p0 == q0 or p0 == q1 or p1 == q0 or p1 == q1:  # noqa: SIM109 (a tuple's test is slower here)
                    continue
                if (
                    lx > entry_box[s2, 3] or hx < entry_box[s2, 0] or ly > entry_box[s2, 4]
                    or hy < entry_box[s2, 1] or lz > entry_box[s2, 5] or hz < entry_box[s2, 2]
                ):
                    continue
                t2 = offset + s2
                if not dense and (cell[t2, 0] != ix or cell[t2, 1] != iy or cell[t2, 2] != iz):
                    continue
                # reported in the cell of the overlap's lower corner (floor is monotonic: the
                # larger of the two lower corners' cells)
                if (
                    max(cx, entry_ends[s2, 2]) != ix or max(cy, entry_ends[s2, 3]) != iy
                    or max(cz, entry_ends[s2, 4]) != iz
                ):
                    continue
                f = element[t2]
                # the pair kept as `ee_candidates` keeps it, written out here: a helper returning the
                # buffers made the contact scenes 8-13 % slower (its arrays counted on every call)
                closing = np.sqrt(
                    max(
                        max(_apart2(motion, p0, q0), _apart2(motion, p0, q1)),
                        max(_apart2(motion, p1, q0), _apart2(motion, p1, q1)),
                    )
                )
                limit = reach + span * closing
                if _ee_far(x, p0, p1, q0, q1, limit) or _ee_gap(x, p0, p1, q0, q1)[0] > limit:
                    continue
                if count == pairs.shape[0]:
                    pairs, apart, rest_gap = _grow(pairs, apart, rest_gap, count)
                pairs[count, 0] = min(e, f)
                pairs[count, 1] = max(e, f)
                a, b, c, d = origin[p0], origin[p1], origin[q0], origin[q1]
                apart[count] = not (
                    _adjacent(ring_start, ring, a, c) or _adjacent(ring_start, ring, a, d)
                    or _adjacent(ring_start, ring, b, c) or _adjacent(ring_start, ring, b, d)
                )
                rest_gap[count] = _ee_gap(rest, p0, p1, q0, q1)[0]
                count += 1
    return pairs[:count], apart[:count], rest_gap[:count]


@nb.njit(**JIT)
def merge_kept(
    pairs: np.ndarray,
    apart: np.ndarray,
    rest: np.ndarray,
    lower: np.ndarray,
    dropped: np.ndarray,
    new_pairs: np.ndarray,
    new_apart: np.ndarray,
    new_rest: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A kept list joined with newly searched pairs in one pass: the rows of pairs (P, 2), apart,
    rest and lower (P,) not flagged in `dropped` (P,) (`vf_dropped`, `ee_dropped`: their pairs
    were searched again), in order, then the new rows (N, 2), (N,), (N,) with a lower bound of
    0 (unknown). Returns the four joined arrays (the copies NumPy's masks and concatenations
    made one array at a time were a tenth of a 100 x 100 pile's run)."""
    count = 0
    for k in range(pairs.shape[0]):
        if not dropped[k]:
            count += 1
    total = count + new_pairs.shape[0]
    out_pairs = np.empty((total, 2), dtype=np.int64)
    out_apart = np.empty(total, dtype=np.bool_)
    out_rest = np.empty(total)
    out_lower = np.zeros(total)
    row = 0
    for k in range(pairs.shape[0]):
        if dropped[k]:
            continue
        out_pairs[row, 0] = pairs[k, 0]
        out_pairs[row, 1] = pairs[k, 1]
        out_apart[row] = apart[k]
        out_rest[row] = rest[k]
        out_lower[row] = lower[k]
        row += 1
    for k in range(new_pairs.shape[0]):
        out_pairs[row, 0] = new_pairs[k, 0]
        out_pairs[row, 1] = new_pairs[k, 1]
        out_apart[row] = new_apart[k]
        out_rest[row] = new_rest[k]
        row += 1
    return out_pairs, out_apart, out_rest, out_lower


@nb.njit(**JIT)
def vf_dropped(vf: np.ndarray, stale: np.ndarray, triangle_fresh: np.ndarray) -> np.ndarray:
    """(P,) bool: the VF pairs (vertex, triangle) of vf (P, 2) with a stale vertex (V,) or a
    triangle with a stale corner (T,): their pairs are searched again."""
    out = np.empty(vf.shape[0], dtype=np.bool_)
    for k in range(vf.shape[0]):
        out[k] = stale[vf[k, 0]] or triangle_fresh[vf[k, 1]]
    return out


@nb.njit(**JIT)
def ee_dropped(ee: np.ndarray, edge_fresh: np.ndarray) -> np.ndarray:
    """(Q,) bool: the EE pairs of ee (Q, 2) with an edge that has a stale end (E,)."""
    out = np.empty(ee.shape[0], dtype=np.bool_)
    for k in range(ee.shape[0]):
        out[k] = edge_fresh[ee[k, 0]] or edge_fresh[ee[k, 1]]
    return out


@nb.njit(**JIT)
def _vf_side(x0: np.ndarray, v: int, a: int, b: int, c: int) -> tuple[float, float, float]:
    """The unit direction at the start of the substep from triangle (a, b, c) to vertex v: the
    side the vertex must stay on (the face normal turned towards v, or the offset direction
    when v is off the face)."""
    dist, _, _, _, ox, oy, oz = _vf_gap(x0, v, a, b, c)
    nx, ny, nz = _face_normal(x0, a, b, c)
    along = ox * nx + oy * ny + oz * nz
    if dist > 0.0 and abs(along) < 0.999:  # beside the face: the offset is the side
        return ox, oy, oz
    if along < 0.0:
        return -nx, -ny, -nz
    return nx, ny, nz


@nb.njit(**JIT)
def _tangential(rel: np.ndarray, nx: float, ny: float, nz: float, limit: float) -> float:
    """Remove the normal part of rel (3,) in place; the fraction of the tangential rest to take
    away so that at most `limit` metres of it go (Coulomb: friction times the normal push)."""
    along = rel[0] * nx + rel[1] * ny + rel[2] * nz
    rel[0] -= along * nx
    rel[1] -= along * ny
    rel[2] -= along * nz
    length = np.sqrt(rel[0] * rel[0] + rel[1] * rel[1] + rel[2] * rel[2])
    if length <= 1e-300:
        return 0.0
    return min(1.0, limit / length)


#: a pair is projected in a substep where its distance may have come within this many times its gap
#: (the others' projections move its vertices too: a pair just outside its gap may be pushed in)
ACTIVE_GAPS = 1.25


@nb.njit(**JIT)
def proximity_sides(
    x: np.ndarray,
    x0: np.ndarray,
    triangles: np.ndarray,
    edges: np.ndarray,
    vf: np.ndarray,
    vf_gap: np.ndarray,
    vf_lower: np.ndarray,
    ee: np.ndarray,
    ee_gap: np.ndarray,
    ee_lower: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Which pairs `project_proximity` treats, and the side each keeps: a pair whose distance may
    come within `ACTIVE_GAPS` times its gap (m) (the lower bound at x0, `vf_lower`/`ee_lower` as
    `colliding_pairs` keeps them, less the pair's relative travel to x); the unit direction from
    the triangle to the vertex, or from the second edge to the first, at x0. Returns active_vf
    (P,) bool, side_vf (P, 3), active_ee (Q,), side_ee (Q, 3) (sides of inactive pairs
    undefined). Row by row: `parts.by_rows`."""
    ids = np.empty(4, dtype=np.int64)
    active_vf = np.zeros(vf.shape[0], dtype=np.bool_)
    side_vf = np.empty((vf.shape[0], 3))
    is_vf, is_ee = opaque(True), opaque(False)  # one compile of `_relative_travel`
    for k in range(vf.shape[0]):
        t = vf[k, 1]
        ids[0], ids[1], ids[2], ids[3] = vf[k, 0], triangles[t, 0], triangles[t, 1], triangles[t, 2]
        if vf_lower[k] - _relative_travel(x0, x, ids, is_vf) > ACTIVE_GAPS * vf_gap[k]:
            continue
        active_vf[k] = True
        nx, ny, nz = _vf_side(x0, vf[k, 0], triangles[t, 0], triangles[t, 1], triangles[t, 2])
        side_vf[k, 0], side_vf[k, 1], side_vf[k, 2] = nx, ny, nz
    active_ee = np.zeros(ee.shape[0], dtype=np.bool_)
    side_ee = np.empty((ee.shape[0], 3))
    for k in range(ee.shape[0]):
        e, f = ee[k, 0], ee[k, 1]
        ids[0], ids[1], ids[2], ids[3] = edges[e, 0], edges[e, 1], edges[f, 0], edges[f, 1]
        if ee_lower[k] - _relative_travel(x0, x, ids, is_ee) > ACTIVE_GAPS * ee_gap[k]:
            continue
        active_ee[k] = True
        dist, _, _, dx, dy, dz = _ee_gap(x0, edges[e, 0], edges[e, 1], edges[f, 0], edges[f, 1])
        if dist == 0.0:
            dx, dy, dz = 0.0, 0.0, 1.0
        side_ee[k, 0], side_ee[k, 1], side_ee[k, 2] = dx, dy, dz
    return active_vf, side_vf, active_ee, side_ee


@nb.njit(**JIT)
def project_proximity(
    x: np.ndarray,
    x0: np.ndarray,
    inv_mass: np.ndarray,
    triangles: np.ndarray,
    edges: np.ndarray,
    vf: np.ndarray,
    vf_gap: np.ndarray,
    active_vf: np.ndarray,
    side_vf: np.ndarray,
    ee: np.ndarray,
    ee_gap: np.ndarray,
    active_ee: np.ndarray,
    side_ee: np.ndarray,
    sweeps: int,
    friction: float,
) -> int:
    """Gauss-Seidel sweeps (in pair order) pushing each active pair (`proximity_sides`) apart to
    its gap (m, per pair) along the side it had at the start of the substep, inverse-mass and
    barycentric weighted; x is changed in place. Friction (position-based Coulomb, Macklin et
    al. 2014): the pair's relative tangential travel this substep shrinks by up to `friction`
    times the normal correction. Returns how many pair projections moved something."""
    moved = 0
    rel = np.empty(3)
    for _ in range(sweeps):
        for k in range(vf.shape[0]):
            if not active_vf[k]:
                continue
            v = vf[k, 0]
            t = vf[k, 1]
            a, b, c = triangles[t, 0], triangles[t, 1], triangles[t, 2]
            _, wa, wb, wc, _, _, _ = _vf_gap(x, v, a, b, c)
            nx, ny, nz = side_vf[k, 0], side_vf[k, 1], side_vf[k, 2]
            gap = (
                (x[v, 0] - wa * x[a, 0] - wb * x[b, 0] - wc * x[c, 0]) * nx
                + (x[v, 1] - wa * x[a, 1] - wb * x[b, 1] - wc * x[c, 1]) * ny
                + (x[v, 2] - wa * x[a, 2] - wb * x[b, 2] - wc * x[c, 2]) * nz
            )
            violation = vf_gap[k] - gap
            if violation <= 0.0:
                continue
            denom = inv_mass[v] + wa * wa * inv_mass[a] + wb * wb * inv_mass[b] + wc * wc * inv_mass[c]
            if denom <= 0.0:
                continue
            lam = violation / denom
            share = _lever_share(lam, violation, inv_mass[v], wa * inv_mass[a], wb * inv_mass[b], wc * inv_mass[c])
            lam *= share
            for axis, n in ((0, nx), (1, ny), (2, nz)):
                x[v, axis] += inv_mass[v] * lam * n
                x[a, axis] -= inv_mass[a] * wa * lam * n
                x[b, axis] -= inv_mass[b] * wb * lam * n
                x[c, axis] -= inv_mass[c] * wc * lam * n
            moved += 1
            if friction > 0.0:
                for axis in range(3):
                    rel[axis] = (
                        x[v, axis] - x0[v, axis] - wa * (x[a, axis] - x0[a, axis])
                        - wb * (x[b, axis] - x0[b, axis]) - wc * (x[c, axis] - x0[c, axis])
                    )
                scale = _tangential(rel, nx, ny, nz, friction * violation * share)
                if scale > 0.0:
                    for axis in range(3):
                        shift = scale * rel[axis] / denom
                        x[v, axis] -= inv_mass[v] * shift
                        x[a, axis] += inv_mass[a] * wa * shift
                        x[b, axis] += inv_mass[b] * wb * shift
                        x[c, axis] += inv_mass[c] * wc * shift
        for k in range(ee.shape[0]):
            if not active_ee[k]:
                continue
            e, f = ee[k, 0], ee[k, 1]
            p0, p1, q0, q1 = edges[e, 0], edges[e, 1], edges[f, 0], edges[f, 1]
            _, s, tt, _, _, _ = _ee_gap(x, p0, p1, q0, q1)
            nx, ny, nz = side_ee[k, 0], side_ee[k, 1], side_ee[k, 2]
            gap = 0.0
            for axis, n in ((0, nx), (1, ny), (2, nz)):
                p_point = x[p0, axis] + s * (x[p1, axis] - x[p0, axis])
                gap += (p_point - x[q0, axis] - tt * (x[q1, axis] - x[q0, axis])) * n
            violation = ee_gap[k] - gap
            if violation <= 0.0:
                continue
            w0, w1, w2, w3 = 1.0 - s, s, 1.0 - tt, tt
            denom = (
                w0 * w0 * inv_mass[p0] + w1 * w1 * inv_mass[p1] + w2 * w2 * inv_mass[q0] + w3 * w3 * inv_mass[q1]
            )
            if denom <= 0.0:
                continue
            lam = violation / denom
            share = _lever_share(
                lam, violation, w0 * inv_mass[p0], w1 * inv_mass[p1], w2 * inv_mass[q0], w3 * inv_mass[q1]
            )
            lam *= share
            for axis, n in ((0, nx), (1, ny), (2, nz)):
                x[p0, axis] += inv_mass[p0] * w0 * lam * n
                x[p1, axis] += inv_mass[p1] * w1 * lam * n
                x[q0, axis] -= inv_mass[q0] * w2 * lam * n
                x[q1, axis] -= inv_mass[q1] * w3 * lam * n
            moved += 1
            if friction > 0.0:
                for axis in range(3):
                    rel[axis] = (
                        w0 * (x[p0, axis] - x0[p0, axis]) + w1 * (x[p1, axis] - x0[p1, axis])
                        - w2 * (x[q0, axis] - x0[q0, axis]) - w3 * (x[q1, axis] - x0[q1, axis])
                    )
                scale = _tangential(rel, nx, ny, nz, friction * violation * share)
                if scale > 0.0:
                    for axis in range(3):
                        shift = scale * rel[axis] / denom
                        x[p0, axis] -= inv_mass[p0] * w0 * shift
                        x[p1, axis] -= inv_mass[p1] * w1 * shift
                        x[q0, axis] += inv_mass[q0] * w2 * shift
                        x[q1, axis] += inv_mass[q1] * w3 * shift
    return moved


@nb.njit(**JIT)
def _lever_share(lam: float, violation: float, m0: float, m1: float, m2: float, m3: float) -> float:
    """The share of a pair projection's multiplier lam that moves no vertex farther than the
    violation (m), vertex k moving m_k lam (its weight times its inverse mass): 1 where none
    would. With every vertex free none does; where the only free one has a small weight in the
    pair (an edge's end at a barycentric weight near 0, the others pinned or held) it would move
    as a long lever, violation / weight (a collapsing sheet under the anchor solver was thrown to
    1e14 m). Capped, such a pair closes its gap over the sweeps and substeps, its friction scaled
    alike, and the continuous check keeps it from crossing meanwhile."""
    reach = lam * max(max(m0, m1), max(m2, m3))
    return violation / reach if reach > violation else 1.0


@nb.njit(**JIT)
def _relative_travel(x0: np.ndarray, x1: np.ndarray, ids: np.ndarray, is_vf: bool) -> float:
    """A bound (m) on how much the distance of a pair (vertices `ids`, see `_advance`) can
    shrink moving linearly from x0 to x1: the largest travel of each side beyond the four
    vertices' mean travel, summed (a common translation changes no distance)."""
    mx = 0.0
    my = 0.0
    mz = 0.0
    for i in range(4):
        mx += 0.25 * (x1[ids[i], 0] - x0[ids[i], 0])
        my += 0.25 * (x1[ids[i], 1] - x0[ids[i], 1])
        mz += 0.25 * (x1[ids[i], 2] - x0[ids[i], 2])
    first = 0.0  # the vertex (VF) or the first edge's largest travel relative to the mean
    second = 0.0  # the triangle's or the second edge's
    for i in range(4):
        dx = x1[ids[i], 0] - x0[ids[i], 0] - mx
        dy = x1[ids[i], 1] - x0[ids[i], 1] - my
        dz = x1[ids[i], 2] - x0[ids[i], 2] - mz
        travel = np.sqrt(dx * dx + dy * dy + dz * dz)
        if i == 0 or (i == 1 and not is_vf):
            first = max(first, travel)
        else:
            second = max(second, travel)
    bound = first + second
    return bound


@nb.njit(**JIT)
def _advance(
    x0: np.ndarray,
    x1: np.ndarray,
    ids: np.ndarray,
    is_vf: bool,
    buf: np.ndarray,
    bound: float,
) -> tuple[bool, float]:
    """Conservative advancement of one pair (its four vertices `ids`, VF: vertex then triangle;
    EE: edge then edge) from x0 to x1: True when its distance may fall below SEPARATION times
    its start value within the substep (a collision), False when it provably stays above.
    A pair that touches at x0 (within `TOUCHING`) is not judged: no advancement can prove it
    apart (none does where the substeps keep the pairs apart and the sides of a tear start
    parted).

    `bound`: the pair's `_relative_travel`. Returns the verdict and a lower bound of the
    distance at x1 (the start distance less the travel)."""
    for i in range(4):
        for axis in range(3):
            buf[i, axis] = x0[ids[i], axis]
    # the rows of buf through `opaque`: the gap kernels compile once, for runtime indices
    r0, r1, r2, r3 = opaque(0), opaque(1), opaque(2), opaque(3)
    start = _vf_gap(buf, r0, r1, r2, r3)[0] if is_vf else _ee_gap(buf, r0, r1, r2, r3)[0]
    after = max(start - bound, 0.0)
    if bound <= 0.0:  # moving as one
        return False, after
    if start <= TOUCHING:
        return False, 0.0
    floor = SEPARATION * start
    t = 0.0
    dist = start
    for _ in range(MAX_ADVANCE_STEPS):
        step = (1.0 - SEPARATION) * dist / bound
        if t + step >= 1.0:
            return False, after
        t += step
        for i in range(4):
            for axis in range(3):
                buf[i, axis] = x0[ids[i], axis] + t * (x1[ids[i], axis] - x0[ids[i], axis])
        dist = _vf_gap(buf, r0, r1, r2, r3)[0] if is_vf else _ee_gap(buf, r0, r1, r2, r3)[0]
        if dist < floor:
            return True, 0.0
    return True, 0.0


@nb.njit(**JIT)
def colliding_pairs(
    x0: np.ndarray,
    x1: np.ndarray,
    triangles: np.ndarray,
    edges: np.ndarray,
    vf: np.ndarray,
    vf_lower: np.ndarray,
    ee: np.ndarray,
    ee_lower: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Masks (P,), (Q,) of the VF and EE pairs that may come into contact moving linearly from x0
    to x1 (conservative: no pair that touches is missed). vf_lower (P,), ee_lower (Q,): lower
    bounds (m) of the pairs' distances at x0, replaced in place by lower bounds at x1 (so the
    next substep skips the pairs that stay clear). Row by row: `parts.by_rows`."""
    buf = np.empty((4, 3))
    ids = np.empty(4, dtype=np.int64)
    is_vf, is_ee = opaque(True), opaque(False)  # one compile of the callees, not one per constant
    hit_vf = np.zeros(vf.shape[0], dtype=np.bool_)
    for k in range(vf.shape[0]):
        t = vf[k, 1]
        ids[0] = vf[k, 0]
        ids[1] = triangles[t, 0]
        ids[2] = triangles[t, 1]
        ids[3] = triangles[t, 2]
        bound = _relative_travel(x0, x1, ids, is_vf)
        if bound <= (1.0 - SEPARATION) * vf_lower[k]:  # provably safe: it cannot close the known gap
            vf_lower[k] -= bound
        else:
            hit_vf[k], vf_lower[k] = _advance(x0, x1, ids, is_vf, buf, bound)
    hit_ee = np.zeros(ee.shape[0], dtype=np.bool_)
    for k in range(ee.shape[0]):
        ids[0] = edges[ee[k, 0], 0]
        ids[1] = edges[ee[k, 0], 1]
        ids[2] = edges[ee[k, 1], 0]
        ids[3] = edges[ee[k, 1], 1]
        bound = _relative_travel(x0, x1, ids, is_ee)
        if bound <= (1.0 - SEPARATION) * ee_lower[k]:
            ee_lower[k] -= bound
        else:
            hit_ee[k], ee_lower[k] = _advance(x0, x1, ids, is_ee, buf, bound)
    return hit_vf, hit_ee


@nb.njit(**JIT)
def _root(parent: np.ndarray, i: int) -> int:
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@nb.njit(**JIT)
def _join(parent: np.ndarray, a: int, b: int) -> None:
    ra = _root(parent, a)
    rb = _root(parent, b)
    if ra != rb:  # the smaller index becomes the root: the result does not depend on pair order
        if ra < rb:
            parent[rb] = ra
        else:
            parent[ra] = rb


@nb.njit(**JIT)
def merge_zones(
    parent: np.ndarray,
    in_zone: np.ndarray,
    triangles: np.ndarray,
    edges: np.ndarray,
    vf: np.ndarray,
    hit_vf: np.ndarray,
    ee: np.ndarray,
    hit_ee: np.ndarray,
) -> None:
    """Join the four vertices of every colliding pair into one impact zone (union-find over
    vertices: parent (V,), in_zone (V,) marks zone members)."""
    for k in range(vf.shape[0]):
        if hit_vf[k]:
            v = vf[k, 0]
            t = vf[k, 1]
            in_zone[v] = True
            for j in range(3):
                in_zone[triangles[t, j]] = True
                _join(parent, v, triangles[t, j])
    for k in range(ee.shape[0]):
        if hit_ee[k]:
            a, b = edges[ee[k, 0], 0], edges[ee[k, 0], 1]
            c, d = edges[ee[k, 1], 0], edges[ee[k, 1], 1]
            for u in (a, b, c, d):
                in_zone[u] = True
            _join(parent, a, b)
            _join(parent, a, c)
            _join(parent, a, d)


@nb.njit(**JIT)
def move_zones(
    x: np.ndarray,
    x0: np.ndarray,
    inv_mass: np.ndarray,
    parent: np.ndarray,
    in_zone: np.ndarray,
    translate: bool,
    driven: np.ndarray,
    drive: np.ndarray,
) -> int:
    """Give every impact zone one translation, x = x0 + the mass-weighted mean displacement of its
    free members (or the mean displacement of its pinned members, which cannot be moved, or else
    of its `driven` (V,) members, `drive` (V, 3): where a moving collider carries them): a
    translation keeps every distance inside the zone, so no pair within it can meet. Without
    `translate` a zone without pinned or driven members stays at x0 (no displacement at all).
    Returns the number of vertices in zones."""
    n = x.shape[0]
    mass = np.zeros(n)
    pinned = np.zeros(n)
    moved = np.zeros((n, 3))
    pinned_moved = np.zeros((n, 3))
    carried = np.zeros(n)
    carried_moved = np.zeros((n, 3))
    members = 0
    for i in range(n):
        if not in_zone[i]:
            continue
        members += 1
        r = _root(parent, i)
        if inv_mass[i] > 0.0:
            m = 1.0 / inv_mass[i]
            mass[r] += m
            for axis in range(3):
                moved[r, axis] += m * (x[i, axis] - x0[i, axis])
            if driven[i]:
                carried[r] += 1.0
                for axis in range(3):
                    carried_moved[r, axis] += drive[i, axis]
        else:
            pinned[r] += 1.0
            for axis in range(3):
                pinned_moved[r, axis] += x[i, axis] - x0[i, axis]
    for i in range(n):
        if not in_zone[i] or inv_mass[i] <= 0.0:
            continue
        r = _root(parent, i)
        for axis in range(3):
            if pinned[r] > 0.0:
                shift = pinned_moved[r, axis] / pinned[r]
            elif carried[r] > 0.0:
                shift = carried_moved[r, axis] / carried[r]
            else:
                shift = moved[r, axis] / mass[r] if translate else 0.0
            x[i, axis] = x0[i, axis] + shift
    return members
