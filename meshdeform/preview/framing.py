"""What the preview camera frames in a torn frame: its main pieces, so pieces that fall away leave the view.

A frame whose mesh is the sequence's own is framed whole. A torn frame's mesh (tearing's new topology) is
cut into connected pieces: polygons and polylines joined by shared vertices, vertices at the same position
counting as one (an input's seams are not cuts; vertices split by a tear part as soon as they move apart).
Its main pieces are the largest by welded vertex count and any at least `MAIN_FRACTION` of its size
(a curtain torn into two halves shows both); smaller pieces (the ones that drop off) are not framed.
"""

from __future__ import annotations

import numpy as np

from meshdeform.mesh import Mesh

#: a piece at least this fraction of the largest one's vertex count is framed with it
MAIN_FRACTION = 0.5


def main_pieces(mesh: Mesh, positions: np.ndarray) -> np.ndarray:
    """(V,) bool: the vertices of the main pieces of `mesh` at `positions` (V, 3) (module docstring);
    vertices no polygon or polyline uses are left out, unless nothing uses any vertex (then all)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from meshdeform.topology import line_edges, polygon_edges, weld

    n = positions.shape[0]
    welding = weld(positions)
    vertex_map = welding.vertex_map
    s, e = polygon_edges(mesh, vertex_map)
    ls, le = line_edges(mesh, vertex_map)
    start, end = np.concatenate([s, ls]), np.concatenate([e, le])
    used = np.zeros(welding.count, dtype=bool)
    used[start] = True
    used[end] = True
    if not used.any():
        return np.ones(n, dtype=bool)
    graph = coo_matrix((np.ones(start.shape[0], dtype=np.int8), (start, end)), shape=(welding.count,) * 2)
    count, labels = connected_components(graph, directed=False)
    if count == 1:
        return used[vertex_map]
    sizes = np.bincount(labels[used], minlength=count)
    main = sizes >= MAIN_FRACTION * sizes.max()
    return (main[labels] & used)[vertex_map]
