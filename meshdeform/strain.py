"""Per-vertex strain: the largest stretch ratio (current / rest length) of a vertex's structural springs.

Used for strain-coloured previews and VTK point data. The per-vertex maximum is a segmented
reduction over springs sorted by endpoint, prepared once per model.
"""

from __future__ import annotations

import numpy as np

from meshdeform.arrays import argsort_int, run_lengths
from meshdeform.model import SpringModel
from meshdeform.topology import SpringKind


class VertexStrain:
    """Callable computing (W,) per-vertex stretch ratios for welded positions; 1.0 where no spring."""

    def __init__(self, model: SpringModel, kind: SpringKind = SpringKind.STRUCTURAL) -> None:
        mask = model.kinds == kind
        self._pairs = model.springs[mask]
        self._rest = np.maximum(model.rest_lengths[mask], 1e-300)
        ends = np.concatenate([self._pairs[:, 0], self._pairs[:, 1]]).astype(np.int64)
        self._order = argsort_int(ends)
        sorted_ends = ends[self._order]
        self._starts, _ = run_lengths(sorted_ends)
        self._vertices = sorted_ends[self._starts]
        self._count = model.vertex_count

    def __call__(self, positions: np.ndarray) -> np.ndarray:
        out = np.ones(self._count)
        if self._pairs.shape[0] == 0:
            return out
        d = positions[self._pairs[:, 1]] - positions[self._pairs[:, 0]]
        ratio = np.sqrt(np.einsum("ij,ij->i", d, d)) / self._rest
        both = np.concatenate([ratio, ratio])[self._order]
        out[self._vertices] = np.maximum.reduceat(both, self._starts)
        return out
