"""Per-vertex strain: the largest stretch ratio (current / rest length) of the segments at each vertex.

Used for strain-coloured previews and VTK point data. The per-vertex maximum is a segmented
reduction over segments sorted by endpoint, prepared once; `VertexStrain` takes a model's
structural springs, the previewer (`meshdeform.preview.EdgeStrain`) a mesh's edges.
"""

from __future__ import annotations

import numpy as np

from meshdeform.arrays import argsort_int, run_lengths
from meshdeform.model import SpringModel
from meshdeform.topology import SpringKind


class SegmentStretch:
    """Callable: (count,) largest current / rest length over the segments (a, b) at each vertex; 1.0 elsewhere."""

    def __init__(self, a: np.ndarray, b: np.ndarray, rest: np.ndarray, count: int) -> None:
        self._a = np.asarray(a, dtype=np.int64)
        self._b = np.asarray(b, dtype=np.int64)
        self._rest = np.maximum(np.asarray(rest, dtype=np.float64), 1e-300)
        ends = np.concatenate([self._a, self._b])
        self._order = argsort_int(ends)
        sorted_ends = ends[self._order]
        self._starts, _ = run_lengths(sorted_ends)
        self._vertices = sorted_ends[self._starts]
        self._count = int(count)

    def __call__(self, positions: np.ndarray) -> np.ndarray:
        out = np.ones(self._count)
        if self._a.shape[0] == 0:
            return out
        d = positions[self._b] - positions[self._a]
        ratio = np.sqrt(np.einsum("ij,ij->i", d, d)) / self._rest
        both = np.concatenate([ratio, ratio])[self._order]
        out[self._vertices] = np.maximum.reduceat(both, self._starts)
        return out


class VertexStrain(SegmentStretch):
    """Per-vertex stretch ratios (W,) over a model's springs of one kind (structural by default)."""

    def __init__(self, model: SpringModel, kind: SpringKind = SpringKind.STRUCTURAL) -> None:
        mask = model.kinds == kind
        pairs = model.springs[mask]
        super().__init__(pairs[:, 0], pairs[:, 1], model.rest_lengths[mask], model.vertex_count)
