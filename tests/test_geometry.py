"""Polygon normals and areas (Newell), vertex normals, normals in the mesh's own layout, cleanup."""

from __future__ import annotations

import numpy as np
import pytest
from factories import grid_sheet
from shared_meshes import MESHES, needs_meshes

from meshdeform.geometry import (
    clean_polygons,
    corner_normals,
    polygon_area_vectors,
    polygon_areas,
    polygon_normals,
    vertex_normals,
)
from meshdeform.mesh import Mesh, polygons_to_csr


def _mesh(positions, polygons, **kwargs) -> Mesh:
    flat, offsets = polygons_to_csr(polygons)
    return Mesh(positions=np.asarray(positions, dtype=np.float64), face_indices=flat, face_offsets=offsets, **kwargs)


def _rotation(seed: int = 0) -> np.ndarray:
    q, r = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] *= -1
    return q


# an L-shaped concave hexagon of area 3 in the xy plane, counter-clockwise
L_SHAPE = [[0, 0, 0], [2, 0, 0], [2, 1, 0], [1, 1, 0], [1, 2, 0], [0, 2, 0]]

# a unit cube, faces wound outwards, one authored normal per face (flat shading)
CUBE_V = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]]
CUBE_F = [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]]
CUBE_N = [[0, 0, -1], [0, 0, 1], [0, -1, 0], [1, 0, 0], [0, 1, 0], [-1, 0, 0]]


def _flat_cube() -> Mesh:
    return _mesh(CUBE_V, CUBE_F, normals=np.array(CUBE_N, dtype=np.float64),
                 face_normal_indices=np.repeat(np.arange(6), 4))  # fmt: skip


def test_newell_normals_and_areas_of_concave_and_convex_polygons() -> None:
    tri = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
    positions = np.array(L_SHAPE + tri, dtype=np.float64)
    mesh = _mesh(positions, [[0, 1, 2, 3, 4, 5], [6, 7, 8], [6, 8, 7]])
    assert np.allclose(polygon_normals(mesh), [[0, 0, 1], [0, 0, 1], [0, 0, -1]])
    assert np.allclose(polygon_areas(mesh), [3.0, 0.5, 0.5])
    # the same from plain arrays, and after a rigid motion far from the origin
    rot = _rotation(1)
    moved = positions @ rot.T + 1e6
    arrays = (mesh.face_indices, mesh.face_offsets)
    assert np.allclose(polygon_areas(arrays, moved), [3.0, 0.5, 0.5], atol=1e-6)
    assert np.allclose(polygon_normals(arrays, moved), np.array([[0, 0, 1], [0, 0, 1], [0, 0, -1]]) @ rot.T)


def test_concave_first_corner_does_not_flip_the_normal() -> None:
    # start the L at its reflex corner (3): a fan from there would produce a wrong-side triangle
    order = [3, 4, 5, 0, 1, 2]
    mesh = _mesh(L_SHAPE, [order])
    assert np.allclose(polygon_normals(mesh), [[0, 0, 1]])
    assert np.isclose(polygon_areas(mesh)[0], 3.0)


@needs_meshes
def test_concave_obj_caps() -> None:
    from meshdeform.io import load

    mesh = load(MESHES / "real" / "concave.obj")
    normals = polygon_normals(mesh)
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0)
    # the recomputed normals match the authored ones (flat shaded: one vn per face)
    per_face_authored = mesh.normals[mesh.face_normal_indices[mesh.face_offsets[:-1]]]
    assert np.allclose(normals, per_face_authored, atol=1e-4)  # the file has 4 decimals


def test_degenerate_polygon_has_zero_normal() -> None:
    mesh = _mesh([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]])
    assert np.array_equal(polygon_normals(mesh), [[0, 0, 0]])
    assert polygon_areas(mesh)[0] == 0


def test_vertex_normals_are_area_weighted() -> None:
    # vertex 0 is shared by a big triangle in the xy plane and a small one in the xz plane
    positions = [[0, 0, 0], [4, 0, 0], [0, 4, 0], [-1, 0, 0], [0, 0, -1]]
    mesh = _mesh(positions, [[0, 1, 2], [0, 3, 4]])
    n = vertex_normals(mesh)
    big, small = polygon_area_vectors(mesh)
    expected = (big + small) / np.linalg.norm(big + small)
    assert np.allclose(n[0], expected)
    assert n[0][2] > 0.9  # tilted toward the big triangle
    assert np.allclose(n[1], [0, 0, 1]) and np.allclose(n[3], small / np.linalg.norm(small))


def test_vertex_normal_counts_a_polygon_once_even_if_it_repeats_the_vertex() -> None:
    # a "pinched" polygon visits vertex 0 twice; a normal triangle shares vertex 0 too
    positions = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [-1, 0, 0], [-1, -1, 0], [0, 0, 1], [0, 1, 1]]
    mesh = _mesh(positions, [[0, 1, 2, 0, 3, 4], [0, 5, 6]])
    n = vertex_normals(mesh)
    area = polygon_area_vectors(mesh)
    expected = area.sum(axis=0) / np.linalg.norm(area.sum(axis=0))
    assert np.allclose(n[0], expected)


def test_flat_grid_corner_normals_are_z() -> None:
    grid = grid_sheet(6, 5)  # xy plane, counter-clockwise: +z
    n = corner_normals(grid)
    assert n.shape == (30, 3)
    assert np.allclose(n, [0, 0, 1])
    flipped = Mesh(positions=grid.positions, face_indices=grid.face_indices[::-1].copy(),
                   face_offsets=grid.face_offsets)  # fmt: skip
    assert np.allclose(corner_normals(flipped), [0, 0, -1])


def test_authored_side_is_kept_when_winding_disagrees() -> None:
    grid = grid_sheet(4)
    down = np.tile([0.0, 0.0, -1.0], (16, 1))  # authored normals point against the winding
    mesh = Mesh(positions=grid.positions, face_indices=grid.face_indices, face_offsets=grid.face_offsets,
                normals=down, face_normal_indices=grid.face_indices.copy())  # fmt: skip
    assert np.allclose(corner_normals(mesh), [0, 0, -1])
    rot = _rotation(2)
    assert np.allclose(corner_normals(mesh, grid.positions @ rot.T), np.array([0, 0, -1]) @ rot.T)


def test_flat_cube_keeps_six_hard_normals_under_rotation() -> None:
    mesh = _flat_cube()
    assert np.allclose(corner_normals(mesh), CUBE_N)
    for seed in range(3):
        rot = _rotation(seed)
        moved = (mesh.positions - 0.5) @ rot.T + [3.0, -2.0, 7.0]
        n = corner_normals(mesh, moved)
        assert n.shape == (6, 3)
        assert np.allclose(n, np.array(CUBE_N, dtype=np.float64) @ rot.T, atol=1e-12)
        assert len(np.unique(np.round(n, 9), axis=0)) == 6
        assert np.allclose(np.abs(n @ n.T) + np.eye(6), np.eye(6) + np.abs(n @ n.T).round())  # axis set


def test_smooth_normals_stay_smooth_and_hard_edges_stay_hard() -> None:
    # a cube where the top face shares one smooth normal per vertex with nothing else,
    # and the four sides share one normal each per side: mix of layouts in one mesh
    normals = np.array(CUBE_N + [[0, 0, 1]] * 4, dtype=np.float64)
    fni = np.concatenate([np.repeat(np.arange(6), 4)])
    fni[4:8] = [6, 7, 8, 9]  # the top face: a normal per corner
    mesh = _mesh(CUBE_V, CUBE_F, normals=normals, face_normal_indices=fni)
    bent = mesh.positions.copy()
    bent[6, 2] += 0.5  # lift one top corner: the top quad is no longer planar
    n = corner_normals(mesh, bent)
    # every top corner sees the same (top) polygon only, so they are equal: smooth within the face
    assert np.allclose(n[6:10], n[6])
    assert not np.allclose(n[6], [0, 0, 1])
    # the bottom normal is untouched by the lift
    assert np.allclose(n[0], [0, 0, -1])


def test_unreferenced_normal_keeps_its_input_direction() -> None:
    mesh = _mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]],
                 normals=np.array([[0, 0, 1.0], [0, 2.0, 0]]), face_normal_indices=np.array([0, 0, 0]))  # fmt: skip
    n = corner_normals(mesh, mesh.positions @ _rotation(4).T)
    assert np.allclose(n[1], [0, 1, 0])
    assert np.isclose(np.linalg.norm(n[0]), 1.0)


def test_without_normals_corner_normals_are_vertex_normals() -> None:
    mesh = _mesh(CUBE_V, CUBE_F)
    n = corner_normals(mesh)
    assert n.shape == (8, 3)
    assert np.allclose(n, vertex_normals(mesh))
    centred = mesh.positions - 0.5
    assert np.allclose(n, centred / np.linalg.norm(centred, axis=1, keepdims=True))


@needs_meshes
@pytest.mark.parametrize("name", ["quadknot.obj", "suzanne.obj", "tube.obj"])
def test_recomputed_normals_agree_with_authored_smooth_normals(name: str) -> None:
    from meshdeform.io import load

    mesh = load(MESHES / "real" / name)
    n = corner_normals(mesh)
    authored = mesh.normals / np.linalg.norm(mesh.normals, axis=1, keepdims=True)
    agreement = np.einsum("ij,ij->i", n, authored)
    assert np.median(agreement) > 0.98
    assert np.mean(agreement > 0.8) > 0.9  # authoring tools weight by angle, we by area


def test_clean_polygons() -> None:
    polys = [[2, 2, 2], [2, 8, 2], [2, 6, 8, 8, 2], [1, 2, 1, 2], [0, 1, 2, 3], [4, 5], [0, 1, 2, 0, 3, 4, 1]]
    flat, offsets = polygons_to_csr(polys)
    result = clean_polygons(flat, offsets)
    assert result.face_keep.tolist() == [False, False, True, False, True, False, True]
    assert result.too_small.tolist() == [False, False, False, False, False, True, False]
    assert result.degenerate.tolist() == [True, True, False, True, False, False, False]
    assert result.repaired.tolist() == [False, False, True, False, False, False, False]
    kept = flat[result.corner_keep]
    assert kept.tolist() == [2, 6, 8, 0, 1, 2, 3, 0, 1, 2, 0, 3, 4, 1]


def test_clean_polygons_degenerate_big_polygon() -> None:
    flat, offsets = polygons_to_csr([[1, 2, 1, 2, 1, 2], [1, 2, 3, 1, 2, 3]])
    result = clean_polygons(flat, offsets)
    assert result.face_keep.tolist() == [False, True]


def test_orientation_is_judged_at_rest_even_through_with_positions_copies() -> None:
    grid = grid_sheet(4)
    down = np.tile([0.0, 0.0, -1.0], (16, 1))
    mesh = Mesh(positions=grid.positions, face_indices=grid.face_indices, face_offsets=grid.face_offsets,
                normals=down, face_normal_indices=grid.face_indices.copy())  # fmt: skip
    assert np.allclose(corner_normals(mesh), [0, 0, -1])
    upside_down = grid.positions * np.array([1.0, -1.0, -1.0])  # turned 180 degrees about x
    # a per-frame copy shares the arrays, so the authored side decided at rest still applies
    assert np.allclose(corner_normals(mesh.with_positions(upside_down)), [0, 0, 1])
    assert np.allclose(corner_normals(mesh, upside_down), [0, 0, 1])
    assert np.allclose(vertex_normals(mesh.with_positions(upside_down)), [0, 0, -1])
