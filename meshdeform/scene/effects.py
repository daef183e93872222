"""Material effects beyond springs: pressure (volume keeping), plasticity (dents), tethers.

- `Pressure` (Force): closed meshes keep their volume; each vertex is pushed along its
  area-weighted normal by p = stiffness * (target - V) / V0 (Pa), divided by its mass.
- `Plasticity` (Force and Constraint): an anchor-style pull toward a rest copy the effect owns;
  after each substep, wherever a vertex is further than `yield_distance` from its rest copy, the
  copy creeps toward it (`rate` of the excess per second), so impacts leave dents. The model's
  arrays stay read-only: the only mutable rest state is this effect's own copy.
- `NearestPinTethers` (Constraint): long-range attachments. Every vertex may be at most
  `max_stretch` times its rest graph distance (shortest path over springs) from its nearest pin;
  beyond that it is projected back, which stops the "rubber cloth" stretch of hanging cloth at
  any iteration count, with any solver.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix, csr_matrix
from scipy.sparse.csgraph import connected_components, dijkstra

from meshdeform.geometry import scatter_triangles, triangle_area_vectors
from meshdeform.model import SpringModel, State
from meshdeform.scene.base import Constraint, Force, Remappable


def enclosed_volume(positions: np.ndarray, triangles: np.ndarray) -> float:
    """Signed volume enclosed by triangles (positive for outward winding), divergence theorem."""
    a = positions[triangles[:, 0]]
    b = positions[triangles[:, 1]]
    c = positions[triangles[:, 2]]
    return float(np.einsum("ij,ij->", a, np.cross(b, c)) / 6.0)


class Pressure(Force):
    """Volume-keeping pressure for a closed mesh.

    stiffness: pressure in Pa at 100% volume loss; volume: target volume as a fraction of the rest
    volume (above 1 inflates).
    """

    def __init__(self, model: SpringModel, stiffness: float, volume: float = 1.0) -> None:
        self.stiffness = float(stiffness)
        v0 = enclosed_volume(model.rest_positions, model.triangles)
        self.orientation = 1.0 if v0 >= 0 else -1.0
        self.rest_volume = abs(v0)
        self.target = float(volume) * self.rest_volume

    def pressure(self, positions: np.ndarray, triangles: np.ndarray) -> float:
        volume = self.orientation * enclosed_volume(positions, triangles)
        return self.stiffness * (self.target - volume) / max(self.rest_volume, 1e-300)

    def accumulate(self, model: SpringModel, state: State, time: float, dt: float, out: np.ndarray) -> None:
        tri = model.triangles
        if tri.shape[0] == 0 or self.rest_volume <= 0:
            return
        x = state.positions
        p = self.pressure(x, tri)
        force = scatter_triangles(tri, triangle_area_vectors(x, tri) * (self.orientation * p), x.shape[0])
        out += force / model.mass[:, None]


class Plasticity(Force, Constraint, Remappable):
    """Anchor-style pull toward an owned rest copy that yields past a threshold (dents stay).

    stiffness: pull in 1/s^2 (acceleration per metre from the rest copy); damping: 1/s, pull on
    velocity; yield_distance: metres a vertex may move from its rest copy elastically; rate: fraction
    of the excess absorbed into the rest copy per second (large = instant).
    Add the same object to `Scene.forces` and `Scene.constraints`.
    """

    def __init__(
        self, model: SpringModel, stiffness: float, yield_distance: float, rate: float, damping: float = 0.0
    ) -> None:
        self.rest = np.array(model.rest_positions, dtype=np.float64, copy=True)
        self.stiffness = float(stiffness)
        self.yield_distance = float(yield_distance)
        self.rate = float(rate)
        self.damping = float(damping)

    def accumulate(self, model: SpringModel, state: State, time: float, dt: float, out: np.ndarray) -> None:
        out -= self.stiffness * (state.positions - self.rest)
        if self.damping > 0:
            out -= self.damping * state.velocities

    def remap(self, model: SpringModel, index_map: np.ndarray) -> None:
        """After a tear (`index_map`: new vertex -> old): copies inherit their rest copy."""
        self.rest = self.rest[index_map]

    def project(self, model: SpringModel, state: State, time: float, dt: float) -> None:
        d = state.positions - self.rest
        length = np.sqrt(np.einsum("ij,ij->i", d, d))
        excess = length - self.yield_distance
        yielding = excess > 0
        if not yielding.any():
            return
        fraction = min(self.rate * dt, 1.0)
        rows = np.flatnonzero(yielding)
        self.rest[rows] += d[rows] * (fraction * excess[rows] / length[rows])[:, None]


#: the most anchor groups whose separation `NearestPinTethers` follows (a Dijkstra search each)
MAX_ANCHOR_GROUPS = 16


class NearestPinTethers(Constraint, Remappable):
    """Long-range attachments: each vertex within `max_stretch` x rest graph distance of its nearest anchor.

    anchors: welded vertices the tethers start from (the recipe's `[material.tethers]` passes
    every hard and soft pin); distances run over every spring of the model weighted by rest
    length. Vertices not connected to an anchor are free. Projected after each solver substep,
    with the velocity away from the anchor removed, so it holds with every solver and follows
    animated and soft pins (the anchors' current positions) and tears (`remap`).

    Where the anchors form several groups (pieces of pinned cloth not joined by springs between
    anchors: two grips), each vertex also knows the nearest anchor of another group and its
    limit there (`other`, `other_limit`): grips that move further apart than the rest distances
    to them together scale the vertex's limit by that ratio (its `max_stretch` kept on top).
    Without it the anchored halves followed their grips within their limits and the springs
    between them took the whole stretch (9.6x where the cloth as a whole stretched 1.3x). More
    than `MAX_ANCHOR_GROUPS` groups (many separate pins) keep the plain limits.

    Not the solvers' option `tethers` (`[simulation] tethers`, `solvers.layout.Tethers`): that
    one is on by default (ratio 1.0) for verlet and xpbd only, runs inside their kernels within
    each substep, ties every free vertex to the nearest hard pin of each of its (up to 4)
    nearest pin groups (paths over structural springs; xpbd's over shear ones too), moves
    positions only, and recipes that tear switch it off unless they set it.
    """

    def __init__(self, model: SpringModel, anchors: np.ndarray, max_stretch: float = 1.05) -> None:
        self.max_stretch = float(max_stretch)
        self._attach(model, anchors)

    def remap(self, model: SpringModel, index_map: np.ndarray) -> None:
        """After a tear: copies of anchors anchor too, and the distances are measured again over
        the springs left (a torn-off piece is no longer held)."""
        self._attach(model, np.flatnonzero(np.isin(index_map, self.anchors)))

    def _attach(self, model: SpringModel, anchors: np.ndarray) -> None:
        anchors = np.unique(np.asarray(anchors, dtype=np.int64))
        self.anchors = anchors
        n = model.vertex_count
        self.other: np.ndarray | None = None
        self.other_limit: np.ndarray | None = None
        if anchors.size == 0 or model.spring_count == 0:
            self.vertices = np.zeros(0, dtype=np.int64)
            self.anchor = np.zeros(0, dtype=np.int64)
            self.limit = np.zeros(0)
            return
        s = model.springs
        graph = coo_matrix((model.rest_lengths, (s[:, 0], s[:, 1])), shape=(n, n)).tocsr()
        dist, _, source = dijkstra(graph, directed=False, indices=anchors, return_predecessors=True, min_only=True)
        reach = np.isfinite(dist) & (source >= 0)
        reach[anchors] = False
        self.vertices = np.flatnonzero(reach)
        self.anchor = source[self.vertices].astype(np.int64)
        self.limit = dist[self.vertices] * self.max_stretch
        self._attach_other_groups(graph, anchors)

    def _attach_other_groups(self, graph: csr_matrix, anchors: np.ndarray) -> None:
        """`other` / `other_limit` (class docstring): for each tethered vertex the nearest anchor
        of a group other than its own anchor's, and max_stretch x the rest distance to it (inf
        where none is reachable); left None with one group or more than `MAX_ANCHOR_GROUPS`."""
        among = graph[anchors][:, anchors]
        count, group = connected_components(among, directed=False)
        if count < 2 or count > MAX_ANCHOR_GROUPS:
            return
        far = np.full((count, self.vertices.shape[0]), np.inf)
        near = np.zeros((count, self.vertices.shape[0]), dtype=np.int64)
        for g in range(count):
            dist, _, source = dijkstra(
                graph, directed=False, indices=anchors[group == g], return_predecessors=True, min_only=True
            )
            far[g] = dist[self.vertices]
            near[g] = source[self.vertices]
        own = group[np.searchsorted(anchors, self.anchor)]
        far[own, np.arange(own.shape[0])] = np.inf
        pick = np.argmin(far, axis=0)
        columns = np.arange(pick.shape[0])
        self.other = np.where(np.isfinite(far[pick, columns]), near[pick, columns], self.anchor)
        self.other_limit = far[pick, columns] * self.max_stretch

    def project(self, model: SpringModel, state: State, time: float, dt: float) -> None:
        if self.vertices.size == 0:
            return
        vi = self.vertices
        x = state.positions[vi]
        a = state.positions[self.anchor]
        d = x - a
        length = np.sqrt(np.einsum("ij,ij->i", d, d))
        limit = self.limit
        if self.other is not None and self.other_limit is not None:  # grips pulled apart: limits scaled
            apart = np.linalg.norm(state.positions[self.other] - a, axis=1)
            limit = limit * np.maximum(apart * self.max_stretch / (limit + self.other_limit), 1.0)
        over = (length > limit) & (model.inv_mass[vi] > 0)
        if not over.any():
            return
        rows = np.flatnonzero(over)
        u = d[rows] / length[rows, None]
        new_x = a[rows] + u * limit[rows, None]
        v = state.velocities[vi[rows]]
        outward = np.maximum(np.einsum("ij,ij->i", v, u), 0.0)
        v = v - outward[:, None] * u
        state.positions[vi[rows]] = new_x
        state.velocities[vi[rows]] = v
        state.previous[vi[rows]] = new_x - v * dt
