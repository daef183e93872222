"""The colouring values of a preview frame: per-vertex strain or displacement."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np

from meshdeform.arrays import run_lengths
from meshdeform.mesh import Mesh
from meshdeform.strain import SegmentStretch


def _edge_keys(mesh: Mesh) -> np.ndarray:
    """Every polygon side and polyline segment as a key a * n + b (a < b), one per occurrence."""
    n = max(mesh.vertex_count, 1)
    a = [mesh.face_indices]
    b = [mesh.face_indices[mesh.corner_next]]
    if mesh.line_count:
        last = np.zeros(mesh.line_indices.shape[0], dtype=bool)
        sizes = np.diff(mesh.line_offsets)
        last[mesh.line_offsets[1:][sizes > 0] - 1] = True
        start = np.flatnonzero(~last)
        a.append(mesh.line_indices[start])
        b.append(mesh.line_indices[start + 1])
    ea = np.concatenate(a).astype(np.int64)
    eb = np.concatenate(b).astype(np.int64)
    lo, hi = np.minimum(ea, eb), np.maximum(ea, eb)
    keep = lo != hi
    return lo[keep] * n + hi[keep]


class EdgeStrain(SegmentStretch):
    """Per-vertex stretch ratio: the largest current / rest length of the edges at each vertex.

    Edges are the mesh's polygon sides and polyline segments; rest lengths come from `rest`
    (V0, 3). For a torn mesh with extra vertices, only edges between original vertices count
    (the others, and vertices without edges, read 1.0).
    """

    def __init__(self, mesh: Mesh, rest: np.ndarray) -> None:
        n = max(mesh.vertex_count, 1)
        keys = np.sort(_edge_keys(mesh))
        if keys.size:
            starts, _ = run_lengths(keys)
            keys = keys[starts]
        a, b = keys // n, keys % n
        ok = (a < rest.shape[0]) & (b < rest.shape[0])
        a, b = a[ok], b[ok]
        d = rest[b] - rest[a]
        length = np.sqrt(np.einsum("ij,ij->i", d, d))
        ok = length > 0
        super().__init__(a[ok], b[ok], length[ok], mesh.vertex_count)


class FrameScalars:
    """The colouring values of a frame, for the current topology: None (flat), the displacement from rest,
    or the strain: the frame's own (`strain_frames[k]`, when it fits), the model's (`strain_fn`, on the
    rest vertex count) or the mesh edges' (`EdgeStrain`)."""

    def __init__(
        self,
        color: str,
        rest: np.ndarray,
        strain_fn: Callable[[np.ndarray], np.ndarray] | None,
        strain_frames: Sequence[np.ndarray] | Mapping[int, np.ndarray] | None,
    ) -> None:
        self.color = color
        self.rest = rest
        self._model_strain = strain_fn
        self._strain_frames = strain_frames
        self._edge_strain: EdgeStrain | None = None
        self._edge_mesh: Mesh | None = None

    def __call__(self, k: int, mesh: Mesh, positions: np.ndarray) -> np.ndarray | None:
        if self.color == "flat":
            return None
        if self.color == "displacement":
            out = np.zeros(positions.shape[0])
            m = min(positions.shape[0], self.rest.shape[0])
            d = positions[:m] - self.rest[:m]
            out[:m] = np.sqrt(np.einsum("ij,ij->i", d, d))
            return out
        if self._strain_frames is not None:
            values = np.asarray(self._strain_frames[k], dtype=np.float64)
            if values.shape == (positions.shape[0],):
                return values
        if self._model_strain is not None and positions.shape[0] == self.rest.shape[0]:
            return np.asarray(self._model_strain(positions), dtype=np.float64)
        if self._edge_mesh is not mesh:
            self._edge_strain = EdgeStrain(mesh, self.rest)
            self._edge_mesh = mesh
        assert self._edge_strain is not None
        return self._edge_strain(positions)

