"""The self-intersection oracle (tests/intersections.py) on cases whose answers are known by
construction: crossing, separated, touching, coplanar and neighbouring triangles, flat and folded
grids, and a blade through a strip whose count is known exactly."""

from __future__ import annotations

import numpy as np
import pytest
from factories import grid_sheet
from intersections import intersecting_pair_array, intersecting_pairs

UNIT = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # in z = 0


def two(first: np.ndarray, second: np.ndarray) -> int:
    """The count for two triangles with six distinct vertices."""
    return intersecting_pairs(np.concatenate([first, second]), np.array([[0, 1, 2], [3, 4, 5]]))


def grid(n: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """A flat n x n grid over 1 m in the XZ plane, its quads split in two: vertices, triangles."""
    mesh = grid_sheet(n, plane="xz", triangles=True)
    return mesh.positions.copy(), mesh.face_indices.reshape(-1, 3)


def test_two_crossing_triangles_are_one_pair() -> None:
    piercing = np.array([[0.2, 0.2, -1.0], [0.3, 0.2, 1.0], [5.0, 5.0, 0.5]])
    assert two(UNIT, piercing) == 1
    assert intersecting_pair_array(np.concatenate([UNIT, piercing]), np.array([[0, 1, 2], [3, 4, 5]])).tolist() == [
        [0, 1]
    ]


def test_separated_triangles_are_none() -> None:
    assert two(UNIT, UNIT + [0.0, 0.0, 0.01]) == 0  # parallel, 1 cm apart
    # an edge passing 1 mm beyond the hypotenuse (x + y = 1), through the plane
    outside = np.array([[0.5005, 0.5005, -1.0], [0.5005, 0.5005, 1.0], [3.0, 3.0, 0.0]])
    assert two(UNIT, outside) == 0
    assert two(UNIT, outside - [0.001, 0.001, 0.0]) == 1  # the same edge 0.4 mm inside


def test_touching_counts_and_lifting_by_a_micrometre_does_not() -> None:
    corner_on_face = np.array([[0.25, 0.25, 0.0], [0.3, 0.3, 1.0], [0.2, 0.4, 1.0]])
    assert two(UNIT, corner_on_face) == 1
    assert two(UNIT, corner_on_face + [0.0, 0.0, 1e-6]) == 0


def test_triangles_sharing_a_vertex_are_excluded_even_when_crossing() -> None:
    # the second triangle's edge pierces the first at (0.3, 0.3, 0); its first corner is the first's corner 0
    piercer = np.array([[0.0, 0.0, 0.0], [0.3, 0.3, -1.0], [0.3, 0.3, 1.0]])
    shared = np.concatenate([UNIT, piercer[1:]])
    assert intersecting_pairs(shared, np.array([[0, 1, 2], [0, 3, 4]])) == 0
    # the same geometry with the corner duplicated instead of shared is a crossing
    assert two(UNIT, piercer) == 1


def test_coplanar_triangles() -> None:
    assert two(UNIT, UNIT + [0.3, 0.3, 0.0]) == 1  # overlapping in one plane: two layers pressed together
    assert two(UNIT, 0.2 * UNIT + [0.1, 0.1, 0.0]) == 1  # one inside the other, no edges crossing
    assert two(UNIT, UNIT + [1.2, 0.0, 0.0]) == 0  # side by side, 0.2 m apart
    assert two(UNIT, -UNIT + [1.001, 1.001, 0.0]) == 0  # facing across a 1.4 mm gap along the hypotenuse
    assert two(UNIT, -UNIT + [0.999, 0.999, 0.0]) == 1  # the same two overlapping by 1.4 mm


def test_a_flat_grid_has_none() -> None:
    vertices, triangles = grid()
    assert len(triangles) == 3042
    assert intersecting_pairs(vertices, triangles) == 0
    assert intersecting_pairs(vertices, triangles, prefilter=False) == 0


def fold(vertices: np.ndarray, lift: float, tilt: float) -> np.ndarray:
    """The grid's half x > 0.5 turned back over the other half (x -> 1 - x), its height rising from
    `lift` at the fold to `lift + tilt / 2` at the far edge."""
    out = vertices.copy()
    right = vertices[:, 0] > 0.5
    out[right, 0] = 1.0 - vertices[right, 0]
    out[right, 1] = lift + (vertices[right, 0] - 0.5) * tilt
    return out


def test_a_grid_folded_through_itself_intersects() -> None:
    vertices, triangles = grid()
    # the folded half starts 10 cm below the other and ends 10 cm above it: it passes through along x = 0.25
    through = fold(vertices, -0.1, 0.4)
    count = intersecting_pairs(through, triangles)
    assert count > 0
    assert intersecting_pairs(through, triangles, prefilter=False) == count
    # every pair has one triangle on each side of the fold
    pairs = intersecting_pair_array(through, triangles)
    side = (vertices[triangles, 0].mean(axis=1) > 0.5)[pairs]
    assert (side[:, 0] != side[:, 1]).all()
    # the same fold 1 cm above the other half throughout: no crossing
    assert intersecting_pairs(fold(vertices, 0.01, 0.02), triangles) == 0


def test_a_grid_folded_flat_onto_itself_intersects() -> None:
    """Two layers in one plane (a cloth collapsed on the ground with nothing between its layers)."""
    vertices, triangles = grid(12)
    assert intersecting_pairs(fold(vertices, 0.0, 0.0), triangles) > 0
    assert intersecting_pairs(fold(vertices, 0.005, 0.0), triangles) == 0  # 5 mm apart


@pytest.mark.parametrize("nx", [2, 7, 16])
def test_a_blade_through_a_strip_cuts_every_triangle_once(nx: int) -> None:
    """A strip of nx - 1 quads along x (z from 0 to 0.1), cut along z = 0.037 by one big vertical
    triangle: the cut runs through the interior of both triangles of every quad, so 2 (nx - 1) pairs."""
    strip = grid_sheet(nx, 2, size=(1.0, 0.1), plane="xz", triangles=True)
    blade = np.array([[-1.0, -1.0, 0.037], [3.0, -1.0, 0.037], [0.5, 2.0, 0.037]])
    vertices = np.concatenate([strip.positions, blade])
    triangles = np.concatenate([strip.face_indices.reshape(-1, 3), np.array([[0, 1, 2]]) + len(strip.positions)])
    pairs = intersecting_pair_array(vertices, triangles)
    assert len(pairs) == 2 * (nx - 1)
    assert (pairs[:, 1] == len(triangles) - 1).all()


def test_the_prefilter_only_drops_what_ipctk_rejects() -> None:
    """A crumpled grid (random offsets of a few cells) has many crossings of every kind; the vectorised
    filter must give exactly the pairs that sending every candidate to ipctk gives."""
    vertices, triangles = grid(20)
    crumpled = vertices + np.random.default_rng(7).normal(scale=0.04, size=vertices.shape)
    filtered = intersecting_pair_array(crumpled, triangles)
    assert len(filtered) > 100
    np.testing.assert_array_equal(filtered, intersecting_pair_array(crumpled, triangles, prefilter=False))


def test_the_count_does_not_depend_on_the_numbering() -> None:
    vertices, triangles = grid(20)
    crumpled = vertices + np.random.default_rng(3).normal(scale=0.03, size=vertices.shape)
    rng = np.random.default_rng(5)
    vertex_order = rng.permutation(len(vertices))
    new_index = np.empty_like(vertex_order)
    new_index[vertex_order] = np.arange(len(vertices))
    face_order = rng.permutation(len(triangles))
    renumbered = new_index[triangles[face_order]][:, [1, 2, 0]]  # corners rotated too
    expected = intersecting_pairs(crumpled, triangles)
    assert expected > 0
    assert intersecting_pairs(crumpled[vertex_order], renumbered) == expected


def test_a_40_by_40_grid_folded_through_itself_is_checked_per_frame() -> None:
    """The size of the benchmarks' sheets, checked frame by frame (no timing: the work is vectorised
    up to ipctk's own calls on the few candidates the filter keeps)."""
    vertices, triangles = grid(40)
    counts = [intersecting_pairs(fold(vertices, lift, 0.4), triangles) for lift in (-0.5, -0.1, 0.05)]
    assert counts[0] == 0 and counts[1] > 0 and counts[2] == 0


def test_bad_input_is_refused() -> None:
    with pytest.raises(ValueError):
        intersecting_pairs(np.zeros((3, 2)), np.array([[0, 1, 2]]))
    with pytest.raises(ValueError):
        intersecting_pairs(UNIT, np.array([[0, 1, 3]]))
