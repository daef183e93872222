"""Material effects: pressure keeps a closed mesh's volume, plasticity leaves dents, tethers stop stretch."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from factories import grid_cloth, grid_sheet, pulled_banner

from meshdeform.errors import RecipeError
from meshdeform.material import KindMaterial, Material
from meshdeform.mesh import Mesh, polygons_to_csr
from meshdeform.model import SpringModel, State
from meshdeform.scene.effects import NearestPinTethers, Plasticity, Pressure, enclosed_volume
from meshdeform.simulate import simulate
from pipeline.build import build_simulation
from pipeline.recipe import parse_recipe

pytestmark = pytest.mark.usefixtures("one_numba_thread")


def ball(subdivisions: int = 2, radius: float = 0.5, center=(0.0, 0.0, 0.0)) -> Mesh:
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    flat, offsets = polygons_to_csr(list(np.asarray(sphere.faces)))
    return Mesh(positions=np.asarray(sphere.vertices) + center, face_indices=flat, face_offsets=offsets)


def test_pressure_pushes_out_when_squeezed_and_in_when_inflated() -> None:
    model = SpringModel.from_mesh(ball())
    pressure = Pressure(model, stiffness=100.0)
    state = State.at_rest(model)
    radial = state.positions / np.linalg.norm(state.positions, axis=1, keepdims=True)
    for factor, sign in ((0.9, 1.0), (1.1, -1.0), (1.0, 0.0)):
        state.positions[:] = model.rest_positions * factor
        out = np.zeros_like(state.positions)
        pressure.accumulate(model, state, 0.0, 0.01, out)
        along = np.einsum("ij,ij->i", out, radial)
        if sign:
            assert np.all(sign * along > 0)
        else:
            assert np.abs(out).max() < 1e-9


SQUASH = """
[simulation]
solver = "verlet"
fps = 24
frames = 24
substeps = 8
iterations = 4
damping = 0.9

[material]
structural = {{ stiffness = 0.2 }}
shear = {{ stiffness = 0.1 }}
bending = {{ stiffness = 0.01 }}
{pressure}

[[colliders]]
ground = {{ height = 0.0 }}
friction = 0.5
"""


def test_pressure_keeps_a_ball_dropped_on_the_ground_near_its_volume() -> None:
    mesh = ball(center=(0.0, 0.55, 0.0))
    v0 = enclosed_volume(mesh.positions, mesh.triangles)
    ratios = []
    for pressure in ("", "pressure = { stiffness = 400.0 }"):
        built = build_simulation(parse_recipe(SQUASH.format(pressure=pressure)), mesh)
        last = list(simulate(built.model, built.scene, built.settings))[-1]
        ratios.append(enclosed_volume(last.positions, mesh.triangles) / v0)
    assert ratios[1] > 0.9
    assert abs(1 - ratios[1]) < 0.5 * abs(1 - ratios[0])


def test_pressure_needs_a_closed_mesh() -> None:
    recipe = parse_recipe("[material.pressure]\nstiffness = 10\n", "p.toml")
    with pytest.raises(RecipeError, match=r"^p\.toml: material\.pressure \(line 1\): pressure needs a closed mesh"):
        build_simulation(recipe, grid_sheet(4))


def test_plastic_rest_copy_creeps_only_past_the_yield_distance() -> None:
    model = grid_cloth(3).model
    effect = Plasticity(model, stiffness=100.0, yield_distance=0.1, rate=1e6)
    state = State.at_rest(model)
    state.positions[0] += [0.0, 0.0, 0.05]  # elastic
    state.positions[1] += [0.0, 0.0, 0.3]  # 0.2 past the yield distance
    effect.project(model, state, 0.0, 0.01)
    np.testing.assert_allclose(effect.rest[0], model.rest_positions[0])
    np.testing.assert_allclose(effect.rest[1], model.rest_positions[1] + [0, 0, 0.2])
    out = np.zeros_like(state.positions)
    effect.accumulate(model, state, 0.0, 0.01, out)
    np.testing.assert_allclose(out[1], [0.0, 0.0, -100.0 * 0.1])


DENT = """
[simulation]
solver = "verlet"
fps = 24
frames = 48
substeps = 4
gravity = [0, 0, 0]
damping = 0.9

[material]
structural = {{ stiffness = 0.3 }}
bending = {{ stiffness = 0.1 }}
{plastic}

[[impacts]]
time = 0.1
point = [0.5, 0.5, 0.05]
radius = 0.3
strength = 3.0
duration = 0.1
falloff = "smooth"
"""


def test_impacts_leave_dents_with_plasticity_and_none_without() -> None:
    mesh = grid_sheet(9)
    centre = 40
    dents = []
    for rate in (20.0, 0.0):
        plastic = f"plasticity = {{ stiffness = 50.0, yield = 0.01, rate = {rate}, damping = 5.0 }}"
        built = build_simulation(parse_recipe(DENT.format(plastic=plastic)), mesh)
        frames = list(simulate(built.model, built.scene, built.settings))
        dents.append(mesh.positions[centre, 2] - frames[-1].positions[centre, 2])
    assert dents[0] > 0.02  # pushed away from the point (-z) and it stayed
    assert abs(dents[1]) < 0.01  # sprang back


def test_tethers_limit_distance_from_the_pins() -> None:
    mesh = grid_sheet(8, 12, size=(0.7, 1.1))
    text = """
[simulation]
solver = "verlet"
frames = 24
substeps = 4
iterations = 1
tethers = 0
[material]
structural = {{ stiffness = 0.05 }}
shear = {{ enabled = false }}
bending = {{ enabled = false }}
density = 2.0
{tethers}
[[pins]]
select = {{ box = {{ min = [0, 0.99, 0], max = [1, 1, 1] }}, relative = true }}
"""
    worst = []
    for tethers in ("", "tethers = { max_stretch = 1.02 }"):
        built = build_simulation(parse_recipe(text.format(tethers=tethers)), mesh)
        last = list(simulate(built.model, built.scene, built.settings))[-1].welded_positions
        # vertical distance from the top edge versus rest: each column hangs from the pin above it
        stretch = (1.1 - last[:, 1]) / np.maximum(1.1 - built.model.rest_positions[:, 1], 1e-9)
        worst.append(stretch[built.model.rest_positions[:, 1] < 1.0].max())
    assert worst[0] > 1.1
    assert worst[1] <= 1.02 + 1e-9


def test_tether_anchor_is_the_nearest_pin_along_the_mesh() -> None:
    material = Material(shear=KindMaterial(enabled=False), bending=KindMaterial(enabled=False))
    model = grid_cloth(5, 2, size=(4.0, 1.0), material=material).model
    tethers = NearestPinTethers(model, np.array([0, 4]), max_stretch=1.5)
    anchor = dict(zip(tethers.vertices.tolist(), tethers.anchor.tolist(), strict=True))
    assert anchor[1] == 0 and anchor[3] == 4 and anchor[6] == 0 and anchor[8] == 4
    limit = dict(zip(tethers.vertices.tolist(), tethers.limit.tolist(), strict=True))
    assert limit[1] == pytest.approx(1.5) and limit[5] == pytest.approx(1.5)


def test_material_tethers_let_grips_that_pull_a_cloth_apart_stretch_it_evenly() -> None:
    """`[material.tethers]` on `pulled_banner` (grips pulled apart by 30 % of the width), under
    the default solver: each vertex is tethered to its nearest grip, so each half followed its
    grip within its limits and the springs between the halves took the whole stretch (9.6x on a
    32 x 20 flag). Its limit now grows by what its own grip's and the other grip's separation
    asks for (`NearestPinTethers.other`): the cloth stretches as it does without tethers."""
    worst = {}
    for tethers in ("", "[material.tethers]\nmax_stretch = 1.03\n"):
        mesh, text = pulled_banner("implicit", extra=tethers)
        built = build_simulation(parse_recipe(text), mesh)
        worst[tethers] = max(f.max_stretch for f in simulate(built.model, built.scene, built.settings))
    plain, tethered = worst.values()
    assert plain < 1.5
    assert tethered < plain + 0.05
