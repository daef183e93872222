"""The output layout of a torn mesh: what the user's files see as the cloth opens.

The input's vertices keep their indices 0..V-1; a corner that now belongs to a split copy
points at an output vertex appended after them (one per input vertex and copy, in the order of
(simulation vertex, input vertex)); per-corner UV and normal indices, groups, polylines and face
properties are unchanged (the faces are the same faces), vertex properties are copied to the
new vertices. The torn model's `vertex_map` maps that grown output layout to the simulation
vertices, so `model.to_input_layout(welded)` gives the output positions, and `mesh` is the
matching `Mesh`. Polylines (ropes) do not tear: only polygon corners are split.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from meshdeform.arrays import argsort_int, run_lengths
from meshdeform.mesh import Mesh
from meshdeform.model import SpringModel, _frozen


@dataclass
class OutputLayout:
    """corner_out: (C,) output vertex of every polygon corner; sim: (V',) output vertex ->
    simulation vertex; source: (V',) output vertex -> the input vertex it was copied from."""

    corner_out: np.ndarray
    sim: np.ndarray
    source: np.ndarray

    @classmethod
    def of_input(cls, mesh: Mesh, model: SpringModel) -> OutputLayout:
        """The untorn layout: the input's own vertices and corners."""
        return cls(
            corner_out=np.asarray(mesh.face_indices, dtype=np.int64).copy(),
            sim=np.asarray(model.vertex_map, dtype=np.int64).copy(),
            source=np.arange(mesh.vertex_count, dtype=np.int64),
        )

    def grow(self, input_mesh: Mesh, old_cv: np.ndarray, cv: np.ndarray) -> None:
        """Give the corners a split moved (old_cv -> cv, (C,) corner -> simulation vertex) an
        output vertex per (new simulation vertex, input vertex)."""
        moved = np.flatnonzero(cv != old_cv)
        if not moved.size:
            return
        inputs = np.asarray(input_mesh.face_indices, dtype=np.int64)[moved]
        vcount = max(input_mesh.vertex_count, 1)
        keys = cv[moved] * vcount + inputs
        order = argsort_int(keys)
        sk = keys[order]
        starts, lengths = run_lengths(sk)
        out_ids = np.empty(moved.shape[0], dtype=np.int64)
        out_ids[order] = self.sim.shape[0] + np.repeat(np.arange(starts.shape[0], dtype=np.int64), lengths)
        self.corner_out[moved] = out_ids
        uniq = sk[starts]
        self.sim = np.concatenate([self.sim, uniq // vcount])
        self.source = np.concatenate([self.source, uniq % vcount])

    def attach(self, model: SpringModel, n: int) -> SpringModel:
        """`model` (n simulation vertices) with this layout's vertex_map and representative."""
        return replace(
            model,
            vertex_map=_frozen(self.sim.copy()),
            representative=_frozen(_first_of(self.sim, n)),
        )

    def mesh(self, input_mesh: Mesh) -> Mesh:
        """The output mesh: the input's faces on the grown vertex set."""
        inp = self.source
        props = {k: np.asarray(v)[inp] for k, v in input_mesh.vertex_properties.items()}
        return replace(
            input_mesh,
            positions=np.asarray(input_mesh.positions)[inp],
            face_indices=self.corner_out.copy(),
            vertex_properties=props,
            welded=self.sim.copy(),  # the lips of a cut are apart, wherever they start
        )


def _first_of(vertex_map: np.ndarray, n: int) -> np.ndarray:
    """(n,) the first output vertex mapping to each simulation vertex (-1 where none)."""
    rep = np.full(n, -1, dtype=np.int64)
    idx = np.arange(vertex_map.shape[0] - 1, -1, -1, dtype=np.int64)
    rep[vertex_map[idx]] = idx
    return rep
