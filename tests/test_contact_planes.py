"""The colliders' contact planes (`Collider.planes`, `Control.planes`) and how the explicit solvers keep them.

The planes are checked against closest points that trimesh computes (not the contact kernels): a
sheet curved over a sphere, every triangle nearer to it than the planes' reach has a plane, at the
sphere's own tangent plane moved out by the thickness. How a solver keeps them is checked on free
particles (`anchor` without anchors or springs), where the planes alone act: a point left inside
the thickness is not launched, and particles on a slope stick or slide by Coulomb's law.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import trimesh
from factories import grid_sheet, slope_turn

from meshdeform.model import SpringModel, State
from meshdeform.scene.colliders import PLANE_REACH, Collider, Plane, Sphere
from meshdeform.solvers import AnchorOptions
from meshdeform.solvers.anchor.solver import AnchorSolver
from meshdeform.solvers.base import Control

CENTRE = np.array([0.0, 0.0, 0.0])
RADIUS = 0.3
THICKNESS = 0.01


def sheet_over_sphere() -> SpringModel:
    """A 16 x 16 sheet of 0.5 m bent over the sphere's top: each vertex at RADIUS plus a height
    that grows from 0 at the centre to 3 thicknesses at the edge, so some triangles lie within the
    planes' reach and some beyond it."""
    mesh = grid_sheet(16, size=0.5, plane="xz", triangles=True, centred=True)
    flat = mesh.positions.copy()
    across = np.hypot(flat[:, 0], flat[:, 2])
    lift = RADIUS + 3.0 * THICKNESS * across / across.max()
    direction = np.stack([flat[:, 0], np.full(len(flat), RADIUS), flat[:, 2]], axis=1)
    direction /= np.linalg.norm(direction, axis=1)[:, None]
    positions = CENTRE + direction * lift[:, None]
    return SpringModel.from_mesh(replace(mesh, positions=positions))


def projected_collider(model: SpringModel) -> tuple[Collider, State]:
    """A sphere collider that has run one pass over the model at rest (its planes are then set)."""
    collider = Collider(Sphere(CENTRE, RADIUS), friction=0.4, thickness=THICKNESS)
    state = State.at_rest(model)
    dt = 1.0 / 192.0
    collider.project(model, state, dt, dt)
    return collider, state


def nearest_vertex(state: State) -> int:
    """The vertex nearest to the sphere (the colliders' pass left it the thickness out)."""
    return int(np.argmin(np.linalg.norm(state.positions - CENTRE, axis=1)))


def test_every_triangle_near_a_sphere_gets_its_tangent_plane_moved_out_by_the_thickness() -> None:
    model = sheet_over_sphere()
    collider, state = projected_collider(model)
    planes = collider.planes(model, state.positions)
    assert planes is not None
    corners = state.positions[np.asarray(model.triangles)]
    closest = trimesh.triangles.closest_point(corners, np.tile(CENTRE, (len(corners), 1)))
    clearance = np.linalg.norm(closest - CENTRE, axis=1) - RADIUS
    reach = PLANE_REACH * THICKNESS
    triangles = [tuple(sorted(t)) for t in np.asarray(model.triangles).tolist()]
    expected = {t for t, c in zip(triangles, clearance, strict=True) if c < reach - 1e-9}
    within = {t for t, c in zip(triangles, clearance, strict=True) if c < reach + 1e-6}
    got = {tuple(sorted(v)) for v in planes.vertices.tolist()}
    assert 0 < len(expected) < len(triangles)  # some near, some beyond the reach
    assert expected <= got <= within
    # each plane: the sphere's tangent plane at the point's nearest surface point, the thickness out
    points = np.einsum("ij,ijk->ik", planes.weights, state.positions[planes.vertices])
    normal = (points - CENTRE) / np.linalg.norm(points - CENTRE, axis=1)[:, None]
    np.testing.assert_allclose(planes.normals, normal, atol=1e-9)
    np.testing.assert_allclose(planes.offsets, normal @ CENTRE + RADIUS + THICKNESS, atol=1e-9)
    np.testing.assert_allclose(planes.weights.sum(axis=1), 1.0, atol=1e-12)
    assert np.all(planes.velocities == 0.0) and np.all(planes.friction == 0.4)


def test_a_point_left_inside_the_thickness_is_not_thrown_out_by_the_next_explicit_step() -> None:
    """Self-collision (or a pin) may leave a vertex nearer to a collider than its thickness after
    the colliders' pass. Its planes then pass through it rather than the thickness out: the
    explicit step turns a plane's position correction into velocity over its own short length, so
    a free vertex 2 mm inside would leave at 2 mm / dt (0.38 m/s at 192 steps a second). Free
    particles here (`anchor` without anchors or springs, no gravity): only the planes act."""
    model = sheet_over_sphere()
    collider, state = projected_collider(model)
    top = nearest_vertex(state)
    state.positions[top] -= 0.002 * (state.positions[top] - CENTRE) / np.linalg.norm(state.positions[top] - CENTRE)
    state.previous[:] = state.positions
    before = state.positions.copy()
    planes = collider.planes(model, state.positions)
    assert planes is not None and np.isin(top, planes.vertices)
    solver = AnchorSolver(AnchorOptions(anchor_stiffness=0.0, neighbour_springs=False, damping=0.0))
    control = Control(accelerations=np.zeros_like(state.positions), planes=planes)
    solver.step(model, state, 1.0 / 192.0, control)
    assert np.abs(state.velocities).max() < 1e-9
    assert np.abs(state.positions - before).max() < 1e-12


@pytest.mark.parametrize("friction", [0.5, 0.2])
def test_a_particle_on_a_slope_sticks_or_slides_by_coulomb_through_its_plane(friction: float) -> None:
    """Free particles (`anchor` without anchors or springs, no air damping) lying the thickness
    above a plane tilted 20 degrees, one explicit step of dt under gravity with the planes of the
    colliders' pass: at friction 0.5 (above tan 20 = 0.36) they stay exactly where they are, still
    (static friction takes back the way they slid in the step); at 0.2 they slide down the slope
    at g (sin 20 - 0.2 cos 20) dt after the step (Coulomb), and keep their distance from the plane."""
    slope = np.radians(20.0)
    turn = slope_turn(20.0)
    normal, down = turn[:, 1], -turn[:, 0]  # the plane's normal; along the plane, downhill
    mesh = grid_sheet(4, size=0.3, plane="xz", centred=True)
    model = SpringModel.from_mesh(replace(mesh, positions=mesh.positions @ turn.T + THICKNESS * normal))
    collider = Collider(Plane((0.0, 0.0, 0.0), normal), friction=friction, thickness=THICKNESS)
    state = State.at_rest(model)
    dt = 1.0 / 192.0
    collider.project(model, state, dt, dt)
    planes = collider.planes(model, state.positions)
    assert planes is not None and planes.offsets.shape[0] == model.vertex_count
    before = state.positions.copy()
    solver = AnchorSolver(AnchorOptions(anchor_stiffness=0.0, neighbour_springs=False, damping=0.0))
    gravity = np.tile([0.0, -9.81, 0.0], (model.vertex_count, 1))
    solver.step(model, state, dt, Control(accelerations=gravity, planes=planes))
    np.testing.assert_allclose(state.positions @ normal, before @ normal, atol=1e-12)  # on the plane
    np.testing.assert_allclose(state.velocities @ normal, 0.0, atol=1e-12)
    if friction > np.tan(slope):
        assert np.abs(state.velocities).max() < 1e-12
        assert np.abs(state.positions - before).max() < 1e-12
    else:
        slide = 9.81 * (np.sin(slope) - friction * np.cos(slope)) * dt
        np.testing.assert_allclose(state.velocities @ down, slide, rtol=1e-9)
        np.testing.assert_allclose((state.positions - before) @ down, slide * dt, rtol=1e-9)
