"""Selections: every kind, relative coordinates, combinations and the errors they give."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from factories import grid_sheet

from meshdeform.errors import SelectionError
from meshdeform.selection import (
    AllOf,
    AnyOf,
    Attribute,
    BoundsFrame,
    Box,
    Group,
    HalfSpace,
    Indices,
    Not,
    Sphere,
    resolve,
)


@pytest.fixture
def grid():
    """11 x 6 vertices over 2 x 1 m in the XY plane: vertex (i, j) at (0.2 i, 0.2 j, 0)."""
    mesh = grid_sheet(11, 6, size=(2.0, 1.0))
    faces_left = np.flatnonzero(np.arange(mesh.face_count) % 10 < 2)  # first two columns of quads
    weight = mesh.positions[:, 1].copy()  # 0 at the bottom, 1 at the top
    color = np.stack([mesh.positions[:, 0] / 2.0, 1.0 - mesh.positions[:, 0] / 2.0, np.zeros(66)], axis=1)
    return replace(mesh, groups={"left": faces_left}, vertex_properties={"weight": weight, "color": color})


def ij(mesh, mask):
    idx = np.flatnonzero(mask)
    return set(zip((idx % 11).tolist(), (idx // 11).tolist(), strict=True))


def test_indices_select_exactly_those_and_reject_out_of_range(grid) -> None:
    assert np.flatnonzero(resolve(Indices((0, 5, 65)), grid)).tolist() == [0, 5, 65]
    with pytest.raises(SelectionError, match="out of range"):
        resolve(Indices((66,), path="pins[0].select.indices"), grid)


def test_box_absolute_and_relative_agree_on_boundaries(grid) -> None:
    absolute = resolve(Box((0, 0.8, -1), (2, 1, 1)), grid)
    relative = resolve(Box((0, 0.8, 0), (1, 1, 1), relative=True), grid)
    assert ij(grid, absolute) == {(i, j) for i in range(11) for j in (4, 5)}
    np.testing.assert_array_equal(absolute, relative)


def test_relative_selection_serves_meshes_of_any_size(grid) -> None:
    big = grid.with_positions(grid.positions * 37.0 + [5.0, -3.0, 2.0])
    box = Box((0.0, 0.9, 0.0), (0.25, 1.0, 1.0), relative=True)
    np.testing.assert_array_equal(resolve(box, grid), resolve(box, big))


def test_sphere_relative_radius_is_a_fraction_of_the_largest_extent(grid) -> None:
    # centre (0.5, 0.5) of the box -> (1, 0.5, 0); radius 0.12 of the 2 m width = 0.24 m
    mask = resolve(Sphere((0.5, 0.5, 0.0), 0.12, relative=True), grid)
    assert ij(grid, mask) == {(i, j) for i in (4, 5, 6) for j in (2, 3)}
    smaller = resolve(Sphere((1.0, 0.5, 0.0), 0.15), grid)
    assert ij(grid, smaller) == {(5, 2), (5, 3)}


def test_half_space_selects_the_side_the_normal_points_to(grid) -> None:
    mask = resolve(HalfSpace((1.0, 0.0, 0.0), (1.0, 0.0, 0.0)), grid)
    assert ij(grid, mask) == {(i, j) for i in range(5, 11) for j in range(6)}


def test_group_selects_the_vertices_of_its_faces_and_names_the_known_ones(grid) -> None:
    assert ij(grid, resolve(Group(("left",)), grid)) == {(i, j) for i in range(3) for j in range(6)}
    with pytest.raises(SelectionError, match=r"no group 'right' \(groups: left\)"):
        resolve(Group(("right",), path="x"), grid)


def test_attribute_threshold_range_and_channel(grid) -> None:
    assert ij(grid, resolve(Attribute("weight", min=0.75), grid)) == {(i, 4) for i in range(11)} | {
        (i, 5) for i in range(11)
    }
    band = resolve(Attribute("weight", min=0.3, max=0.5), grid)
    assert ij(grid, band) == {(i, 2) for i in range(11)}
    red = resolve(Attribute("color", channel=0, min=0.95), grid)
    assert ij(grid, red) == {(10, j) for j in range(6)}
    with pytest.raises(SelectionError, match="choose one with `channel`"):
        resolve(Attribute("color", min=0.5), grid)
    with pytest.raises(SelectionError, match="no vertex property 'pin'"):
        resolve(Attribute("pin"), grid)


def test_any_all_not_combine_masks(grid) -> None:
    left = Box((0, 0, -1), (0.2, 1, 1))
    top = Box((0, 1, -1), (2, 1, 1))
    union = resolve(AnyOf((left, top)), grid)
    both = resolve(AllOf((left, top)), grid)
    minus = resolve(AllOf((top, Not(left))), grid)
    assert union.sum() == 12 + 11 - 2
    assert ij(grid, both) == {(0, 5), (1, 5)}
    assert ij(grid, minus) == {(i, 5) for i in range(2, 11)}


def test_empty_selection_is_an_error_naming_its_path(grid) -> None:
    with pytest.raises(SelectionError, match=r"^pins\[2\]\.select: selects no vertex"):
        resolve(Box((5, 5, 5), (6, 6, 6)), grid, "pins[2].select")


def test_flat_axes_use_the_largest_extent() -> None:
    frame = BoundsFrame.from_positions(np.array([[0.0, 1.0, 0.0], [2.0, 1.0, 4.0]]))
    np.testing.assert_allclose(frame.scale, [2.0, 4.0, 4.0])
    np.testing.assert_allclose(frame.to_world([0.5, -0.25, 0.5]), [1.0, 0.0, 2.0])
    assert frame.length(0.5) == 2.0


def test_selection_of_a_large_mesh_is_vectorised() -> None:
    import time

    mesh = grid_sheet(400)
    start = time.perf_counter()
    mask = resolve(AllOf((Sphere((0.5, 0.5, 0), 0.3, relative=True), Not(Box((0, 0, 0), (0.5, 1, 1))))), mesh)
    assert time.perf_counter() - start < 1.0
    assert 0 < mask.sum() < mesh.vertex_count
