"""Spring order for the solvers' kernels: slabs that can be swept in parallel, sorted for locality.

Vertices are split into P slabs of equal count along the rest shape's longest axis. A spring
whose two ends lie in the same slab belongs to that slab; the few that cross slabs form a
separator. Slabs share no vertex, so Gauss-Seidel sweeps over them give the same result one
after another (the serial build, the default) or one thread each without locks (the parallel
build, where it is faster: `dispatch`); the separator is swept after them. P decides the result, and
depends only on the option and the model (never on the thread count or the build), so results
are byte-identical on any machine and in any worker.

Inside a slab, springs are sorted by their rest distance from the nearest pin (so a forward
sweep carries the pins' hold across the whole cloth in one pass, and the alternating backward
sweep carries the load back), or by their first vertex when nothing is pinned. That order is
then *levelled*: each spring's level is one more than the highest level of the earlier springs
sharing one of its vertices, and springs are stably re-sorted by level. Springs of one level
share no vertex, so a Gauss-Seidel sweep in level order gives bit for bit the result of the
sweep in the sorted order (and the reversed level order that of the reversed sweep), while
consecutive springs no longer wait for each other's results: the CPU overlaps several spring
projections instead of one long chain of dependent loads and stores (docs/performance.md). Levels
are formed within blocks of `LEVEL_BLOCK` consecutive springs of the sorted order (every level
of a block above every level of the blocks before it), so a block is swept while its vertices
are still in cache; the sweep's result is again bit for bit that of the sorted order.

Vertices are renumbered for the kernels in the order the sweep first touches them
(`vertex_order`), so the gathered vertices of consecutive springs sit close in memory.
Works for any spring list (no grid assumption).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from meshdeform.arrays import dense_rank, lexsort_int
from meshdeform.model import SpringModel
from meshdeform.solvers.layout_kernels import first_touch, inherit_order, sweep_levels

#: spring ends in kernel vertex numbering
ENDS = np.dtype([("a", "u4"), ("b", "u4")], align=True)


@dataclass(frozen=True, eq=False)
class SpringLayout:
    """Springs of a model reordered: `order` (S,) indexes the model's spring arrays.

    a, b: (S,) int64 end vertices in the new order; rest: (S,) rest lengths;
    offsets: (P + 2,) slab p is order[offsets[p]:offsets[p + 1]], the separator is
    order[offsets[P]:offsets[P + 1]]. vertex_order: (W,) kernel vertex k -> model vertex, in
    the order the sweep first touches them; vertex_rank: its inverse; ends: (S,) `ENDS`
    records, the springs' ends (a, b) in kernel numbering.
    """

    order: np.ndarray
    a: np.ndarray
    b: np.ndarray
    rest: np.ndarray
    offsets: np.ndarray
    parts: int
    vertex_order: np.ndarray
    vertex_rank: np.ndarray
    ends: np.ndarray

    def take(self, per_spring: np.ndarray) -> np.ndarray:
        """A per-spring model array in this layout's order (contiguous float64)."""
        return np.ascontiguousarray(np.asarray(per_spring, dtype=np.float64)[self.order])


#: springs per levelled block (see the module docstring): a block's springs (512 KB of records) and
#: the vertices they touch stay in a core's L2 cache (1 MB on the machine it was tuned on) while
#: they are swept; levelling the whole slab at once spreads a level over the whole slab (slower
#: sweeps on large cloths: docs/performance.md)
LEVEL_BLOCK = 8192

#: springs from which `partitions = 0` (auto) makes two slabs; below it one parallel sweep
#: would cost more in launches and separator than it saves
AUTO_PARALLEL_SPRINGS = 4096


def resolve_parts(parts: int, springs: int) -> int:
    """Slab count: the option, or for 0 (auto) 2 from AUTO_PARALLEL_SPRINGS springs up, else 1.

    Depends only on the option and the spring count, never on the thread count, so a model
    gets the same spring order (and bit for bit the same results) on every machine and in a
    worker with one Numba thread as in the main process.
    """
    if parts > 0:
        return int(parts)
    return 2 if springs >= AUTO_PARALLEL_SPRINGS else 1


@dataclass(frozen=True, eq=False)
class KernelChunks:
    """Per-thread work of a parallel substep (uint64 bounds, one chunk per slab).

    vertices: vertex ranges, of model vertices where the State (model order) is read or
    written, of kernel vertices where the scratch is worked on between substeps; tethers: the
    tethers of each kernel vertex range (tethers are sorted by kernel vertex), so the thread
    that predicts a vertex also applies that vertex's tethers and no two threads touch one vertex.
    """

    vertices: np.ndarray
    tethers: np.ndarray


def chunk_bounds(count: int, parts: int) -> np.ndarray:
    """(parts + 1,) uint64 bounds splitting 0..count-1 into `parts` near-equal ranges."""
    return (np.arange(parts + 1, dtype=np.uint64) * np.uint64(count)) // np.uint64(max(parts, 1))


def kernel_chunks(layout: SpringLayout, tether_vertices: np.ndarray) -> KernelChunks:
    """Vertex and tether chunks, one of each per slab (see `KernelChunks`)."""
    vertices = chunk_bounds(layout.vertex_order.shape[0], layout.parts)
    tethers = np.searchsorted(np.asarray(tether_vertices, dtype=np.int64), vertices.astype(np.int64), side="left")
    return KernelChunks(vertices=vertices, tethers=tethers.astype(np.uint64))


def pin_distance(model: SpringModel) -> np.ndarray | None:
    """Rest distance along structural springs from every vertex to the nearest pin (None: no pins).

    Vertices not connected to any pin get a distance beyond every connected one.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    from meshdeform.topology import SpringKind

    pins = np.flatnonzero(model.pinned)
    n = model.vertex_count
    if pins.size == 0 or n == 0:
        return None
    structural = np.asarray(model.kinds) == SpringKind.STRUCTURAL
    pairs = np.asarray(model.springs)[structural]
    length = np.maximum(np.asarray(model.rest_lengths)[structural], 1e-12)
    graph = coo_matrix((length, (pairs[:, 0], pairs[:, 1])), shape=(n, n)).tocsr()
    dist = dijkstra(graph, directed=False, indices=pins, min_only=True)
    finite = np.isfinite(dist)
    top = float(dist[finite].max()) if finite.any() else 0.0
    return np.where(finite, dist, 2.0 * top + 1.0)


def vertex_slabs(rest_positions: np.ndarray, parts: int) -> np.ndarray:
    """(V,) int64: each vertex's slab of `parts` slabs of equal count along the longest axis of the
    rest positions (V, 3), ties in vertex order (the same slabs on any machine)."""
    n = rest_positions.shape[0]
    axis = int(np.argmax(rest_positions.max(axis=0) - rest_positions.min(axis=0))) if n else 0
    rank = np.empty(n, dtype=np.int64)
    rank[np.argsort(rest_positions[:, axis], kind="stable")] = np.arange(n)
    return rank * parts // max(n, 1)


def spring_layout(model: SpringModel, parts: int, mask: np.ndarray | None = None) -> SpringLayout:
    """Partitioned, locality-sorted order of the model's springs (or of those in `mask`)."""
    springs = np.asarray(model.springs, dtype=np.int64)
    index = np.arange(springs.shape[0], dtype=np.int64) if mask is None else np.flatnonzero(mask)
    parts = resolve_parts(parts, index.shape[0])
    a = springs[index, 0]
    b = springs[index, 1]
    n = max(model.vertex_count, 1)
    if parts > 1 and model.vertex_count >= 64 * parts:
        slab = vertex_slabs(model.rest_positions, parts)
        sa, sb = slab[a], slab[b]
        group = np.where(sa == sb, sa, parts)
    else:
        parts = 1
        group = np.zeros(a.shape[0], dtype=np.int64)
    lo = np.minimum(a, b)
    hi = np.maximum(a, b)
    dist = pin_distance(model)
    if dist is not None:
        # from the pins outward: a forward sweep carries a pin's hold all the way in one pass
        rank = dense_rank(dist)  # orders and ties exactly as the distances do
        order_local = lexsort_int((hi, lo, np.minimum(rank[a], rank[b]), group))
    else:
        order_local = lexsort_int((hi, lo, group))
    # level the sorted order (same sweep result, independent neighbours): see the module docstring
    level = sweep_levels(a[order_local], b[order_local], n, LEVEL_BLOCK)
    sorted_group = group[order_local]
    order_local = order_local[lexsort_int((hi[order_local], lo[order_local], level, sorted_group))]
    order = index[order_local]
    counts = np.bincount(group, minlength=parts + 1)
    offsets = np.zeros(parts + 2, dtype=np.int64)
    np.cumsum(counts, out=offsets[1:])
    vertex_order = first_touch(springs[order, 0], springs[order, 1], model.vertex_count)
    vertex_rank = np.empty_like(vertex_order)
    vertex_rank[vertex_order] = np.arange(vertex_order.shape[0], dtype=np.int64)
    return _assemble(model, order, offsets, parts, vertex_order, vertex_rank)


def _assemble(
    model: SpringModel, order: np.ndarray, offsets: np.ndarray, parts: int, vertex_order: np.ndarray,
    vertex_rank: np.ndarray,
) -> SpringLayout:
    """A SpringLayout of the model's springs in `order`, with the per-spring arrays taken in that order."""
    springs = np.asarray(model.springs)
    oa = springs[order, 0].astype(np.int64)
    ob = springs[order, 1].astype(np.int64)
    ends = np.zeros(order.shape[0], dtype=ENDS)
    ends["a"] = vertex_rank[oa]
    ends["b"] = vertex_rank[ob]
    return SpringLayout(
        order=order,
        a=oa,
        b=ob,
        rest=np.ascontiguousarray(np.asarray(model.rest_lengths, dtype=np.float64)[order]),
        offsets=offsets,
        parts=parts,
        vertex_order=vertex_order,
        vertex_rank=vertex_rank,
        ends=ends,
    )


def inherited_layout(
    previous: SpringLayout, model: SpringModel, index_map: np.ndarray, parent: np.ndarray
) -> SpringLayout | None:
    """The layout of a torn model derived from its predecessor's, without sorting afresh.

    Tearing removes springs and moves spring ends to copies of split vertices (appended after the
    kept ones, `index_map` new vertex -> previous vertex); every new spring descends from one
    previous spring (`parent`) and joins the same two vertices or their copies. So each spring
    takes its parent's place in the order and slab (copies of a slab's vertex stay in that slab:
    slabs still share no vertex), kept vertices keep their kernel numbers and copies are
    appended: linear in the springs, with no sort (docs/performance.md compares it with a fresh
    layout). None when the model does not descend from `previous` that way (then the caller builds
    a fresh layout).
    """
    n_old = previous.vertex_order.shape[0]
    n = model.vertex_count
    index_map = np.asarray(index_map, dtype=np.int64)
    springs = np.asarray(model.springs)
    if index_map.shape[0] != n or n < n_old or not np.array_equal(index_map[:n_old], np.arange(n_old)):
        return None
    order, key = inherit_order(
        previous.order, previous.a, previous.b, np.asarray(parent, dtype=np.int64), springs, index_map
    )
    if order.shape[0] != springs.shape[0]:
        return None
    offsets = np.searchsorted(key[order], previous.offsets, side="left").astype(np.int64)
    vertex_order = np.concatenate([previous.vertex_order, np.arange(n_old, n, dtype=np.int64)])
    vertex_rank = np.concatenate([previous.vertex_rank, np.arange(n_old, n, dtype=np.int64)])
    return _assemble(model, order, offsets, previous.parts, vertex_order, vertex_rank)


@dataclass(frozen=True, eq=False)
class Tethers:
    """Long range attachments (Kim, Tang, Mueller 2012): vertex -> pins along the mesh.

    vertex, pin: (T,) int64; limit: (T,) the rest geodesic distance (over structural springs)
    times the allowed ratio; |x_vertex - x_pin| is kept at or below it; group: (T,) int64 the
    pin group the pin belongs to (a vertex has at most one tether per group).
    """

    vertex: np.ndarray
    pin: np.ndarray
    limit: np.ndarray
    group: np.ndarray


#: the spring kinds tether paths run along unless told (`tethers`): structural
TETHER_PATH_KINDS = (0,)


def tethers(
    model: SpringModel, ratio: float, groups: int = 4, kinds: tuple[int, ...] = TETHER_PATH_KINDS
) -> Tethers:
    """Tethers from every free vertex to the nearest pin of each of its `groups` nearest pin groups.

    A pin group is a connected set of pinned vertices (a pinned corner, a pinned edge), so a
    cloth held at two corners gets two tethers per vertex, one held along an edge one.
    Distances run along springs of `kinds` (default structural only: on a grid the Manhattan
    distance, which lets a vertex diagonal from a pin stretch up to 41 % before its tether
    acts; with shear springs too it is the octile distance, within 8 % of the straight line).
    Every path is at least the straight rest distance, so the rest shape never violates a tether.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components, dijkstra

    from meshdeform.topology import SpringKind

    pinned = np.asarray(model.pinned)
    pins = np.flatnonzero(pinned)
    n = model.vertex_count
    if pins.size == 0 or n == 0:
        return Tethers(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros(0, np.int64))
    structural = np.asarray(model.kinds) == SpringKind.STRUCTURAL
    pairs = np.asarray(model.springs)[structural]
    along = np.isin(np.asarray(model.kinds), np.asarray(kinds, dtype=np.int64))
    ends = np.asarray(model.springs)[along]
    length = np.maximum(np.asarray(model.rest_lengths)[along], 1e-12)
    graph = coo_matrix((length, (ends[:, 0], ends[:, 1])), shape=(n, n)).tocsr()
    both = pinned[pairs[:, 0]] & pinned[pairs[:, 1]]
    pin_graph = coo_matrix(
        (np.ones(int(both.sum())), (pairs[both, 0], pairs[both, 1])), shape=(n, n)
    ).tocsr()[pins][:, pins]
    count, label = connected_components(pin_graph, directed=False)
    dists = np.full((count, n), np.inf)
    sources = np.full((count, n), -1, dtype=np.int64)
    for g in range(count):
        d, _, src = dijkstra(graph, directed=False, indices=pins[label == g], min_only=True, return_predecessors=True)
        dists[g] = d
        sources[g] = src
    if count > groups:
        # keep each vertex's `groups` nearest groups
        cut = np.partition(dists, groups - 1, axis=0)[groups - 1]
        dists = np.where(dists <= cut[None, :], dists, np.inf)
    keep = np.isfinite(dists) & ~pinned[None, :] & (sources >= 0)
    g_idx, vertex = np.nonzero(keep)
    order = np.argsort(vertex, kind="stable")
    g_idx, vertex = g_idx[order], vertex[order]
    return Tethers(
        vertex=vertex.astype(np.int64),
        pin=sources[g_idx, vertex].astype(np.int64),
        limit=np.ascontiguousarray(dists[g_idx, vertex] * float(ratio)),
        group=g_idx.astype(np.int64),
    )
