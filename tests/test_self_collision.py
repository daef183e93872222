"""Self-collision: the cloth never passes through itself and keeps its thickness between parts.

Judged by an independent oracle (tests/intersections.py: ipctk's predicates) and by distances
computed here with SciPy, never by the code under test.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from factories import KNIT, grid_sheet, punched_plate, twisted_strip
from intersections import intersecting_pairs
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import shortest_path
from scipy.spatial import cKDTree
from test_collider_contact import box_distance, lattice

from meshdeform.contact import broad_phase, self_kernels
from meshdeform.contact.broad_phase import overlapping_pairs
from meshdeform.contact.self_collision import SelfCollision, SelfCollisionSettings, rigid_motion
from meshdeform.io import load, write_obj
from meshdeform.mesh import Mesh
from meshdeform.model import SpringModel, State
from meshdeform.scene.base import Scene
from meshdeform.scene.colliders import Collider, Plane
from meshdeform.simulate import Settings, simulate
from pipeline.build import build_simulation
from pipeline.job import run_job
from pipeline.recipe import parse_recipe

THICKNESS = 0.005


def _collapsing_sheet(n: int) -> Mesh:
    """An upright n x n sheet of 1 m with a 2 mm random ripple, its lower edge just above the ground:
    it folds onto itself as it falls (the scene that interpenetrates without self-collision)."""
    mesh = grid_sheet(n, plane="xy", triangles=True, centred=True, offset=(0.0, 0.52, 0.0))
    rng = np.random.default_rng(1)
    mesh.positions[:, 2] += 0.002 * rng.standard_normal(mesh.positions.shape[0])
    return mesh


def _run(model: SpringModel, self_collision: bool, frames: int, state: State | None = None) -> list[np.ndarray]:
    ground = Collider(Plane((0.0, 0.0, 0.0), (0.0, 1.0, 0.0)), 0.3, 0.01)
    contact = SelfCollision(SelfCollisionSettings(thickness=THICKNESS), [ground]) if self_collision else None
    scene = Scene(constraints=[ground], self_collision=contact)
    return [f.welded_positions for f in simulate(model, scene, Settings(frames=frames), state=state)]


@pytest.fixture(scope="module")
def collapse() -> tuple[SpringModel, list[np.ndarray], list[np.ndarray]]:
    model = SpringModel.from_mesh(_collapsing_sheet(24), KNIT)
    return model, _run(model, False, 40), _run(model, True, 40)


def test_the_collapsing_sheet_interpenetrates_without_self_collision(collapse) -> None:
    model, off, _ = collapse
    assert max(intersecting_pairs(x, model.triangles) for x in off) > 0


def test_no_two_triangles_intersect_in_any_frame_with_self_collision(collapse) -> None:
    model, _, on = collapse
    assert [intersecting_pairs(x, model.triangles) for x in on] == [0] * len(on)


def test_parts_far_apart_in_the_mesh_keep_the_thickness(collapse) -> None:
    """Vertices at least 3 edges apart in the mesh never come closer than the thickness (less
    1 mm): a necessary condition of the vertex-triangle distance kept (a vertex is on its triangles)."""
    model, _, on = collapse
    tri = np.asarray(model.triangles)
    edges = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    n = model.vertex_count
    graph = csr_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    hops = shortest_path(graph, unweighted=True, directed=False)
    closest = np.inf
    for x in on:
        pairs = cKDTree(x).query_pairs(THICKNESS, output_type="ndarray")
        far = pairs[hops[pairs[:, 0], pairs[:, 1]] >= 3] if pairs.size else pairs
        if far.size:
            closest = min(closest, float(np.linalg.norm(x[far[:, 0]] - x[far[:, 1]], axis=1).min()))
    assert closest >= THICKNESS - 0.001


def test_the_ground_keeps_its_thickness_under_a_pile(collapse) -> None:
    _, _, on = collapse
    assert min(float(x[:, 1].min()) for x in on) >= 0.01 - 0.001


def _two_sheets(gap: float, n: int = 8) -> Mesh:
    """Two horizontal n x n sheets of 0.5 m, `gap` apart, as one mesh (two pieces)."""
    lower = grid_sheet(n, plane="xz", size=0.5, triangles=True, centred=True, offset=(0.0, 0.3, 0.0))
    upper = grid_sheet(n, plane="xz", size=0.5, triangles=True, centred=True, offset=(0.03, 0.3 + gap, 0.02))
    return _stacked(lower, upper)


def _stacked(lower: Mesh, upper: Mesh) -> Mesh:
    """Two meshes as one (two pieces): lower's vertices first, then upper's."""
    count = lower.positions.shape[0]
    return Mesh(
        positions=np.concatenate([lower.positions, upper.positions]),
        face_indices=np.concatenate([lower.face_indices, upper.face_indices + count]),
        face_offsets=np.concatenate([lower.face_offsets, upper.face_offsets[1:] + lower.face_indices.shape[0]]),
    )


def test_two_layers_closer_than_the_thickness_fall_together_undeformed() -> None:
    """Two sheets 2 mm apart (a lined garment's layers, closer than the 5 mm thickness: they keep
    their rest distance) fall freely with self-collision on: nothing but rounding may deform
    them. The proximity step projects such pairs back to the distance they already have, which
    moves vertices by 1e-16 m; the implicit solver took that for a push, restarted those vertices'
    BDF2 history (without the air drag the others' history carries) and the layers drifted apart
    by 11 cm in 12 frames."""
    mesh = _two_sheets(0.002)
    model = SpringModel.from_mesh(mesh)
    ground = Collider(Plane((0.0, -100.0, 0.0), (0.0, 1.0, 0.0)))
    contact = SelfCollision(SelfCollisionSettings(thickness=THICKNESS), [ground])
    rest = np.asarray(model.rest_positions)
    for frame in simulate(model, Scene(constraints=[ground], self_collision=contact), Settings(frames=12)):
        x = frame.welded_positions
        assert np.abs((x - x.mean(axis=0)) - (rest - rest.mean(axis=0))).max() < 1e-9


def _thrown(speed: float, self_collision: bool) -> tuple[SpringModel, np.ndarray, list[np.ndarray]]:
    """The upper of two sheets 5 cm apart thrown down at `speed` m/s onto the lower one, pinned
    at its corners; the model, the upper sheet's mask and the frames."""
    mesh = _two_sheets(0.05)
    pinned = np.zeros(mesh.positions.shape[0], dtype=bool)
    pinned[[0, 7, 56, 63]] = True  # the lower sheet's corners
    model = SpringModel.from_mesh(mesh, pinned_input=pinned)
    state = State.at_rest(model)
    upper = np.arange(model.vertex_count) >= 64
    state.velocities[upper, 1] = -speed
    state.previous[upper] = state.positions[upper] - state.velocities[upper] / (24.0 * Settings().substeps)
    return model, upper, _run(model, self_collision, 6, state)


def test_a_thrown_sheet_passes_through_another_without_self_collision() -> None:
    model, upper, frames = _thrown(20.0, False)
    assert frames[-1][upper, 1].mean() < frames[-1][~upper, 1].mean()
    triangles = np.asarray(model.triangles)
    point, height = _heights_over(frames[-1], triangles[~upper[triangles[:, 0]]], np.flatnonzero(upper))
    assert (frames[-1][np.flatnonzero(upper)[point], 1] < height).any()  # what the check below catches


def _heights_over(x: np.ndarray, triangles: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each of `points` (P,) vertex indices of x (V, 3): the heights (y) above it of the
    surface of `triangles` (T, 3) where the triangle's projection on the XZ plane covers the point's
    (barycentric interpolation), as (point, height) rows (K,) and (K,): a point over a folded
    surface has a row for each layer."""
    a, b, c = x[triangles[:, 0]], x[triangles[:, 1]], x[triangles[:, 2]]
    p = x[points]
    e1, e2 = (b - a)[:, [0, 2]], (c - a)[:, [0, 2]]
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]  # (T,)
    w = p[:, None, [0, 2]] - a[None, :, [0, 2]]  # (P, T, 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = (w[..., 0] * e2[:, 1] - w[..., 1] * e2[:, 0]) / det
        v = (e1[:, 0] * w[..., 1] - e1[:, 1] * w[..., 0]) / det
    inside = (np.abs(det) > 1e-12) & (u >= 0.0) & (v >= 0.0) & (u + v <= 1.0)
    point, triangle = np.nonzero(inside)
    height = a[triangle, 1] + u[point, triangle] * (b - a)[triangle, 1] + v[point, triangle] * (c - a)[triangle, 1]
    return point, height


@pytest.mark.parametrize("speed", [20.0, 50.0])
def test_a_sheet_thrown_at_another_never_passes_through(speed: float) -> None:
    """At 50 m/s the upper sheet moves 10 cm per substep, twenty times the thickness: it still
    never crosses the lower one: no intersection, and in every frame each vertex of the upper
    sheet over the lower one is above it there (the lower sheet, pinned at its corners, sags into
    a bowl under the blow, so their mean heights say nothing). Without self-collision 49 of them
    end up to 29 cm below it (`test_a_thrown_sheet_passes_through_another_without_self_collision`)."""
    model, upper, frames = _thrown(speed, True)
    triangles = np.asarray(model.triangles)
    lower_triangles = triangles[~upper[triangles[:, 0]]]
    for x in frames:
        assert intersecting_pairs(x, model.triangles) == 0
        point, height = _heights_over(x, lower_triangles, np.flatnonzero(upper))
        assert point.size  # the sheets overlap
        assert (x[np.flatnonzero(upper)[point], 1] > height).all()


def _sheet_over_sheet(lower_height: float, upper_height: float) -> tuple[SpringModel, np.ndarray]:
    """Two 6 x 6 triangulated sheets of 0.3 m lying flat (XZ) at the given heights (m), the upper
    one shifted 1 and 1.3 cm sideways, as one model of two pieces, and its upper sheet's mask."""
    lower = grid_sheet(6, plane="xz", size=0.3, triangles=True, centred=True, offset=(0.0, lower_height, 0.0))
    upper = grid_sheet(6, plane="xz", size=0.3, triangles=True, centred=True, offset=(0.01, upper_height, 0.013))
    count = lower.positions.shape[0]
    mesh = _stacked(lower, upper)
    model = SpringModel.from_mesh(mesh)
    return model, np.arange(model.vertex_count) >= count


def test_an_impact_zone_does_not_carry_a_layer_into_the_ground() -> None:
    """A sheet falling through one that lies on the ground within one substep, with no proximity
    sweeps, so only impact zones part them: a zone's common translation would carry the lower
    sheet down into the ground's thickness (its mean motion is the upper sheet's fall, halved).
    Afterwards no triangle pair intersects, every vertex keeps the ground's 1 cm less 1 mm, and
    the upper sheet is still above the lower one."""
    model, top = _sheet_over_sheet(0.012, 0.03)
    state = State.at_rest(model)
    dt = 1.0 / 240.0
    ground = Collider(Plane((0.0, 0.0, 0.0), (0.0, 1.0, 0.0)), 0.3, 0.01)
    contact = SelfCollision(SelfCollisionSettings(thickness=THICKNESS, sweeps=0), [ground])
    contact.project(model, state, dt, dt)  # a substep at rest: where the next one starts
    state.positions[top, 1] = -0.01  # the end of a substep at 9.6 m/s: through the lower sheet
    state.velocities[top, 1] = -0.04 / dt
    ground.project(model, state, 2 * dt, dt)  # as `simulate` runs them: the colliders, then self-collision
    contact.project(model, state, 2 * dt, dt)
    x = state.positions
    assert contact.work.zone_rounds > 0  # the zones were what parted them
    assert intersecting_pairs(x, model.triangles) == 0
    assert float(x[:, 1].min()) >= 0.01 - 0.001
    assert x[top, 1].mean() > x[~top, 1].mean()


def test_a_layer_pressed_onto_a_sheet_lying_on_the_ground_is_pushed_off_it_by_the_thickness() -> None:
    """Two sheets 1 cm apart in the rest mesh (so they keep the full thickness), the lower one lying
    on the ground at the ground's thickness, the upper one moved down to 1 mm above it within a
    substep: after the substep (the ground, then self-collision, as `simulate` runs them) the
    layers are at least the thickness less 1 mm apart (the planes' heights: both sheets stay flat)
    and the lower one still lies on the ground. The proximity step moves both layers half of the
    4 mm they lack; the ground pushed the lower one back and the pair was left 2 mm short."""
    model, top = _sheet_over_sheet(0.01, 0.02)
    state = State.at_rest(model)
    dt = 1.0 / 240.0
    ground = Collider(Plane((0.0, 0.0, 0.0), (0.0, 1.0, 0.0)), 0.3, 0.01)
    contact = SelfCollision(SelfCollisionSettings(thickness=THICKNESS), [ground])
    contact.project(model, state, dt, dt)  # a substep at rest: where the next one starts
    state.positions[top, 1] = 0.011
    state.velocities[top, 1] = -0.009 / dt
    ground.project(model, state, 2 * dt, dt)
    contact.project(model, state, 2 * dt, dt)
    x = state.positions
    assert float(x[top, 1].min() - x[~top, 1].max()) >= THICKNESS - 0.001
    assert float(x[~top, 1].min()) >= 0.01 - 1e-6


def test_runs_are_byte_identical() -> None:
    model = SpringModel.from_mesh(_collapsing_sheet(12))
    first = _run(model, True, 8)
    second = _run(model, True, 8)
    assert all(a.tobytes() == b.tobytes() for a, b in zip(first, second, strict=True))


def test_searches_split_over_two_threads_give_the_same_bytes(monkeypatch) -> None:
    """The candidate searches, the proximity step's sides and the continuous check run in parts
    on two threads where they are long (`contact.parts`): the run is byte for byte the
    one-thread run, and the splits did run."""
    import meshdeform.contact.parts as parts
    import meshdeform.contact.self_collision as self_collision

    model = SpringModel.from_mesh(_collapsing_sheet(12))
    monkeypatch.setattr(self_collision, "split_threads", lambda: 1)
    one = _run(model, True, 24)  # the sheet lies folded on itself from frame 12 or so
    split = []
    search = parts.search_in_parts

    def counted(*args, **kwargs):
        split.append(args[2].shape[0] >= parts.MIN_QUERIES and args[5] >= 2)
        return search(*args, **kwargs)

    monkeypatch.setattr(self_collision, "split_threads", lambda: 2)
    monkeypatch.setattr(self_collision, "search_in_parts", counted)
    monkeypatch.setattr(parts, "MIN_QUERIES", 8)
    monkeypatch.setattr(parts, "MIN_ROWS", 8)  # proximity and the continuous check too
    two = _run(model, True, 24)
    assert sum(split) >= 10  # whole and partial searches, split in parts
    assert all(a.tobytes() == b.tobytes() for a, b in zip(one, two, strict=True))


@pytest.mark.parametrize("dense_factor", [0.0, 1e9])  # always hashed, always dense
def test_broad_phase_finds_exactly_the_overlapping_boxes(dense_factor: float) -> None:
    rng = np.random.default_rng(7)
    qlo = rng.uniform(0, 1, (300, 3))
    qhi = qlo + rng.uniform(0, 0.1, (300, 3))
    elo = rng.uniform(0, 1, (400, 3))
    ehi = elo + rng.uniform(0, 0.2, (400, 3))
    found = overlapping_pairs(qlo, qhi, elo, ehi, dense_factor=dense_factor)
    overlap = np.all((qlo[:, None] <= ehi[None]) & (qhi[:, None] >= elo[None]), axis=2)
    expected = set(zip(*np.nonzero(overlap), strict=True))
    assert len(found) == len(expected)  # each pair once
    assert set(map(tuple, found.tolist())) == expected
    same = overlapping_pairs(elo, ehi, elo, ehi, upper_only=True, dense_factor=dense_factor)
    overlap = np.all((elo[:, None] <= ehi[None]) & (ehi[:, None] >= elo[None]), axis=2)
    assert set(map(tuple, same.tolist())) == {(a, b) for a, b in zip(*np.nonzero(overlap), strict=True) if a < b}
    assert len(same) == np.count_nonzero(np.triu(overlap, 1))


@pytest.mark.parametrize("dense_factor", [0.0, 1e9])  # always hashed, always dense
def test_a_box_thrown_far_away_keeps_the_grid_small_and_the_pairs_exact(dense_factor: float) -> None:
    """A vertex a diverging substep throws 1e14 m (or to 1e300 m, or to a non-finite place) must
    not make a grid of billions of cells before the frame's divergence guard stops the run: the
    cell grows, the pairs of the finite boxes stay those of NumPy's all-pairs test."""
    rng = np.random.default_rng(5)
    lo = rng.uniform(0, 1, (3000, 3))
    hi = lo + rng.uniform(0, 0.02, (3000, 3))
    lo[9], hi[9] = 1e300, 1e300
    overlap = None
    for far in (1e14, 1e307):  # a box from the cloth out to `far` m along every axis
        hi[5] = far
        _, start, element, _, _ = broad_phase.grid_for(lo, hi, lo, hi, dense_factor)
        assert start.shape[0] < 1e7 and element.shape[0] < 1e7  # at the given cell: 1e48 entries
        found = overlapping_pairs(lo, hi, lo, hi, upper_only=True, dense_factor=dense_factor)
        overlap = np.all((lo[:, None] <= hi[None]) & (hi[:, None] >= lo[None]), axis=2)
        expected = {(a, b) for a, b in zip(*np.nonzero(overlap), strict=True) if a < b}
        assert set(map(tuple, found.tolist())) == expected
        assert (found == 5).any(axis=1).sum() > 100  # the long box meets many others
    lo[11, 0], hi[12, 1], lo[13, 2] = np.nan, np.inf, -np.inf
    found = overlapping_pairs(lo, hi, lo, hi, upper_only=True, dense_factor=dense_factor)
    finite = np.isfinite(lo).all(axis=1) & np.isfinite(hi).all(axis=1)
    kept = {(a, b) for a, b in zip(*np.nonzero(overlap), strict=True) if a < b and finite[a] and finite[b]}
    assert kept <= set(map(tuple, found.tolist()))  # the finite boxes' pairs all found still


def test_the_scan_grid_finds_exactly_the_overlapping_boxes_in_element_order() -> None:
    """The one-cell grid of a search with few queries (`broad_phase.scan_grid`): every element whose
    box overlaps the query's, each once, in element order; against NumPy's all-pairs test."""
    rng = np.random.default_rng(11)
    qlo = rng.uniform(-1, 1, (40, 3))
    qhi = qlo + rng.uniform(0, 0.3, (40, 3))
    qlo[0], qhi[0] = -2.0, 2.0  # a box around all of them
    elo = rng.uniform(-1, 1, (500, 3))
    ehi = elo + rng.uniform(0, 0.3, (500, 3))
    overlap = np.all((qlo[:, None] <= ehi[None]) & (qhi[:, None] >= elo[None]), axis=2)
    found = np.empty(8, dtype=np.int64)
    for q in range(qlo.shape[0]):
        count, found = broad_phase.query_grown(qlo, qhi, q, elo, ehi, *broad_phase.scan_grid(np.arange(500)), -1, found)
        assert found[:count].tolist() == np.flatnonzero(overlap[q]).tolist()
    assert overlap.any(axis=1).sum() > 10  # the boxes do meet


@pytest.mark.parametrize("dense_factor", [0.0, 1e9])  # always hashed, always dense
def test_a_grid_of_the_elements_near_a_few_queries_finds_their_pairs_in_order(dense_factor: float) -> None:
    """A partial search's grid holds only the elements near its queries (`broad_phase.near_elements`):
    each of those queries finds exactly the elements whose boxes overlap its own, in element order
    (NumPy's all-pairs test), as from a grid of them all, while far elements are left out; a
    non-finite element box is kept, a non-finite query box keeps every element."""
    rng = np.random.default_rng(17)
    elo = rng.uniform(0, 1, (4000, 3))
    ehi = elo + rng.uniform(0, 0.03, (4000, 3))
    ehi[7, 1] = np.inf
    qlo = rng.uniform(0, 1, (2000, 3))
    qhi = qlo + rng.uniform(0, 0.03, (2000, 3))
    clustered = np.flatnonzero(np.all(qlo < 0.2, axis=1))  # a few queries in one corner
    scattered = np.array([clustered[0], int(np.argmax(qlo.sum(axis=1)))])  # and two corners apart
    overlap = np.all((qlo[:, None] <= ehi[None]) & (qhi[:, None] >= elo[None]), axis=2)
    for queries in (clustered, scattered):
        near = broad_phase.near_elements(qlo, qhi, queries, elo, ehi)
        assert np.all(np.diff(near) > 0) and 7 in near
        assert near.shape[0] < 0.2 * elo.shape[0]  # the grid's elements: a fraction of them all
        assert set(np.flatnonzero(overlap[queries].any(axis=0))) <= set(near.tolist())
        grid = broad_phase.grid_for(qlo, qhi, elo, ehi, dense_factor, near=queries)
        found = np.empty(8, dtype=np.int64)
        for q in queries:
            count, found = broad_phase.query_grown(qlo, qhi, q, elo, ehi, *grid, -1, found)
            assert found[:count].tolist() == np.flatnonzero(overlap[q]).tolist()
    qhi[clustered[0], 2] = np.nan
    assert broad_phase.near_elements(qlo, qhi, clustered, elo, ehi).shape[0] == elo.shape[0]


def test_the_dense_and_the_hashed_grid_report_the_same_pairs_in_the_same_order() -> None:
    """Contact's bytes do not depend on which grid a rebuild used (a cloth spreading out moves
    from the dense grid to the hashed one)."""
    rng = np.random.default_rng(3)
    lo = rng.uniform(-0.2, 0.2, (500, 3))
    hi = lo + rng.uniform(0, 0.08, (500, 3))
    hashed = overlapping_pairs(lo, hi, lo, hi, upper_only=True, dense_factor=0.0)
    dense = overlapping_pairs(lo, hi, lo, hi, upper_only=True, dense_factor=1e9)
    assert hashed.shape[0] > 500
    assert hashed.tobytes() == dense.tobytes()


@pytest.mark.parametrize("dense_factor", [0.0, 1e9])  # always hashed, always dense
@pytest.mark.parametrize("thrown", [0.0, 1e9])  # a vertex thrown far: its edges' boxes are long
def test_edge_pairs_found_cell_by_cell_are_every_close_pair_and_the_queries_own(
    dense_factor: float, thrown: float
) -> None:
    """A whole search's edge-edge pairs, found cell by cell (`ee_candidates_in_cells`, and the long
    edges' own, `long_edge_pairs`), are every pair of edges that share no vertex and lie within
    the reach, as ipctk's edge-edge distance finds them over all pairs (written elsewhere), each
    once, with the flags and rest distances that the edge-by-edge search (`ee_candidates`) gives
    them. With a vertex thrown 1e9 m (a diverging substep) the cell stays the cloth's."""
    import ipctk

    from meshdeform.contact.broad_phase import cell_size, grid_for, swept_boxes
    from meshdeform.contact.self_collision import _rings, _Topology, long_edge_pairs

    rng = np.random.default_rng(11)
    model = SpringModel.from_mesh(grid_sheet(12, 12))
    x = np.asarray(model.rest_positions) + rng.normal(0.0, 0.04, (model.vertex_count, 3))  # crumpled
    if thrown:
        x[70] = x[60] + thrown  # through the cloth's corner, out along the diagonal
    topology = _Topology.of(model)
    edges = topology.edges
    n = model.vertex_count
    reach = 0.03
    lo, hi = swept_boxes(x, x, edges, 0.5 * reach)
    inv_cell, start, element, cell, box = grid_for(lo, hi, lo, hi, dense_factor=dense_factor)
    ring_start, ring = _rings(edges, n)
    rest = np.array(model.rest_positions, dtype=np.float64)
    shared = (np.arange(n), ring_start, ring, np.zeros((n, 3)), 1.0, reach)
    in_cells = self_kernels.ee_candidates_in_cells(
        x, rest, np.arange(start.shape[0] - 1), lo, hi, inv_cell, start, element, cell, box, edges, *shared, 0
    )
    if thrown:
        assert inv_cell == 1.0 / cell_size(lo, hi)  # the cell of the boxes' sizes: not grown
        assert element.shape[0] > start[-1]  # the long edges set apart
        found_long = long_edge_pairs(x, rest, lo, hi, (inv_cell, start, element, cell, box), edges, *shared)
        assert found_long[0].shape[0] > 0
        in_cells = tuple(np.concatenate(part) for part in zip(in_cells, found_long, strict=True))
    by_edge = self_kernels.ee_candidates(
        x, rest, np.arange(edges.shape[0]), np.ones(edges.shape[0], dtype=bool), lo, hi, inv_cell, start, element,
        cell, box, edges, *shared, True, 0,
    )
    found = [tuple(pair) for pair in in_cells[0].tolist()]
    assert len(found) == len(set(found))  # each pair once
    expected = set()
    for e in range(edges.shape[0]):
        for f in range(e + 1, edges.shape[0]):
            if set(edges[e]) & set(edges[f]):
                continue
            d2 = ipctk.edge_edge_distance(x[edges[e, 0]], x[edges[e, 1]], x[edges[f, 0]], x[edges[f, 1]])
            if d2 <= reach * reach:
                expected.add((e, f))
    assert len(expected) > 100
    assert set(found) == expected
    mine = {tuple(p): (bool(a), float(b)) for p, a, b in zip(in_cells[0].tolist(), *in_cells[1:], strict=True)}
    theirs = {tuple(p): (bool(a), float(b)) for p, a, b in zip(by_edge[0].tolist(), *by_edge[1:], strict=True)}
    assert mine == theirs


def _sampled_min_distance(x0: np.ndarray, x1: np.ndarray, samples: int = 2001) -> float:
    """Distance of point 0 to triangle (1, 2, 3) along the straight path, densely sampled, by
    minimising over a barycentric lattice (independent of the kernels)."""
    grid = np.linspace(0.0, 1.0, 41)
    u, v = np.meshgrid(grid, grid, indexing="ij")
    keep = u + v <= 1.0
    u, v = u[keep], v[keep]
    best = np.inf
    for t in np.linspace(0.0, 1.0, samples):
        x = x0 + t * (x1 - x0)
        points = x[1] + u[:, None] * (x[2] - x[1]) + v[:, None] * (x[3] - x[1])
        best = min(best, float(np.linalg.norm(points - x[0], axis=1).min()))
    return best


def test_a_scanned_mesh_with_slivers_falls_with_self_collision_without_stretching(shared_meshes: Path) -> None:
    """The Stanford bunny (8 171 vertices) has rest neighbours 0.3 um to 0.15 mm apart, closer
    than the parting's distance self-collision keeps between neighbours: they keep their rest
    distance instead, so in free fall with self-collision on its springs keep their lengths (they
    were pushed apart to it: 17 % stretch in the first frame)."""
    path = shared_meshes / "real" / "bunny.ply"
    text = "[simulation]\nframes = 2\n\n[self_collision]\n"
    built = build_simulation(parse_recipe(text), load(path))
    frames = list(simulate(built.model, built.scene, built.settings))
    assert max(frame.max_stretch for frame in frames) < 1.001


def test_the_continuous_check_misses_no_crossing() -> None:
    """Random vertex-triangle motions: whenever dense sampling finds the pair passing within 5 %
    of its start distance, the conservative check flags it."""
    rng = np.random.default_rng(11)
    triangles = np.array([[1, 2, 3]], dtype=np.int64)
    edges = np.zeros((0, 2), dtype=np.int64)
    pairs = np.array([[0, 0]], dtype=np.int64)
    crossings = 0
    for _ in range(60):
        x0 = rng.normal(size=(4, 3))
        x0[0] = x0[1:].mean(axis=0) + rng.normal(size=3) * 0.5
        x1 = x0 + rng.normal(size=(4, 3)) * 0.8
        start = _sampled_min_distance(x0, x0, samples=1)
        near = _sampled_min_distance(x0, x1) < 0.05 * start
        no_pairs = np.zeros((0, 2), dtype=np.int64)
        hit, _ = self_kernels.colliding_pairs(
            x0, x1, triangles, edges, pairs, np.zeros(1), no_pairs, np.zeros(0)
        )
        if near:
            crossings += 1
            assert hit[0]
    assert crossings >= 3  # the sample did test crossings


def test_the_report_says_what_contact_took(tmp_path) -> None:
    """Through the CLI: a sheet falling under 300 g hits the ground at about 40 m/s in the first
    frame, which needs the swept test; the report gives per-frame figures and names that frame."""
    import json

    from typer.testing import CliRunner

    from meshdeform.io import write_obj
    from pipeline.cli import app

    write_obj(tmp_path / "sheet.obj", grid_sheet(8, plane="xz", size=0.5, triangles=True, offset=(0.0, 0.3, 0.0)))
    (tmp_path / "r.toml").write_text(
        "[simulation]\nframes = 4\ngravity = [0, -3000, 0]\n"
        "[self_collision]\n[[colliders]]\nground = { height = 0.0 }\n"
    )
    args = ["simulate", str(tmp_path / "sheet.obj"), "-r", str(tmp_path / "r.toml"), "-o", str(tmp_path / "out"), "-q"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["self_collision"]["thickness"] == 0.005  # the [material] default
    assert all(len(v) == 4 for k, v in report["self_collision"].items() if k != "thickness")
    assert all(len(v) == 4 for v in report["collider_contact"].values())
    assert report["collider_contact"]["swept"][0] > 0
    assert 1 in report["contact_extra_work_frames"]


def test_check_names_self_collision_and_refuses_a_typo(tmp_path) -> None:
    from typer.testing import CliRunner

    from pipeline.cli import app

    good, bad = tmp_path / "good.toml", tmp_path / "bad.toml"
    good.write_text("[self_collision]\nthickness = 0.004\n")
    bad.write_text("[self_collision]\nthicknes = 0.004\n")
    result = CliRunner().invoke(app, ["check", str(good)])
    assert result.exit_code == 0 and "self-collision (thickness 4 mm)" in result.output
    result = CliRunner().invoke(app, ["check", str(bad)])
    assert result.exit_code == 2 and "self_collision.thicknes (line 2)" in result.output


@pytest.mark.parametrize("solver", ["xpbd", "verlet", "springs", "implicit", "anchor"])
def test_every_solver_keeps_the_collapsing_sheet_free_of_intersections(solver: str) -> None:
    """Each solver lets this 16 x 16 sheet fold through itself without self-collision (8 to 8,000
    pairs measured) and none with it."""
    model = SpringModel.from_mesh(_collapsing_sheet(16), KNIT)

    def worst(self_collision: bool) -> int:
        ground = Collider(Plane((0.0, 0.0, 0.0), (0.0, 1.0, 0.0)), 0.3, 0.01)
        contact = SelfCollision(SelfCollisionSettings(thickness=THICKNESS), [ground]) if self_collision else None
        scene = Scene(constraints=[ground], self_collision=contact)
        frames = simulate(model, scene, Settings(solver=solver, frames=30))
        return max(intersecting_pairs(f.welded_positions, model.triangles) for f in frames)

    assert worst(False) > 0
    assert worst(True) == 0


def test_a_spinning_pair_of_layers_keeps_its_pairs_and_never_crosses() -> None:
    """Two 24 x 24 sheets of 0.5 m, 7 mm apart, spinning together in their plane at 12 rad/s
    without gravity (3 m/s at the corners, 6 mm a substep, a quarter of an edge), the upper one
    sinking onto the lower at 0.2 m/s. Every vertex moves fast, but each with its neighbours and
    the layer below: the pairs are searched again in under 30 % of the substeps (with boxes and
    a cull by each vertex's own motion: 160 of 264), and no two triangles ever intersect."""
    mesh = _two_sheets(0.007, 24)
    count = mesh.positions.shape[0] // 2
    model = SpringModel.from_mesh(mesh)
    state = State.at_rest(model)
    x = state.positions.copy()
    spin = 12.0
    state.velocities[:, 0] = -spin * x[:, 2]
    state.velocities[:, 2] = spin * x[:, 0]
    state.velocities[count:, 1] = -0.2
    settings = Settings(solver="xpbd", frames=12)  # 22 substeps a frame: the motions above
    state.previous[:] = x - state.velocities * settings.dt
    contact = SelfCollision(SelfCollisionSettings(thickness=THICKNESS))
    frames = list(simulate(model, Scene(gravity=(0.0, 0.0, 0.0), self_collision=contact), settings, state=state))
    assert [intersecting_pairs(f.welded_positions, model.triangles) for f in frames] == [0] * len(frames)
    corner = np.array([x[0]] + [f.welded_positions[0] for f in frames])
    turned = np.unwrap(np.arctan2(corner[:, 2], corner[:, 0]))  # frame by frame, past a half turn
    assert abs(turned[-1] - turned[0]) > 1.0  # it did spin (12 rad/s for half a second, less what the springs take)
    builds = sum(f.contact.pair_builds for f in frames)
    assert builds < 0.3 * settings.substeps * len(frames)


def test_a_fine_sheet_spinning_over_another_keeps_short_pair_lists() -> None:
    """Two 5 cm sheets of 2 mm edges, 1.5 mm apart (self-collision's thickness there: half an
    edge, 1.1 mm), the upper spinning at 160 rad/s over the lower (up to 5.6 m/s at its corners,
    a substep at 88 a frame moves them an edge) without gravity. Each vertex's kept pairs are
    those that may come within the thickness while the list holds: a list held over 8.2 ms (17
    such substeps) reached 3 cm ahead and kept up to 474 triangles a vertex (of the other
    sheet's 1 058), 8 s for two frames; its span now shrinks with the motion, and no vertex
    keeps more than 120 (the triangles within about 4 edges of it). No two triangles ever
    intersect."""
    n, size = 24, 0.05
    lower = grid_sheet(n, plane="xz", size=size, triangles=True, centred=True)
    upper = grid_sheet(n, plane="xz", size=size, triangles=True, centred=True, offset=(0.0, 0.0015, 0.0))
    count = lower.positions.shape[0]
    mesh = _stacked(lower, upper)
    model = SpringModel.from_mesh(mesh)
    state = State.at_rest(model)
    settings = Settings(solver="xpbd", frames=2, substeps=88)
    x = state.positions
    state.velocities[count:, 0] = -160.0 * x[count:, 2]
    state.velocities[count:, 2] = 160.0 * x[count:, 0]
    state.previous[:] = x - state.velocities * settings.dt
    contact = SelfCollision(SelfCollisionSettings())
    kept = []
    search = contact._pairs

    def recording(model, topology, x0, x1, threads):
        pairs = search(model, topology, x0, x1, threads)
        kept.append(np.bincount(pairs.vf[:, 0], minlength=x1.shape[0]).max(initial=0))
        return pairs

    contact._pairs = recording
    frames = list(simulate(model, Scene(gravity=(0.0, 0.0, 0.0), self_collision=contact), settings, state=state))
    assert [intersecting_pairs(f.welded_positions, model.triangles) for f in frames] == [0] * len(frames)
    assert len(kept) >= settings.substeps * len(frames)
    assert max(kept) <= 120


def test_every_pair_within_the_thickness_is_in_the_substeps_list() -> None:
    """The pair lists kept from substep to substep (relative motion, partial searches) miss no pair:
    at the end of every substep of a collapsing sheet, each vertex-triangle and edge-edge pair that
    shares no vertex and lies within the thickness, as ipctk's broad phase and distances find them
    (written elsewhere), is in the list self-collision used for that substep."""
    import ipctk

    model = SpringModel.from_mesh(_collapsing_sheet(16))
    ground = Collider(Plane((0.0, 0.0, 0.0), (0.0, 1.0, 0.0)), 0.3, 0.01)
    contact = SelfCollision(SelfCollisionSettings(thickness=THICKNESS), [ground])
    used = []
    search = contact._pairs

    def recording(model, topology, x0, x1, threads):
        pairs = search(model, topology, x0, x1, threads)
        used.append((x1.copy(), pairs.vf.copy(), pairs.ee.copy()))
        return pairs

    contact._pairs = recording
    list(simulate(model, Scene(constraints=[ground], self_collision=contact), Settings(solver="xpbd", frames=16)))
    faces = np.asarray(model.triangles, dtype=np.int32)
    edges = np.asarray(contact._topology.edges, dtype=np.int32)
    mesh = ipctk.CollisionMesh(np.asarray(model.rest_positions, dtype=np.float64), edges, faces)
    limit = (0.999 * contact.thickness) ** 2
    checked = 0
    for x1, vf, ee in used[::3]:
        candidates = ipctk.Candidates()
        candidates.build(mesh, np.asfortranarray(x1), contact.thickness)
        listed_vf = {(int(v), int(t)) for v, t in vf}
        listed_ee = {(int(e), int(f)) for e, f in ee}
        for c in candidates.fv_candidates:
            v, t = c.vertex_id, c.face_id
            ids = c.vertex_ids(edges, faces)
            if v in faces[t] or c.compute_distance(x1[list(ids)].ravel()) >= limit:
                continue
            assert (v, t) in listed_vf, (v, t)
            checked += 1
        for c in candidates.ee_candidates:
            e, f = sorted((c.edge0_id, c.edge1_id))
            if set(edges[e]) & set(edges[f]):
                continue
            ids = c.vertex_ids(edges, faces)
            if c.compute_distance(x1[list(ids)].ravel()) >= limit:
                continue
            assert (e, f) in listed_ee, (e, f)
            checked += 1
    assert checked > 100  # the sheet did fold onto itself: pairs within the thickness were there to find


def test_a_plate_carrying_the_cloth_through_self_collision_zones_stays_out_of_it() -> None:
    """A 0.6 m plate (a box, 1 cm thick) rising at 5 m/s through a 1 m sheet (25 x 25, triangles)
    lying flat without gravity, self-collision on without proximity sweeps, so that impact zones
    alone keep the folds around the plate's rim apart, implicit: where the zones fall back to
    where the substep started, the plate has moved on into that start, 2.6 cm a substep. The
    moving collider is projected once more after them: the sheet's faces keep the plate's
    thickness less 1 mm (4 mm into it when this was written; today the clearance holds without
    that pass too) and never pass through themselves. (With the proximity sweeps no zone forms
    there any more: the rest neighbours around the folds are kept a tenth of the thickness apart.)"""
    mesh = grid_sheet(25, 25, size=1.0, plane="xz", triangles=True, centred=True, offset=(0.0, 0.5, 0.0))
    text = (
        '[simulation]\nsolver = "implicit"\nfps = 24\nframes = 8\ngravity = [0, 0, 0]\n\n[self_collision]\n\n'
        "[[colliders]]\nbox = { min = [-0.3, 0.0, -0.3], max = [0.3, 0.01, 0.3] }\nfriction = 0.5\nthickness = 0.005\n"
        "animate = [{ time = 0.0, translate = [0, 0, 0] }, { time = 0.05, translate = [0, 0, 0] }, "
        "{ time = 0.65, translate = [0, 3.0, 0] }]\n"
    )
    built = build_simulation(parse_recipe(text), mesh)
    contact = built.scene.self_collision
    built.scene.self_collision = SelfCollision(replace(contact.settings, sweeps=0), contact.colliders)
    lo, hi = np.array([-0.3, 0.0, -0.3]), np.array([0.3, 0.01, 0.3])
    zoned = 0
    for frame in simulate(built.model, built.scene, built.settings):
        rise = 3.0 * min(max(frame.time - 0.05, 0.0) / 0.6, 1.0)
        samples = lattice(frame.welded_positions, np.asarray(frame.model.triangles), n=6)
        assert box_distance(samples, lo + [0, rise, 0], hi + [0, rise, 0]).min() >= 0.005 - 0.001, frame.index
        assert intersecting_pairs(frame.welded_positions, frame.model.triangles) == 0, frame.index
        zoned += frame.contact.zone_rounds
    assert zoned > 0  # the zones were there


@pytest.mark.parametrize(("solver", "speed"), [("verlet", 20.0), ("xpbd", 60.0), ("implicit", 20.0)])
def test_a_plate_punched_fast_through_a_lying_sheet_stays_out_of_it_and_of_itself(solver: str, speed: float) -> None:
    """The plate of the test above rising 3 m at 20 or 60 m/s through the sheet: the frames it moves
    in take more substeps (the speed a moving collider would carry the cloth at counts as the
    cloth's, `meshdeform.simulate.fast_substeps`), and after self-collision's zones the colliders
    and the zones run again until neither moves what the other left. Before: verlet at 20 m/s
    ended with 2 intersecting pairs, xpbd at 60 m/s with 63 (stretched 9x), implicit at 20 m/s
    diverged; the last pass of the moving plate alone, or none, left a face in the plate."""
    plate = punched_plate(solver, speed)
    built = build_simulation(parse_recipe(plate.recipe), plate.mesh)
    frames = []
    for frame in simulate(built.model, built.scene, built.settings):
        rise = np.array([0.0, plate.rise(frame.time), 0.0])
        samples = lattice(frame.welded_positions, np.asarray(frame.model.triangles), n=6)
        assert box_distance(samples, plate.lo + rise, plate.hi + rise).min() >= 0.005 - 0.001, frame.index
        assert intersecting_pairs(frame.welded_positions, frame.model.triangles) == 0, frame.index
        frames.append(frame)
    assert max(f.substeps for f in frames) > built.settings.substeps
    assert max(f.max_stretch for f in frames) < 3.0


def test_a_tilted_sheet_shot_at_a_small_plate_at_50_m_s_folds_over_it_and_stays_out_of_it() -> None:
    """A 0.8 m sheet (32 x 32, alternating diagonals), tilted, shot at 50 m/s from 2.7 m above onto a
    0.4 m plate 1 cm thick, xpbd with self-collision: the sheet overhangs the plate and folds over
    its rims within a frame, a layer landing on the layer that landed. Self-collision pushed the
    lower layer into the plate, and the colliders' pass after it started its paths from the
    positions the velocities imply, inside the plate here, to which its fail-safe put the
    vertices back, every substep to the end: 4 vertices
    stayed 4.5 mm inside (found by an acceptance run). Every vertex and face point keeps the plate's
    thickness less 1 mm, and no two triangles of the sheet cross."""
    from scipy.spatial.transform import Rotation

    mesh = grid_sheet(32, 32, size=0.8, plane="xz", triangles="alternate", centred=True)
    turned = Rotation.from_euler("xyz", [20, 0, 12], degrees=True).apply(mesh.positions) + [0.0, 3.21, 0.0]
    mesh = replace(mesh, positions=turned)
    text = (
        '[simulation]\nsolver = "xpbd"\nfps = 24\nframes = 2\ninitial_velocity = [0.5, -50, 0.3]\n'
        "[material]\nthickness = 0.004\n[self_collision]\n"
        "[[colliders]]\nbox = { min = [-0.2, 0.5, -0.2], max = [0.2, 0.51, 0.2] }\nfriction = 0.3\nthickness = 0.005\n"
    )
    built = build_simulation(parse_recipe(text), mesh)
    lo, hi = np.array([-0.2, 0.5, -0.2]), np.array([0.2, 0.51, 0.2])
    landed = 0
    for frame in simulate(built.model, built.scene, built.settings):
        samples = lattice(frame.welded_positions, np.asarray(frame.model.triangles), n=6)
        distance = box_distance(samples, lo, hi)
        assert distance.min() >= 0.005 - 0.001, (frame.index, distance.min())
        assert intersecting_pairs(frame.welded_positions, frame.model.triangles) == 0, frame.index
        landed += int(frame.contact.zone_rounds > 0 or frame.contact.projections > 0)
    assert landed > 0  # the layers met


@pytest.mark.parametrize(("solver", "degrees"), [("xpbd", 720), ("implicit", 1080)])
def test_a_strip_twisted_by_turning_pins_never_passes_through_itself(solver: str, degrees: int) -> None:
    """`factories.twisted_strip` (its bottom row of pins turned `degrees` over 2 s, through a
    recipe): the strip winds into a rope around itself, its pinned row ends turned whole, and no
    two of its triangles that share no vertex intersect in any frame (the ipctk oracle). Impact
    zones holding pins that turn took the pins' mean translation, which cannot follow a turn: 31
    pairs under xpbd at 720 degrees, 220 under implicit at 1080."""
    mesh, text = twisted_strip(solver, degrees)
    built = build_simulation(parse_recipe(text), mesh)
    frames = list(simulate(built.model, built.scene, built.settings))
    bottom = frames[-1].welded_positions[:20]
    assert np.allclose(bottom[:, 1], 0.3) and np.abs(bottom[-1, [0, 2]] - [0.2, 0.0]).max() < 1e-9  # turned whole
    assert [intersecting_pairs(f.welded_positions, f.model.triangles) for f in frames] == [0] * 48


def test_rigid_motion_is_the_turn_and_shift_of_points_that_move_as_one_body() -> None:
    """`rigid_motion`, which turns a zone with its pins: five points turned 40 degrees about a
    random axis (scipy's `Rotation`) and shifted give back that turn and shift; a row of points
    turned 30 degrees about an axis across it gives the turn about that axis (the least one that
    takes the row to its new direction); a translation, a stretch and half a revolution give
    None (the zone translates, or moves apart)."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(7)
    points = rng.normal(size=(5, 3))
    turn = Rotation.from_rotvec(np.radians(40.0) * np.array([1.0, 2.0, -0.5]) / np.sqrt(5.25)).as_matrix()
    shift = np.array([0.3, -0.1, 2.0])
    found = rigid_motion(points, points @ turn.T + shift)
    assert found is not None
    assert np.allclose(found[0], turn, atol=1e-12) and np.allclose(found[1], shift, atol=1e-12)
    row = np.stack([np.linspace(-0.2, 0.2, 7), np.zeros(7), np.zeros(7)], axis=1)
    about_y = Rotation.from_euler("y", 30.0, degrees=True).as_matrix()
    found = rigid_motion(row, row @ about_y.T + [0.0, 0.01, 0.0])
    assert found is not None and np.allclose(found[0], about_y, atol=1e-12)
    assert rigid_motion(points, points + [0.1, 0.0, 0.0]) is None
    assert rigid_motion(points, 1.01 * points) is None
    half = Rotation.from_euler("z", 180.0, degrees=True).as_matrix()
    assert rigid_motion(points, points @ half.T) is None


def test_pins_driven_through_the_cloth_are_reported_where_self_collision_cannot_hold(tmp_path) -> None:
    """The lower of two sheets 5 cm apart pinned whole, the upper one's corners pinned and driven
    10 cm down through it in 0.4 s (the recipe forces a crossing no contact can undo: pinned
    vertices go where their animation puts them), through `run_job`: the cloth does cross
    (the ipctk oracle finds pairs from some frame on), and the report says so no later than the
    first such frame: `self_collision.unresolved` counts the substeps whose impact zones ran out
    of rounds, and one warning names the frames."""
    mesh_path = tmp_path / "sheets.obj"
    write_obj(mesh_path, _two_sheets(0.05))
    text = (
        '[simulation]\nfps = 24\nframes = 12\ngravity = [0, 0, 0]\n\n[self_collision]\nthickness = 0.005\n\n'
        f"[[pins]]\nselect = {{ indices = {list(range(64))} }}\n\n"
        "[[pins]]\nselect = { indices = [64, 71, 120, 127] }\n"
        "animate = [{ time = 0.0, translate = [0, 0, 0] }, { time = 0.4, translate = [0, -0.1, 0] }]\n\n"
        '[output]\nformats = ["npz"]\n'
    )
    report = run_job(mesh_path, parse_recipe(text), tmp_path / "out").report
    with np.load(tmp_path / "out" / "positions.npz") as data:
        positions = data["positions"].astype(np.float64)
    triangles = np.asarray(load(mesh_path).face_indices).reshape(-1, 3)  # `_two_sheets` is triangles
    crossed = [k for k in range(1, positions.shape[0]) if intersecting_pairs(positions[k], triangles)]
    assert crossed  # the pins did drive the cloth through itself
    unresolved = report["self_collision"]["unresolved"]
    first_reported = next(k for k, count in enumerate(unresolved, start=1) if count)
    assert first_reported <= crossed[0]
    (warning,) = [w for w in report["warnings"] if w.startswith("self_collision: in ")]
    assert f"({first_reported}" in warning


@pytest.mark.parametrize("solver", ["xpbd", "implicit"])
def test_the_two_sides_of_a_tear_never_pass_through_each_other(tmp_path, solver: str) -> None:
    """The tear sample (a curtain pulled apart by its side edges until it tears down the middle)
    with self-collision and a ground, through `run_job`: every frame's OBJ, read back by trimesh
    (its quads split by trimesh) with the torn topology, has no intersecting pair of triangles
    that share no vertex (the ipctk oracle). The sides of the tear slide along each other in the
    cloth's plane as the halves sag; their copies started where their originals were, the pairs
    across the tear were left unjudged while within 1 mm, and the halves overlapped in that
    plane (31 pairs under xpbd, 164 under implicit)."""
    import trimesh

    root = Path(__file__).resolve().parents[1]
    recipe = (root / "samples" / "recipes" / "tear.toml").read_text()
    recipe = recipe.replace('solver = "xpbd"', f'solver = "{solver}"').replace('["obj", "vtk"]', '["obj"]')
    recipe += '\n[self_collision]\n\n[[colliders]]\nground = { height = -0.3 }\n'
    report = run_job(root / "samples" / "meshes" / "curtain.obj", parse_recipe(recipe), tmp_path / "out").report
    assert report["solver"] == solver and max(report["pieces"]) > 1  # it did tear
    frames = sorted((tmp_path / "out" / "frames").glob("frame_*.obj"))
    assert len(frames) >= report["frames"]  # (and the rest pose)
    for path in frames:
        mesh = trimesh.load(path, process=False, maintain_order=True, force="mesh")
        assert intersecting_pairs(np.asarray(mesh.vertices), np.asarray(mesh.faces)) == 0, path.name


def test_a_cut_at_the_end_of_a_frame_leaves_its_sides_apart_in_that_frame(tmp_path) -> None:
    """A flat 10 x 10 sheet, nothing moving, cut in two along a plane by the last substep of frame
    1, with self-collision: the OBJs of frames 1 (the cut's) and 2, read back by trimesh,
    have no intersecting pair (the ipctk oracle; with the sides left where the cut made them,
    unjudged while within a fifth of the thickness, frame 2 had 67), no vertex moved more
    than a twentieth of an edge for the parting, and nothing was set moving."""
    import trimesh

    write_obj(tmp_path / "sheet.obj", grid_sheet(10, plane="xy", size=0.9))
    text = (
        "[simulation]\nfps = 24\nframes = 2\ngravity = [0, 0, 0]\n\n[self_collision]\n\n"
        "[[cuts]]\ntime = 0.0416666\nplane = { point = [0.45, 0, 0], normal = [1, 0, 0] }\n\n"
        '[output]\nformats = ["obj"]\n'
    )
    report = run_job(tmp_path / "sheet.obj", parse_recipe(text), tmp_path / "out").report
    assert report["split_vertices"][0] > 0 and report["pieces"][0] == 2  # cut in frame 1
    assert max(report["max_speed"]) < 0.01  # the parting sets nothing moving (0.8 m/s parted within the surface)
    rest = trimesh.load(tmp_path / "sheet.obj", process=False, maintain_order=True, force="mesh")
    files = sorted((tmp_path / "out" / "frames").glob("frame_*.obj"))  # the rest pose, frames 1 and 2
    assert len(files) == 3
    for path in files:
        mesh = trimesh.load(path, process=False, maintain_order=True)
        assert intersecting_pairs(np.asarray(mesh.vertices), np.asarray(mesh.faces)) == 0, path.name
        originals = cKDTree(np.asarray(rest.vertices)).query(np.asarray(mesh.vertices))[0]
        assert originals.max() <= 0.1 / 20  # the grid's edge is 0.1 m


def test_triangles_cross_agrees_with_the_ipctk_oracle_on_random_pairs() -> None:
    """`triangle_distance.triangles_cross` (the check of a tear's parting) against the test
    suite's independent oracle (ipctk's predicates, `tests/intersections.py`) on 400 random pairs
    of triangles sharing no vertex, about a third of them crossing."""
    from meshdeform.contact.triangle_distance import triangles_cross

    rng = np.random.default_rng(5)
    count = 400
    points = rng.normal(0.0, 1.0, (count, 6, 3))
    points[:, 3:] = 0.6 * points[:, 3:] + points[:, :1]  # the second triangle near the first
    vertices = points.reshape(-1, 3)
    triangles = np.arange(6 * count, dtype=np.int64).reshape(-1, 3)
    pairs = np.stack([2 * np.arange(count), 2 * np.arange(count) + 1], axis=1)
    mine = triangles_cross(vertices, triangles, pairs)
    theirs = np.zeros(count, dtype=bool)
    for k in range(count):
        theirs[k] = intersecting_pairs(vertices[6 * k : 6 * k + 6], triangles[:2]) == 1
    assert 0.2 * count < theirs.sum() < 0.8 * count
    assert (mine == theirs).all()


def test_a_split_whose_fans_lie_folded_over_each_other_is_parted_without_a_crossing() -> None:
    """Two triangles that a tear left touching at one point (a vertex and its copy), the second
    (narrower) folded down over the first at 0.6 degrees: parted along the split's normal, the first's
    corner one way and the second's the other (`PART_FRACTION` of a 5 mm thickness), they would
    cross (the ipctk oracle says so); `_parting` takes another way, and the oracle finds them
    apart."""
    from meshdeform.contact.self_collision import _parting

    x = np.array([[0, 0, 0], [1, -0.5, 0], [1, 0.5, 0], [0, 0, 0], [1, -0.3, 0.01], [1, 0.3, 0.01]], dtype=float)
    triangles = np.array([[0, 1, 2], [3, 4, 5]], dtype=np.int64)
    group = np.array([0, 1, 2, 0, 4, 5])  # vertex 3 is a copy of vertex 0
    rows = np.array([0, 3])
    step = 0.1 * THICKNESS
    across = np.array([[0.0, 0.0, step], [0.0, 0.0, -step]])  # the first side up, the other down
    inward = np.array([[step, 0.0, 0.0], [step, 0.0, 0.0]])
    naive = x.copy()
    naive[rows] += across + inward
    assert intersecting_pairs(naive, triangles) == 1
    offset = _parting(triangles, x, group, rows, across, inward)
    parted = x.copy()
    parted[rows] += offset
    assert intersecting_pairs(parted, triangles) == 0
    assert np.linalg.norm(parted[0] - parted[3]) > 0.5 * step  # parted, not left touching


def test_a_sheet_shredded_on_a_bar_never_passes_through_itself() -> None:
    """A 1 m sheet (30 x 30, triangles of alternating diagonals) dropped from 0.6 m onto a 4 cm
    bar and the ground, every spring tearable at 1.02 times its length, xpbd, self-collision on:
    it shreds into some 90 pieces, tearing in hundreds of substeps, and no frame has an
    intersecting pair of triangles that share no vertex (the ipctk oracle, the torn topology).
    Before: 17 to 33 pairs in a frame. Two ways through: a split's fans folded over each other
    and parted along its normal into a crossing (`_parting` now takes another way), and the
    copies of one vertex, left to the continuous check alone, closing on each other substep by
    substep to within `self_kernels.TOUCHING`, where no pair is judged (proximity now keeps them
    the parting's distance apart)."""
    mesh = grid_sheet(30, size=1.0, plane="xz", triangles="alternate", centred=True, offset=(0.0, 0.6, 0.0))
    text = (
        '[simulation]\nsolver = "xpbd"\nfps = 24\nframes = 48\n\n[self_collision]\n\n'
        "[[colliders]]\nbox = { min = [-0.6, 0.3, -0.02], max = [0.6, 0.34, 0.02] }\nfriction = 0.3\n\n"
        "[[colliders]]\nground = { height = 0.0 }\n\n"
        "[[tears]]\nselect = { box = { min = [-1, -1, -0.1], max = [1, 1, 0.1] } }\nmax_stretch = 1.02\n"
    )
    built = build_simulation(parse_recipe(text), mesh)
    worst = 0
    for frame in simulate(built.model, built.scene, built.settings):
        worst = max(worst, intersecting_pairs(frame.welded_positions, np.asarray(frame.model.triangles)))
    assert frame.pieces > 20  # it shredded
    assert worst == 0
