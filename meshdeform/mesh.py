"""The in-memory mesh: polygons kept as polygons, vertex order kept exactly.

A `Mesh` is what the readers produce and the writers consume. Polygons are stored flat
(CSR layout: `face_indices` holds every corner, `face_offsets` where each polygon starts) so
quads and n-gons survive untouched and everything stays vectorisable. Per-corner UV and normal
indices mirror OBJ's `v/vt/vn` so that UV seams and hard edges survive a round trip.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path

import numpy as np

#: the largest coordinate magnitude a mesh may hold (in its own units): a kilometre-sized asset in
#: micrometres stays far below it, and squared lengths stay far from float64 overflow; past it a
#: number is a typo or garbage, and the readers refuse it
MAX_COORDINATE = 1e12


@dataclass(frozen=True, eq=False)
class Mesh:
    """A polygon mesh as read from a file, in the file's own vertex order.

    positions: (V, 3) float64 vertex positions.
    face_indices: (C,) int64, the vertex index of every polygon corner, polygon after polygon.
    face_offsets: (F + 1,) int64, polygon k is `face_indices[face_offsets[k]:face_offsets[k + 1]]`.
    uvs / face_uv_indices: texture coordinates (T, 2 or 3) and, per corner, the index into them.
    normals / face_normal_indices: normals (N, 3) and, per corner, the index into them.
    line_indices / line_offsets: polylines (OBJ `l` elements) in the same CSR layout.
    statements: OBJ lines that are neither geometry nor elements (`g`, `o`, `usemtl`, `s`,
        `mtllib`), each with the number of faces written before it, so writers can replay them.
    groups: group / object name -> indices of the faces in it (OBJ `g` and `o`).
    vertex_properties: extra per-vertex arrays (PLY properties, OBJ vertex colours), (V,) or (V, k).
    face_properties: extra per-face scalar arrays (PLY).
    source: the file it was read from, if any.
    warnings: what the reader repaired or dropped, one sentence each.
    welded: (V,) int64, which vertices are one point of the surface (equal ids), when the positions
        cannot tell: a torn mesh's split copies start where their originals are yet are separate
        points (set by tearing: each vertex's simulation vertex). None: vertices at one position
        are one point (an input's vertices split at UV seams).
    """

    positions: np.ndarray
    face_indices: np.ndarray
    face_offsets: np.ndarray
    uvs: np.ndarray | None = None
    face_uv_indices: np.ndarray | None = None
    normals: np.ndarray | None = None
    face_normal_indices: np.ndarray | None = None
    line_indices: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    line_offsets: np.ndarray = field(default_factory=lambda: np.zeros(1, np.int64))
    statements: tuple[tuple[int, str], ...] = ()
    groups: dict[str, np.ndarray] = field(default_factory=dict)
    vertex_properties: dict[str, np.ndarray] = field(default_factory=dict)
    face_properties: dict[str, np.ndarray] = field(default_factory=dict)
    source: Path | None = None
    warnings: tuple[str, ...] = ()
    welded: np.ndarray | None = None

    @property
    def vertex_count(self) -> int:
        return int(self.positions.shape[0])

    @property
    def face_count(self) -> int:
        return int(self.face_offsets.shape[0] - 1)

    @property
    def line_count(self) -> int:
        return int(self.line_offsets.shape[0] - 1)

    @cached_property
    def face_sizes(self) -> np.ndarray:
        """Corners per polygon, (F,) int64."""
        return np.diff(self.face_offsets)

    @cached_property
    def corner_face(self) -> np.ndarray:
        """The polygon each corner belongs to, (C,) int64."""
        return np.repeat(np.arange(self.face_count, dtype=np.int64), self.face_sizes)

    @cached_property
    def corner_next(self) -> np.ndarray:
        """Index (into face_indices) of the next corner around the same polygon, (C,) int64."""
        corners = np.arange(self.face_indices.shape[0], dtype=np.int64)
        nxt = corners + 1
        last = self.face_offsets[1:] - 1
        nxt[last] = self.face_offsets[:-1]
        return nxt

    @cached_property
    def triangles(self) -> np.ndarray:
        """Fan triangulation of every polygon, (T, 3) int64, for areas, normals and rendering."""
        return fan_triangulate(self.face_indices, self.face_offsets)

    @cached_property
    def triangle_face(self) -> np.ndarray:
        """The polygon each fan triangle comes from, (T,) int64."""
        return np.repeat(np.arange(self.face_count, dtype=np.int64), np.maximum(self.face_sizes - 2, 0))

    def polygons(self) -> list[np.ndarray]:
        """Polygons as a list of index arrays (for small meshes, tests and debugging only)."""
        return np.split(self.face_indices, self.face_offsets[1:-1])

    def with_positions(self, positions: np.ndarray) -> Mesh:
        """The same mesh with other positions (same vertex count and order)."""
        positions = np.asarray(positions, dtype=np.float64)
        if positions.shape != self.positions.shape:
            raise ValueError(f"positions shape {positions.shape} != {self.positions.shape}")
        return replace(self, positions=positions)


def fan_triangulate(face_indices: np.ndarray, face_offsets: np.ndarray) -> np.ndarray:
    """Split each polygon (v0, v1, ..., vk) into triangles (v0, vi, vi+1), vectorised."""
    sizes = np.diff(face_offsets)
    tri_counts = np.maximum(sizes - 2, 0)
    total = int(tri_counts.sum())
    if total == 0:
        return np.zeros((0, 3), dtype=np.int64)
    starts = np.repeat(face_offsets[:-1], tri_counts)
    # i runs 1..k-2 within each polygon
    first_tri = np.cumsum(tri_counts) - tri_counts
    local = np.arange(total, dtype=np.int64) - np.repeat(first_tri, tri_counts) + 1
    tris = np.empty((total, 3), dtype=np.int64)
    tris[:, 0] = face_indices[starts]
    tris[:, 1] = face_indices[starts + local]
    tris[:, 2] = face_indices[starts + local + 1]
    return tris


def polygons_to_csr(polygons: list[list[int]] | list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Flat corner indices and offsets from a list of polygons."""
    sizes = np.fromiter((len(p) for p in polygons), dtype=np.int64, count=len(polygons))
    offsets = np.zeros(len(polygons) + 1, dtype=np.int64)
    np.cumsum(sizes, out=offsets[1:])
    if len(polygons):
        flat = np.concatenate([np.asarray(p, dtype=np.int64) for p in polygons])
    else:
        flat = np.zeros(0, dtype=np.int64)
    return flat, offsets


def grid_mesh(nx: int, ny: int, size: tuple[float, float] = (1.0, 1.0), plane: str = "xy") -> Mesh:
    """A quad grid of nx x ny vertices with UVs, vertex (i, j) at index j * nx + i.

    plane "xy" makes a hanging sheet (Y up), "xz" a horizontal one.
    """
    u = np.linspace(0.0, 1.0, nx)
    v = np.linspace(0.0, 1.0, ny)
    uu, vv = np.meshgrid(u, v)
    positions = np.zeros((nx * ny, 3))
    if plane == "xy":
        positions[:, 0] = uu.ravel() * size[0]
        positions[:, 1] = vv.ravel() * size[1]
    elif plane == "xz":
        positions[:, 0] = uu.ravel() * size[0]
        positions[:, 2] = vv.ravel() * size[1]
    else:
        raise ValueError(f"unknown plane {plane!r}")
    idx = np.arange(nx * ny, dtype=np.int64).reshape(ny, nx)
    quads = np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]], axis=-1).reshape(-1, 4)
    offsets = np.arange(0, quads.size + 1, 4, dtype=np.int64)
    uvs = np.stack([uu.ravel(), vv.ravel()], axis=1)
    flat = quads.ravel()
    return Mesh(
        positions=positions,
        face_indices=flat,
        face_offsets=offsets,
        uvs=uvs,
        face_uv_indices=flat.copy(),
    )
