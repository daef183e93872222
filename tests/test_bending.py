"""Bending springs on any mesh (meshdeform/topology.py, DESIGN.md section 2).

Triangle meshes bend across every interior edge: the springs are checked pair by pair against
trimesh's `face_adjacency_unshared` (an independent implementation of face adjacency) on
generated meshes, the Platonic solids and real scans; quad meshes keep exactly the springs
they had, checked byte for byte against an explicit construction; mixed meshes bend each
region by its own rule. Physics: a triangulated cube and sphere dropped on the ground keep
their shape better with bending on than off, measured after a Procrustes fit (trimesh)
removes the rigid motion.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import trimesh
from factories import KNIT, grid_cloth, grid_sheet, write_grid
from typer.testing import CliRunner

from meshdeform.io import load
from meshdeform.material import KindMaterial
from meshdeform.mesh import Mesh, grid_mesh, polygons_to_csr
from meshdeform.model import SpringModel
from meshdeform.scene.colliders import Collider, Plane
from meshdeform.simulate import Scene, Settings, simulate
from meshdeform.solvers import solver_class
from meshdeform.tearing import Cut, Tearer
from meshdeform.topology import SpringKind, Springs, build_springs
from pipeline.cli import app


def triangle_mesh(vertices: np.ndarray, faces: np.ndarray) -> Mesh:
    """A Mesh of (T, 3) triangles over (V, 3) vertices."""
    faces = np.asarray(faces, dtype=np.int64)
    return Mesh(
        positions=np.asarray(vertices, dtype=np.float64),
        face_indices=faces.ravel(),
        face_offsets=np.arange(0, faces.size + 1, 3, dtype=np.int64),
    )


def from_trimesh(t: trimesh.Trimesh) -> Mesh:
    return triangle_mesh(t.vertices, t.faces)


def kind_pairs(springs: Springs, kind: SpringKind) -> set[tuple[int, int]]:
    return {(int(a), int(b)) for a, b in springs.pairs[springs.kinds == kind]}


def trimesh_bending(vertices: np.ndarray, triangles: np.ndarray) -> set[tuple[int, int]]:
    """The pairs opposite every interior edge by trimesh (`face_adjacency_unshared`), less its edges."""
    t = trimesh.Trimesh(vertices=vertices, faces=triangles, process=False)
    unshared = np.sort(np.asarray(t.face_adjacency_unshared), axis=1)
    edges = {(int(a), int(b)) for a, b in np.sort(np.asarray(t.edges_unique), axis=1)}
    return {(int(a), int(b)) for a, b in unshared if a != b} - edges


def assert_bending_matches_trimesh(mesh: Mesh) -> Springs:
    """The triangle mesh's springs: its edges, no shear, and trimesh's pairs as bending springs."""
    welding, springs = build_springs(mesh)
    vertices = mesh.positions[welding.representative]
    triangles = welding.vertex_map[mesh.face_indices.reshape(-1, 3)]
    reference = trimesh_bending(vertices, triangles)
    t = trimesh.Trimesh(vertices=vertices, faces=triangles, process=False)
    edges = {(int(a), int(b)) for a, b in np.sort(np.asarray(t.edges_unique), axis=1) if a != b}
    assert kind_pairs(springs, SpringKind.STRUCTURAL) == edges
    assert springs.count(SpringKind.SHEAR) == 0
    assert kind_pairs(springs, SpringKind.BENDING) == reference
    return springs


def tetrahedron() -> Mesh:
    return triangle_mesh(
        [[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], [[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]]
    )


def octahedron() -> Mesh:
    vertices = np.concatenate([np.eye(3), -np.eye(3)])  # +x +y +z -x -y -z
    faces = [[0, 1, 2], [1, 3, 2], [3, 4, 2], [4, 0, 2], [1, 0, 5], [3, 1, 5], [4, 3, 5], [0, 4, 5]]
    return triangle_mesh(vertices, faces)


GENERATED = {
    "triangulated grid": lambda: grid_sheet(9, 7, triangles=True, uvs=False),
    "trimesh box": lambda: from_trimesh(trimesh.creation.box()),
    "box subdivided": lambda: from_trimesh(trimesh.creation.box().subdivide()),
    "icosphere(1)": lambda: from_trimesh(trimesh.creation.icosphere(1)),
    "icosphere(3)": lambda: from_trimesh(trimesh.creation.icosphere(3)),
    "uv sphere": lambda: from_trimesh(trimesh.creation.uv_sphere(count=[10, 12])),
    "tetrahedron": tetrahedron,
    "octahedron": octahedron,
    "icosahedron": lambda: from_trimesh(trimesh.creation.icosahedron()),
}


@pytest.mark.parametrize("name", sorted(GENERATED))
def test_triangle_meshes_bend_across_every_interior_edge_as_trimesh_pairs_them(name: str) -> None:
    springs = assert_bending_matches_trimesh(GENERATED[name]())
    assert springs.count(SpringKind.BENDING) > 0 or name == "tetrahedron"


def test_platonic_triangle_solids_bend_by_their_second_neighbours() -> None:
    """Tetrahedron: every vertex pair is an edge, so no bending. Octahedron: the pair across each
    of its 12 edges is one of the 3 diameters. Icosahedron: the pair across each of its 30 edges
    is a pair at two edges' distance, and each of those 30 pairs (12 x 5 / 2) has exactly one
    edge between its two common neighbours, so 30 springs, of length phi times the edge."""
    assert build_springs(tetrahedron())[1].counts() == {"structural": 6, "shear": 0, "bending": 0}
    octa = octahedron()
    _, springs = build_springs(octa)
    assert springs.counts() == {"structural": 12, "shear": 0, "bending": 3}
    bend = springs.pairs[springs.kinds == SpringKind.BENDING]
    np.testing.assert_allclose(np.linalg.norm(octa.positions[bend[:, 0]] - octa.positions[bend[:, 1]], axis=1), 2.0)
    ico = from_trimesh(trimesh.creation.icosahedron())
    _, springs = build_springs(ico)
    assert springs.counts() == {"structural": 30, "shear": 0, "bending": 30}
    p = ico.positions
    length = np.linalg.norm(p[springs.pairs[:, 1]] - p[springs.pairs[:, 0]], axis=1)
    edge = length[springs.kinds == SpringKind.STRUCTURAL]
    np.testing.assert_allclose(edge, edge[0])
    np.testing.assert_allclose(length[springs.kinds == SpringKind.BENDING], edge[0] * (1 + 5**0.5) / 2)
    # each vertex ends 5 bending springs: its second ring
    ends = springs.pairs[springs.kinds == SpringKind.BENDING].ravel()
    assert (np.bincount(ends, minlength=12) == 5).all()


#: the triangle-only files of the shared real meshes (scans and exports: irregular, some not welded)
REAL_TRIANGLE_MESHES = ("bunny.ply", "reference.ply", "sphere840.ply", "teapot.obj", "tube.obj")


@pytest.mark.parametrize("name", REAL_TRIANGLE_MESHES)
def test_real_triangle_meshes_bend_as_trimesh_pairs_them(shared_meshes: Path, name: str) -> None:
    mesh = load(shared_meshes / "real" / name)
    assert (mesh.face_sizes == 3).all()
    springs = assert_bending_matches_trimesh(mesh)
    assert springs.count(SpringKind.BENDING) > 0.8 * springs.count(SpringKind.STRUCTURAL)


def test_platonic_shelf_bends_its_triangle_solids_and_braces_its_polygon_ones(shared_meshes: Path) -> None:
    """The five solids in one file (a real mixed mesh): the cube's 6 quads give 12 shear diagonals,
    the dodecahedron's 12 pentagons 60, and neither gets a straight bending line (corner angles of
    90 and 108 degrees); the triangle solids give 0 + 3 + 30 bending springs."""
    mesh = load(shared_meshes / "real" / "platonic_shelf.ply")
    _, springs = build_springs(mesh)
    assert springs.counts() == {"structural": 6 + 12 + 12 + 30 + 30, "shear": 12 + 60, "bending": 0 + 3 + 30}


def reference_grid_springs(nx: int, ny: int) -> tuple[np.ndarray, np.ndarray]:
    """The springs of grid_mesh(nx, ny) as the quad rules define them, built pair by pair:
    structural edges, then both diagonals of each quad (shear), then skip-one pairs along rows
    and columns (bending), each kind sorted by (lo, hi); pairs (S, 2) int32, kinds (S,) int8."""

    def v(i: int, j: int) -> int:
        return j * nx + i

    structural, shear, bending = set(), set(), set()
    for j in range(ny):
        for i in range(nx):
            if i + 1 < nx:
                structural.add((v(i, j), v(i + 1, j)))
            if j + 1 < ny:
                structural.add((v(i, j), v(i, j + 1)))
            if i + 1 < nx and j + 1 < ny:
                shear |= {(v(i, j), v(i + 1, j + 1)), (v(i + 1, j), v(i, j + 1))}
            if i + 2 < nx:
                bending.add((v(i, j), v(i + 2, j)))
            if j + 2 < ny:
                bending.add((v(i, j), v(i, j + 2)))
    groups = [sorted(tuple(sorted(p)) for p in kind) for kind in (structural, shear, bending)]
    pairs = np.array([p for group in groups for p in group], dtype=np.int32).reshape(-1, 2)
    kinds = np.repeat(np.arange(3, dtype=np.int8), [len(g) for g in groups])
    return pairs, kinds


def assert_same_bytes(springs: Springs, pairs: np.ndarray, kinds: np.ndarray) -> None:
    assert springs.pairs.dtype == pairs.dtype and springs.kinds.dtype == kinds.dtype
    assert springs.pairs.shape == pairs.shape
    assert springs.pairs.tobytes() == pairs.tobytes() and springs.kinds.tobytes() == kinds.tobytes()


@pytest.mark.parametrize(("nx", "ny"), [(2, 2), (3, 5), (8, 6), (17, 11)])
def test_quad_grids_keep_exactly_their_springs(nx: int, ny: int) -> None:
    _, springs = build_springs(grid_mesh(nx, ny))
    assert_same_bytes(springs, *reference_grid_springs(nx, ny))


def test_quad_cube_keeps_exactly_its_springs() -> None:
    """Corners of the unit cube: its 12 edges are the pairs at distance 1 (structural), its 12
    face diagonals those at sqrt(2) (shear); right angles everywhere, so no bending."""
    corners = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], dtype=float)
    quads = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]]
    flat, offsets = polygons_to_csr(quads)
    _, springs = build_springs(Mesh(positions=corners, face_indices=flat, face_offsets=offsets))
    i, j = np.triu_indices(8, 1)
    distance = np.linalg.norm(corners[i] - corners[j], axis=1)
    edges = np.stack([i, j], axis=1)[np.isclose(distance, 1.0)]
    diagonals = np.stack([i, j], axis=1)[np.isclose(distance, 2**0.5)]
    pairs = np.concatenate([edges, diagonals]).astype(np.int32)  # triu_indices: already (lo, hi) sorted
    kinds = np.repeat(np.array([0, 1], dtype=np.int8), [12, 12])
    assert_same_bytes(springs, pairs, kinds)


def half_triangulated_grid(nx: int, ny: int, k: int) -> Mesh:
    """grid_mesh(nx, ny) at unit spacing whose quads in columns i >= k are split into two triangles."""
    grid = grid_mesh(nx, ny, size=(nx - 1.0, ny - 1.0))
    quads = grid.face_indices.reshape(-1, 4)
    column = np.arange(quads.shape[0]) % (nx - 1)
    split = quads[column >= k]
    polygons = [*quads[column < k].tolist(), *split[:, [0, 1, 2]].tolist(), *split[:, [0, 2, 3]].tolist()]
    flat, offsets = polygons_to_csr(polygons)
    return Mesh(positions=grid.positions, face_indices=flat, face_offsets=offsets)


def test_mixed_mesh_bends_each_region_by_its_own_rule() -> None:
    """Quads in columns 0..k-1, triangles beyond. The quad region (a (k+1) x ny vertex grid) keeps
    its diagonals and its straight skip-one lines, those on column k included (its edges are quad
    edges); the triangle region (an (nx-k) x ny triangulated grid) bends across its own interior
    edges only: not across column k, where each edge lies on a quad and a triangle."""
    nx, ny, k = 9, 6, 4
    _, springs = build_springs(half_triangulated_grid(nx, ny, k))
    qx, tx = k + 1, nx - k
    quad_lines = ny * (qx - 2) + qx * (ny - 2)
    tri_edges = ny * (tx - 1) + tx * (ny - 1) + (tx - 1) * (ny - 1)
    tri_boundary = 2 * (tx - 1) + 2 * (ny - 1)
    assert springs.counts() == {
        "structural": nx * (ny - 1) + ny * (nx - 1) + (tx - 1) * (ny - 1),
        "shear": 2 * k * (ny - 1),
        "bending": quad_lines + tri_edges - tri_boundary,
    }
    bend = springs.pairs[springs.kinds == SpringKind.BENDING]
    x = np.tile(np.arange(nx), ny)
    y = np.repeat(np.arange(ny), nx)
    dx, dy = np.abs(x[bend[:, 1]] - x[bend[:, 0]]), np.abs(y[bend[:, 1]] - y[bend[:, 0]])
    in_quads = (x[bend] <= k).all(axis=1)
    # straight lines: two steps along a row or a column, all in the quad region
    straight = ((dx == 2) & (dy == 0)) | ((dx == 0) & (dy == 2))
    assert (straight == in_quads).all() and int(straight.sum()) == quad_lines
    # across triangle edges: all in the triangle region, none reaching back to column k - 1
    assert (x[bend[~in_quads]] >= k).all()


def test_inspect_counts_bending_springs_of_a_triangle_mesh(tmp_path: Path) -> None:
    n, m = 7, 5
    path = write_grid(tmp_path / "tri.obj", n, m, triangles=True)
    result = CliRunner().invoke(app, ["inspect", str(path), "--json"])
    assert result.exit_code == 0, result.output
    edges = n * (m - 1) + m * (n - 1) + (n - 1) * (m - 1)
    boundary = 2 * (n - 1) + 2 * (m - 1)
    assert json.loads(result.stdout)["springs"] == {"structural": edges, "shear": 0, "bending": edges - boundary}
    text = CliRunner().invoke(app, ["inspect", str(path)]).stdout
    assert f"structural {edges}, shear 0, bending {edges - boundary}" in text


def test_a_cut_triangle_sheet_keeps_bending_only_across_edges_it_still_shares() -> None:
    """After a cut the torn model's bending springs are again exactly trimesh's pairs across the
    torn triangles' interior edges: those across the opened edges are gone, the others stay."""
    mesh, model, _ = grid_cloth(12, pins=("top",), triangles=True, uvs=False)
    tearer = Tearer(mesh, model, None, [Cut.plane(0.1, point=[0, 0.45, 0], normal=[0, 1, 0])])
    options = solver_class("xpbd").options_class(tethers=None)
    settings = Settings(solver="xpbd", frames=8, options=options)
    frames = list(simulate(model, Scene(gravity=(0, -9.81, 0), tearing=tearer), settings))
    torn = frames[-1].model
    assert frames[-1].pieces == 2 and torn.vertex_count > model.vertex_count
    bending = {(int(a), int(b)) for a, b in np.sort(torn.springs[torn.kinds == SpringKind.BENDING], axis=1)}
    assert bending == trimesh_bending(torn.rest_positions, torn.triangles)
    assert len(bending) < model.spring_counts()["bending"]


# Physics: a closed triangle mesh dropped on the ground under gravity, default solver and material.

#: metres the lowest vertex starts above the ground; frames at 24 fps (2 s: it lands and settles).
#: High enough that the impact crumples a shell without bending springs: from 0.3 m the icosphere
#: (a convex triangulated shell, rigid without them) lands whole either way since implicit sinks
#: its contacts instead of letting go of them (docs/performance.md)
DROP_HEIGHT, DROP_FRAMES = 0.6, 48
GROUND_THICKNESS = 0.01


def shape_error(rest: np.ndarray, positions: np.ndarray) -> float:
    """RMS distance (m) between rest and current positions once the best rigid motion is removed."""
    _, fitted, _ = trimesh.registration.procrustes(rest, positions, reflection=False, scale=False)
    return float(np.sqrt(np.mean(np.sum((fitted - positions) ** 2, axis=1))))


def dropped_shape_error(mesh: Mesh, bending: bool) -> tuple[float, float]:
    """Shape error (m) of the last frame and the lowest final height (m) of `mesh` dropped on a plane."""
    lifted = mesh.positions.copy()
    lifted[:, 1] += DROP_HEIGHT - lifted[:, 1].min()
    mesh = mesh.with_positions(lifted)
    # a knit shell (1000 N/m, bending 0.05): soft enough in its plane that its flat vertices give
    # way without bending springs; the woven default (10 000 N/m) sags 2.1 mm without them, 2.0 with
    material = KNIT if bending else replace(KNIT, bending=KindMaterial(stiffness=0.05, enabled=False))
    model = SpringModel.from_mesh(mesh, material)
    assert (model.spring_counts()["bending"] > 0) == bending
    ground = Collider(Plane((0.0, 0.0, 0.0), (0.0, 1.0, 0.0)), friction=0.5, thickness=GROUND_THICKNESS)
    scene = Scene(gravity=(0.0, -9.81, 0.0), constraints=[ground])
    *_, last = simulate(model, scene, Settings(frames=DROP_FRAMES))
    return shape_error(model.rest_positions, last.welded_positions), float(last.welded_positions[:, 1].min())


DROPPED = {
    "triangulated cube": lambda: from_trimesh(trimesh.creation.box(extents=(0.5, 0.5, 0.5)).subdivide()),
    "icosphere": lambda: from_trimesh(trimesh.creation.icosphere(2, radius=0.25)),
}


@pytest.mark.parametrize("name", sorted(DROPPED))
def test_a_dropped_triangle_mesh_keeps_its_shape_better_with_bending(name: str) -> None:
    mesh = DROPPED[name]()
    with_bending, low_on = dropped_shape_error(mesh, bending=True)
    without, low_off = dropped_shape_error(mesh, bending=False)
    # both landed: resting on the ground, kept the collider's thickness above it
    for low in (low_on, low_off):
        assert GROUND_THICKNESS * 0.5 < low < GROUND_THICKNESS * 2
    assert without > 2e-3  # without bending the shell sags visibly (millimetres on a 0.5 m body)
    assert with_bending < 0.5 * without
