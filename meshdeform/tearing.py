"""Tearing and scripted cuts that really open the mesh: vertices split, faces separate, pieces fall.

The model of a tear (the one Obi Cloth and most real-time tearing use, here on polygons):

- A *tearable* spring whose stretch ratio (current / rest length; optionally averaged over the
  last `average` substeps so one-substep spikes do not tear) exceeds its break threshold fails.
  A failing shear or bending spring is simply removed. A failing structural spring (a mesh
  edge u-v) tears the cloth open at one of its ends: that vertex is split by the plane through
  it perpendicular to the spring, so the polygons around it on the far side of the plane get a
  copy of the vertex of their own. The crack runs along mesh edges (through vertices, across
  the pull), never through a polygon, so no face ever spans a tear and no face is re-meshed.
  The spring itself survives on the far side (between the copy and the other end): the material
  that failed is the one around the vertex, and every polygon edge keeps its spring.
- Which end: a tearable, not hard-pinned end whose polygons lie on both sides of the plane
  (otherwise splitting it changes nothing); of two such ends the one on a boundary (an existing
  crack tip or the cloth's edge), then the lower index. When several failing springs pick the
  same vertex, the most stretched one sets its plane.
- A crack runs on in the same update: the load concentrates at its tips, so a tearable
  neighbour at the end of the new opening whose spring across the crack is already stretched to
  `tip` (0.9) of its threshold splits too (by the plane perpendicular to that spring), up to
  `lookahead` (8) vertices deep. Without it a crack could only advance one vertex per update,
  slower than the load builds up elsewhere in a fine mesh (which then fragments).
- A scripted cut (`Cut`) at a time splits, in one go, every vertex near a plane or a swept
  polyline whose polygons lie on both sides of it (the crack follows the mesh edges nearest to
  the cut surface), optionally only the vertices of a selection. Cuts may split hard-pinned
  vertices (each copy stays pinned to the same target); tearing never does, since a pin that
  holds both copies cannot relieve the stress.

Splitting (vectorised, run only on the substeps where something breaks): the polygon corners
around each vertex to split are grouped by connected components (scipy) of "the two polygons
share an edge at this vertex and lie on the same side"; the group holding the lowest corner
keeps the vertex index, every other group becomes a new simulation vertex appended at the end,
ordered by (vertex, lowest corner), so the same input always tears the same way. Positions,
previous positions and velocities are copied; masses are redistributed by incident rest area
(the total is kept); springs are rebuilt from the split polygons with `meshdeform.topology`
(structural, shear, bending, without welding: split copies coincide) and only springs that
descend from a spring of the previous model are kept, with its rest length, stiffness and
damping; shear and bending springs whose ends the crack separates disappear with the shared
edges. The result is a new, frozen `SpringModel` plus an index map (new vertex -> old vertex),
as DESIGN.md section 1 asks; the State is resized in place.

Output layout: the input's vertices keep their indices 0..V-1; a corner that now belongs to a
split copy points at an output vertex appended after them (one per input vertex and copy);
per-corner UV and normal indices, groups, polylines and face properties are unchanged (the
faces are the same faces), vertex properties are copied to the new vertices. The new model's
`vertex_map` maps that grown output layout to the simulation vertices, so
`model.to_input_layout(welded)` gives the output positions, and `Tearer.mesh` is the matching
`Mesh`. Polylines (ropes) do not tear: only polygon corners are split.

Speed: the per-substep test is one compiled pass over the tearable springs (with the averaging
ring buffer); everything else runs only on substeps where a spring breaks or a cut falls, and
touches only the neighbourhood of the split vertices (three rings of polygons) apart from a few
O(springs) array copies. Each update hands the solver a new model, which it prepares from
scratch (about 20 xpbd substeps of work); updates are therefore budgeted like a token bucket
(`interval`, `burst`): a crack running through the cloth is applied on the substeps it happens,
heavy sustained tearing waits (failures collect and are applied together) so that it costs at
most about one preparation per `interval` (a frame at 24 fps).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numba as nb
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from meshdeform.arrays import argsort_int, lexsort_int, run_lengths
from meshdeform.mesh import Mesh, fan_triangulate
from meshdeform.model import SpringModel, State
from meshdeform.topology import KIND_NAMES, SpringKind, derive_springs

__all__ = ["Cut", "TearEvent", "TearRegion", "TearSettings", "Tearer", "mesh_pieces"]

_INF = np.inf

#: topology updates are budgeted like a token bucket: up to DEFAULT_BURST of them run on the
#: substeps their springs break, after which one more is allowed per DEFAULT_INTERVAL seconds
#: (failures in between wait and are applied together). Each update hands the solver a new model
#: to prepare, which costs about 20 xpbd substeps (0.6 of a frame on a 128 x 128 cloth): a crack
#: running through the cloth fits in the burst, and heavy sustained tearing (a cloth shredding)
#: costs at most about one preparation per frame at 24 fps.
DEFAULT_INTERVAL = 1.0 / 24.0
DEFAULT_BURST = 32
#: a crack runs on in the same update through tips whose springs across it reach this fraction
#: of their threshold (the load concentrates at a crack tip), at most this many vertices deep
DEFAULT_TIP = 0.9
DEFAULT_LOOKAHEAD = 8


def _frozen(array: np.ndarray) -> np.ndarray:
    array = np.ascontiguousarray(array)
    array.flags.writeable = False
    return array


# ---------------------------------------------------------------------------------------------
# settings
# ---------------------------------------------------------------------------------------------


def kind_thresholds(max_stretch: float | Mapping[str, float] | None) -> np.ndarray:
    """(3,) break stretch per spring kind from a number (structural springs only) or a per-kind
    table {"structural": 1.5, "shear": 2.0, "bending": 2.5}; kinds not given never break (inf)."""
    out = np.full(3, _INF)
    if max_stretch is None:
        return out
    if isinstance(max_stretch, Mapping):
        for name, value in max_stretch.items():
            if name not in KIND_NAMES:
                raise ValueError(f"unknown spring kind {name!r}; choose from {', '.join(KIND_NAMES)}")
            out[KIND_NAMES.index(name)] = float(value)
    else:
        out[SpringKind.STRUCTURAL] = float(max_stretch)
    if np.any(out <= 1.0):
        raise ValueError("a break stretch must be greater than 1 (1 is the rest length)")
    return out


@dataclass(frozen=True)
class TearRegion:
    """Where and when the cloth tears.

    mask: (W,) bool over the model's welded vertices that may tear (None: all of them).
    max_stretch: break stretch ratio: a number applies to structural springs (shear and bending
        then only go where the mesh opens), a table {kind: ratio} sets each kind.
    vertex_max_stretch: optional (W,) per-vertex break stretch of structural springs (a painted
        map), replacing the structural value of `max_stretch`; vertices whose value is not above
        1 (or not finite) do not tear.
    average: a spring breaks when its stretch averaged over this many substeps exceeds the
        threshold (1: the current substep alone).
    """

    mask: np.ndarray | None = None
    max_stretch: float | Mapping[str, float] | None = 1.5
    vertex_max_stretch: np.ndarray | None = None
    average: int = 1


@dataclass(frozen=True, eq=False)
class TearSettings:
    """Per welded vertex: break thresholds per kind (3, W) (inf: never), tearable (W,) bool,
    averaging window (W,) int. A spring is tested when either end tears; its threshold is the
    lower of its two ends' and its window the longer; only a tearable end is ever split.

    interval, burst: the budget of topology updates (see DEFAULT_INTERVAL); tip, lookahead: how
    a crack runs on within one update (see the module docstring)."""

    thresholds: np.ndarray
    tearable: np.ndarray
    window: np.ndarray
    interval: float = DEFAULT_INTERVAL
    burst: int = DEFAULT_BURST
    tip: float = DEFAULT_TIP
    lookahead: int = DEFAULT_LOOKAHEAD

    @classmethod
    def from_regions(
        cls,
        model: SpringModel,
        regions: Sequence[TearRegion],
        interval: float = DEFAULT_INTERVAL,
        burst: int = DEFAULT_BURST,
    ) -> TearSettings:
        """Later regions win where they overlap (as pins do). Hard-pinned vertices never tear.

        interval, burst: the budget of topology updates (see DEFAULT_INTERVAL): up to `burst`
        updates on the substeps springs break, then one per `interval` seconds of simulated time
        (interval 0: no limit, every failure is applied on its substep)."""
        n = model.vertex_count
        thresholds = np.full((3, n), _INF)
        window = np.ones(n, dtype=np.int64)
        tearable = np.zeros(n, dtype=bool)
        for region in regions:
            mask = np.ones(n, dtype=bool) if region.mask is None else np.asarray(region.mask, dtype=bool)
            if mask.shape != (n,):
                raise ValueError(f"tear mask has shape {mask.shape}, expected ({n},)")
            if int(region.average) < 1:
                raise ValueError("average must be at least 1 substep")
            per_kind = kind_thresholds(region.max_stretch)
            values = np.repeat(per_kind[:, None], n, axis=1)
            if region.vertex_max_stretch is not None:
                vm = np.asarray(region.vertex_max_stretch, dtype=np.float64)
                if vm.shape != (n,):
                    raise ValueError(f"vertex_max_stretch has shape {vm.shape}, expected ({n},)")
                values[SpringKind.STRUCTURAL] = np.where(np.isfinite(vm) & (vm > 1.0), vm, _INF)
            thresholds[:, mask] = values[:, mask]
            window[mask] = int(region.average)
            tearable[mask] = True
        tearable &= ~np.asarray(model.pinned)
        tearable &= np.isfinite(thresholds).any(axis=0)
        thresholds[:, ~tearable] = _INF
        if not interval >= 0:
            raise ValueError("the tear update interval must be 0 or more seconds")
        if int(burst) < 1:
            raise ValueError("the tear update burst must be at least 1")
        return cls(thresholds, tearable, window, float(interval), int(burst), DEFAULT_TIP, DEFAULT_LOOKAHEAD)

    def take(self, index_map: np.ndarray) -> TearSettings:
        """The settings for a grown vertex set (copies inherit their original's values)."""
        return replace(
            self,
            thresholds=self.thresholds[:, index_map],
            tearable=self.tearable[index_map],
            window=self.window[index_map],
        )


@dataclass(frozen=True, eq=False)
class Cut:
    """A scripted cut at `time` (s): through a plane (`point`, `normal`), or along a polyline
    (`points` (K, 3), K >= 2) swept along `direction` (the cut surface is the polyline moved
    along that direction; seen along it, the mesh is cut where the polyline crosses it).
    `mask` (W,) limits the vertices that may split (None: all)."""

    time: float
    point: np.ndarray | None = None
    normal: np.ndarray | None = None
    points: np.ndarray | None = None
    direction: np.ndarray | None = None
    mask: np.ndarray | None = None

    @classmethod
    def plane(cls, time: float, point: Sequence[float], normal: Sequence[float], mask: np.ndarray | None = None) -> Cut:
        n = np.asarray(normal, dtype=np.float64).reshape(3)
        if not np.linalg.norm(n) > 0:
            raise ValueError("a cut plane needs a non-zero normal")
        p = np.asarray(point, dtype=np.float64).reshape(3)
        return cls(float(time), point=p, normal=n / np.linalg.norm(n), mask=mask)

    @classmethod
    def polyline(
        cls, time: float, points: Sequence[Sequence[float]], direction: Sequence[float], mask: np.ndarray | None = None
    ) -> Cut:
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        d = np.asarray(direction, dtype=np.float64).reshape(3)
        if p.shape[0] < 2:
            raise ValueError("a cut polyline needs at least 2 points")
        if not np.linalg.norm(d) > 0:
            raise ValueError("a cut polyline needs a non-zero direction")
        return cls(float(time), points=p, direction=d / np.linalg.norm(d), mask=mask)


# ---------------------------------------------------------------------------------------------
# compiled per-substep test
# ---------------------------------------------------------------------------------------------


@nb.njit(cache=True, error_model="numpy", nogil=True)
def _over_threshold(x, a, b, inv_rest, thr, window, ring, step, out_index, out_ratio):  # pragma: no cover
    """Stretch of each tested spring (averaged over its window with the ring buffer, whose rows
    are substeps); writes the springs above their threshold to out_*, returns how many."""
    rows = ring.shape[0]
    slot = step % rows
    count = 0
    for i in range(a.shape[0]):
        ia = a[i]
        ib = b[i]
        dx = x[ib, 0] - x[ia, 0]
        dy = x[ib, 1] - x[ia, 1]
        dz = x[ib, 2] - x[ia, 2]
        r = np.sqrt(dx * dx + dy * dy + dz * dz) * inv_rest[i]
        w = window[i]
        if rows > 1:
            ring[slot, i] = r
            if w > 1:
                total = 0.0
                for j in range(w):
                    total += ring[(step - j) % rows, i]
                r = total / w
        if r > thr[i]:
            out_index[count] = i
            out_ratio[count] = r
            count += 1
    return count


# ---------------------------------------------------------------------------------------------
# topology helpers (all vectorised)
# ---------------------------------------------------------------------------------------------


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


def _lumped_area(rest: np.ndarray, triangles: np.ndarray, n: int) -> np.ndarray:
    if triangles.shape[0] == 0:
        return np.zeros(n)
    e1 = rest[triangles[:, 1]] - rest[triangles[:, 0]]
    e2 = rest[triangles[:, 2]] - rest[triangles[:, 0]]
    area = 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)
    return np.bincount(triangles.ravel(), weights=np.repeat(area / 3.0, 3), minlength=n)


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
    return int(np.unique(labels).shape[0]) if labels.size else 0


# ---------------------------------------------------------------------------------------------
# the engine
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class TearEvent:
    """A topology change: the new model, index_map (W',) new vertex -> previous vertex, parent
    (S',) new spring -> the previous model's spring it descends from, and how many springs broke
    and vertices were added by it."""

    model: SpringModel
    index_map: np.ndarray
    parent: np.ndarray
    broken: int
    split: int


@dataclass
class _Counters:
    broken: int = 0
    split: int = 0
    changed: bool = False


@dataclass
class _SpringState:
    """Per-model data of the tested springs (rebuilt on every topology change).

    index: tested springs (into the model's springs); a, b, inv_rest, thr, window: theirs;
    ring: (rows, tested) stretch of the last substeps; stuck: failed springs no end of which
    can split (not tested again until the topology changes); pending: largest stretch of
    springs that failed since the last update (0: none); all_thr, all_window: (S,) of every
    spring (inf: not tested).
    """

    index: np.ndarray
    a: np.ndarray
    b: np.ndarray
    inv_rest: np.ndarray
    thr: np.ndarray
    window: np.ndarray
    ring: np.ndarray
    stuck: np.ndarray
    pending: np.ndarray
    all_thr: np.ndarray
    all_window: np.ndarray
    any_pending: bool = False
    by_vertex: tuple[np.ndarray, np.ndarray] | None = None


class Tearer:
    """Breaks springs, splits vertices and applies scripted cuts during `meshdeform.simulate`.

    mesh: the input mesh the model was built from (its polygons are what opens); model: that
    model; settings: where and when springs break (None: only cuts); cuts: scripted cuts.
    The simulate loop calls `start(model)` once and `after_substep(model, state, time)` after
    every substep; a returned `TearEvent` carries the new model (the state has been resized in
    place). `mesh` is the current output mesh, `origin` the original welded vertex of every
    current vertex, `pieces` the current number of connected pieces.

    Springs are tested every substep; failures collect and the topology is updated at most
    every `settings.interval` seconds of simulated time (cuts at their own time), because every
    update hands the solver a new model to prepare.
    """

    def __init__(
        self,
        mesh: Mesh,
        model: SpringModel,
        settings: TearSettings | None = None,
        cuts: Sequence[Cut] = (),
    ) -> None:
        if np.asarray(model.vertex_map).shape != (mesh.vertex_count,):
            raise ValueError("the model was not built from this mesh (vertex counts differ)")
        if settings is not None and settings.tearable.shape != (model.vertex_count,):
            raise ValueError("tear settings are for another model (vertex counts differ)")
        self.input_mesh = mesh
        self.initial_model = model
        self.initial_settings = settings
        self.cuts = tuple(sorted(cuts, key=lambda c: c.time))
        for cut in self.cuts:
            if cut.mask is not None and np.asarray(cut.mask).shape != (model.vertex_count,):
                raise ValueError("cut mask is for another model (vertex counts differ)")
        self._nxt = np.asarray(mesh.corner_next, dtype=np.int64)
        self._prv = np.empty_like(self._nxt)
        self._prv[self._nxt] = np.arange(self._nxt.shape[0], dtype=np.int64)
        self._corner_face = np.asarray(mesh.corner_face, dtype=np.int64)
        self._offsets = np.asarray(mesh.face_offsets, dtype=np.int64)
        self._sizes = np.asarray(mesh.face_sizes, dtype=np.int64)
        self._tri_corners = fan_triangulate(np.arange(mesh.face_indices.shape[0], dtype=np.int64), self._offsets)
        self._tri_face = np.asarray(mesh.triangle_face, dtype=np.int64)
        self._line_inputs = np.asarray(mesh.line_indices, dtype=np.int64)
        self._line_offsets = np.asarray(mesh.line_offsets, dtype=np.int64)
        self.reset()

    @property
    def enabled(self) -> bool:
        """Whether anything can ever tear or be cut."""
        return bool(self.cuts) or (self.initial_settings is not None and bool(self.initial_settings.tearable.any()))

    # -- state ------------------------------------------------------------------------------------
    def reset(self) -> None:
        """Back to the untorn input (a new run)."""
        model = self.initial_model
        self.model = model
        self.settings = self.initial_settings
        self.origin = np.arange(model.vertex_count, dtype=np.int64)
        self._cv = np.asarray(model.vertex_map, dtype=np.int64)[self.input_mesh.face_indices]
        self._corner_out = np.asarray(self.input_mesh.face_indices, dtype=np.int64).copy()
        self._out_sim = np.asarray(model.vertex_map, dtype=np.int64).copy()
        self._out_input = np.arange(self.input_mesh.vertex_count, dtype=np.int64)
        self._pending_cuts = list(self.cuts)
        self._step = 0
        self._tokens = float(self.initial_settings.burst) if self.initial_settings is not None else 0.0
        self._token_time = 0.0
        self._mesh: Mesh | None = self.input_mesh
        self._pieces: int | None = None
        self._frame = _Counters()
        self.total_broken = 0
        self.total_split = 0
        self.updates = 0
        self._springs = self._spring_state(model, None, None)

    def start(self, model: SpringModel) -> None:
        """Called by simulate before the first substep: a run from the initial model resets."""
        if model is self.initial_model:
            self.reset()
        elif model is not self.model:
            raise ValueError("Tearer: simulate was given a model this tearer did not build")

    @property
    def mesh(self) -> Mesh:
        """The output mesh of the current topology (the input mesh until something opens)."""
        if self._mesh is None:
            base = self.input_mesh
            inp = self._out_input
            props = {k: np.asarray(v)[inp] for k, v in base.vertex_properties.items()}
            self._mesh = replace(
                base,
                positions=np.asarray(base.positions)[inp],
                face_indices=self._corner_out.copy(),
                vertex_properties=props,
            )
        return self._mesh

    @property
    def output_vertex_map(self) -> np.ndarray:
        """(V',) output vertex -> current simulation vertex (the model's vertex_map)."""
        return self._out_sim

    @property
    def output_origin(self) -> np.ndarray:
        """(V',) output vertex -> the input vertex it was copied from."""
        return self._out_input

    @property
    def pieces(self) -> int:
        """Connected pieces of the current mesh (polygons and polylines joined by shared vertices)."""
        if self._pieces is None:
            referenced = np.zeros(self.model.vertex_count, dtype=bool)
            referenced[self._cv] = True
            if self._line_inputs.size:
                referenced[self._out_sim[self._line_inputs]] = True
            self._pieces = mesh_pieces(self.model, referenced)
        return self._pieces

    def frame_stats(self) -> tuple[int, int, bool]:
        """(springs broken, vertices added, topology changed) since the last call; resets them."""
        c = self._frame
        self._frame = _Counters()
        return c.broken, c.split, c.changed

    # -- per model spring data ----------------------------------------------------------------------
    def _spring_state(self, model: SpringModel, parent: np.ndarray | None, old: _SpringState | None) -> _SpringState:
        s = self.settings
        springs = np.asarray(model.springs, dtype=np.int64)
        if s is None or springs.shape[0] == 0:
            e = np.zeros(0, dtype=np.int64)
            f = np.zeros(0)
            return _SpringState(e, e, e, f, f, e, np.ones((1, 0)), np.zeros(0, bool), f, f, e)
        if old is not None and parent is not None and old.all_thr.shape[0]:
            # a spring descends from one spring between the originals of its ends: same values
            all_thr = old.all_thr[parent]
            all_window = old.all_window[parent]
        else:
            kinds = np.asarray(model.kinds, dtype=np.int64)
            a, b = springs[:, 0], springs[:, 1]
            all_thr = np.minimum(s.thresholds[kinds, a], s.thresholds[kinds, b])
            all_window = np.maximum(s.window[a], s.window[b]).astype(np.int64)
        index = np.flatnonzero(np.isfinite(all_thr))
        rows = int(s.window.max()) if s.window.size else 1
        ring = np.ones((rows, index.shape[0]))
        if old is not None and parent is not None and rows > 1 and old.ring.shape[0] == rows and old.index.size:
            # springs inherit the stretch history of the spring they descend from
            slot = np.full(int(max(old.index.max(), parent.max(initial=0))) + 1, -1, dtype=np.int64)
            slot[old.index] = np.arange(old.index.shape[0])
            src = slot[parent[index]]
            known = src >= 0
            ring[:, known] = old.ring[:, src[known]]
        tested = springs[index]
        rest = np.asarray(model.rest_lengths, dtype=np.float64)[index]
        return _SpringState(
            index=index,
            a=np.ascontiguousarray(tested[:, 0]),
            b=np.ascontiguousarray(tested[:, 1]),
            inv_rest=np.ascontiguousarray(1.0 / np.maximum(rest, 1e-300)),
            thr=np.ascontiguousarray(all_thr[index]),
            window=np.ascontiguousarray(all_window[index]),
            ring=ring,
            stuck=np.zeros(index.shape[0], dtype=bool),
            pending=np.zeros(index.shape[0]),
            all_thr=all_thr,
            all_window=all_window,
        )

    # -- the per-substep entry point -----------------------------------------------------------------
    def after_substep(self, model: SpringModel, state: State, time: float) -> TearEvent | None:
        """Apply due cuts, test the springs, split; None when the topology did not change."""
        if model is not self.model:
            raise ValueError("Tearer.after_substep: not the model of the last tear event")
        events: list[TearEvent] = []
        while self._pending_cuts and self._pending_cuts[0].time <= time + 1e-9:
            event = self._apply_cut(self._pending_cuts.pop(0), state)
            if event is not None:
                events.append(event)
        sp = self._springs
        if sp.index.shape[0]:
            out_index = np.empty(sp.index.shape[0], dtype=np.int64)
            out_ratio = np.empty(sp.index.shape[0])
            count = _over_threshold(
                state.positions, sp.a, sp.b, sp.inv_rest, sp.thr, sp.window, sp.ring, self._step, out_index, out_ratio
            )
            if count:
                idx = out_index[:count]
                fresh = ~sp.stuck[idx]
                if fresh.any():
                    idx = idx[fresh]
                    sp.pending[idx] = np.maximum(sp.pending[idx], out_ratio[:count][fresh])
                    sp.any_pending = True
            s = self.settings
            assert s is not None
            if s.interval > 0:  # refill the update budget
                self._tokens = min(float(s.burst), self._tokens + (time - self._token_time) / s.interval)
            self._token_time = time
            if sp.any_pending and (s.interval <= 0 or self._tokens >= 1.0 - 1e-9):
                event = self._tear(state)
                if event is not None:
                    self._tokens -= 1.0
                    events.append(event)
        self._step += 1
        if not events:
            return None
        self.updates += 1
        if len(events) == 1:
            return events[0]
        index_map = events[0].index_map
        parent = events[0].parent
        for e in events[1:]:
            index_map = index_map[e.index_map]
            parent = parent[e.parent]
        return TearEvent(
            model=events[-1].model,
            index_map=index_map,
            parent=parent,
            broken=sum(e.broken for e in events),
            split=sum(e.split for e in events),
        )

    # -- local geometry queries (only the vertices involved, never the whole mesh) --------------------
    def _corners_of(self, vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Corners at each entry of `vertices` (entries may repeat): (entry per item, corner per item)."""
        n = self.model.vertex_count
        wanted = np.zeros(n, dtype=bool)
        wanted[vertices] = True
        cs = np.flatnonzero(wanted[self._cv])
        order = argsort_int(self._cv[cs])
        cs = cs[order]
        at = self._cv[cs]
        starts, lengths = run_lengths(at)
        pos = np.searchsorted(at[starts], vertices)
        first = starts[pos]
        count = lengths[pos]
        owner = np.repeat(np.arange(vertices.shape[0], dtype=np.int64), count)
        begin = np.cumsum(count) - count
        local = np.arange(owner.shape[0], dtype=np.int64) - np.repeat(begin, count)
        return owner, cs[np.repeat(first, count) + local]

    def _centroids(self, x: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """Current centroids (k, 3) of these polygons."""
        if faces.shape[0] == 0:
            return np.zeros((0, 3))
        size = self._sizes[faces]
        begin = np.cumsum(size) - size
        local = np.arange(int(size.sum()), dtype=np.int64) - np.repeat(begin, size)
        pts = x[self._cv[np.repeat(self._offsets[faces], size) + local]]
        return np.add.reduceat(pts, begin, axis=0) / size[:, None]

    def _on_boundary(self, vertices: np.ndarray) -> np.ndarray:
        """(k,) bool: whether each vertex has an edge used by one polygon only."""
        n = max(self.model.vertex_count, 1)
        owner, corners = self._corners_of(vertices)
        here = self._cv[corners]
        other = np.concatenate([self._cv[self._nxt[corners]], self._cv[self._prv[corners]]])
        who = np.concatenate([owner, owner])
        keep = other != np.concatenate([here, here])
        keys = np.sort(who[keep] * n + other[keep])
        starts, lengths = run_lengths(keys)
        out = np.zeros(vertices.shape[0], dtype=bool)
        out[keys[starts[lengths == 1]] // n] = True
        return out

    # -- tearing ---------------------------------------------------------------------------------
    def _tear(self, state: State) -> TearEvent | None:
        sp = self._springs
        local = np.flatnonzero(sp.pending > 0)
        ratio = sp.pending[local]
        sp.pending[:] = 0.0
        sp.any_pending = False
        if local.size == 0:
            return None
        model = self.model
        spring = sp.index[local]
        structural = np.asarray(model.kinds)[spring] == SpringKind.STRUCTURAL
        remove = spring[~structural]  # failing shear / bending springs just go
        split_mask = np.zeros(model.vertex_count, dtype=bool)
        side = np.zeros(self._cv.shape[0], dtype=np.int8)
        acted = ~structural
        ahead = 0
        if structural.any():
            rows = np.flatnonzero(structural)
            chosen, vertices, normals = self._choose_ends(state.positions, spring[rows], ratio[rows])
            ok = vertices >= 0
            # no end can split: not tested again until the topology changes
            sp.stuck[local[rows[chosen[~ok]]]] = True
            if ok.any():
                acted[rows[chosen[ok]]] = True
                v = vertices[ok]
                nrm = normals[ok]
                ahead_v, ahead_n = self._crack_ahead(state.positions, v, nrm)
                ahead = int(ahead_v.shape[0])
                v = np.concatenate([v, ahead_v])
                nrm = np.concatenate([nrm, ahead_n])
                split_mask[v] = True
                owner, corners = self._corners_of(v)
                centroid = self._centroids(state.positions, self._corner_face[corners])
                d = np.einsum("ij,ij->i", centroid - state.positions[v][owner], nrm[owner])
                side[corners] = (d > 0).astype(np.int8)
        if not split_mask.any() and remove.size == 0:
            return None
        event = self._apply(state, split_mask, side, remove, int(np.count_nonzero(acted)) + ahead)
        if event is None:
            sp.stuck[local[acted]] = True
        return event

    def _tested_structural(self) -> tuple[np.ndarray, np.ndarray]:
        """Tested structural springs by vertex: (indptr (W+1,), tested-spring slots)."""
        sp = self._springs
        if sp.by_vertex is None:
            n = self.model.vertex_count
            slots = np.flatnonzero(np.asarray(self.model.kinds)[sp.index] == SpringKind.STRUCTURAL)
            ends = np.concatenate([sp.a[slots], sp.b[slots]])
            order = argsort_int(ends)
            indptr = np.zeros(n + 1, dtype=np.int64)
            np.cumsum(np.bincount(ends, minlength=n), out=indptr[1:])
            sp.by_vertex = (indptr, np.concatenate([slots, slots])[order])
        return sp.by_vertex

    def _crack_ahead(self, x: np.ndarray, vertices: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Crack tips that give way in the same update: (vertices, plane normals).

        A crack concentrates the load at its tips. From each vertex being split, the crack runs
        on along its plane: a neighbour lying near that plane (a tip of the new opening) that may
        tear, is not pinned and has a structural spring across the crack (within 45 degrees of
        the plane normal) stretched to `settings.tip` times its threshold is split too, by the
        plane perpendicular to its most stretched such spring; up to `settings.lookahead` rings.
        """
        s = self.settings
        assert s is not None
        empty = (np.zeros(0, dtype=np.int64), np.zeros((0, 3)))
        if s.lookahead <= 0 or s.tip <= 0 or vertices.size == 0:
            return empty
        sp = self._springs
        indptr, slots = self._tested_structural()
        n = self.model.vertex_count
        taken = np.zeros(n, dtype=bool)
        taken[vertices] = True
        able = s.tearable & ~np.asarray(self.model.pinned)
        unit = normals / np.maximum(np.linalg.norm(normals, axis=1), 1e-300)[:, None]
        front, front_n = vertices, unit
        found_v: list[np.ndarray] = []
        found_n: list[np.ndarray] = []

        def springs_at(verts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            start = indptr[verts]
            count = indptr[verts + 1] - start
            owner = np.repeat(np.arange(verts.shape[0], dtype=np.int64), count)
            begin = np.cumsum(count) - count
            local = np.arange(owner.shape[0], dtype=np.int64) - np.repeat(begin, count)
            return owner, slots[np.repeat(start, count) + local]

        for _ in range(s.lookahead):
            # neighbours of the front that lie near its plane: where the opening ends
            owner, slot = springs_at(front)
            here = front[owner]
            other = np.where(sp.a[slot] == here, sp.b[slot], sp.a[slot])
            d = x[other] - x[here]
            length = np.maximum(np.linalg.norm(d, axis=1), 1e-300)
            near_plane = np.abs(np.einsum("ij,ij->i", d, front_n[owner])) < 0.5 * length
            keep = near_plane & able[other] & ~taken[other]
            cand, cand_n = other[keep], front_n[owner[keep]]
            if cand.size == 0:
                break
            first = np.unique(cand, return_index=True)[1]  # one plane per candidate (the first front's)
            cand, cand_n = cand[first], cand_n[first]
            # their springs across the crack, and how far they are stretched toward breaking
            owner2, slot2 = springs_at(cand)
            e = x[sp.b[slot2]] - x[sp.a[slot2]]
            elen = np.maximum(np.linalg.norm(e, axis=1), 1e-300)
            across = np.abs(np.einsum("ij,ij->i", e, cand_n[owner2])) > 0.7071 * elen
            load = np.where(across, elen * sp.inv_rest[slot2] / sp.thr[slot2], 0.0)
            best = np.full(cand.shape[0], -1.0)
            np.maximum.at(best, owner2, load)
            gives = best >= s.tip
            if not gives.any():
                break
            # the plane of each new tip: perpendicular to its most loaded spring across the crack
            row = np.flatnonzero(load == best[owner2])
            pick = np.full(cand.shape[0], -1, dtype=np.int64)
            pick[owner2[row[::-1]]] = row[::-1]
            tips = np.flatnonzero(gives)
            new_n = e[pick[tips]]
            new_n /= np.maximum(np.linalg.norm(new_n, axis=1), 1e-300)[:, None]
            new_n *= np.where(np.einsum("ij,ij->i", new_n, cand_n[tips]) < 0, -1.0, 1.0)[:, None]
            front, front_n = cand[tips], new_n
            taken[front] = True
            found_v.append(front)
            found_n.append(front_n)
        if not found_v:
            return empty
        return np.concatenate(found_v), np.concatenate(found_n)

    def _choose_ends(
        self, x: np.ndarray, springs: np.ndarray, ratio: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For failing structural springs: which end to split and the plane normal there.

        Returns (rows, vertex, normal): one row per vertex to split (set by the most stretched
        spring choosing it, ties to the lower spring index), then the rows of springs with no
        end that can split, with vertex -1.
        """
        model = self.model
        assert self.settings is not None
        pairs = np.asarray(model.springs, dtype=np.int64)[springs]
        k = pairs.shape[0]
        ends = np.concatenate([pairs[:, 0], pairs[:, 1]])
        direction = np.concatenate([x[pairs[:, 1]] - x[pairs[:, 0]], x[pairs[:, 0]] - x[pairs[:, 1]]])
        row = np.concatenate([np.arange(k), np.arange(k)])
        eligible = self.settings.tearable[ends] & ~np.asarray(model.pinned)[ends]
        cand = np.flatnonzero(eligible)
        if cand.size:
            # splitting only helps where polygons lie on both sides of the plane
            owner, corners = self._corners_of(ends[cand])
            centroid = self._centroids(x, self._corner_face[corners])
            d = np.einsum("ij,ij->i", centroid - x[ends[cand]][owner], direction[cand][owner])
            front = np.bincount(owner, weights=(d > 0).astype(np.float64), minlength=cand.shape[0])
            total = np.bincount(owner, minlength=cand.shape[0])
            eligible[cand[(front == 0) | (front == total)]] = False
        boundary = np.zeros(2 * k, dtype=bool)
        if eligible.any():
            boundary[eligible] = self._on_boundary(ends[eligible])
        # per spring: eligible first, then on a boundary (a crack tip or the edge), then the first end
        score = eligible.astype(np.int64) * 4 + boundary * 2 + np.repeat([1, 0], k)
        best = np.where(score[:k] >= score[k:], np.arange(k), np.arange(k, 2 * k))
        has = eligible[best]
        spring_rows = np.flatnonzero(has)
        cand_idx = best[spring_rows]
        vert = ends[cand_idx]
        order = np.lexsort((springs[spring_rows], -ratio[spring_rows], vert))
        vs = vert[order]
        first = np.ones(vs.shape[0], dtype=bool)
        first[1:] = vs[1:] != vs[:-1]
        chosen = order[first]
        none_rows = np.flatnonzero(~has)
        del row
        return (
            np.concatenate([spring_rows[chosen], none_rows]),
            np.concatenate([vert[chosen], np.full(none_rows.shape[0], -1, dtype=np.int64)]),
            np.concatenate([direction[cand_idx[chosen]], np.zeros((none_rows.shape[0], 3))]),
        )

    # -- cuts ---------------------------------------------------------------------------------------
    def _apply_cut(self, cut: Cut, state: State) -> TearEvent | None:
        x = state.positions
        n = self.model.vertex_count
        cv = self._cv
        centroid = self._centroids(x, np.arange(self._sizes.shape[0], dtype=np.int64))
        s = cv
        e = cv[self._nxt]
        if cut.normal is not None:
            assert cut.point is not None
            vside = (x - cut.point) @ cut.normal > 0
            face_side = (centroid - cut.point) @ cut.normal > 0
            crossing = vside[s] != vside[e]
        else:
            assert cut.points is not None and cut.direction is not None
            e1, e2 = _basis(cut.direction)
            poly = np.stack([cut.points @ e1, cut.points @ e2], axis=1)
            flat = np.stack([x @ e1, x @ e2], axis=1)
            face_side = _polyline_side(np.stack([centroid @ e1, centroid @ e2], axis=1), poly)
            crossing = _segments_cross(flat[s], flat[e], poly)
        near = np.zeros(n, dtype=bool)
        near[s[crossing]] = True
        near[e[crossing]] = True
        if cut.mask is not None:
            near &= np.asarray(cut.mask, dtype=bool)[self.origin]
        side = face_side[self._corner_face].astype(np.int8)
        # only vertices with polygons on both sides split
        count = np.bincount(cv, minlength=n)
        front = np.bincount(cv, weights=side.astype(np.float64), minlength=n)
        near &= (front > 0) & (front < count)
        if not near.any():
            return None
        return self._apply(state, near, side, np.zeros(0, dtype=np.int64), 0)

    # -- applying a split ------------------------------------------------------------------------------
    def _apply(
        self, state: State, split_mask: np.ndarray, side: np.ndarray, remove: np.ndarray, broken: int
    ) -> TearEvent | None:
        """Split, rebuild the model, grow the output layout and the state; None if nothing changed."""
        model = self.model
        n = model.vertex_count
        if split_mask.any():
            cv, index_map = split_vertices(self._cv, self._nxt, n, split_mask, side)
        else:
            cv, index_map = self._cv, np.arange(n, dtype=np.int64)
        new_count = index_map.shape[0] - n
        if new_count == 0 and remove.size == 0:
            return None
        new_model, parent = self._rebuild(cv, index_map, remove)
        # springs the opening separated (no descendant left) count as broken too
        lost = np.bincount(parent, minlength=model.spring_count) == 0
        lost[remove] = False
        broken_total = broken + int(np.count_nonzero(lost))
        # the output layout: corners moved to a copy get an output vertex per (copy, input vertex)
        moved = np.flatnonzero(cv != self._cv)
        if moved.size:
            inputs = np.asarray(self.input_mesh.face_indices, dtype=np.int64)[moved]
            vcount = max(self.input_mesh.vertex_count, 1)
            keys = cv[moved] * vcount + inputs
            order = argsort_int(keys)
            sk = keys[order]
            first = np.ones(sk.shape[0], dtype=bool)
            first[1:] = sk[1:] != sk[:-1]
            out_ids = np.empty(moved.shape[0], dtype=np.int64)
            out_ids[order] = self._out_sim.shape[0] + np.cumsum(first) - 1
            self._corner_out[moved] = out_ids
            uniq = sk[first]
            self._out_sim = np.concatenate([self._out_sim, uniq // vcount])
            self._out_input = np.concatenate([self._out_input, uniq % vcount])
        new_model = replace(
            new_model,
            vertex_map=_frozen(self._out_sim.copy()),
            representative=_frozen(_first_of(self._out_sim, index_map.shape[0])),
        )
        self._cv = cv
        self.origin = self.origin[index_map]
        if new_count and self.settings is not None:
            self.settings = self.settings.take(index_map)
        state.positions = np.ascontiguousarray(state.positions[index_map])
        state.previous = np.ascontiguousarray(state.previous[index_map])
        state.velocities = np.ascontiguousarray(state.velocities[index_map])
        self._springs = self._spring_state(new_model, parent, self._springs)
        self.model = new_model
        self._mesh = None
        self._pieces = None
        self._frame.broken += broken_total
        self._frame.split += new_count
        self._frame.changed = True
        self.total_broken += broken_total
        self.total_split += new_count
        return TearEvent(model=new_model, index_map=index_map, parent=parent, broken=broken_total, split=new_count)

    def _faces_touching(self, cv: np.ndarray, vertices: np.ndarray) -> np.ndarray:
        faces = np.zeros(self._sizes.shape[0], dtype=bool)
        faces[self._corner_face[vertices[cv]]] = True
        return faces

    def _vertices_of(self, cv: np.ndarray, faces: np.ndarray, n: int) -> np.ndarray:
        out = np.zeros(n, dtype=bool)
        out[cv[faces[self._corner_face]]] = True
        return out

    def _rebuild(self, cv: np.ndarray, index_map: np.ndarray, remove: np.ndarray) -> tuple[SpringModel, np.ndarray]:
        """The model of the split topology and each new spring's parent (old spring index).

        Only the neighbourhood of the split vertices is re-derived: springs with an end at a split
        vertex (or its copies) or with both ends within one ring of them are rebuilt from the
        polygons around them (three rings, so bending springs see every neighbour of their middle
        vertex), and kept only where they descend from an old spring; every other spring stays.
        """
        old = self.model
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
            ring1 = self._vertices_of(cv, self._faces_touching(cv, split), n) | split
            ring2 = self._vertices_of(cv, self._faces_touching(cv, ring1), n) | ring1
            local_faces = self._faces_touching(cv, ring2)
            rest = np.asarray(old.rest_positions)[index_map]
            pairs, kinds = self._local_springs(cv, local_faces, ring2, rest, n)
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
            korder = np.argsort(okeys, kind="stable")
            okeys = okeys[korder]
            ma, mb = index_map[pairs[:, 0]], index_map[pairs[:, 1]]
            keys = (np.minimum(ma, mb) * n_old + np.maximum(ma, mb)) * 3 + kinds
            pos = np.minimum(np.searchsorted(okeys, keys), max(okeys.shape[0] - 1, 0))
            match = okeys[pos] == keys if okeys.size else np.zeros(keys.shape[0], dtype=bool)
            local_parent = candidates[korder[pos[match]]]
            parent = np.concatenate([unchanged, local_parent])
            new_pairs = np.concatenate([old_pairs[unchanged], pairs[match].astype(np.int32)])
            triangles = cv[self._tri_corners]
            mass = self._masses(cv, index_map, split, rest, triangles)
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
        self, cv: np.ndarray, faces: np.ndarray, within: np.ndarray, rest: np.ndarray, n: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """Springs (pairs, kinds) of the given polygons (and the polylines touching `within`)."""
        corner_mask = faces[self._corner_face]
        sizes = self._sizes[faces]
        offsets = np.zeros(sizes.shape[0] + 1, dtype=np.int64)
        np.cumsum(sizes, out=offsets[1:])
        line_indices = np.zeros(0, dtype=np.int64)
        line_offsets = np.zeros(1, dtype=np.int64)
        if self._line_inputs.size:
            verts = self._out_sim[self._line_inputs]
            lsizes = np.diff(self._line_offsets)
            nonempty = lsizes > 0
            touch = np.zeros(lsizes.shape[0], dtype=bool)
            touch[nonempty] = np.logical_or.reduceat(within[verts], self._line_offsets[:-1][nonempty])
            keep = np.repeat(touch, lsizes)
            line_indices = verts[keep]
            line_offsets = np.zeros(int(touch.sum()) + 1, dtype=np.int64)
            np.cumsum(lsizes[touch], out=line_offsets[1:])
        local = Mesh(
            positions=rest,
            face_indices=cv[corner_mask],
            face_offsets=offsets,
            line_indices=line_indices,
            line_offsets=line_offsets,
        )
        springs = derive_springs(local, np.arange(n, dtype=np.int64), rest)
        return springs.pairs.astype(np.int64), springs.kinds.astype(np.int64)

    def _masses(
        self, cv: np.ndarray, index_map: np.ndarray, split: np.ndarray, rest: np.ndarray, triangles: np.ndarray
    ) -> np.ndarray:
        """Old masses, with each split vertex's mass shared among its copies by incident rest area."""
        old = self.model
        mass = np.asarray(old.mass)[index_map].copy()
        touch = split[triangles].any(axis=1)
        tris = triangles[touch]
        n = index_map.shape[0]
        area = _lumped_area(rest, tris, n)
        corners = np.bincount(cv, minlength=n).astype(np.float64)
        idx = np.flatnonzero(split)
        a = area[idx]
        scale = float(a[a > 0].mean()) if np.any(a > 0) else 1.0
        weight = a + 1e-6 * scale * corners[idx]
        total = np.bincount(index_map[idx], weights=weight, minlength=old.vertex_count)[index_map[idx]]
        share = np.where(total > 0, weight / np.where(total > 0, total, 1.0), 1.0)
        mass[idx] = np.asarray(old.mass)[index_map[idx]] * share
        return np.where(mass > 0, mass, np.asarray(old.mass)[index_map])


def _first_of(vertex_map: np.ndarray, n: int) -> np.ndarray:
    """(n,) the first output vertex mapping to each simulation vertex (-1 where none)."""
    rep = np.full(n, -1, dtype=np.int64)
    idx = np.arange(vertex_map.shape[0] - 1, -1, -1, dtype=np.int64)
    rep[vertex_map[idx]] = idx
    return rep


# ---------------------------------------------------------------------------------------------
# cut geometry
# ---------------------------------------------------------------------------------------------


def _basis(direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors orthogonal to `direction` and to each other."""
    d = direction / np.linalg.norm(direction)
    helper = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(d, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(d, e1)


def _polyline_side(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """(N,) bool: which side of a 2D polyline each point is on (by its nearest segment)."""
    a = poly[:-1]
    b = poly[1:]
    ab = b - a
    length2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300)
    best = np.full(points.shape[0], np.inf)
    sign = np.zeros(points.shape[0], dtype=bool)
    for k in range(a.shape[0]):
        ap = points - a[k]
        t = np.clip(ap @ ab[k] / length2[k], 0.0, 1.0)
        closest = a[k] + t[:, None] * ab[k]
        d = np.einsum("ij,ij->i", points - closest, points - closest)
        cross = ab[k, 0] * ap[:, 1] - ab[k, 1] * ap[:, 0]
        better = d < best
        best = np.where(better, d, best)
        sign = np.where(better, cross > 0, sign)
    return sign


def _segments_cross(p: np.ndarray, q: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """(N,) bool: whether 2D segment p-q crosses any segment of the polyline."""
    out = np.zeros(p.shape[0], dtype=bool)

    def orient(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
        return (b[..., 0] - a[..., 0]) * (c[..., 1] - a[..., 1]) - (b[..., 1] - a[..., 1]) * (c[..., 0] - a[..., 0])

    for k in range(poly.shape[0] - 1):
        a, b = poly[k], poly[k + 1]
        d1 = orient(a, b, p)
        d2 = orient(a, b, q)
        d3 = orient(p, q, a[None, :])
        d4 = orient(p, q, b[None, :])
        out |= ((d1 > 0) != (d2 > 0)) & ((d3 > 0) != (d4 > 0))
    return out
