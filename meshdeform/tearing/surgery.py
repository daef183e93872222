"""Mesh surgery: split vertices by regrouping their polygon corners, and rebuild the model.

Splitting (vectorised, run only on the substeps where something breaks): the polygon corners
around each vertex to split are grouped by connected components (scipy) of "the two polygons
share an edge at this vertex and lie on the same side"; the group holding the lowest corner
keeps the vertex index, every other group becomes a new simulation vertex appended at the end,
ordered by (vertex, lowest corner), so the same input always tears the same way. No face ever
spans a tear and no face is re-meshed: the faces stay, only their corners move to copies.

Rebuilding: masses are redistributed by incident rest area (the total is kept); springs are
rebuilt from the split polygons with `meshdeform.topology` (structural, shear, bending, without
welding: split copies coincide) and only springs that descend from a spring of the previous
model are kept, with its rest length, stiffness and damping; shear and bending springs whose
ends the crack separates disappear with the shared edges. A failing structural spring itself
survives on the far side (between the copy and the other end): the material that failed is the
one around the vertex, and every polygon edge keeps its spring. Only the neighbourhood of the
split vertices is re-derived (three rings of polygons), apart from a few O(springs) array
copies. The result is a new, frozen `SpringModel` plus each new spring's parent, as DESIGN.md
section 1 asks.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from meshdeform.arrays import argsort_int, lexsort_int, run_lengths, unique_int
from meshdeform.mesh import Mesh
from meshdeform.model import SpringModel, _frozen, lumped_area
from meshdeform.tearing.corners import Corners
from meshdeform.topology import SpringKind, derive_springs


def _edge_runs(cv: np.ndarray, nxt: np.ndarray, n: int, mask: np.ndarray | None = None):
    """Half-edges (corner h: edge cv[h] -> cv[nxt[h]]) grouped by undirected edge.

    Returns (half-edges sorted by edge key, run starts, run lengths, lo, hi) over the half-edges
    selected by `mask` (all when None); degenerate edges (lo == hi) are left out.
    """
    a = cv
    b = cv[nxt]
    keep = a != b
    if mask is not None:
        keep &= mask
    h = np.flatnonzero(keep)
    lo = np.minimum(a[h], b[h])
    hi = np.maximum(a[h], b[h])
    order = argsort_int(lo * n + hi)
    h = h[order]
    keys = (lo * n + hi)[order]
    starts, lengths = run_lengths(keys)
    return h, starts, lengths, lo[order], hi[order]


def split_vertices(
    cv: np.ndarray, nxt: np.ndarray, n: int, split: np.ndarray, side: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Split the vertices in `split` ((n,) bool) by the side labels of their corners.

    Two corners at a split vertex stay together when their polygons share an edge at it and
    their `side` ((C,) int) is the same; each connected group of corners becomes one vertex.
    Returns (new corner -> vertex (C,), index_map (n',) new vertex -> old vertex), where the
    group holding the lowest corner keeps the old index and the others are appended, ordered
    by (old vertex, lowest corner).
    """
    at_split = split[cv]
    corners = np.flatnonzero(at_split)
    if corners.size == 0:
        return cv, np.arange(n, dtype=np.int64)
    node = np.full(cv.shape[0], -1, dtype=np.int64)
    node[corners] = np.arange(corners.shape[0], dtype=np.int64)
    # half-edges touching a split vertex, grouped by edge: consecutive ones in a run are twins
    touch = at_split | at_split[nxt]
    h, starts, lengths, lo, hi = _edge_runs(cv, nxt, n, touch)
    links_a: list[np.ndarray] = []
    links_b: list[np.ndarray] = []
    multi = lengths >= 2
    if multi.any():
        # pair each half-edge with the next one of the same edge (chain over the run)
        in_run = np.ones(h.shape[0], dtype=bool)
        in_run[starts] = False  # a run's first half-edge has no predecessor
        second = np.flatnonzero(in_run)
        h1 = h[second - 1]
        h2 = h[second]
        for vert_of in (lo[second], hi[second]):
            # the corner of each half-edge at this end vertex
            c1 = np.where(cv[h1] == vert_of, h1, nxt[h1])
            c2 = np.where(cv[h2] == vert_of, h2, nxt[h2])
            ok = split[vert_of] & (side[c1] == side[c2])
            links_a.append(node[c1[ok]])
            links_b.append(node[c2[ok]])
    la = np.concatenate(links_a) if links_a else np.zeros(0, dtype=np.int64)
    lb = np.concatenate(links_b) if links_b else np.zeros(0, dtype=np.int64)
    m = corners.shape[0]
    graph = coo_matrix((np.ones(la.shape[0], dtype=np.int8), (la, lb)), shape=(m, m))
    ncomp, label = connected_components(graph, directed=False)
    # lowest corner of each component (corners are sorted, so the first occurrence)
    first = np.full(ncomp, m, dtype=np.int64)
    rev = np.arange(m - 1, -1, -1)
    first[label[rev]] = rev
    comp_corner = corners[first]
    comp_vertex = cv[comp_corner]
    order = lexsort_int((comp_corner, comp_vertex))
    sv = comp_vertex[order]
    is_first = np.ones(ncomp, dtype=bool)
    is_first[1:] = sv[1:] != sv[:-1]
    new_of_comp = np.empty(ncomp, dtype=np.int64)
    extra = np.flatnonzero(~is_first)
    new_of_comp[order[is_first]] = sv[is_first]
    new_of_comp[order[extra]] = n + np.arange(extra.shape[0], dtype=np.int64)
    out = cv.copy()
    out[corners] = new_of_comp[label]
    index_map = np.concatenate([np.arange(n, dtype=np.int64), sv[extra]])
    return out, index_map


def mesh_pieces(model: SpringModel, referenced: np.ndarray | None = None) -> int:
    """Connected pieces of a model: components of its structural springs among the vertices
    that polygons or polylines use (`referenced` (W,) bool; default every vertex)."""
    n = model.vertex_count
    if n == 0:
        return 0
    s = np.asarray(model.springs)[np.asarray(model.kinds) == SpringKind.STRUCTURAL]
    graph = coo_matrix((np.ones(s.shape[0], dtype=np.int8), (s[:, 0], s[:, 1])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    if referenced is not None:
        labels = labels[referenced]
    return int(unique_int(labels).shape[0]) if labels.size else 0


def rebuild(
    old: SpringModel,
    corners: Corners,
    cv: np.ndarray,
    index_map: np.ndarray,
    remove: np.ndarray,
    line_vertices: np.ndarray,
    line_offsets: np.ndarray,
) -> tuple[SpringModel, np.ndarray]:
    """The model of the split topology and each new spring's parent (old spring index).

    cv: (C,) corner -> new vertex after the split; index_map: (W',) new vertex -> old vertex;
    remove: old springs that go (failed shear and bending springs); line_vertices, line_offsets:
    the polylines (CSR) on old simulation vertices. The model keeps `old`'s vertex_map and
    representative: the output layout sets them.

    Only the neighbourhood of the split vertices is re-derived: springs with an end at a split
    vertex (or its copies) or with both ends within one ring of them are rebuilt from the
    polygons around them (three rings, so bending springs see every neighbour of their middle
    vertex), and kept only where they descend from an old spring; every other spring stays.
    """
    n_old = old.vertex_count
    n = index_map.shape[0]
    old_pairs = np.asarray(old.springs)  # int32, read-only
    removed = np.zeros(old.spring_count, dtype=bool)
    removed[remove] = True
    if n == n_old:
        parent = np.flatnonzero(~removed)
        new_pairs = old_pairs[parent]
        mass = np.asarray(old.mass)
        triangles = np.asarray(old.triangles)
    else:
        split = np.zeros(n, dtype=bool)
        split[n_old:] = True
        split[index_map[n_old:]] = True
        ring1 = corners.vertices_of(cv, corners.faces_touching(cv, split), n) | split
        ring2 = corners.vertices_of(cv, corners.faces_touching(cv, ring1), n) | ring1
        local_faces = corners.faces_touching(cv, ring2)
        rest = np.asarray(old.rest_positions)[index_map]
        pairs, kinds = _local_springs(corners, cv, local_faces, ring2, rest, n, line_vertices, line_offsets)
        code_new = ring1.astype(np.int8) + split.astype(np.int8)
        sel = (code_new[pairs[:, 0]] + code_new[pairs[:, 1]]) >= 2
        pairs, kinds = pairs[sel], kinds[sel]
        oa, ob = old_pairs[:, 0], old_pairs[:, 1]
        # the same rule on the old springs (split is within ring1): code 2 split, 1 ring, 0 else
        code = ring1[:n_old].astype(np.int8) + split[:n_old].astype(np.int8)
        old_sel = (code[oa] + code[ob]) >= 2
        old_sel &= ~removed
        candidates = np.flatnonzero(old_sel)
        old_sel |= removed
        unchanged = np.flatnonzero(~old_sel)
        okinds = np.asarray(old.kinds, dtype=np.int64)
        olo = np.minimum(oa[candidates], ob[candidates]).astype(np.int64)
        ohi = np.maximum(oa[candidates], ob[candidates]).astype(np.int64)
        okeys = (olo * n_old + ohi) * 3 + okinds[candidates]
        korder = argsort_int(okeys)
        okeys = okeys[korder]
        ma, mb = index_map[pairs[:, 0]], index_map[pairs[:, 1]]
        keys = (np.minimum(ma, mb) * n_old + np.maximum(ma, mb)) * 3 + kinds
        pos = np.minimum(np.searchsorted(okeys, keys), max(okeys.shape[0] - 1, 0))
        match = okeys[pos] == keys if okeys.size else np.zeros(keys.shape[0], dtype=bool)
        local_parent = candidates[korder[pos[match]]]
        parent = np.concatenate([unchanged, local_parent])
        new_pairs = np.concatenate([old_pairs[unchanged], pairs[match].astype(np.int32)])
        triangles = cv[corners.tri_corners]
        mass = _masses(old, cv, index_map, split, rest, triangles)
    pinned = np.asarray(old.pinned)[index_map]
    rest_positions = np.asarray(old.rest_positions)[index_map] if n != n_old else np.asarray(old.rest_positions)
    new_model = SpringModel(
        rest_positions=_frozen(rest_positions),
        springs=_frozen(new_pairs.astype(np.int32)),
        rest_lengths=_frozen(np.asarray(old.rest_lengths)[parent]),
        kinds=_frozen(np.asarray(old.kinds)[parent]),
        stiffness=_frozen(np.asarray(old.stiffness)[parent]),
        compression=_frozen(np.asarray(old.compression)[parent]),
        damping=_frozen(np.asarray(old.damping)[parent]),
        mass=_frozen(mass),
        inv_mass=_frozen(np.where(pinned, 0.0, 1.0 / mass)),
        pinned=_frozen(pinned),
        vertex_map=old.vertex_map,
        representative=old.representative,
        triangles=_frozen(np.asarray(triangles, dtype=np.int32)),
        material=old.material,
    )
    return new_model, parent


def _local_springs(
    corners: Corners,
    cv: np.ndarray,
    faces: np.ndarray,
    within: np.ndarray,
    rest: np.ndarray,
    n: int,
    line_vertices: np.ndarray,
    line_offsets: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Springs (pairs, kinds) of the given polygons ((F,) bool) and of the polylines touching
    `within` ((n,) bool), over the n new vertices at rest positions `rest` (n, 3)."""
    corner_mask = faces[corners.face]
    sizes = corners.sizes[faces]
    offsets = np.zeros(sizes.shape[0] + 1, dtype=np.int64)
    np.cumsum(sizes, out=offsets[1:])
    line_indices = np.zeros(0, dtype=np.int64)
    local_line_offsets = np.zeros(1, dtype=np.int64)
    if line_vertices.size:
        lsizes = np.diff(line_offsets)
        nonempty = lsizes > 0
        touch = np.zeros(lsizes.shape[0], dtype=bool)
        touch[nonempty] = np.logical_or.reduceat(within[line_vertices], line_offsets[:-1][nonempty])
        keep = np.repeat(touch, lsizes)
        line_indices = line_vertices[keep]
        local_line_offsets = np.zeros(int(touch.sum()) + 1, dtype=np.int64)
        np.cumsum(lsizes[touch], out=local_line_offsets[1:])
    local = Mesh(
        positions=rest,
        face_indices=cv[corner_mask],
        face_offsets=offsets,
        line_indices=line_indices,
        line_offsets=local_line_offsets,
    )
    springs = derive_springs(local, np.arange(n, dtype=np.int64), rest)
    return springs.pairs.astype(np.int64), springs.kinds.astype(np.int64)


def _masses(
    old: SpringModel, cv: np.ndarray, index_map: np.ndarray, split: np.ndarray, rest: np.ndarray, triangles: np.ndarray
) -> np.ndarray:
    """Old masses, with each split vertex's mass shared among its copies by incident rest area."""
    mass = np.asarray(old.mass)[index_map].copy()
    touch = split[triangles].any(axis=1)
    tris = triangles[touch]
    n = index_map.shape[0]
    area = lumped_area(rest, tris, n)
    corners = np.bincount(cv, minlength=n).astype(np.float64)
    idx = np.flatnonzero(split)
    a = area[idx]
    scale = float(a[a > 0].mean()) if np.any(a > 0) else 1.0
    weight = a + 1e-6 * scale * corners[idx]
    total = np.bincount(index_map[idx], weights=weight, minlength=old.vertex_count)[index_map[idx]]
    share = np.where(total > 0, weight / np.where(total > 0, total, 1.0), 1.0)
    mass[idx] = np.asarray(old.mass)[index_map[idx]] * share
    return np.where(mass > 0, mass, np.asarray(old.mass)[index_map])
