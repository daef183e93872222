"""Self-collision: the cloth never passes through itself, and keeps a thickness between its parts.

The method (Bridson, Fedkiw, Anderson 2002, with a conservative continuous check in place of
cubic root finding), run as the last Constraint of every substep, on the positions x the solver
and the colliders produced, from the positions x0 the substep started at:

1. **Proximity.** Vertex-triangle and edge-edge pairs of the cloth closer than the thickness are
   pushed apart to it (Gauss-Seidel in a fixed pair order, inverse-mass and barycentric
   weighted), along the side each pair had at the start of the substep, so a pair that crossed
   within one substep is pulled back rather than pushed further through. A pair already closer
   than the thickness in the rest mesh keeps its rest distance instead, so a fine mesh is not
   inflated. Rest neighbours (a vertex and a triangle of its one-ring, edges with neighbouring
   ends) and the copies of one vertex that a tear made are kept only a tenth of the thickness
   apart (`PART_FRACTION`, the parting's distance): the springs keep rest neighbours apart
   (held a thickness apart, a fine cloth compressed in its plane was pushed apart too), but left
   to them entirely they lay a hundredth of a millimetre apart in a crumpled cloth's creases,
   where the continuous check could not prove them apart and zoned them in every substep; and
   two copies of one vertex closed on each other until they touched, where no pair is judged.
2. **Guarantee.** Every pair that shares no vertex is checked along its straight path from x0
   to x by conservative advancement (Li et al. 2021, "additive CCD"): the pair's distance can
   shrink at most by a bound on its vertices' relative travel, so stepping by a fraction of the
   current distance over that bound either proves the pair stays apart or flags it. No
   root finding, so no rounding can let a crossing slip through.
3. **Fail-safe.** The vertices of flagged pairs form impact zones (Provot 1997; Bridson et al.
   2002): each zone takes one common translation (its mass-weighted mean displacement), which
   keeps all distances inside it, and the check repeats until nothing is flagged. It always
   ends: at worst all involved vertices share one translation. A zone with pinned members
   moves as they do: by their translation, or, where they turn as one rigid body (a row of
   pins twisting a strip), by that turn (`rigid_motion`): every point of the zone then follows
   one invertible affine map along the substep, so no pair inside it can meet (the check, which
   cannot prove a close pair apart while it turns, leaves such pairs out: `_inside`). Where
   colliders take part, the colliders and zones that fall back to where the substep started
   then run in turns (`FINAL_ROUNDS`) until neither moves what the other left: that start is
   clear of a still collider; a zone with a member a moving collider pushed moves as the
   collider carries that start instead (`Collider.carry`), clear of it too (docs/performance.md,
   "Zones carried by a moving collider").

Because the rest mesh is free of intersections and every substep moves from an
intersection-free state along paths proven not to touch, no two triangles that share no vertex
ever intersect after a substep, at any speed. The broad phase is a hashed grid filled by
counting sort (`broad_phase`), and all kernels run serially in fixed orders, so the result is
the same bytes whatever the executor or thread count.

Tearing: the copies a tear makes start where their original is, touching the triangles of its
other side, so right after a tear the vertices of each split are parted (`part_seams`: along the
split's normal, a tenth of the thickness one way and the other, and a little into their own
triangles, their whole substep with them; another way, or none, where that would make the
triangles around the split cross: `_parting`) and every pair of the two sides starts apart.
Proximity keeps a pair whose vertices came from one rest vertex, or neighbours (`origin`,
updated by `remap`), the parting's distance apart, not the thickness (they were one vertex at
rest: a tear opens as it would without self-collision; neighbours closer at rest, their rest
distance: `_neighbour_gap`), so they never close to within
`self_kernels.TOUCHING`, where the continuous check no longer judges them; that check takes
every pair sharing no vertex, the two sides of a tear included, so they never pass through each
other, and new boundary edges take part like any other.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from meshdeform.contact import self_kernels
from meshdeform.contact.broad_phase import (
    SCAN_QUERIES,
    grid_for,
    near_elements,
    overlapping_pairs,
    scan_grid,
    strays,
    swept_boxes,
)
from meshdeform.contact.parts import by_rows, search_in_parts
from meshdeform.contact.triangle_distance import triangles_cross
from meshdeform.geometry import scatter_triangles, triangle_area_vectors
from meshdeform.model import SpringModel, State
from meshdeform.scene.base import Constraint, Remappable
from meshdeform.scene.colliders import Collider, pushed_vertices
from meshdeform.solvers.threads import ThreadPicker, split_threads


@dataclass(frozen=True)
class SelfCollisionSettings:
    """thickness: metres kept between parts of the cloth that are not rest neighbours (their rest
        distance where less; rest neighbours and a tear's copies of one vertex: a tenth of it).
    friction: Coulomb coefficient between touching parts (0: slide freely).
    sweeps: proximity Gauss-Seidel sweeps per substep.
    max_rounds: impact-zone rounds per substep before all flagged vertices take one shared
        translation (the last resort that always succeeds).
    """

    thickness: float = 0.005
    friction: float = 0.1
    sweeps: int = 2
    max_rounds: int = 64


@dataclass
class ContactWork:
    """What self-collision did in a span of substeps: proximity projections, pairs flagged by the
    continuous check, impact-zone rounds, the largest zone (vertices), how often candidate
    pairs were searched afresh (all of them, or those of the vertices that strayed: `_Pairs`), and
    the substeps whose zones ran out of rounds with pairs the check still could not prove apart
    (`unresolved`: there the cloth may pass through itself; the job report warns)."""

    projections: int = 0
    flagged_pairs: int = 0
    zone_rounds: int = 0
    largest_zone: int = 0
    pair_builds: int = 0
    unresolved: int = 0

    def add(self, other: ContactWork) -> None:
        self.unresolved += other.unresolved
        self.pair_builds += other.pair_builds
        self.projections += other.projections
        self.flagged_pairs += other.flagged_pairs
        self.zone_rounds += other.zone_rounds
        self.largest_zone = max(self.largest_zone, other.largest_zone)


@dataclass(frozen=True)
class _Topology:
    """The contact primitives of one model: triangles (T, 3), unique edges (E, 2), int64."""

    triangles: np.ndarray
    edges: np.ndarray

    @classmethod
    def of(cls, model: SpringModel) -> _Topology:
        triangles = np.ascontiguousarray(model.triangles, dtype=np.int64)
        pairs = np.sort(triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        edges = np.unique(pairs, axis=0) if pairs.size else np.zeros((0, 2), dtype=np.int64)
        return cls(triangles, np.ascontiguousarray(edges, dtype=np.int64))


def _rings(edges: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Vertex adjacency as CSR (start (n + 1,), sorted neighbours) from edges (E, 2)."""
    both = np.concatenate([edges, edges[:, ::-1]]) if edges.size else np.zeros((0, 2), dtype=np.int64)
    order = np.lexsort((both[:, 1], both[:, 0]))
    both = both[order]
    start = np.zeros(n + 1, dtype=np.int64)
    np.add.at(start, both[:, 0] + 1, 1)
    return np.cumsum(start), np.ascontiguousarray(both[:, 1], dtype=np.int64)


@dataclass
class _Pairs:
    """Candidate pairs kept over several substeps (a Verlet list): VF (P, 2) and EE (Q, 2), each
    pair's flag that it is apart in the rest mesh (`origin`s neither equal nor neighbours), rest distance (m)
    and a lower bound (m) of its current distance that the continuous check keeps up to date
    (`self_kernels.colliding_pairs`).

    Each vertex has a carried-on path: after substep `built` (V,) it is at `base` (V, 3) and
    moves on by `motion` (V, 3, m) a substep. The list covers a vertex for `span` substeps
    (`list_substeps`) from its `built` while it stays within the slack (m) of that path (`stale`: the
    departure common to all vertices taken out, as a common translation brings no pair closer).
    Over such a span two points come closer by at most `span` times their relative
    motion plus twice the slack (and a triangle's or an edge's points by at most their corners'
    largest such figure), so the pairs further apart than the thickness plus that reach cannot
    come within the thickness or touch and are left out. The reach is relative, so parts of the
    cloth that move together (a falling or sliding sheet, neighbours anywhere) keep only the
    pairs within the thickness, however fast they go. A vertex the list no longer covers gets
    a new path and its pairs are searched again (`SelfCollision._regather`).
    """

    vf: np.ndarray
    vf_apart: np.ndarray
    vf_rest: np.ndarray
    vf_lower: np.ndarray
    ee: np.ndarray
    ee_apart: np.ndarray
    ee_rest: np.ndarray
    ee_lower: np.ndarray
    base: np.ndarray
    motion: np.ndarray
    built: np.ndarray

    @classmethod
    def empty(cls, n: int) -> _Pairs:
        """No pairs, for n vertices whose paths are yet to be set (`SelfCollision._regather`)."""
        none, flags = np.zeros((0, 2), dtype=np.int64), np.zeros(0, dtype=np.bool_)
        return cls(
            none, flags, np.zeros(0), np.zeros(0), none, flags, np.zeros(0), np.zeros(0),
            np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n, dtype=np.int64),
        )

    def stale(
        self, x0: np.ndarray, x1: np.ndarray, substep: int, slack: float, span: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The vertices (V,) bool this list does not cover in substep number `substep`, from x0
        to x1 (V, 3): past their span of `span` substeps, or an end of the substep further than `slack` (m) from
        their path after the common departure (then every point between the ends is within it
        too); and those common departures at x0 and x1 (3,) each."""
        age = (substep - self.built).astype(np.float64)
        at_end, at_start = np.empty(x1.shape[0], dtype=np.bool_), np.empty(x1.shape[0], dtype=np.bool_)
        common_end = strays(x1, self.base, self.motion, age, slack, at_end)
        common_start = strays(x0, self.base, self.motion, age - 1.0, slack, at_start)
        return at_end | at_start | (age > span), common_start, common_end


class SelfCollision(Constraint, Remappable):
    """The cloth's contact with itself, as the last Constraint of a substep (see the module
    docstring). `colliders`: the scene's colliders, projected again between the proximity step
    and the continuous check where the proximity step moved something (a layer pushed by the
    cloth above it stays out of the collider).
    `work` accumulates what it did (`take_work` hands it over per frame)."""

    def __init__(self, settings: SelfCollisionSettings | None = None, colliders: Sequence[Collider] = ()) -> None:
        self.settings = settings or SelfCollisionSettings()
        self.colliders = tuple(colliders)
        self._model: SpringModel | None = None
        self._topology: _Topology | None = None
        self._origin: np.ndarray | None = None
        self._rings: tuple[np.ndarray, np.ndarray] | None = None
        self._start: np.ndarray | None = None
        #: (V,) int64: the last tear's index map (each vertex's vertex before it), whose splits
        #: `part_seams` parts; None once parted
        self._tear_map: np.ndarray | None = None
        self._held: _Pairs | None = None
        self._substep = 0  # substeps projected so far: the age of the kept pairs
        self._span = 1  # substeps the kept list of candidate pairs covers (`_list_span`)
        self._longest_span = 1  # substeps a list covers at most at this step length (`list_substeps`)
        self._edge = 0.0  # the median rest edge (m) of the model last prepared
        self._margin = 0.0
        self._capacity = (0, 0)
        #: threads the split kernels use, by measurement (`threads.ThreadPicker`)
        self._picker = ThreadPicker(1)
        #: the grid cells (1/m) of the last whole search, for the VF and the EE grid
        self._cells: tuple[float, float] | None = None
        #: the thickness kept on the model last prepared (`contact_thickness`), metres
        self.thickness = self.settings.thickness
        #: (V,) bool: the vertices the last `project` moved (None before the first)
        self.moved: np.ndarray | None = None
        self.work = ContactWork()

    def take_work(self) -> ContactWork:
        """The work done since the last call (then reset)."""
        work, self.work = self.work, ContactWork()
        return work

    def remap(self, model: SpringModel, index_map: np.ndarray) -> None:
        """After a tear (index_map: new vertex -> old): copies keep their original's origin and
        start, and the vertices of each split (the original and its copies) are marked to be parted
        (`part_seams`)."""
        if self._origin is not None and self._origin.shape[0] > int(index_map.max(initial=-1)):
            self._origin = self._origin[index_map]
            if self._start is not None:
                self._start = self._start[index_map]
            self._tear_map = np.asarray(index_map, dtype=np.int64)

    def _prepare(self, model: SpringModel) -> _Topology:
        if self._model is model and self._topology is not None:
            return self._topology
        n = model.vertex_count
        self._model = model
        self._topology = _Topology.of(model)
        if self._origin is None or self._origin.shape[0] != n:  # a first (untorn) model
            self._origin = np.arange(n, dtype=np.int64)
            self._rings = _rings(self._topology.edges, n)
            self._start = None
            self._tear_map = None
        self._held = None
        # a writable copy: the model's read-only array would make the kernels that read it and
        # the positions compile twice (Numba types a read-only array apart)
        self._rest = np.array(model.rest_positions, dtype=np.float64)
        most = split_threads()  # in the thread that prepares the model, as the solvers' builds
        if self._picker.most != most:  # (a torn model keeps what the picker measured)
            self._picker = ThreadPicker(most)
        edge = median_edge(model)
        self._edge = edge
        self.thickness = contact_thickness(self.settings.thickness, edge)
        self._margin = MARGIN_FRACTION * edge if edge > 0 else self.thickness
        return self._topology

    def _pairs(
        self, model: SpringModel, topology: _Topology, x0: np.ndarray, x1: np.ndarray, threads: int
    ) -> _Pairs:
        """The candidate pairs for a substep from x0 to x1: the kept list where it covers the
        vertices, the pairs of the others searched again (all of them where most strayed) on
        `threads` threads."""
        held = self._held
        slack = 0.5 * self._margin
        n = x0.shape[0]
        if held is not None and held.base.shape[0] == n:
            stale, common_start, common_end = held.stale(x0, x1, self._substep, slack, self._span)
            if not stale.any():
                return held
            # many strays, or strays so fast that the list's span would reach too far for them
            if np.count_nonzero(stale) > REGATHER_FRACTION * n or self._list_span(x0, x1, stale) < self._span:
                held = None
        if held is None:
            self._span = self._list_span(x0, x1, None)
            held = _Pairs.empty(n)
            stale, common_start, common_end = np.ones(n, dtype=np.bool_), np.zeros(3), np.zeros(3)
        self.work.pair_builds += 1
        self._held = self._regather(
            model, topology, held, stale, x0 - common_start, x1 - common_end, slack, threads
        )
        return self._held

    def _list_span(self, x0: np.ndarray, x1: np.ndarray, among: np.ndarray | None) -> int:
        """The substeps a list searched now covers: `list_substeps` of the step (`_longest_span`),
        fewer where the substep's fastest motion relative to the cloth's mean, of the vertices
        `among` ((V,) bool; None: all of them) from x0 to x1 (V, 3), would let two of them close
        by more than `SPAN_EDGES` median edges over the span, but at least `LIST_MIN_SUBSTEPS`.
        A pair is kept within the thickness plus the span's closing, so on a mesh whose edges
        are short for its speed (a scanned model landing at 4 m/s in its 64 fast steps a frame,
        edges of 1.5 mm) a span of 8.2 ms held each vertex's pairs of a few centimetres around
        it: hundreds a vertex, re-searched as it strays."""
        motion = x1 - x0
        relative = motion - motion.mean(axis=0)
        if among is not None:
            relative = relative[among]
        fastest = float(np.sqrt(np.max(np.einsum("ij,ij->i", relative, relative), initial=0.0)))
        span = self._longest_span
        if fastest > 0.0 and self._edge > 0.0:
            span = min(span, int(SPAN_EDGES * self._edge / (2.0 * fastest)))
        return max(span, LIST_MIN_SUBSTEPS)

    def _regather(
        self, model: SpringModel, topology: _Topology, pairs: _Pairs, stale: np.ndarray,
        x0: np.ndarray, x1: np.ndarray, slack: float, threads: int,
    ) -> _Pairs:
        """`pairs` with new paths for the `stale` vertices (V,) bool, from their motion x0 -> x1
        (V, 3, the common departures taken out), and every pair touching one of them searched
        again: a stale vertex against all triangles, a triangle with a stale corner against the
        other vertices, an edge with a stale end against all edges."""
        fresh = np.flatnonzero(stale)
        now = self._substep
        pairs.base[fresh] = x1[fresh]
        pairs.motion[fresh] = x1[fresh] - x0[fresh]
        pairs.built[fresh] = now
        age = (now - pairs.built).astype(np.float64)[:, None]
        carried = pairs.base + age * pairs.motion  # every vertex on its path, now
        # the boxes hold each vertex's path from the start of this substep to the end of its span,
        # in a frame moving with the cloth's mean motion (a common motion changes no distance): a
        # pair that comes within the thickness while the list holds has its paths within `reach`
        # of each other at that moment, so its boxes overlap
        drift = pairs.motion - pairs.motion.mean(axis=0)
        first, last = carried - drift, carried + (self._span - age) * drift
        reach = self.thickness + 2.0 * slack
        vertices = np.arange(x0.shape[0], dtype=np.int64)[:, None]
        qlo, qhi = swept_boxes(first, last, vertices, reach)
        tlo, thi = swept_boxes(first, last, topology.triangles, 0.0)
        elo, ehi = swept_boxes(first, last, topology.edges, 0.5 * reach)
        corners, ends = stale[topology.triangles], stale[topology.edges]  # (or-ed by column: any(axis=1) is 5x slower)
        triangle_fresh = corners[:, 0] | corners[:, 1] | corners[:, 2]
        edge_fresh = ends[:, 0] | ends[:, 1]
        ring_start, ring = self._rings
        rest = self._rest
        shared = (topology.triangles, self._origin, ring_start, ring, pairs.motion, self._span, reach)
        everyone = fresh.shape[0] == x0.shape[0]
        capacity = self._capacity if everyone else (0, 0)
        # a partial search keeps the cells of the last whole one (`grid_for`) and holds only the
        # elements near its queries (`near_elements`); where it has only a few queries of a kind,
        # they read those elements' boxes (`scan_grid`)
        vf_cell, ee_cell = (None, None) if everyone or self._cells is None else self._cells

        def grid(queries: np.ndarray, *boxes: np.ndarray, inv_cell: float | None) -> tuple:
            if everyone:
                return grid_for(*boxes, inv_cell=inv_cell)
            if queries.shape[0] < SCAN_QUERIES:
                return scan_grid(near_elements(*boxes[:2], queries, *boxes[2:]))
            return grid_for(*boxes, inv_cell=inv_cell, near=queries)

        vf_grid = grid(fresh, qlo, qhi, tlo, thi, inv_cell=vf_cell)
        found_vf = [
            search_in_parts(
                self_kernels.vf_candidates, (carried, rest), fresh,
                (np.zeros(x0.shape[0], dtype=np.bool_), qlo, qhi, tlo, thi, False, *vf_grid, *shared),
                capacity[0], threads,
            )
        ]  # fmt: skip
        if not everyone:
            fresh_triangles = np.flatnonzero(triangle_fresh)
            by_triangle = grid(fresh_triangles, tlo, thi, qlo, qhi, inv_cell=vf_cell)
            found_vf.append(search_in_parts(
                self_kernels.vf_candidates, (carried, rest), fresh_triangles,
                (stale, qlo, qhi, tlo, thi, True, *by_triangle, *shared), 0, threads,
            ))  # fmt: skip
        fresh_edges = np.flatnonzero(edge_fresh)
        ee_grid = grid(fresh_edges, elo, ehi, elo, ehi, inv_cell=ee_cell)
        if edge_fresh.all():  # every edge against every edge: pairs of entries cell by cell
            found_ee = search_in_parts(
                self_kernels.ee_candidates_in_cells, (carried, rest), np.arange(ee_grid[1].shape[0] - 1),
                (elo, ehi, *ee_grid, topology.edges, *shared[1:]), capacity[1], threads,
            )  # fmt: skip
            found_long = long_edge_pairs(carried, rest, elo, ehi, ee_grid, topology.edges, *shared[1:])
            found_ee = tuple(np.concatenate(part) for part in zip(found_ee, found_long, strict=True))
        else:
            found_ee = search_in_parts(
                self_kernels.ee_candidates, (carried, rest), fresh_edges,
                (edge_fresh, elo, ehi, *ee_grid, topology.edges, *shared[1:], False), capacity[1], threads,
            )  # fmt: skip
        if everyone:
            self._capacity = (int(1.25 * found_vf[0][0].shape[0]), int(1.25 * found_ee[0].shape[0]))
            self._cells = (vf_grid[0], ee_grid[0])
        new_vf = found_vf[0] if len(found_vf) == 1 else tuple(np.concatenate(p) for p in zip(*found_vf, strict=True))
        # the kept pairs (those touching no stale vertex), in order, then the new ones
        vf, vf_apart, vf_rest, vf_lower = self_kernels.merge_kept(
            pairs.vf, pairs.vf_apart, pairs.vf_rest, pairs.vf_lower,
            self_kernels.vf_dropped(pairs.vf, stale, triangle_fresh), *new_vf,
        )  # fmt: skip
        ee, ee_apart, ee_rest, ee_lower = self_kernels.merge_kept(
            pairs.ee, pairs.ee_apart, pairs.ee_rest, pairs.ee_lower,
            self_kernels.ee_dropped(pairs.ee, edge_fresh), *found_ee,
        )  # fmt: skip
        return _Pairs(
            vf, vf_apart, vf_rest, vf_lower, ee, ee_apart, ee_rest, ee_lower,
            pairs.base, pairs.motion, pairs.built,
        )

    def part_seams(self, model: SpringModel, state: State) -> None:
        """Part the two sides of a tear, right after it (`meshdeform.simulate` calls it after the
        `remap` of a tear). The copies a tear makes start where their original is, touching the
        other side; each split's free vertices (the original and its copies, marked by `remap`)
        move apart along the split's normal (the area-weighted normal of all their triangles,
        where the substep starts: `_start`, else the previous positions) by `PART_FRACTION` of
        the thickness times their side's step (`_side_steps`: one side of a tear one way, the
        other the other way), their whole substep with them (start, previous and current
        positions alike, so their velocities are kept), and `PART_INWARD` times as far into
        their own triangles (towards their mean centroid), which parts the sides where the
        split's normal does not (a seam folded shut: its sides' normals cancel). Across the
        cloth a move changes the springs' lengths only to second order, within it to first
        (`PART_INWARD`). Where the triangles around a split's members lay folded over each
        other, that parting would make them cross (nothing guards it: they touch where the split
        was): such a split tries others in turn (`PARTINGS`: the way across reversed, either part
        alone, shorter), at last none (`_parting`). The sides then start apart, and the
        continuous check keeps them so (two sides touching cannot be proven apart, and sliding
        along each other in one plane they overlapped)."""
        group, self._tear_map = self._tear_map, None
        if group is None or group.shape[0] != model.vertex_count:
            return
        parting = np.bincount(group)[group] > 1  # the vertices of a split: an old vertex more than one came from
        topology = self._prepare(model)
        triangles = topology.triangles
        n = model.vertex_count
        if self._start is not None and self._start.shape[0] != n:
            self._start = None
        start = self._start if self._start is not None else state.previous
        rows = np.flatnonzero(parting & (np.asarray(model.inv_mass) > 0.0))
        if rows.shape[0] == 0 or triangles.shape[0] == 0:
            return
        vertex_normals = scatter_triangles(triangles, triangle_area_vectors(start, triangles), n)
        # each split's normal: the sum over its members, by the old vertex they came from
        old = group[rows]
        split_normals = np.zeros((int(old.max()) + 1, 3))
        np.add.at(split_normals, old, vertex_normals[rows])
        lengths = np.linalg.norm(split_normals, axis=1)
        unit = split_normals / np.maximum(lengths, 1e-300)[:, None]
        steps = _side_steps(rows, old, topology.edges)
        # towards the mean centroid of its own triangles (a third of each centroid per corner)
        centroid_thirds = scatter_triangles(triangles, start[triangles].mean(axis=1), n)[rows]
        count = np.maximum(np.bincount(triangles.ravel(), minlength=n)[rows], 1)
        inward = 3.0 * centroid_thirds / count[:, None] - start[rows]
        inward /= np.maximum(np.linalg.norm(inward, axis=1), 1e-300)[:, None]
        scale = PART_FRACTION * self.thickness
        offset = _parting(
            triangles, state.positions, group, rows, scale * steps[:, None] * unit[old], scale * PART_INWARD * inward
        )
        for positions in (state.positions, state.previous, self._start):
            if positions is not None:
                positions[rows] += offset

    def _impact_zones(
        self, model: SpringModel, topology: _Topology, x0: np.ndarray, x: np.ndarray, inv_mass: np.ndarray,
        work: ContactWork, translate: bool, threads: int, driven: np.ndarray, drive: np.ndarray,
    ) -> bool:
        """The continuous check along x0 -> x (V, 3), and impact zones in x until it flags
        nothing: each zone takes its members' mass-weighted mean displacement (`translate`) or
        goes back to x0, unless pinned members move it (by their translation, or by their turn
        where they turn as one rigid body: `_turn_with_pins`), or `driven` (V,) members that a
        moving collider carries by `drive` (V, 3) (`self_kernels.move_zones`); the pairs inside a
        zone that moved as one are not checked again (`_inside`). Returns whether any zone
        formed."""
        n = x.shape[0]
        parent = np.arange(n, dtype=np.int64)
        in_zone = np.zeros(n, dtype=np.bool_)
        settings = self.settings
        zoned = False
        whole = np.full(n, -1, dtype=np.int64)  # each vertex's zone where it moved as one (`_whole_zones`)
        for round_ in range(settings.max_rounds + 2):
            pairs = self._pairs(model, topology, x0, x, threads)
            vf, ee = pairs.vf, pairs.ee
            hit_vf, hit_ee = by_rows(
                functools.partial(
                    self_kernels.colliding_pairs, x0, x, topology.triangles, topology.edges,
                ),
                ((vf, pairs.vf_lower), (ee, pairs.ee_lower)),
                threads,
            )
            if zoned:  # a pair inside a zone that moved as one cannot meet: its path is one affine map's
                hit_vf &= ~_inside(whole, vf[:, :1], topology.triangles[vf[:, 1]])
                hit_ee &= ~_inside(whole, topology.edges[ee[:, 0]], topology.edges[ee[:, 1]])
            flagged = int(hit_vf.sum() + hit_ee.sum())
            if flagged == 0:
                break
            if round_ > settings.max_rounds:  # the last resort's check: what it could not prove apart
                work.unresolved += 1
                break
            zoned = True
            work.flagged_pairs += flagged
            work.zone_rounds += 1
            self_kernels.merge_zones(parent, in_zone, topology.triangles, topology.edges, vf, hit_vf, ee, hit_ee)
            if round_ == settings.max_rounds:  # last resort: every flagged vertex in one zone
                members = np.flatnonzero(in_zone)
                parent[members] = members[0]
            roots = _roots(parent, in_zone)
            zone_sizes = np.bincount(roots)
            work.largest_zone = max(work.largest_zone, int(zone_sizes.max(initial=0)))
            self_kernels.move_zones(x, x0, inv_mass, parent, in_zone, translate, driven, drive)
            members = np.flatnonzero(in_zone)
            turned = _turn_with_pins(x, x0, inv_mass, members, roots)
            whole[:] = -1
            whole[members] = _whole_zones(x, x0, members, roots, turned)
        return zoned

    def project(self, model: SpringModel, state: State, time: float, dt: float) -> None:
        """The substep's contact (module docstring), its split kernels on the threads the picker
        gives (`threads.ThreadPicker`: a substep's contact is comparable work from one to the next)."""
        topology = self._prepare(model)
        self._picker.timed(lambda threads: self._project(model, topology, state, time, dt, threads))

    def _colliders_again(
        self, model: SpringModel, state: State, time: float, dt: float, clear: np.ndarray
    ) -> np.ndarray:
        """The colliders once more, after self-collision moved the cloth within the substep: each
        vertex's path runs from `clear` (V, 3), where the colliders last left it, clear of them, to
        where it is now. (From state.previous, which `_settle` makes what the velocities imply,
        a path could start inside a collider, and a contact the corrections cannot free goes back
        to its start: a cloth shot at 50 m/s onto a 1 cm plate was left inside it.) Returns the
        positions they leave, clear of them: the next pass's start."""
        for collider in self.colliders:
            collider.project(model, state, time, dt, start=clear)
        return state.positions.copy()

    def _neighbour_gap(self, rest: np.ndarray) -> np.ndarray:
        """The distance (m) proximity keeps between rest neighbours (or copies of one vertex) whose
        distance in the rest mesh is `rest` (P,): the parting's, `PART_FRACTION` of the thickness,
        or the rest distance where that is less and more than `self_kernels.TOUCHING` (a sliver of
        a scanned mesh: pushed to the parting's distance, a falling bunny stretched 17 % in its
        first frame). Copies of one vertex lie at one rest place: the parting's distance."""
        close = PART_FRACTION * self.thickness
        return np.where(rest > self_kernels.TOUCHING, np.minimum(close, rest), close)

    def _project(
        self, model: SpringModel, topology: _Topology, state: State, time: float, dt: float, threads: int
    ) -> None:
        if topology.triangles.shape[0] == 0:
            self.moved = None
            return
        self._substep += 1
        longest = list_substeps(dt)
        if longest != self._longest_span:  # a list covers the span it was searched for: another is searched anew
            self._longest_span, self._held = longest, None
        x = state.positions
        n = x.shape[0]
        x0 = self._start if self._start is not None and self._start.shape[0] == n else state.previous.copy()
        x1 = x.copy()
        inv_mass = np.ascontiguousarray(model.inv_mass, dtype=np.float64)
        settings = self.settings
        work = ContactWork()

        # 1. proximity: pairs within the thickness, pushed apart along their start side
        pairs = self._pairs(model, topology, x0, x1, threads)
        # rest neighbours and the copies of one vertex: the parting's distance, so that they never
        # close to within `self_kernels.TOUCHING` nor lie so close that the continuous check
        # cannot prove them apart (module docstring), or their rest distance where that is less
        vf_gap = np.where(pairs.vf_apart, np.minimum(self.thickness, pairs.vf_rest), self._neighbour_gap(pairs.vf_rest))
        ee_gap = np.where(pairs.ee_apart, np.minimum(self.thickness, pairs.ee_rest), self._neighbour_gap(pairs.ee_rest))
        active_vf, side_vf, active_ee, side_ee = by_rows(
            functools.partial(self_kernels.proximity_sides, x, x0, topology.triangles, topology.edges),
            ((pairs.vf, vf_gap, pairs.vf_lower), (pairs.ee, ee_gap, pairs.ee_lower)),
            threads,
        )
        work.projections = self_kernels.project_proximity(
            x, x0, inv_mass, topology.triangles, topology.edges, pairs.vf, vf_gap, active_vf, side_vf,
            pairs.ee, ee_gap, active_ee, side_ee, settings.sweeps, settings.friction,
        )

        _settle(state, x1, dt)
        # the colliders again, where the proximity step moved something (it may push a layer into
        # them); where it moved nothing they already hold the positions they left. A collider
        # that pushes back a vertex the proximity step moved into it leaves that vertex's pairs
        # short of their gap by its push (proximity moves both sides, the collider puts one back:
        # a layer pressed onto a sheet lying on the ground kept 2.7 mm of the 5): those pairs once
        # more, the pushed-back vertices held where the collider put them (no inverse mass), then
        # the colliders again
        clear = x1  # where the colliders left the cloth: clear of them
        if work.projections:
            moved = np.any(x != x1, axis=1)
            clear = self._colliders_again(model, state, time, dt, clear)
            held = moved & pushed_vertices(self.colliders, n)
            if held.any():
                before = x.copy()
                # the pairs touching a held vertex, in their order (the rest are not projected)
                vf_held = np.flatnonzero(held[pairs.vf[:, 0]] | held[topology.triangles[pairs.vf[:, 1]]].any(axis=1))
                ee_held = np.flatnonzero(held[topology.edges[pairs.ee]].reshape(-1, 4).any(axis=1))
                vf, ee = pairs.vf[vf_held], pairs.ee[ee_held]
                vf_held_gap, ee_held_gap = vf_gap[vf_held], ee_gap[ee_held]
                active_vf, side_vf, active_ee, side_ee = by_rows(
                    functools.partial(self_kernels.proximity_sides, x, x0, topology.triangles, topology.edges),
                    ((vf, vf_held_gap, pairs.vf_lower[vf_held]), (ee, ee_held_gap, pairs.ee_lower[ee_held])),
                    threads,
                )
                free_mass = np.where(held, 0.0, inv_mass)
                more = self_kernels.project_proximity(
                    x, x0, free_mass, topology.triangles, topology.edges, vf, vf_held_gap, active_vf, side_vf,
                    ee, ee_held_gap, active_ee, side_ee, settings.sweeps, settings.friction,
                )
                _settle(state, before, dt)
                if more:
                    work.projections += more
                    clear = self._colliders_again(model, state, time, dt, clear)
        x2 = x.copy()

        # 2. and 3. the continuous check along x0 -> x, impact zones until nothing is flagged
        driven, drive = np.zeros(n, dtype=np.bool_), np.zeros((n, 3))
        zoned = self._impact_zones(
            model, topology, x0, x, inv_mass, work, translate=True, threads=threads, driven=driven, drive=drive
        )
        _settle(state, x2, dt)
        if zoned and self.colliders:
            # a zone's common translation can carry a vertex a collider held into the collider's
            # thickness (a falling layer caught by one lying on the ground moves it down with
            # it): the colliders again, then the continuous check with zones that stay where the
            # substep started (clear of both, since the last substep ended so)
            for round_ in range(FINAL_ROUNDS):
                before = x.copy()
                clear = self._colliders_again(model, state, time, dt, clear)
                if round_ and np.array_equal(before, x):
                    break
                x3 = x.copy()
                # a zone with a member a moving collider pushed moves as the collider carries that
                # start: the start itself is inside a collider that moved on
                driven[:] = False
                for collider in self.colliders:
                    if collider.moves and collider.pushed is not None:
                        carried = collider.pushed & ~driven
                        drive[carried] = collider.carry(x0[carried], time - dt, time) - x0[carried]
                        driven |= carried
                if not self._impact_zones(
                    model, topology, x0, x, inv_mass, work, translate=False, threads=threads, driven=driven, drive=drive
                ):
                    break
                _settle(state, x3, dt)
        self._start = x.copy()
        self.moved = np.any(x != x1, axis=1)
        self.work.add(work)


#: rounds of the colliders and zones that stay where the substep started after the first
#: zones (`_project`): each round's colliders may move a vertex a zone put back, and each round's
#: zones may put back a vertex a collider moved, until either leaves the other nothing to do
FINAL_ROUNDS = 8

#: the vertices of a split move apart along its normal by this fraction of the thickness, the
#: first one way, the next the other, and so on (`part_seams`): the sides of a tear start apart
PART_FRACTION = 0.1
#: ... and into its own triangles by this fraction of that: a move within the surface changes the
#: springs' lengths to first order (5 % of the way to its triangles' centroid, 2.5 mm on a 10 cm
#: grid, set a cut sheet lying still moving at 0.8 m/s; 0.25 mm, this fraction of 5 mm, at 1 mm/s)
PART_INWARD = 0.5
#: the partings a split tries in turn, as (share of the way across the cloth, share of the way
#: into its own triangles), until one makes no triangles cross (`_parting`)
PARTINGS = (
    (1.0, 1.0), (-1.0, 1.0), (0.0, 1.0), (1.0, 0.0), (-1.0, 0.0),
    (0.25, 0.25), (-0.25, 0.25), (0.0, 0.25), (0.0625, 0.0625), (-0.0625, 0.0625), (0.0, 0.0625),
)  # fmt: skip
#: the candidate pairs' margin: this fraction of the median rest edge length (see `_Pairs`: pairs
#: hold until some vertex moves half of it, so a larger margin means fewer searches but more pairs)
MARGIN_FRACTION = 0.25


#: the time (s) a list of candidate pairs covers at most, rounded to whole substeps (`_Pairs`,
#: `list_substeps`): a longer span keeps the pairs whose relative motion could close their gap
#: within it, but sweeps wider boxes. 4 substeps of xpbd's default 22 a frame at 24 fps (implicit's
#: few steps take `LIST_MIN_SUBSTEPS`; docs/performance.md, "Self-collision's pair lists over a span
#: of time", "Edge pairs cell by cell" and "Slow steps")
LIST_SPAN = 8.2e-3
#: the fewest substeps a list covers: implicit's few, long steps (8 or 4 a frame) search less
#: often at a wider reach and gain (3 against `LIST_SPAN`'s 2 and 1: 1.05-1.3x on the contact
#: benchmarks with self-collision), where xpbd's 22 a frame keep `LIST_SPAN`'s 4 (3 was slower)
LIST_MIN_SUBSTEPS = 3
#: a list's span keeps two vertices at the substep's fastest relative motion from closing by more
#: than this many median edges over it (`SelfCollision._list_span`): spans of xpbd's 22 and
#: implicit's steps on the contact benchmarks' sheets stay as `list_substeps` gives them
SPAN_EDGES = 2.0
#: when more than this fraction of the vertices strayed from their paths, the whole list is
#: searched afresh (one query a vertex, triangle and edge) rather than their pairs alone: a
#: partial search of many costs more than a whole one and leaves paths of mixed ages that stray
#: again sooner (docs/performance.md, "A whole search once a fifth of the vertices strayed")
REGATHER_FRACTION = 0.2


def long_edge_pairs(
    x: np.ndarray, rest: np.ndarray, elo: np.ndarray, ehi: np.ndarray, grid: tuple, edges: np.ndarray, *tail
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The edge pairs of a whole search that the cell-by-cell pass (`ee_candidates_in_cells`) does
    not see: those of the long edges the grid (`broad_phase.grid_for` of the edge boxes elo, ehi)
    keeps out of its cells (`broad_phase.LONG_CELLS`), each of which reads every edge's box
    (`ee_candidates`, each pair once). tail: `ee_candidates`' arguments after `edges` up to `every`
    (origin, ring_start, ring, motion, span, reach). Empty where no edge is long."""
    start, element = grid[1], grid[2]
    long_edges = element[start[-1] :]
    is_long = np.zeros(edges.shape[0], dtype=np.bool_)
    is_long[long_edges] = True
    return self_kernels.ee_candidates(x, rest, long_edges, is_long, elo, ehi, *grid, edges, *tail, False, 0)


def list_substeps(dt: float) -> int:
    """Substeps of dt (s) that a list of candidate pairs covers: `LIST_SPAN` rounded, at least
    `LIST_MIN_SUBSTEPS`."""
    return max(LIST_MIN_SUBSTEPS, round(LIST_SPAN / dt)) if dt > 0.0 else LIST_MIN_SUBSTEPS


#: the thickness self-collision keeps is at most this fraction of the median rest edge length
THICKNESS_EDGE_FRACTION = 0.5


def median_edge(model: SpringModel) -> float:
    """The median length (m) of the rest mesh's triangle edges (0 without triangles)."""
    triangles = np.asarray(model.triangles)
    if triangles.shape[0] == 0:
        return 0.0
    rest = model.rest_positions
    pairs = triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    return float(np.median(np.linalg.norm(rest[pairs[:, 1]] - rest[pairs[:, 0]], axis=1)))


def contact_thickness(thickness: float, edge: float) -> float:
    """The thickness (m) self-collision keeps on a mesh whose median edge is `edge` (m): the one
    asked, at most `THICKNESS_EDGE_FRACTION` of the edge. A thickness of several edges would make
    every vertex a contact of dozens of rest neighbours (a fine scan at the default 5 mm gathers
    millions of pairs) and cannot be kept anyway where the cloth folds within a few edges."""
    return min(thickness, THICKNESS_EDGE_FRACTION * edge) if edge > 0 else thickness


def _side_steps(members: np.ndarray, split: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Each member's step along its split's normal (M,): the vertices `members` (M,) of the
    splits `split` (M,) (the vertex before the tear each came from), the mesh's `edges` (E, 2).
    Members joined by an edge lie on one side of the tear (the edges across it are gone), so
    each connected run of them (scipy's connected components) takes one step, and the members
    of one split take different ones: +1, -1, +2, -2, ... in the order of the splits and their
    members. Both sides of a seam then move apart along its normal, and its edges do not cross."""
    slot = np.full(int(max(members.max(initial=-1), edges.max(initial=-1))) + 1, -1, dtype=np.int64)
    slot[members] = np.arange(members.shape[0])
    a, b = slot[edges[:, 0]], slot[edges[:, 1]]
    joined = (a >= 0) & (b >= 0)
    graph = coo_matrix(
        (np.ones(int(joined.sum())), (a[joined], b[joined])), shape=(members.shape[0], members.shape[0])
    )
    _, run = connected_components(graph, directed=False)
    candidates = (1.0, -1.0, 2.0, -2.0, 3.0, -3.0)
    order = np.argsort(split, kind="stable")
    bounds = np.flatnonzero(np.diff(split[order])) + 1
    step_of_run: dict[int, float] = {}
    # a loop over the splits of one tear (tens, at most a few hundred: a tear is a rare event)
    for runs in np.split(run[order], bounds):
        taken = {step_of_run[r] for r in runs.tolist() if r in step_of_run}
        for r in runs.tolist():
            if r not in step_of_run:
                step_of_run[r] = next((c for c in candidates if c not in taken), 0.0)
                taken.add(step_of_run[r])
    return np.array([step_of_run[r] for r in run.tolist()])


def _parting(
    triangles: np.ndarray, x: np.ndarray, group: np.ndarray, rows: np.ndarray, across: np.ndarray,
    inward: np.ndarray,
) -> np.ndarray:
    """The parting (R, 3, m) of the moving members `rows` (R,) of the splits (`group` (V,): the
    vertex each came from), from its part across the cloth `across` and into the member's own
    triangles `inward` (R, 3 each): both, for every split whose parting makes no pair of triangles
    cross; a split with a member in a pair that it makes cross (the sides of a seam that lay
    folded over each other) takes the next of `PARTINGS` (the way across reversed, either part
    alone, shorter), and none at last: such a split's sides touch where they came apart, as
    the tear left them. The check (`triangle_distance.triangles_cross`) takes the pairs sharing
    no vertex of a triangle around a moving member and any triangle whose box, before or after
    the parting, overlaps its own. A crossing whose splits all take none is the touching itself
    (the check counts a corner on a corner), and ends the search."""
    n = x.shape[0]
    splits, row_split = np.unique(group[rows], return_inverse=True)
    split_of_vertex = np.full(n, -1, dtype=np.int64)
    split_of_vertex[rows] = row_split
    reach = np.abs(across).sum(axis=1) + np.abs(inward).sum(axis=1)  # every parting stays within it
    moving = np.flatnonzero((split_of_vertex[triangles] >= 0).any(axis=1))
    grown = np.zeros(n)
    grown[rows] = reach
    lo = x[triangles].min(axis=1) - grown[triangles].max(axis=1)[:, None]
    hi = x[triangles].max(axis=1) + grown[triangles].max(axis=1)[:, None]
    candidates = overlapping_pairs(lo[moving], hi[moving], lo, hi)
    pairs = np.stack([moving[candidates[:, 0]], candidates[:, 1]], axis=1)
    # each pair once (a moving triangle against one that moves too: the lower first), sharing no vertex
    pairs = pairs[(pairs[:, 0] < pairs[:, 1]) | (split_of_vertex[triangles[pairs[:, 1]]] < 0).all(axis=1)]
    one, other = triangles[pairs[:, 0]], triangles[pairs[:, 1]]
    pairs = np.ascontiguousarray(pairs[~(one[:, :, None] == other[:, None, :]).any(axis=(1, 2))], dtype=np.int64)
    if not pairs.shape[0]:
        return across + inward
    choice = np.zeros(splits.shape[0], dtype=np.int64)
    ways = np.array([*PARTINGS, (0.0, 0.0)])
    trial = x.copy()
    while True:
        way = ways[choice[row_split]]
        offset = way[:, :1] * across + way[:, 1:] * inward
        trial[rows] = x[rows] + offset
        crossing = pairs[triangles_cross(trial, triangles, pairs)]
        involved = split_of_vertex[triangles[crossing].ravel()]
        involved = np.unique(involved[involved >= 0])
        involved = involved[choice[involved] < len(PARTINGS)]
        if involved.shape[0] == 0:
            return offset
        choice[involved] += 1


def _settle(state: State, before: np.ndarray, dt: float) -> None:
    """Velocities follow the positions contact moved since `before` (position-based dynamics:
    v += dx / dt), and previous positions follow the velocities, as the colliders keep them."""
    x = state.positions
    changed = x != before
    moved = np.flatnonzero(changed[:, 0] | changed[:, 1] | changed[:, 2])
    if moved.size and dt > 0:
        state.velocities[moved] += (x[moved] - before[moved]) / dt
        state.previous[moved] = x[moved] - state.velocities[moved] * dt


def _turn_with_pins(
    x: np.ndarray, x0: np.ndarray, inv_mass: np.ndarray, members: np.ndarray, roots: np.ndarray
) -> set[int]:
    """After `self_kernels.move_zones`, in place on x (V, 3): the free members of each zone whose
    pinned members (`members` (M,) of the zones, their `roots` (M,)) move from x0 to x as one rigid
    body that turns (`rigid_motion`) take that motion, x = R x0 + t, instead of the pinned members'
    mean translation. A zone's points then all follow x0 + s (R x0 + t - x0) along the substep: one
    invertible affine map for each s (a turn of less than half a revolution a substep), which
    keeps any two of its triangles apart that were apart at x0; a translation cannot follow a row
    of pins that turns (a strip twisted by its animated pins: the zone and its pins crossed).
    Returns the roots of the zones turned."""
    turned: set[int] = set()
    pinned = inv_mass[members] <= 0.0
    if np.count_nonzero(pinned) < 2:
        return turned
    for root in np.unique(roots[pinned]):
        zone = members[roots == root]
        pins = zone[inv_mass[zone] <= 0.0]
        if pins.shape[0] < 2:
            continue
        motion = rigid_motion(x0[pins], x[pins])
        if motion is None:
            continue
        turn, shift = motion
        free = zone[inv_mass[zone] > 0.0]
        x[free] = x0[free] @ turn.T + shift
        turned.add(int(root))
    return turned


def _whole_zones(x: np.ndarray, x0: np.ndarray, members: np.ndarray, roots: np.ndarray, turned: set[int]) -> np.ndarray:
    """For the zone `members` (M,) and their `roots` (M,): each one's root where its zone moved as
    one from x0 to x (V, 3) (every member by the same displacement within `RIGID_TOLERANCE`, or
    turned with its pins: `_turn_with_pins`), else -1 (pinned members that neither translate
    alike nor turn as one body pull their zone apart)."""
    if not members.shape[0]:
        return np.zeros(0, dtype=np.int64)
    moved = x[members] - x0[members]
    zones, first, slot = np.unique(roots, return_index=True, return_inverse=True)
    spread = np.zeros(zones.shape[0])
    np.maximum.at(spread, slot, np.abs(moved - moved[first[slot]]).max(axis=1))
    whole = spread <= RIGID_TOLERANCE
    if turned:
        whole |= np.isin(zones, np.fromiter(turned, dtype=np.int64))
    return np.where(whole[slot], roots, -1)


def _inside(whole: np.ndarray, first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """(P,) bool: the pairs whose vertices (first (P, a), second (P, b) vertex indices) all lie in
    one zone that moved as one (`whole` (V,): that zone's root, -1 elsewhere)."""
    zone = whole[first[:, 0]]
    inside = zone >= 0
    for column in (*first.T[1:], *second.T):
        inside &= whole[column] == zone
    return inside


#: pinned members that follow a rigid motion this close (m, at each pin) move their zone with it
#: (`_turn_with_pins`); keyframed pins are rigid to rounding
RIGID_TOLERANCE = 1e-12


def rigid_motion(start: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The turn R (3, 3) and shift t (3,) with end = start @ R.T + t for the points start, end
    (K, 3), K >= 2, where one exists within `RIGID_TOLERANCE` and turns them by less than half a
    revolution (None otherwise, or where they only translate: the translation is `move_zones`'s).
    Points on a line fix no turn about it: the least turn that takes the line to its new
    direction (a row of pins). Kabsch's fit (1976) otherwise."""
    centre_start, centre_end = start.mean(axis=0), end.mean(axis=0)
    a, b = start - centre_start, end - centre_end
    if np.abs(b - a).max() <= RIGID_TOLERANCE:
        return None
    u, sigma, vt = np.linalg.svd(a.T @ b)
    if sigma[0] <= 0.0:
        return None
    if sigma[1] <= 1e-12 * sigma[0]:  # collinear: the least turn from the line's direction to its new one
        farthest = int(np.argmax(np.einsum("ij,ij->i", a, a)))
        before, after = a[farthest], b[farthest]
        turn = _least_turn(before / np.linalg.norm(before), after / max(float(np.linalg.norm(after)), 1e-300))
        if turn is None:
            return None
    else:
        flip = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
        turn = vt.T @ np.diag([1.0, 1.0, flip]) @ u.T
    if np.trace(turn) <= -1.0 + 1e-9:  # half a revolution or more: no invertible path
        return None
    shift = centre_end - centre_start @ turn.T
    if np.abs(start @ turn.T + shift - end).max() > RIGID_TOLERANCE:
        return None
    return turn, shift


def _least_turn(before: np.ndarray, after: np.ndarray) -> np.ndarray | None:
    """The rotation (3, 3) taking the unit vector `before` to the unit vector `after` about their
    common normal (Rodrigues), the identity where they agree; None where they are opposite (half a
    revolution, about no axis in particular)."""
    axis = np.cross(before, after)
    sine, cosine = float(np.linalg.norm(axis)), float(np.dot(before, after))
    if sine <= 1e-15:
        return np.eye(3) if cosine > 0.0 else None
    k = axis / sine
    cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + sine * cross + (1.0 - cosine) * (cross @ cross)


def _roots(parent: np.ndarray, in_zone: np.ndarray) -> np.ndarray:
    """The zone root of each zone member (follows parent links to the top)."""
    members = np.flatnonzero(in_zone)
    roots = parent[members]
    while True:
        up = parent[roots]
        if np.array_equal(up, roots):
            return roots
        roots = up
