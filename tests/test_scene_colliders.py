"""Colliders: signed distances, no vertex inside any collider in any frame, friction, tunnelling, animation."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from factories import grid_cloth, grid_sheet

from meshdeform.model import State
from meshdeform.scene.colliders import Box, Capsule, Collider, Plane, Sphere, TriangleMesh
from meshdeform.scene.pins import Keyframe, Keyframes
from meshdeform.simulate import Scene, Settings, simulate
from meshdeform.solvers import VerletOptions
from meshdeform.topology import SpringKind
from pipeline.build import build_simulation
from pipeline.recipe import parse_recipe

pytestmark = pytest.mark.usefixtures("one_numba_thread")


def test_primitive_signed_distances_and_normals() -> None:
    p = np.array([[0.0, 2.0, 0.0], [0.0, 0.5, 0.0], [3.0, 0.0, 0.0]])
    d, n = Sphere((0, 0, 0), 1.0).query(p)
    np.testing.assert_allclose(d, [1.0, -0.5, 2.0])
    np.testing.assert_allclose(n, [[0, 1, 0], [0, 1, 0], [1, 0, 0]])
    d, n = Box((-1, -1, -1), (1, 1, 1)).query(np.array([[0.0, 3.0, 0.0], [0.0, 0.8, 0.1], [2.0, 2.0, 0.0]]))
    np.testing.assert_allclose(d, [2.0, -0.2, np.sqrt(2)])
    np.testing.assert_allclose(n[:2], [[0, 1, 0], [0, 1, 0]])
    d, _ = Capsule((0, 0, 0), (2, 0, 0), 0.5).query(np.array([[1.0, 1.0, 0.0], [3.0, 0.0, 0.0], [1.0, 0.2, 0.0]]))
    np.testing.assert_allclose(d, [0.5, 0.5, -0.3])
    d, n = Plane((0, 1, 0), (0, 2, 0)).query(np.array([[5.0, 0.5, 1.0]]))
    np.testing.assert_allclose(d, [-0.5])


def test_triangle_mesh_collider_matches_the_sphere_it_approximates() -> None:
    ball = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    shape = TriangleMesh(ball.vertices, ball.faces)
    assert shape.solid
    points = np.random.default_rng(0).normal(size=(200, 3))
    points *= np.random.default_rng(1).uniform(0.5, 1.5, size=(200, 1)) / np.linalg.norm(points, axis=1, keepdims=True)
    d, n = shape.query(points)
    r = np.linalg.norm(points, axis=1)
    np.testing.assert_allclose(d, r - 1.0, atol=0.02)  # the facets sit inside the true sphere by < 1.3 %
    assert np.all(np.einsum("ij,ij->i", n, points / r[:, None]) > 0.9)


DROP = """
[simulation]
solver = "verlet"
fps = 24
frames = 30
substeps = 6
iterations = 8

# a limp cloth that drapes within the 30 frames (verlet's bending springs have the material's
# spring constant: at the default 0.05 the cloth tents over the ball and reaches the floor later)
[material]
stretch_modulus = 1000.0   # a knit
bending = {{ stiffness = 0.001 }}

[[colliders]]
sphere = {{ center = [0, 0.45, 0], radius = 0.3 }}
friction = 0.3
thickness = {thickness}

[[colliders]]
ground = {{ height = 0.0 }}
thickness = 0.005
friction = 0.5
"""


def test_cloth_dropped_on_a_sphere_and_the_ground_never_gets_inside() -> None:
    thickness = 0.02
    sheet = grid_sheet(14, size=1.4, plane="xz", centred=True, offset=(0.0, 1.0, 0.0))  # 1 m above the floor
    built = build_simulation(parse_recipe(DROP.format(thickness=thickness)), sheet)
    lowest = []
    for frame in simulate(built.model, built.scene, built.settings):
        p = frame.positions
        assert np.linalg.norm(p - [0, 0.45, 0], axis=1).min() >= 0.3 + thickness - 1e-9, frame.index
        assert p[:, 1].min() >= 0.005 - 1e-9, frame.index
        lowest.append(p[:, 1].min())
    # it really fell: draped over the ball with the corners on the floor
    assert lowest[-1] < 0.02
    # faces keep the thickness too: the cap's triangles sit at >= 0.32 from the centre, so its
    # vertices at up to sqrt(0.32^2 + rho^2), rho the circumradius of a grid triangle (half a diagonal)
    rho = 0.5 * np.sqrt(2.0) * 1.4 / 13
    top = frame.positions[:, 1].max()
    assert 0.75 + thickness - 1e-9 <= top <= 0.45 + np.hypot(0.3 + thickness, rho) + 0.005


def test_cloth_on_a_triangle_mesh_collider_stays_outside(tmp_path) -> None:
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.3)
    ball.apply_translation([0, 0.45, 0])
    path = tmp_path / "ball.obj"
    ball.export(path)
    text = DROP.format(thickness=0.02).replace("sphere = { center = [0, 0.45, 0], radius = 0.3 }", 'mesh = "ball.obj"')
    recipe_path = tmp_path / "drop.toml"
    recipe_path.write_text(text)
    from pipeline.recipe import load_recipe

    sheet = grid_sheet(10, size=1.4, plane="xz", centred=True, offset=(0.0, 1.0, 0.0))
    built = build_simulation(load_recipe(recipe_path), sheet)
    shape = built.scene.constraints[0].shape
    for frame in simulate(built.model, built.scene, built.settings):
        d, _ = shape.query(frame.positions)
        assert d.min() >= 0.02 - 1e-6, frame.index


def single_vertex_state(prev, now):
    model = grid_cloth(2).model
    state = State.at_rest(model)
    state.previous[:] = prev
    state.positions[:] = now
    state.velocities[:] = (np.asarray(now) - np.asarray(prev)) / 0.01
    return model, state


def test_fast_vertex_does_not_tunnel_through_a_thin_box() -> None:
    # a 2 cm table top; in one substep a vertex goes from 10 cm above to 10 cm below it
    table = Collider(Box((-1, 0.49, -1), (1, 0.51, 1)), friction=0.0, thickness=0.005)
    model, state = single_vertex_state([0.2, 0.61, 0.3], [0.2, 0.39, 0.3])
    table.project(model, state, 0.01, 0.01)
    np.testing.assert_allclose(state.positions[:, 1], 0.515)
    assert np.all(state.velocities[:, 1] >= 0)


def test_thin_open_mesh_keeps_each_vertex_on_its_side() -> None:
    sheet_mesh = grid_sheet(5, size=2.0, plane="xz")
    shape = TriangleMesh(sheet_mesh.positions - [1, 0, 1], sheet_mesh.triangles)
    assert not shape.solid
    floor = Collider(shape, friction=0.0, thickness=0.01)
    model, state = single_vertex_state([0.1, 0.05, 0.1], [0.1, -0.04, 0.1])  # crossed from above
    floor.project(model, state, 0.01, 0.01)
    np.testing.assert_allclose(state.positions[:, 1], 0.01)
    floor = Collider(shape, friction=0.0, thickness=0.01)
    model, state = single_vertex_state([0.1, -0.05, 0.1], [0.1, -0.005, 0.1])  # below it, staying below
    floor.project(model, state, 0.01, 0.01)
    np.testing.assert_allclose(state.positions[:, 1], -0.01)


def test_friction_slows_sliding() -> None:
    speeds = []
    for friction in (0.0, 0.5):
        model = grid_cloth(2, plane="xz").model
        state = State.at_rest(model)
        state.velocities[:] = (1.0, 0.0, 0.0)
        state.previous[:] = state.positions - state.velocities * 0.01
        scene = Scene(gravity=(0, -9.81, 0), constraints=[Collider(Plane((0, 0, 0), (0, 1, 0)), friction, 0.0)])
        settings = Settings(solver="verlet", fps=25, frames=8, substeps=4, options=VerletOptions(damping=0.0))
        frames = list(simulate(model, scene, settings, state=state))
        speeds.append((frames[-1].positions[:, 0].mean() - frames[-2].positions[:, 0].mean()) * 25)
    assert speeds[0] == pytest.approx(1.0, rel=0.05)
    # Coulomb: it loses mu g = 4.9 m/s per second of contact, so it stops after about 0.2 s
    assert abs(speeds[1]) < 0.02


def test_animated_collider_pushes_cloth_and_nothing_gets_inside() -> None:
    model = grid_cloth(10, plane="xz", centred=True, offset=(0.0, 0.3, 0.0)).model
    keys = Keyframes([Keyframe(0.0, translate=(0, 0, 0)), Keyframe(0.5, translate=(0, 0.6, 0))], pivot=(0, 0, 0))
    ball = Collider(Sphere((0, 0, 0), 0.25), friction=0.5, thickness=0.01, keys=keys)
    scene = Scene(gravity=(0, -9.81, 0), constraints=[ball])
    settings = Settings(solver="verlet", fps=24, frames=18, substeps=6)
    top = []
    for frame in simulate(model, scene, settings):
        center = keys.apply(np.zeros((1, 3)), frame.time)[0]
        assert np.linalg.norm(frame.positions - center, axis=1).min() >= 0.26 - 1e-9, frame.index
        top.append(frame.positions[:, 1].max())
    assert top[-1] > 0.8  # carried up on the rising ball


def test_a_rising_plate_carries_the_cloth_it_lifts_without_throwing_or_stretching_it() -> None:
    """The default solver: a 0.6 m plate rising at 0.5 m/s into a 1 m sheet lying flat 5 cm above
    it, no gravity. The plate does work v_p * (the impulse it gives) = v_p M v_cm on the cloth, and
    the cloth cannot run ahead of it (v_cm <= v_p), so its kinetic energy stays within M v_p^2: twice
    that of the whole cloth at the plate's speed (velocities from frame differences). Carried, the
    sheet keeps near its rest lengths. The colliders' one pass of point impulses each substep (all
    the implicit solver got before) gave it 69 times that energy and 3.5x stretch: it threw the sheet
    about, 13 m/s at the edges."""
    speed = 0.5
    model = grid_cloth(20, plane="xz", centred=True, offset=(0.0, 0.05, 0.0)).model
    keys = Keyframes([Keyframe(0.0, translate=(0, 0, 0)), Keyframe(1.0, translate=(0, speed, 0))], pivot=(0, 0, 0))
    plate = Collider(Box((-0.3, -0.01, -0.3), (0.3, 0.0, 0.3)), friction=0.5, thickness=0.005, keys=keys)
    mass = np.asarray(model.mass)
    rest = np.asarray(model.rest_positions)
    a, b = np.asarray(model.springs)[np.asarray(model.kinds) == SpringKind.STRUCTURAL].T
    rest_length = np.linalg.norm(rest[a] - rest[b], axis=1)
    before, lifted = rest, 0.0
    for frame in simulate(model, Scene(gravity=(0, 0, 0), constraints=[plate]), Settings(fps=24, frames=14)):
        x = frame.welded_positions
        velocity = (x - before) * 24.0
        before = x
        kinetic = 0.5 * float(mass @ np.einsum("ij,ij->i", velocity, velocity))
        assert kinetic <= mass.sum() * speed**2, (frame.index, kinetic / (0.5 * mass.sum() * speed**2))
        assert (np.linalg.norm(x[a] - x[b], axis=1) / rest_length).max() < 1.1, frame.index
        lifted = float(mass @ x[:, 1] / mass.sum()) - 0.05
    assert lifted > 0.6 * speed * (14 / 24 - 0.1)  # carried up most of the plate's way after it met the sheet


def test_static_ground_handles_a_vertex_that_crossed_it_within_a_substep() -> None:
    """A vertex that starts the substep below a static ground and ends above it is still swept-tested
    (the plane's normals must be a writable per-vertex array, not a broadcast view)."""
    model = grid_cloth(2, plane="xz", centred=True).model
    state = State.at_rest(model)
    state.previous[:] = state.positions
    state.previous[:, 1] = -0.5
    state.positions[:, 1] = 0.5
    ground = Collider(Plane((0, 0, 0), (0, 1, 0)), friction=0.0, thickness=0.01)
    ground.project(model, state, time=0.1, dt=0.01)
    assert np.all(np.isfinite(state.positions))
    assert np.all(state.positions[:, 1] >= 0.01 - 1e-12)


@pytest.mark.parametrize("beside", ["box", "mesh", "sphere"])
def test_the_ground_runs_in_its_scenes_pipeline_with_the_bytes_of_the_ground_alone(beside) -> None:
    """A plane runs in the compiled contact pipeline of a box or mesh collider of its scene (one
    pipeline to compile in a fresh process instead of two), in the simple one beside a sphere,
    and alone in one of its own; its contact is the same arithmetic in every pipeline, so a sheet
    dropped on the ground lands to the same bytes whether a collider it never reaches sits beside
    the ground or not."""
    import meshdeform.contact.collider_kernels as ck

    far = {
        "sphere": lambda: Sphere((5.0, 0.5, 5.0), 0.5),
        "box": lambda: Box((5.0, 0.0, 5.0), (6.0, 1.0, 6.0)),
        "mesh": lambda: TriangleMesh(
            np.array([[5.0, 0.0, 5.0], [6.0, 0.0, 5.0], [5.0, 1.0, 5.0], [5.0, 0.0, 6.0]]),
            np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]),
        ),
    }[beside]
    model = grid_cloth(10, plane="xz", size=1.0, centred=True, offset=(0.0, 0.3, 0.0)).model
    settings = Settings(frames=16)

    def landing(with_far: bool) -> np.ndarray:
        ground = Collider(Plane((0.0, 0.0, 0.0), (0.0, 1.0, 0.0)), friction=0.4, thickness=0.01)
        scene = Scene(constraints=[ground, Collider(far())] if with_far else [ground])
        frames = np.array([f.positions for f in simulate(model, scene, settings)])
        pipeline = ck.contact_kernel(ck.PLANE, ground.company)
        shared = {"box": ck.contact_box, "mesh": ck.contact_mesh, "sphere": ck.contact_simple}[beside]
        assert pipeline is (shared if with_far else ck.contact_plane)
        return frames

    alone, beside_far = landing(False), landing(True)
    assert alone[:, :, 1].min() < 0.02  # it landed: the ground's contact ran
    assert alone.tobytes() == beside_far.tobytes()


def test_a_moving_colliders_speed_is_read_where_it_can_reach_the_cloth() -> None:
    """`Collider.largest_speed`, which sets a frame's fast steps: a 0.2 m box sliding at 3 m/s
    moves at 3 m/s for a point it can reach within the second (0.5 m off), 0 for one 10 m off; a
    ball of 0.2 m spinning twice a second in place moves as fast as its bounds' corners (0.28 m
    from its axis, measured by chords over eighths of the second), not as it would carry a point
    a metre off; a plane rising at 2 m/s carries any point at 2 m/s; a still collider moves at 0."""
    slide = Keyframes([Keyframe(0.0, translate=(0, 0, 0)), Keyframe(1.0, translate=(3.0, 0, 0))], pivot=(0, 0, 0))
    box = Collider(Box((-0.1, -0.1, -0.1), (0.1, 0.1, 0.1)), keys=slide)
    near, far = np.array([[0.6, 0.0, 0.0]]), np.array([[10.0, 0.0, 0.0]])
    assert box.largest_speed(near, 0.0, 1.0) == pytest.approx(3.0)
    assert box.largest_speed(far, 0.0, 1.0) == 0.0
    spin = Keyframes([Keyframe(0.0, rotate=(0, 0, 0)), Keyframe(1.0, rotate=(0, 720, 0))], pivot=(0, 0, 0))
    ball = Collider(Sphere((0, 0, 0), 0.2), keys=spin)
    corner = 0.2 * np.sqrt(2.0)  # the corners' distance from the spin axis (y)
    # a chord over an eighth of the frame's 720 degrees: 90 degrees, sqrt(2) times the radius
    chord = np.sqrt(2.0) * corner * 8.0
    assert ball.largest_speed(np.array([[1.0, 0.0, 0.0]]), 0.0, 1.0) == pytest.approx(chord)
    rise = Keyframes([Keyframe(0.0, translate=(0, 0, 0)), Keyframe(1.0, translate=(0, 2.0, 0))], pivot=(0, 0, 0))
    plane = Collider(Plane((0, 0, 0), (0, 1, 0)), keys=rise)
    assert plane.largest_speed(np.array([[5.0, 3.0, -2.0]]), 0.0, 1.0) == pytest.approx(2.0)
    assert Collider(Sphere((0, 0, 0), 0.2)).largest_speed(near, 0.0, 1.0) == 0.0
