"""Deforming mesh colliders (`meshdeform.scene.deforming`), checked by oracles that are not the code
under test: every cloth triangle sampled on a barycentric lattice and each sample's distance to
the body *at that frame's time* measured by brute force over all of the body's triangles
(`test_collider_contact.mesh_distance`); the bodies are convex, so a sample is outside when it is
in front of one of the posed body's face planes (trimesh's face normals). In every frame every
sample stays outside the body and at least the thickness minus 1 mm from it, while the body
swells, sweeps through the cloth or carries it.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from factories import grid_cloth
from test_collider_contact import SLACK, THICKNESS, lattice, mesh_distance

from meshdeform.scene.deforming import DeformingCollider, DeformingMesh
from meshdeform.simulate import Frame, Scene, Settings, simulate

pytestmark = pytest.mark.usefixtures("one_numba_thread")

BALL = trimesh.creation.icosphere(subdivisions=2, radius=1.0)


def check_frame(frame: Frame, body: DeformingMesh) -> float:
    """Asserts the frame's cloth surface is outside the body at the frame's time, at least the
    thickness minus the slack away; returns the nearest approach (m)."""
    samples = lattice(frame.welded_positions, np.asarray(frame.model.triangles), n=6)
    vertices = body.positions_at(frame.time)
    d = mesh_distance(samples, vertices, body.triangles)
    posed = trimesh.Trimesh(vertices, body.triangles, process=False)
    heights = np.einsum("nfk,fk->nf", samples[:, None, :] - vertices[body.triangles[:, 0]][None], posed.face_normals)
    assert (heights.max(axis=1) > 0).all(), frame.index
    assert d.min() >= THICKNESS - SLACK, (frame.index, d.min())
    return float(d.min())


def test_a_swelling_ball_lifts_the_cloth_lying_on_it_and_never_lets_it_in() -> None:
    centre = np.array([0.0, 0.0, 0.0])

    def swell(t: float) -> np.ndarray:  # radius 0.15 m growing to 0.3 m over half a second
        radius = 0.15 + 0.15 * min(t / 0.5, 1.0)
        return centre + radius * np.asarray(BALL.vertices)

    body = DeformingMesh(swell(0.0), np.asarray(BALL.faces), swell)
    model = grid_cloth(12, size=1.0, plane="xz", centred=True, offset=(0.0, 0.2, 0.0)).model
    collider = DeformingCollider(body, friction=0.3, thickness=THICKNESS)
    nearest, top = np.inf, 0.0
    for frame in simulate(model, Scene(constraints=[collider]), Settings(fps=24, frames=18)):
        nearest = min(nearest, check_frame(frame, body))
        top = frame.positions[:, 1].max()
    assert nearest < THICKNESS + 0.004  # it lay on the ball
    assert top > 0.3  # and rode up with it: the ball's top is at 0.3 m at the end


@pytest.mark.parametrize("speed", [2.0, 8.0])
def test_a_ball_swept_through_a_hanging_cloth_pushes_it_and_never_passes_through(speed: float) -> None:
    start = np.array([0.0, 0.0, -0.6])

    def sweep(t: float) -> np.ndarray:  # a 0.15 m ball moving along +z through the curtain at `speed` m/s
        return start + np.array([0.0, 0.0, speed * t]) + 0.15 * np.asarray(BALL.vertices)

    body = DeformingMesh(sweep(0.0), np.asarray(BALL.faces), sweep)
    from factories import TOP_CORNERS

    model = grid_cloth(12, size=1.0, plane="xy", centred=True, offset=(0.0, 0.0, 0.0), pins=TOP_CORNERS).model
    collider = DeformingCollider(body, friction=0.1, thickness=THICKNESS)
    frames = int(np.ceil(0.6 / speed * 24)) + 4
    pushed = 0.0
    for frame in simulate(model, Scene(constraints=[collider]), Settings(fps=24, frames=frames)):
        check_frame(frame, body)
        pushed = max(pushed, frame.positions[:, 2].max())
    assert pushed > 0.1  # the ball carried the cloth ahead of it


@pytest.mark.parametrize("solver", ["implicit", "springs"])
@pytest.mark.parametrize("friction", [0.0, 1.0])
def test_friction_is_relative_to_the_moving_surface(friction: float, solver: str) -> None:
    """`springs` keeps the contacts on planes that move with the surface in every explicit step
    (`Control.planes`), its friction relative to their velocity."""
    # a flat slab (1.2 x 0.1 x 1.2 m) sliding along +x at 0.5 m/s under a cloth lying on it
    slab = trimesh.creation.box(extents=(1.2, 0.1, 1.2))

    def slide(t: float) -> np.ndarray:
        return np.asarray(slab.vertices) + np.array([0.5 * t, -0.05, 0.0])

    body = DeformingMesh(slide(0.0), np.asarray(slab.faces), slide)
    model = grid_cloth(8, size=0.5, plane="xz", centred=True, offset=(0.0, 0.012, 0.0)).model
    collider = DeformingCollider(body, friction=friction, thickness=THICKNESS)
    for frame in simulate(model, Scene(constraints=[collider]), Settings(solver=solver, fps=24, frames=24)):
        check_frame(frame, body)
    moved = frame.positions[:, 0].mean()
    if friction > 0:
        assert moved > 0.35  # carried along most of the slab's 0.5 m
    else:
        assert abs(moved) < 0.05  # the slab slid away under it


def test_a_thin_plate_shot_through_a_curtain_at_20_m_s_carries_it_and_never_tunnels() -> None:
    # a 1 cm plate moves 3.8 cm a substep: more than its thickness and the contact thickness, so
    # only the swept test relative to the moving surface can catch the cloth in its path
    plate = trimesh.creation.box(extents=(0.5, 0.5, 0.01))

    def shoot(t: float) -> np.ndarray:  # from 0.3 m behind the curtain to 0.2 m in front, then still
        return np.asarray(plate.vertices) + np.array([0.0, 0.0, -0.3 + min(20.0 * t, 0.5)])

    body = DeformingMesh(shoot(0.0), np.asarray(plate.faces), shoot)
    from factories import TOP_CORNERS

    model = grid_cloth(12, size=1.0, plane="xy", centred=True, pins=TOP_CORNERS).model
    collider = DeformingCollider(body, friction=0.1, thickness=THICKNESS)
    # xpbd: 22 substeps a frame (the 3.8 cm above); implicit's cloth, which loses less of the blow,
    # whips up over the plate and round behind it (its centre 1.1 m up, measured: no crossing)
    for frame in simulate(model, Scene(constraints=[collider]), Settings(solver="xpbd", fps=24, frames=4)):
        check_frame(frame, body)
    # the cloth in the plate's path went with it, in front of the plate at the end (without the
    # swept test relative to the plate's motion it stays behind: the plate passes through it)
    centre = np.linalg.norm(np.asarray(model.rest_positions)[:, :2], axis=1) < 0.1
    assert frame.welded_positions[centre, 2].min() > 0.2


def test_a_deforming_bodys_speed_is_read_where_it_can_reach_the_cloth() -> None:
    """`DeformingCollider.largest_speed`, which sets a frame's fast steps: a body of two boxes, one
    at the origin rising at 0.1 m/s and one 5 m off swinging along x at 10 m/s, moves at 0.1 m/s
    for cloth points beside the first box (within its thickness of where it rises to) and at 10 m/s
    for a point in the second's path (its triangles' swept bounds reach it); for points 100 m off
    it reaches nothing: 0."""
    cube = trimesh.creation.box(extents=(0.2, 0.2, 0.2))
    corners, faces = np.asarray(cube.vertices), np.asarray(cube.faces)
    rest = np.concatenate([corners, corners + [5.0, 0.0, 0.0]])
    triangles = np.concatenate([faces, faces + corners.shape[0]])
    count = corners.shape[0]

    def track(t: float) -> np.ndarray:
        moved = rest.copy()
        moved[:count, 1] += 0.1 * t
        moved[count:, 0] += 10.0 * t
        return moved

    body = DeformingCollider(DeformingMesh(rest, triangles, track), thickness=THICKNESS)
    near_slow = np.array([[0.0, 0.15, 0.0], [0.3, 0.2, 0.1]])
    near_fast = np.array([[6.0, 0.0, 0.0]])
    assert body.largest_speed(near_slow, 0.0, 0.5) == pytest.approx(0.1)
    assert body.largest_speed(near_fast, 0.0, 0.5) == pytest.approx(10.0)
    assert body.largest_speed(np.array([[100.0, 0.0, 0.0]]), 0.0, 0.5) == 0.0
