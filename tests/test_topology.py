"""Spring topology against the closed-form counts of DESIGN.md section 2 and independent references."""

from __future__ import annotations

import numpy as np
import pytest
from factories import grid_sheet

from meshdeform.mesh import Mesh, polygons_to_csr
from meshdeform.topology import (
    STRAIGHT_COS,
    SpringKind,
    _straightest_continuations,
    adjacency,
    boundary_edge_count,
    boundary_edges,
    build_springs,
    edge_incidence,
    is_closed,
    topology_stats,
    weld,
)


def expected_grid_counts(n: int, m: int) -> dict[str, int]:
    return {
        "structural": n * (m - 1) + m * (n - 1),
        "shear": 2 * (n - 1) * (m - 1),
        "bending": n * max(m - 2, 0) + m * max(n - 2, 0),
    }


@pytest.mark.parametrize(("n", "m"), [(2, 2), (2, 5), (3, 3), (7, 4), (17, 11), (64, 64)])
def test_quad_grid_spring_counts_match_formulas(n: int, m: int) -> None:
    _, springs = build_springs(grid_sheet(n, m))
    assert springs.counts() == expected_grid_counts(n, m)


def test_springs_are_unique_and_never_self_loops() -> None:
    _, springs = build_springs(grid_sheet(9, 6))
    pairs = springs.pairs
    assert (pairs[:, 0] < pairs[:, 1]).all()
    keys = pairs[:, 0].astype(np.int64) * 1000 + pairs[:, 1]
    assert np.unique(keys).size == keys.size


def test_grid_spring_geometry_by_kind() -> None:
    """Structural springs are grid edges, shear the quad diagonals, bending span two edges in a line."""
    n, m = 6, 5
    mesh = grid_sheet(n, m, size=(n - 1.0, m - 1.0))  # unit spacing
    welding, springs = build_springs(mesh)
    p = mesh.positions[welding.representative]
    length = np.linalg.norm(p[springs.pairs[:, 1]] - p[springs.pairs[:, 0]], axis=1)
    np.testing.assert_allclose(length[springs.kinds == SpringKind.STRUCTURAL], 1.0)
    np.testing.assert_allclose(length[springs.kinds == SpringKind.SHEAR], np.sqrt(2.0))
    np.testing.assert_allclose(length[springs.kinds == SpringKind.BENDING], 2.0)


def test_curved_grid_keeps_bending_springs() -> None:
    """A grid rolled into a half cylinder still has its straightest continuations."""
    n, m = 24, 6
    mesh = grid_sheet(n, m)
    angle = mesh.positions[:, 0] * np.pi
    curved = np.stack([np.cos(angle), mesh.positions[:, 1], np.sin(angle)], axis=1)
    _, springs = build_springs(mesh.with_positions(curved))
    assert springs.counts() == expected_grid_counts(n, m)


def test_uv_seam_copies_share_springs() -> None:
    """Splitting a grid's middle column into two copies (a UV seam) changes no spring."""
    n, m = 6, 4
    mesh = grid_sheet(n, m)
    seam_col = 3
    copies = np.arange(m) * n + seam_col
    new_index = mesh.vertex_count + np.arange(m)
    positions = np.concatenate([mesh.positions, mesh.positions[copies]])
    faces = mesh.face_indices.reshape(-1, 4).copy()
    # quads right of the seam use the copies
    remap = np.arange(mesh.vertex_count)
    quad_left_col = np.arange(faces.shape[0]) % (n - 1)
    right = quad_left_col >= seam_col
    lookup = dict(zip(copies.tolist(), new_index.tolist(), strict=True))
    remap_right = remap.copy()
    remap_right[copies] = [lookup[c] for c in copies.tolist()]
    faces[right] = remap_right[faces[right]]
    split = Mesh(positions=positions, face_indices=faces.ravel(), face_offsets=mesh.face_offsets)
    welding, springs = build_springs(split)
    assert welding.count == n * m
    np.testing.assert_array_equal(welding.vertex_map[new_index], welding.vertex_map[copies])
    assert springs.counts() == expected_grid_counts(n, m)


def test_weld_keeps_first_seen_order_and_treats_negative_zero_as_zero() -> None:
    positions = np.array([[1.0, 0, 0], [0.0, 0, 0], [1.0, 0, 0], [-0.0, 0, 0], [2.0, 0, 0]])
    welding = weld(positions)
    np.testing.assert_array_equal(welding.vertex_map, [0, 1, 0, 1, 2])
    np.testing.assert_array_equal(welding.representative, [0, 1, 4])


def test_triangulated_grid_bends_across_every_interior_edge() -> None:
    """Each quad split along its (i, j)-(i+1, j+1) diagonal: no shear (triangles are rigid in their
    plane), one bending spring per interior edge and no straight skip-one line. Unit spacing: the
    pair across a diagonal is the quad's other diagonal (sqrt 2); across a row or column edge it is
    a knight's move (sqrt 5)."""
    n, m = 8, 5
    mesh = grid_sheet(n, m, size=(n - 1.0, m - 1.0), triangles=True, uvs=False)
    welding, springs = build_springs(mesh)
    diagonals = (n - 1) * (m - 1)
    edges = n * (m - 1) + m * (n - 1) + diagonals
    boundary = 2 * (n - 1) + 2 * (m - 1)
    assert springs.counts() == {"structural": edges, "shear": 0, "bending": edges - boundary}
    p = mesh.positions[welding.representative]
    bend = springs.pairs[springs.kinds == SpringKind.BENDING]
    length = np.linalg.norm(p[bend[:, 1]] - p[bend[:, 0]], axis=1)
    assert np.count_nonzero(np.isclose(length, np.sqrt(2.0))) == diagonals
    assert np.count_nonzero(np.isclose(length, np.sqrt(5.0))) == edges - boundary - diagonals


def test_polyline_rope_gets_structural_and_bending_springs() -> None:
    k = 12
    positions = np.zeros((k, 3))
    positions[:, 0] = np.linspace(0, 1, k)
    mesh = Mesh(
        positions=positions,
        face_indices=np.zeros(0, np.int64),
        face_offsets=np.zeros(1, np.int64),
        line_indices=np.arange(k, dtype=np.int64),
        line_offsets=np.array([0, k], dtype=np.int64),
    )
    _, springs = build_springs(mesh)
    assert springs.counts() == {"structural": k - 1, "shear": 0, "bending": k - 2}


def test_ngon_diagonals_are_shear_springs() -> None:
    """A hexagon has 6 edges and 6*3/2 = 9 diagonals; its two long diagonals through no vertex stay shear."""
    t = np.linspace(0, 2 * np.pi, 7)[:-1]
    positions = np.stack([np.cos(t), np.sin(t), np.zeros(6)], axis=1)
    mesh = Mesh(positions=positions, face_indices=np.arange(6, dtype=np.int64), face_offsets=np.array([0, 6]))
    _, springs = build_springs(mesh)
    assert springs.counts()["structural"] == 6
    assert springs.counts()["shear"] == 9


def test_topology_stats_on_cube_with_extra_triangle() -> None:
    """A closed cube has no boundary; a triangle laid over one of its faces makes non-manifold edges."""
    corners = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], dtype=float)
    quads = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]]
    flat, offsets = polygons_to_csr(quads)
    cube = Mesh(positions=corners, face_indices=flat, face_offsets=offsets)
    welding, springs = build_springs(cube)
    stats = topology_stats(cube, welding, springs)
    assert (stats.boundary_edges, stats.non_manifold_edges, stats.pieces) == (0, 0, 1)
    flat2, offsets2 = polygons_to_csr([*quads, [4, 5, 7]])
    extra = Mesh(positions=corners, face_indices=flat2, face_offsets=offsets2)
    w2, s2 = build_springs(extra)
    stats2 = topology_stats(extra, w2, s2)
    assert stats2.non_manifold_edges == 2  # 4-5 and 5-7 lie on the quad and the triangle, 4-7 is new
    assert stats2.boundary_edges == 1


def test_two_pieces_are_counted() -> None:
    a = grid_sheet(3)
    shifted = a.positions + [5.0, 0, 0]
    positions = np.concatenate([a.positions, shifted])
    faces = np.concatenate([a.face_indices, a.face_indices + a.vertex_count])
    offsets = np.concatenate([a.face_offsets, a.face_offsets[1:] + a.face_indices.size])
    mesh = Mesh(positions=positions, face_indices=faces, face_offsets=offsets)
    welding, springs = build_springs(mesh)
    assert topology_stats(mesh, welding, springs).pieces == 2


def test_edge_incidence_boundary_and_closed_surfaces() -> None:
    """A grid's boundary is its outline; a tetrahedron is closed; opening a face opens three edges."""
    n, m = 5, 4
    mesh = grid_sheet(n, m)
    edges = boundary_edges(mesh.face_indices, mesh.face_indices[mesh.corner_next], mesh.vertex_count)
    assert edges.shape == (2 * (n - 1) + 2 * (m - 1), 2)
    assert (edges[:, 0] < edges[:, 1]).all()
    tetra = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
    pairs, counts = edge_incidence(tetra.ravel(), tetra[:, [1, 2, 0]].ravel(), 4)
    assert pairs.shape == (6, 2) and (counts == 2).all()
    assert is_closed(tetra) and boundary_edge_count(tetra) == 0
    assert not is_closed(tetra[1:]) and boundary_edge_count(tetra[1:]) == 3
    assert not is_closed(np.zeros((0, 3), dtype=np.int64)) and boundary_edge_count(np.zeros((0, 3))) == 0


def test_straightest_continuations_match_a_plain_search_on_an_irregular_mesh() -> None:
    """Every (v, a, b) triple against a plain Python search of the definition: b is the neighbour of
    v most opposite to a (the last of equally opposite ones in neighbour order), a is b's too, the
    angle a-v-b is at least the straightness threshold, each pair once with a < b; on a jittered
    10 x 10 grid with a few vertices of 5, 6 and 8 neighbours (extra edges across quads)."""
    rng = np.random.default_rng(7)
    sheet = grid_sheet(10)
    positions = sheet.positions + rng.normal(0.0, 0.02, sheet.positions.shape)
    grid = np.arange(100).reshape(10, 10)
    edges = np.concatenate(
        [np.stack([grid[:, :-1].ravel(), grid[:, 1:].ravel()], 1), np.stack([grid[:-1].ravel(), grid[1:].ravel()], 1)]
    )
    extra = np.array([[11, 22], [12, 21], [44, 55], [45, 54], [33, 44], [66, 77], [67, 76]])
    pairs = np.sort(np.concatenate([edges, extra]), axis=1)
    indptr, neighbours = adjacency(pairs, 100)
    centres, firsts, seconds = _straightest_continuations(positions, indptr, neighbours, STRAIGHT_COS)
    got = set(zip(centres.tolist(), firsts.tolist(), seconds.tolist(), strict=True))

    def best(v: int, a: int) -> int:
        choice, choice_cos = -1, STRAIGHT_COS
        for b in neighbours[indptr[v] : indptr[v + 1]].tolist():
            if b == a:
                continue
            u, w = positions[a] - positions[v], positions[b] - positions[v]
            cos = float(np.dot(u, w) / (np.linalg.norm(u) * np.linalg.norm(w)))
            if cos <= choice_cos:
                choice, choice_cos = b, cos
        return choice

    expected = set()
    for v in range(100):
        for a in neighbours[indptr[v] : indptr[v + 1]].tolist():
            b = best(v, a)
            if b >= 0 and best(v, b) == a and a < b:
                expected.add((v, a, b))
    assert got == expected
    assert len(expected) > 80  # most interior vertices continue in two directions
