"""Forces: gravity by up axis, impacts (falloff, timing, direction, rays, repeats), wind, turbulence."""

from __future__ import annotations

import numpy as np
import pytest
from factories import grid_cloth, grid_sheet

from meshdeform.model import SpringModel, State
from meshdeform.scene import gravity_vector
from meshdeform.scene.forces import Impact, Turbulence, Wind, falloff, ray_hit
from meshdeform.simulate import simulate
from pipeline.build import build_simulation
from pipeline.recipe import parse_recipe

pytestmark = pytest.mark.usefixtures("one_numba_thread")


@pytest.fixture
def sheet() -> tuple[SpringModel, State]:
    model = grid_cloth(11).model  # 1 x 1 m in the XY plane
    return model, State.at_rest(model)


def accel(force, model, state, time: float, dt: float = 1e-3) -> np.ndarray:
    """The force's accelerations over the substep [time, time + dt) (s): (W, 3), m/s^2."""
    out = np.zeros_like(state.positions)
    force.accumulate(model, state, time, dt, out)
    return out


def test_gravity_follows_the_up_axis() -> None:
    assert gravity_vector("y") == (0.0, -9.81, 0.0)
    assert gravity_vector("z") == (0.0, 0.0, -9.81)
    with pytest.raises(ValueError):
        gravity_vector("x")


def test_impact_falls_off_as_one_over_one_plus_d_squared(sheet) -> None:
    model, state = sheet
    point = np.array([0.5, 0.5, 0.2])
    impact = Impact(time=0.0, radius=0.4, strength=3.0, duration=0.1, point=point)
    a = accel(impact, model, state, 0.05)
    d = np.linalg.norm(state.positions - point, axis=1)
    magnitude = np.linalg.norm(a, axis=1)
    near, far = int(np.argmin(d)), int(np.argmax(d))
    assert magnitude[near] > 3 * magnitude[far]
    expected_ratio = (1 + (d[far] / 0.4) ** 2) / (1 + (d[near] / 0.4) ** 2)
    assert magnitude[near] / magnitude[far] == pytest.approx(expected_ratio, rel=1e-9)
    # the original deformer (radius 1): a = strength / duration / (1 + d^2)
    original = Impact(time=0.0, radius=1.0, strength=3.0, duration=0.1, point=point)
    np.testing.assert_allclose(np.linalg.norm(accel(original, model, state, 0.0), axis=1), 30.0 / (1 + d * d))
    # radial: away from the point; a negative strength pulls toward it ("black hole")
    unit = (state.positions - point) / d[:, None]
    np.testing.assert_allclose(a, magnitude[:, None] * unit, atol=1e-12)
    hole = Impact(time=0.0, radius=0.4, strength=-3.0, duration=0.1, point=point)
    np.testing.assert_allclose(accel(hole, model, state, 0.05), -a)


def test_smooth_falloff_stops_at_the_radius() -> None:
    d = np.array([0.0, 0.1, 0.2, 0.29, 0.3, 0.5])
    f = falloff(d, 0.3, "smooth")
    assert f[0] == 1.0 and np.all(np.diff(f) <= 0) and np.all(f[4:] == 0.0) and f[3] > 0


@pytest.mark.parametrize("substeps", [4, 10, 37])
def test_impact_velocity_change_does_not_depend_on_the_substep(sheet, substeps: int) -> None:
    model, state = sheet
    dt = 1.0 / (24 * substeps)
    impact = Impact(time=0.013, radius=0.5, strength=2.0, duration=0.05, point=(0.5, 0.5, 0.1))
    total = np.zeros_like(state.positions)
    for k in range(int(0.2 / dt)):
        total += accel(impact, model, state, k * dt, dt) * dt
    d = np.linalg.norm(state.positions - [0.5, 0.5, 0.1], axis=1)
    np.testing.assert_allclose(np.linalg.norm(total, axis=1), 2.0 * falloff(d, 0.5), rtol=1e-9)


def test_repeating_impacts_fire_every_interval_count_times(sheet) -> None:
    model, state = sheet
    impact = Impact(time=0.2, radius=0.5, strength=1.0, duration=0.05, point=(0, 0, 0), every=0.5, count=2)
    active = [bool(np.any(accel(impact, model, state, t))) for t in (0.1, 0.21, 0.3, 0.71, 0.8, 1.21)]
    assert active == [False, True, False, True, False, False]


def test_ray_impact_hits_the_surface_and_pushes_along_its_normal(sheet) -> None:
    model, state = sheet
    hit = ray_hit(state.positions, model.triangles, np.array([0.3, 0.6, 1.0]), np.array([0.0, 0.0, -1.0]))
    assert hit is not None
    np.testing.assert_allclose(hit[0], [0.3, 0.6, 0.0], atol=1e-12)
    assert ray_hit(state.positions, model.triangles, np.array([3.0, 0, 1]), np.array([0.0, 0, -1])) is None
    impact = Impact(
        time=0, radius=0.2, strength=1.0, duration=0.1, ray=((0.3, 0.6, 1.0), (0, 0, -1)), direction="normal"
    )
    a = accel(impact, model, state, 0.0)
    # into the surface as seen from the ray's origin: -z; strongest at the hit point
    assert np.all(a[:, 2] < 0) and np.allclose(a[:, :2], 0.0)
    strongest = state.positions[np.argmax(-a[:, 2])]
    assert np.linalg.norm(strongest[:2] - [0.3, 0.6]) < 0.08


def test_face_on_wind_gives_dynamic_pressure_drag_and_edge_on_wind_none(sheet) -> None:
    model, state = sheet
    wind = Wind((0.0, 0.0, 2.0), drag=1.0, lift=0.0, air_density=1.2)
    force = accel(wind, model, state, 0.0) * model.mass[:, None]
    np.testing.assert_allclose(force.sum(axis=0), [0.0, 0.0, 0.5 * 1.2 * 1.0 * 4.0], atol=1e-12)
    edge_on = Wind((2.0, 0.0, 0.0), drag=1.0, lift=0.5)
    assert np.abs(accel(edge_on, model, state, 0.0)).max() < 1e-12
    # a cloth moving with the wind feels none of it
    state.velocities[:] = (0.0, 0.0, 2.0)
    assert np.abs(accel(wind, model, state, 0.0)).max() < 1e-12


def test_oblique_wind_has_lift_across_it(sheet) -> None:
    model, state = sheet
    u = np.array([1.0, 0.0, 1.0]) / np.sqrt(2)  # 45 degrees onto the XY sheet
    drag_only = accel(Wind(3 * u, drag=1.0, lift=0.0), model, state, 0.0).sum(axis=0)
    with_lift = accel(Wind(3 * u, drag=1.0, lift=1.0), model, state, 0.0).sum(axis=0)
    assert np.linalg.norm(np.cross(drag_only, u)) < 1e-9 * np.linalg.norm(drag_only)
    lift = with_lift - drag_only
    assert abs(lift @ u) < 1e-9 and np.linalg.norm(lift) > 0.1 * np.linalg.norm(drag_only)


def test_air_damping_pulls_velocity_toward_the_wind(sheet) -> None:
    model, state = sheet
    state.velocities[:] = (1.0, 0.0, 0.0)
    a = accel(Wind((0.0, 0.0, 0.0), drag=0.0, lift=0.0, air_damping=0.5), model, state, 0.0)
    np.testing.assert_allclose(a, np.tile([-0.5, 0.0, 0.0], (model.vertex_count, 1)))


def test_turbulence_is_seeded_and_smooth() -> None:
    points = np.random.default_rng(1).uniform(0, 2, size=(500, 3))
    a, b, c = Turbulence(5, scale=1.0), Turbulence(5, scale=1.0), Turbulence(6, scale=1.0)
    np.testing.assert_array_equal(a(points, 0.3), b(points, 0.3))
    assert np.abs(a(points, 0.3) - c(points, 0.3)).max() > 0.5
    rms = np.sqrt(np.mean(a(points, 0.3) ** 2))
    assert 0.5 < rms < 1.6
    # smooth in time and space: tiny steps change it a little
    assert np.abs(a(points, 0.301) - a(points, 0.3)).max() < 0.05 * rms
    assert np.abs(a(points + 0.001, 0.3) - a(points, 0.3)).max() < 0.05 * rms


FLAG = """
[simulation]
solver = "verlet"
frames = 6
substeps = 4
seed = {seed}
[[pins]]
select = {{ box = {{ min = [0, 0, 0], max = [0.01, 1, 1] }}, relative = true }}
[wind]
velocity = [4, 0, 1]
turbulence = 0.5
"""


def run(recipe_text: str) -> np.ndarray:
    built = build_simulation(parse_recipe(recipe_text), grid_sheet(9, 6, size=(1.6, 1.0)))
    return np.stack([f.positions for f in simulate(built.model, built.scene, built.settings)])


def test_same_recipe_and_seed_give_identical_positions_another_seed_differs() -> None:
    first = run(FLAG.format(seed=1))
    np.testing.assert_array_equal(first, run(FLAG.format(seed=1)))
    assert np.abs(first - run(FLAG.format(seed=2))).max() > 1e-4


@pytest.mark.parametrize("solver", ["implicit", "springs", "verlet", "xpbd"])
def test_a_cloth_given_an_initial_velocity_drifts_at_it_and_its_pins_stay(solver: str) -> None:
    """`initial_velocity` through a recipe, no gravity, no air damping: a free 12 x 12 sheet's
    centre of mass moves (0.5, 1.0, -0.25) m/s x 1 s in 24 frames (to 1e-9: from the first
    step on, the velocity each solver reads, whether its own or (x - previous) / dt) and its
    vertices keep their shape; a sheet pinned at one corner keeps that corner where it was."""
    velocity = np.array([0.5, 1.0, -0.25])
    head = (
        f'[simulation]\nsolver = "{solver}"\nframes = 24\ngravity = [0, 0, 0]\ndamping = 0.0\n'
        f"initial_velocity = [{velocity[0]}, {velocity[1]}, {velocity[2]}]\n"
    )
    mesh = grid_sheet(12)
    built = build_simulation(parse_recipe(head), mesh)
    mass = np.asarray(built.model.mass)
    frames = list(simulate(built.model, built.scene, built.settings))
    moved = mass @ (frames[-1].welded_positions - built.model.rest_positions) / mass.sum()
    np.testing.assert_allclose(moved, velocity * 1.0, rtol=1e-9, atol=1e-9)
    spread = frames[-1].welded_positions - built.model.rest_positions - moved
    assert np.abs(spread).max() < 1e-9
    pinned = build_simulation(parse_recipe(head + "\n[[pins]]\nselect = { indices = [0] }\n"), mesh)
    corner = pinned.model.rest_positions[pinned.model.pinned][0].copy()
    last = list(simulate(pinned.model, pinned.scene, pinned.settings))[-1]
    np.testing.assert_array_equal(last.welded_positions[pinned.model.pinned][0], corner)
    assert np.linalg.norm(last.welded_positions - pinned.model.rest_positions, axis=1).max() > 0.1


def test_a_sheet_shot_at_50_m_per_s_onto_a_1_cm_plate_never_crosses_it() -> None:
    """A 20 x 20 sheet of 1 m, 10 cm above a 1 cm plate (a box collider), given 50 m/s straight
    down by `initial_velocity` (default solver and steps): the first frame takes the steps its
    speed needs, and in no frame does any vertex lie below the plate's top within its extent."""
    mesh = grid_sheet(20, plane="xz", offset=(-0.5, 0.41, -0.5))
    text = (
        "[simulation]\nframes = 12\ninitial_velocity = [0, -50, 0]\n\n"
        "[[colliders]]\nbox = { min = [-1, 0.30, -1], max = [1, 0.31, 1] }\nfriction = 0.3\n"
    )
    built = build_simulation(parse_recipe(text), mesh)
    frames = list(simulate(built.model, built.scene, built.settings))
    assert frames[0].substeps > built.settings.substeps  # the kick's speed chose more steps
    lowest = min(float(f.welded_positions[:, 1].min()) for f in frames)
    assert lowest > 0.31  # on or above the plate's top (plus its thickness), never through it
    assert lowest < 0.33  # it did land on the plate
