"""Vectorised polygon geometry: normals, areas and per-corner normals of n-gon meshes.

Everything works on the CSR polygon layout of `Mesh` (`face_indices` / `face_offsets`), so quads
and concave n-gons are handled directly, without triangulating. Polygon normals use Newell's
method (the sum of edge cross products), which is exact for planar polygons of any shape, convex
or not, and a robust average for slightly non-planar ones.
"""

from __future__ import annotations

import weakref
from collections.abc import Callable
from typing import NamedTuple, TypeVar

import numpy as np

from meshdeform.mesh import Mesh

__all__ = [
    "NORMAL_DECIMALS",
    "NormalLayout",
    "PolygonCleanup",
    "clean_polygons",
    "corner_normals",
    "normal_layout",
    "polygon_area_vectors",
    "polygon_areas",
    "polygon_normals",
    "scatter_triangles",
    "surface_normals",
    "triangle_area_vectors",
    "triangle_vertex_normals",
    "vertex_normals",
]

MeshOrArrays = Mesh | tuple[np.ndarray, np.ndarray]
T = TypeVar("T")

# Data that does not change between frames (unique polygon/target pairs, orientation signs),
# keyed by the identity of the arrays it is derived from. `Mesh.with_positions` copies share those
# arrays, so a per-frame copy hits the cache too. Entries go away with their arrays (weakrefs).
_CACHE: dict[tuple, tuple[tuple[weakref.ref, ...], object]] = {}


def _cached(name: str, arrays: tuple[np.ndarray, ...], compute: Callable[[], T]) -> T:
    """compute(), remembered for as long as `arrays` (the same objects) are alive."""
    key = (name, *map(id, arrays))
    entry = _CACHE.get(key)
    if entry is not None and all(ref() is arr for ref, arr in zip(entry[0], arrays, strict=True)):
        return entry[1]  # type: ignore[return-value]
    value = compute()
    try:
        refs = tuple(weakref.ref(arr, lambda _ref, key=key: _CACHE.pop(key, None)) for arr in arrays)
    except TypeError:  # not weak-referenceable: no caching
        return value
    _CACHE[key] = (refs, value)
    return value


class _Topo(NamedTuple):
    face_indices: np.ndarray
    face_offsets: np.ndarray
    sizes: np.ndarray
    corner_face: np.ndarray
    corner_next: np.ndarray


def _topology(mesh_or_arrays: MeshOrArrays) -> _Topo:
    """Face arrays plus the per-corner helpers, taken from the Mesh's cache when there is one."""
    if isinstance(mesh_or_arrays, Mesh):
        m = mesh_or_arrays
        return _Topo(m.face_indices, m.face_offsets, m.face_sizes, m.corner_face, m.corner_next)
    face_indices, face_offsets = mesh_or_arrays
    face_indices = np.asarray(face_indices, dtype=np.int64)
    face_offsets = np.asarray(face_offsets, dtype=np.int64)
    sizes = np.diff(face_offsets)
    corner_face = np.repeat(np.arange(sizes.shape[0], dtype=np.int64), sizes)
    corner_next = np.arange(face_indices.shape[0], dtype=np.int64) + 1
    nonempty = sizes > 0
    corner_next[face_offsets[1:][nonempty] - 1] = face_offsets[:-1][nonempty]
    return _Topo(face_indices, face_offsets, sizes, corner_face, corner_next)


def _positions(mesh_or_arrays: MeshOrArrays, positions: np.ndarray | None) -> np.ndarray:
    if positions is None:
        if not isinstance(mesh_or_arrays, Mesh):
            raise TypeError("positions are required when faces are given as arrays")
        positions = mesh_or_arrays.positions
    return np.asarray(positions, dtype=np.float64)


def _face_sum(values: np.ndarray, topo: _Topo) -> np.ndarray:
    """Sum per-corner rows (C, k) into per-polygon rows (F, k)."""
    n_faces = topo.sizes.shape[0]
    if n_faces == 0:
        return np.zeros((0, values.shape[1]), dtype=values.dtype)
    if np.all(topo.sizes > 0):
        return np.add.reduceat(values, topo.face_offsets[:-1], axis=0)
    out = np.empty((n_faces, values.shape[1]), dtype=values.dtype)
    for k in range(values.shape[1]):
        out[:, k] = np.bincount(topo.corner_face, weights=values[:, k], minlength=n_faces)
    return out


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (..., 3) arrays (faster than np.cross for big arrays)."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def polygon_area_vectors(mesh_or_arrays: MeshOrArrays, positions: np.ndarray | None = None) -> np.ndarray:
    """Area-weighted polygon normals (F, 3): unit normal times area, by Newell's method.

    Corners are taken relative to each polygon's first corner, which keeps precision for small
    polygons far from the origin (and drops the two edge terms that touch it). Works for concave
    polygons: the cross products of the "inward" corners subtract, as they should.
    """
    topo = _topology(mesh_or_arrays)
    pos = _positions(mesh_or_arrays, positions)
    n_faces = topo.sizes.shape[0]
    if topo.face_indices.shape[0] == 0:
        return np.zeros((n_faces, 3))
    k = int(topo.sizes[0])
    if k >= 3 and topo.face_indices.shape[0] == k * n_faces and np.all(topo.sizes == k):
        # all polygons have k corners: (F, k) blocks, no per-corner bookkeeping
        corners = pos[topo.face_indices.reshape(n_faces, k)]
        rel = corners[:, 1:] - corners[:, :1]
        return 0.5 * _cross(rel[:, :-1], rel[:, 1:]).sum(axis=1)
    p = pos[topo.face_indices]
    p -= pos[topo.face_indices[topo.face_offsets[:-1][topo.corner_face]]]
    return 0.5 * _face_sum(_cross(p, p[topo.corner_next]), topo)


def _normalise(vectors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors (zero where the input is zero) and the lengths."""
    length = np.sqrt(np.einsum("ij,ij->i", vectors, vectors))
    out = np.zeros_like(vectors)
    ok = length > 0
    out[ok] = vectors[ok] / length[ok, None]
    return out, length


def polygon_normals(mesh_or_arrays: MeshOrArrays, positions: np.ndarray | None = None) -> np.ndarray:
    """Unit polygon normals (F, 3) by Newell's method; zero for polygons of zero area."""
    return _normalise(polygon_area_vectors(mesh_or_arrays, positions))[0]


def polygon_areas(mesh_or_arrays: MeshOrArrays, positions: np.ndarray | None = None) -> np.ndarray:
    """Polygon areas (F,): the length of the Newell area vector (exact for planar polygons)."""
    return _normalise(polygon_area_vectors(mesh_or_arrays, positions))[1]


def _unique_pairs(corner_face: np.ndarray, targets: np.ndarray, n_targets: int) -> tuple[np.ndarray, np.ndarray]:
    """(polygon, target) pairs with each pair once, so a polygon that references the same
    vertex or normal at several corners is counted once (flat-shaded faces do that)."""
    if corner_face.shape[0] == 0:
        return corner_face, targets
    n = np.int64(max(n_targets, 1))
    key = np.sort(corner_face * n + targets)  # (np.unique is much slower here)
    first = np.ones(key.shape[0], dtype=bool)
    np.not_equal(key[1:], key[:-1], out=first[1:])
    if first.all():
        return corner_face, targets
    key = key[first]
    return key // n, key % n


def _scatter_sum(pair_face: np.ndarray, pair_target: np.ndarray, face_vectors: np.ndarray, n: int) -> np.ndarray:
    out = np.empty((n, 3))
    for k in range(3):
        out[:, k] = np.bincount(pair_target, weights=face_vectors[pair_face, k], minlength=n)
    return out


def _cached_pairs(topo: _Topo, targets: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    return _cached(
        f"pairs{n}", (targets, topo.face_offsets), lambda: _unique_pairs(topo.corner_face, targets, n)
    )


def vertex_normals(mesh_or_arrays: MeshOrArrays, positions: np.ndarray | None = None) -> np.ndarray:
    """Area-weighted vertex normals (V, 3): the normalised sum of the area vectors of the
    polygons around each vertex. Vertices used by no polygon get a zero normal."""
    topo = _topology(mesh_or_arrays)
    pos = _positions(mesh_or_arrays, positions)
    n_vertices = pos.shape[0]
    area_vectors = polygon_area_vectors(mesh_or_arrays, pos)
    pair_face, pair_vertex = _cached_pairs(topo, topo.face_indices, n_vertices)
    return _normalise(_scatter_sum(pair_face, pair_vertex, area_vectors, n_vertices))[0]


def triangle_area_vectors(positions: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area vectors (T, 3) of a triangle list (T, 3): unit normal times area, (p1 - p0) x (p2 - p0) / 2."""
    p0 = positions[triangles[:, 0]]
    p1 = positions[triangles[:, 1]]
    p2 = positions[triangles[:, 2]]
    return 0.5 * np.cross(p1 - p0, p2 - p0)


def scatter_triangles(triangles: np.ndarray, per_triangle: np.ndarray, n: int) -> np.ndarray:
    """Spread a per-triangle vector (T, 3) equally over its three corners: (n, 3) sums per vertex."""
    out = np.empty((n, 3))
    flat = triangles.ravel()
    for c in range(3):
        out[:, c] = np.bincount(flat, weights=np.repeat(per_triangle[:, c] / 3.0, 3), minlength=n)
    return out


def triangle_vertex_normals(positions: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (W, 3) of a triangle list (T, 3) (zero for vertices
    without triangles): a third of each triangle's area vector to each corner, normalised.

    For the simulation model, whose `triangles` fan-triangulate its polygons over welded
    vertices. On a triangle mesh this is `vertex_normals` up to rounding; on polygons a corner
    counts only the fan triangles that touch it. Kept apart from `vertex_normals` because the
    impacts directed along the surface normal (`scene.forces.Impact`) depend on its exact bytes.
    """
    n = scatter_triangles(triangles, triangle_area_vectors(positions, triangles), positions.shape[0])
    length = np.linalg.norm(n, axis=1)
    return np.where(length[:, None] > 0, n / np.maximum(length, 1e-300)[:, None], 0.0)


def corner_normals(mesh: Mesh, positions: np.ndarray | None = None) -> np.ndarray:
    """Normals for `positions` in the mesh's own normal layout (N, 3).

    For each input normal index n: the normalised sum of the area vectors of the polygons whose
    corners reference n. Normals shared across a smooth region stay smooth, normals owned by
    one face (hard edges, flat shading) stay hard, and all of them follow the deformation.
    Where the authored normal points against the polygon winding at rest, the new normal is
    flipped to keep the authored side; "at rest" is the first mesh seen with these normal
    arrays, so call it with the input mesh (and per-frame `positions`, or `with_positions`
    copies, which share the arrays). Normals no polygon references (or whose polygons have no
    area) keep their input direction. Without input normals: per-vertex normals (V, 3).

    One normal shared by a whole region (a flat plane written with a single `vn`) stays one
    normal here; the frame writers use `surface_normals`, which splits it per vertex.
    """
    if mesh.normals is None or mesh.face_normal_indices is None:
        return vertex_normals(mesh, positions)
    targets = np.asarray(mesh.face_normal_indices, dtype=np.int64)
    input_normals = _normalise(np.asarray(mesh.normals, dtype=np.float64).reshape(-1, 3))[0]
    return _target_normals(mesh, positions, targets, input_normals, "sign")


def _target_normals(
    mesh: Mesh, positions: np.ndarray | None, targets: np.ndarray, input_normals: np.ndarray, sign_name: str
) -> np.ndarray:
    """Area-weighted normals (K, 3) of K normal slots: slot k is the normalised sum of the area
    vectors of the polygons with a corner in `targets` (C,) equal to k, flipped where the rest
    result points against `input_normals` (K, 3) (unit), and `input_normals[k]` where it has no area."""
    pos = _positions(mesh, positions)
    topo = _topology(mesh)
    n_normals = int(input_normals.shape[0])
    pair_face, pair_normal = _cached_pairs(topo, targets, n_normals)

    def rest_sign() -> np.ndarray:
        rest = _normalise(_scatter_sum(pair_face, pair_normal, polygon_area_vectors(mesh), n_normals))[0]
        return np.where(np.einsum("ij,ij->i", rest, input_normals) < 0, -1.0, 1.0)

    # judged once, on the positions of the first mesh seen with these normals (the input, at rest)
    sign = _cached(sign_name, (mesh.normals, mesh.face_normal_indices, mesh.face_offsets), rest_sign)

    summed = _scatter_sum(pair_face, pair_normal, polygon_area_vectors(mesh, pos), n_normals)
    out, length = _normalise(summed)
    out *= sign[:, None]
    missing = length == 0
    out[missing] = input_normals[missing]
    return out


#: input normals whose unit vectors agree to this many decimals (about 1e-4 rad; Blender writes
#: `vn` with 4) count as one normal when `normal_layout` groups the corners of a vertex
NORMAL_DECIMALS = 4


class NormalLayout(NamedTuple):
    """How the frame writers lay out recomputed normals (see `normal_layout`)."""

    corner_normal: np.ndarray  # (C,) int64, output normal index of every polygon corner
    input_normal: np.ndarray  # (K, 3) unit input normal of each output normal
    vertex: np.ndarray  # (K,) int64, welded vertex of each output normal (`topology.weld` numbering)

    @property
    def hard_edges(self) -> bool:
        """Whether some position has more than one output normal (a hard edge of the input)."""
        return bool(np.unique(self.vertex).shape[0] < self.vertex.shape[0])


def normal_layout(mesh: Mesh) -> NormalLayout | None:
    """The output normal layout of a mesh with input normals (None without them).

    Corners are grouped by (welded vertex, input normal value): the corners around one position
    whose input normals agree (to `NORMAL_DECIMALS` decimals of the unit vector) share one output
    normal, so a region written with a single shared `vn` (a flat plane from Blender) gets a
    normal per vertex, a smooth mesh split at UV seams stays smooth across them, and a position
    with distinct input normals (a real hard edge) keeps one normal per side. Output normals are
    numbered by welded vertex (input vertex order), then by input normal value. Judged on the
    first mesh seen with these normal arrays (the input, at rest) and cached with them. A torn mesh
    (`Mesh.welded` set) groups by its `welded` ids instead: the two lips of a cut get a normal each.
    """
    if mesh.normals is None or mesh.face_normal_indices is None:
        return None

    def build() -> NormalLayout:
        from meshdeform.topology import weld

        unit = _normalise(np.asarray(mesh.normals, dtype=np.float64).reshape(-1, 3))[0]
        if unit.shape[0] == 0:
            return NormalLayout(np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.zeros(0, dtype=np.int64))
        # +0 so -0 rounds to the same integer key as 0
        quantised = np.rint(unit * 10.0**NORMAL_DECIMALS).astype(np.int64) + 0
        _, value_id = np.unique(quantised, axis=0, return_inverse=True)
        value_id = value_id.ravel().astype(np.int64)
        points = weld(mesh.positions).vertex_map if mesh.welded is None else np.asarray(mesh.welded, np.int64)
        welded = points[np.asarray(mesh.face_indices, dtype=np.int64)]
        normal_ids = np.asarray(mesh.face_normal_indices, dtype=np.int64)
        keys = welded * (int(value_id.max()) + 1) + value_id[normal_ids]
        _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
        return NormalLayout(inverse.ravel().astype(np.int64), unit[normal_ids[first]], welded[first])

    arrays = (mesh.normals, mesh.face_normal_indices, mesh.face_offsets)
    return _cached("layout", arrays if mesh.welded is None else (*arrays, mesh.welded), build)


def surface_normals(mesh: Mesh, positions: np.ndarray | None = None) -> np.ndarray:
    """Normals (K, 3) for `positions` in `normal_layout(mesh)`, the layout the frame writers use:
    each the area-weighted average of the polygons of its (welded vertex, input normal) group,
    on the authored side (as `corner_normals`). Without input normals: `vertex_normals` (V, 3)."""
    layout = normal_layout(mesh)
    if layout is None:
        return vertex_normals(mesh, positions)
    return _target_normals(mesh, positions, layout.corner_normal, layout.input_normal, "layout sign")


class PolygonCleanup(NamedTuple):
    """What `clean_polygons` found: masks to apply and counts for the warnings."""

    corner_keep: np.ndarray  # (C,) bool, corners that survive
    face_keep: np.ndarray  # (F,) bool, polygons that survive
    too_small: np.ndarray  # (F,) bool, polygons written with 1 or 2 corners
    degenerate: np.ndarray  # (F,) bool, polygons left with < 3 distinct corners after removing repeats
    repaired: np.ndarray  # (F,) bool, kept polygons that had consecutive repeated corners removed


def clean_polygons(face_indices: np.ndarray, face_offsets: np.ndarray) -> PolygonCleanup:
    """Find degenerate polygons: drop consecutive repeated corners (cyclically, so `2 6 8 8 2`
    becomes `2 6 8`), then drop polygons with fewer than 3 distinct corners (`2 2 2`, `2 8 2`,
    `1 2 1 2`) and polygons written with fewer than 3 corners. Vectorised."""
    topo = _topology((face_indices, face_offsets))
    fi = topo.face_indices
    sizes = topo.sizes
    n_faces = sizes.shape[0]
    too_small = sizes < 3
    repeat = fi == fi[topo.corner_next]
    # a polygon whose corners are all equal repeats at every corner: remove all of them
    corner_keep = ~repeat
    kept_sizes = np.bincount(topo.corner_face[corner_keep], minlength=n_faces) if n_faces else np.zeros(0, np.int64)
    had_repeat = kept_sizes != sizes
    degenerate = (kept_sizes < 3) & ~too_small

    # kept polygons of 4+ corners may still have < 3 distinct corners (1 2 1 2): check those
    check = (kept_sizes >= 4) & ~degenerate & ~too_small
    if np.any(check):
        quads = check & (kept_sizes == 4)
        if np.any(quads):
            qf = np.flatnonzero(quads)
            q_corners = np.flatnonzero(corner_keep & quads[topo.corner_face]).reshape(-1, 4)
            qv = fi[q_corners]
            degenerate[qf[(qv[:, 0] == qv[:, 2]) & (qv[:, 1] == qv[:, 3])]] = True
        big = check & (kept_sizes > 4)
        if np.any(big):
            sel = corner_keep & big[topo.corner_face]
            pair_face, _ = _unique_pairs(topo.corner_face[sel], fi[sel], int(fi.max(initial=0)) + 1)
            distinct = np.bincount(pair_face, minlength=n_faces)
            degenerate |= big & (distinct < 3)

    face_keep = ~(too_small | degenerate)
    corner_keep &= face_keep[topo.corner_face]
    repaired = had_repeat & face_keep
    return PolygonCleanup(corner_keep, face_keep, too_small, degenerate, repaired)
