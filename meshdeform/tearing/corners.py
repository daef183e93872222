"""The polygon corners a tear regroups, and local queries on them.

The faces never change when the cloth tears: only which simulation vertex each polygon corner
points at does. `Corners` holds what is fixed for a run (each corner's next and previous corner
in its polygon, its face, the faces' offsets and sizes, the fan triangulation's corners); the
current topology is the array `cv` (C,) corner -> simulation vertex, passed to every query.
The queries touch only the vertices or faces asked about, never the whole mesh, since they run
on the substeps something breaks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from meshdeform.arrays import argsort_int, run_lengths
from meshdeform.mesh import Mesh, fan_triangulate


@dataclass(frozen=True, eq=False)
class Corners:
    """Fixed corner topology of the input mesh's polygons (C corners, F faces, T triangles).

    nxt, prv: (C,) the next and previous corner in the same polygon; face: (C,) each corner's
    polygon; offsets: (F+1,) and sizes: (F,) the polygons' corner ranges; tri_corners: (T, 3)
    the corners of the fan triangulation (so `cv[tri_corners]` is the model's triangles).
    """

    nxt: np.ndarray
    prv: np.ndarray
    face: np.ndarray
    offsets: np.ndarray
    sizes: np.ndarray
    tri_corners: np.ndarray

    @classmethod
    def from_mesh(cls, mesh: Mesh) -> Corners:
        nxt = np.asarray(mesh.corner_next, dtype=np.int64)
        prv = np.empty_like(nxt)
        prv[nxt] = np.arange(nxt.shape[0], dtype=np.int64)
        offsets = np.asarray(mesh.face_offsets, dtype=np.int64)
        return cls(
            nxt=nxt,
            prv=prv,
            face=np.asarray(mesh.corner_face, dtype=np.int64),
            offsets=offsets,
            sizes=np.asarray(mesh.face_sizes, dtype=np.int64),
            tri_corners=fan_triangulate(np.arange(mesh.face_indices.shape[0], dtype=np.int64), offsets),
        )

    @property
    def face_count(self) -> int:
        return int(self.sizes.shape[0])

    def of(self, cv: np.ndarray, n: int, vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Corners at each entry of `vertices` (entries may repeat; n simulation vertices):
        (entry per item, corner per item)."""
        wanted = np.zeros(n, dtype=bool)
        wanted[vertices] = True
        cs = np.flatnonzero(wanted[cv])
        order = argsort_int(cv[cs])
        cs = cs[order]
        at = cv[cs]
        starts, lengths = run_lengths(at)
        pos = np.searchsorted(at[starts], vertices)
        owner, index = expand_ranges(starts[pos], lengths[pos])
        return owner, cs[index]

    def centroids(self, cv: np.ndarray, x: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """Current centroids (k, 3) of these polygons for positions x (n, 3)."""
        if faces.shape[0] == 0:
            return np.zeros((0, 3))
        size = self.sizes[faces]
        _, corners = expand_ranges(self.offsets[faces], size)
        pts = x[cv[corners]]
        return np.add.reduceat(pts, np.cumsum(size) - size, axis=0) / size[:, None]

    def on_boundary(self, cv: np.ndarray, n: int, vertices: np.ndarray) -> np.ndarray:
        """(k,) bool: whether each vertex has an edge used by one polygon only."""
        base = max(n, 1)
        owner, corners = self.of(cv, n, vertices)
        here = cv[corners]
        other = np.concatenate([cv[self.nxt[corners]], cv[self.prv[corners]]])
        who = np.concatenate([owner, owner])
        keep = other != np.concatenate([here, here])
        keys = np.sort(who[keep] * base + other[keep])
        starts, lengths = run_lengths(keys)
        out = np.zeros(vertices.shape[0], dtype=bool)
        out[keys[starts[lengths == 1]] // base] = True
        return out

    def faces_touching(self, cv: np.ndarray, vertices: np.ndarray) -> np.ndarray:
        """(F,) bool: the polygons with a corner at one of `vertices` ((n,) bool)."""
        faces = np.zeros(self.face_count, dtype=bool)
        faces[self.face[vertices[cv]]] = True
        return faces

    def vertices_of(self, cv: np.ndarray, faces: np.ndarray, n: int) -> np.ndarray:
        """(n,) bool: the vertices of these polygons ((F,) bool)."""
        out = np.zeros(n, dtype=bool)
        out[cv[faces[self.face]]] = True
        return out


def expand_ranges(start: np.ndarray, count: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every index of k ranges [start, start + count) ((k,) int each), in order: (the range of
    each item, the item), both (sum(count),) int64. Reads a CSR row set without a Python loop."""
    owner = np.repeat(np.arange(start.shape[0], dtype=np.int64), count)
    begin = np.cumsum(count) - count
    local = np.arange(owner.shape[0], dtype=np.int64) - np.repeat(begin, count)
    return owner, np.repeat(start, count) + local
