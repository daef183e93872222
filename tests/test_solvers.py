"""The solver interface: registry, defaults, stepping, caches, layouts and rest reporting."""

from __future__ import annotations

import math

import numpy as np
import pytest
from factories import TOP_CORNERS, grid_cloth, pulled_banner

from meshdeform.errors import MeshdeformError
from meshdeform.mesh import grid_mesh
from meshdeform.model import SpringModel, State
from meshdeform.scene.base import Force
from meshdeform.simulate import Frame, Scene, Settings, rest_frame, simulate
from meshdeform.solvers import (
    SOLVERS,
    AnchorOptions,
    Control,
    SolverOptions,
    SpringsOptions,
    VerletOptions,
    XPBDOptions,
    make_solver,
    solver_class,
)
from meshdeform.solvers.layout import spring_layout, tethers

NAMES = ("anchor", "verlet", "xpbd", "springs", "implicit")


def cloth(n: int = 8, pins: bool = True) -> SpringModel:
    """An n x n cloth, hanging from its top corners when `pins` (`factories.grid_cloth`)."""
    return grid_cloth(n, pins=TOP_CORNERS if pins else ()).model


def test_all_five_solvers_registered_by_name() -> None:
    assert set(NAMES) <= set(SOLVERS)
    for name in NAMES:
        solver = make_solver(name)
        assert solver.name == name
        assert callable(solver.step)


def test_unknown_solver_lists_the_known_ones() -> None:
    with pytest.raises(MeshdeformError, match="xpbd"):
        make_solver("nope")
    with pytest.raises(MeshdeformError):
        Settings(solver="nope")


def test_settings_resolve_solver_defaults() -> None:
    assert Settings(solver="implicit").substeps == solver_class("implicit").default_substeps
    assert Settings(solver="xpbd").substeps == solver_class("xpbd").default_substeps
    assert Settings(solver="xpbd", substeps=3).substeps == 3
    assert Settings(solver="xpbd").iterations == solver_class("xpbd").default_iterations
    assert Settings(solver="verlet", options=VerletOptions(iterations=7)).iterations == 7
    assert Settings(solver="xpbd", fps=25, substeps=4).dt == pytest.approx(0.01)
    assert type(Settings(solver="anchor").options) is AnchorOptions  # None: the solver's own defaults


@pytest.mark.parametrize("name", NAMES)
def test_every_solver_declares_the_contract(name: str) -> None:
    """What the CLI help, the guard's hints and the recipe read from each registered solver."""
    cls = solver_class(name)
    assert cls.name == name and cls.summary and "\n" not in cls.summary and cls.hint
    assert cls.default_substeps >= 1 and cls.default_iterations >= 0
    assert issubclass(cls.options_class, SolverOptions)
    assert type(make_solver(name).options) is cls.options_class


def test_options_of_another_solver_are_refused() -> None:
    with pytest.raises(MeshdeformError, match="XPBDOptions"):
        make_solver("verlet", XPBDOptions())
    with pytest.raises(MeshdeformError, match="springs"):
        make_solver("springs", AnchorOptions())  # a subclass, but anchor's options
    with pytest.raises(MeshdeformError):
        Settings(solver="anchor", options=SpringsOptions())


@pytest.mark.parametrize("name", NAMES)
def test_step_moves_free_vertices_and_keeps_pins(name: str) -> None:
    """Five steps of 1/96 s under gravity: a horizontal cloth pinned at two corners falls (its free
    vertices by millimetres on average, whatever the material's stiffness), and its pins stay."""
    model = grid_cloth(8, pins=TOP_CORNERS, plane="xz").model
    solver = make_solver(name)
    state = State.at_rest(model)
    control = Control(np.tile([0.0, -9.81, 0.0], (model.vertex_count, 1)))
    before = control.accelerations.copy()
    for _ in range(5):
        solver.step(model, state, 1.0 / 96.0, control)
    assert np.isfinite(state.positions).all()
    assert np.array_equal(control.accelerations, before)  # control is read-only for solvers
    free = ~model.pinned
    assert (state.positions[free, 1] < model.rest_positions[free, 1] + 1e-4).all()
    assert np.mean(state.positions[free, 1] - model.rest_positions[free, 1]) < -1e-3
    assert np.array_equal(state.positions[model.pinned], model.rest_positions[model.pinned])


@pytest.mark.parametrize("name", NAMES)
def test_solver_rebuilds_its_cache_for_another_model(name: str) -> None:
    solver = make_solver(name)
    for model in (cloth(6), cloth(9), cloth(6)):
        state = State.at_rest(model)
        control = Control(np.zeros((model.vertex_count, 3)))
        solver.step(model, state, 0.01, control)
        assert np.allclose(state.positions, model.rest_positions)


def test_anchor_rejects_unknown_frame() -> None:
    with pytest.raises(MeshdeformError, match="anchor_frame"):
        make_solver("anchor", AnchorOptions(anchor_frame="sideways"))


def test_anchor_springs_back_after_a_kick() -> None:
    """A velocity kick dents the mesh; without gravity it returns to rest and stops."""
    mesh = grid_mesh(5, 5, plane="xz")
    model = SpringModel.from_mesh(mesh, pinned_input=np.arange(25) == 0)

    class Kick(Force):
        kicks = True

        def accumulate(self, model, state, time, dt, out) -> None:
            if time < 1e-9:
                out[12, 1] += 2.0 / dt  # dv = 2 m/s over the first substep

        def largest_kick(self, start: float, end: float) -> float:
            return 2.0 if start < 1e-9 else 0.0

    settings = Settings(solver="anchor", frames=24 * 12, substeps=4)
    frames = list(simulate(model, Scene(gravity=(0, 0, 0), forces=[Kick()]), settings))
    assert frames[0].welded_positions[12, 1] > 0.01
    assert np.allclose(frames[-1].welded_positions, model.rest_positions, atol=1e-4)
    assert frames[-1].at_rest


def test_anchor_neighbour_springs_carry_pins() -> None:
    """With neighbour springs, a pinned corner holds its neighbours closer than without."""
    model = cloth(8)
    scene = Scene()
    plain = list(simulate(model, scene, Settings(solver="anchor", frames=48)))[-1]
    carried = list(
        simulate(model, scene, Settings(solver="anchor", frames=48, options=AnchorOptions(neighbour_springs=True)))
    )[-1]
    near = 8 * 6  # the vertex below the pinned top-left corner
    assert carried.welded_positions[near, 1] > plain.welded_positions[near, 1]


@pytest.mark.parametrize("parts", [1, 2, 3])
def test_layout_slabs_share_no_vertex(parts: int) -> None:
    model = cloth(24)
    lay = spring_layout(model, parts)
    assert lay.offsets[-1] == model.spring_count
    assert np.array_equal(np.sort(lay.order), np.arange(model.spring_count))
    seen = []
    for p in range(lay.parts):
        sl = slice(lay.offsets[p], lay.offsets[p + 1])
        seen.append(set(lay.a[sl]) | set(lay.b[sl]))
    for i in range(len(seen)):
        for j in range(i + 1, len(seen)):
            assert not (seen[i] & seen[j])
    assert np.array_equal(lay.rest, model.rest_lengths[lay.order])


@pytest.mark.parametrize("jitter", [0.0, 0.2])
def test_xpbd_springs_share_constants_only_where_they_are_equal(jitter: float) -> None:
    """Every spring's shared constants record holds its own rest length and compliance; a uniform
    grid needs few records (one per kind, mass pair and boundary case), a jittered one (every rest
    length different) one per spring."""
    mesh = grid_mesh(12, 12, plane="xy")
    rng = np.random.default_rng(3)
    mesh.positions[:, :2] += rng.uniform(-jitter, jitter, (mesh.positions.shape[0], 2)) / 11
    pinned = np.zeros(144, dtype=bool)
    pinned[[132, 143]] = True
    model = SpringModel.from_mesh(mesh, pinned_input=pinned)
    solver = make_solver("xpbd")
    solver.step(model, State.at_rest(model), 1e-3, Control(np.zeros((144, 3))))
    order = solver.layout.order
    records = solver.constants[solver.params["k"]]
    assert np.array_equal(records["rest"], model.rest_lengths[order])
    k = model.stiffness[order] * model.material.stretch_modulus
    assert np.allclose(records["at"], 1.0 / (k * 1e-6), rtol=1e-12)
    if jitter:
        assert solver.constant_count == model.spring_count
    else:
        assert solver.constant_count < model.spring_count // 5


def test_tethers_hold_at_rest_and_reach_each_pin_group() -> None:
    model = cloth(10)
    t = tethers(model, 1.0)
    x = model.rest_positions
    dist = np.linalg.norm(x[t.vertex] - x[t.pin], axis=1)
    assert (dist <= t.limit + 1e-12).all()
    assert t.vertex.shape[0] == 2 * (model.vertex_count - 2)  # both corners, every free vertex
    assert set(np.unique(t.pin)) == set(np.flatnonzero(model.pinned))


def test_one_or_two_slabs_agree_in_quality() -> None:
    model = cloth(24)
    last = {}
    for parts in (1, 2):
        settings = Settings(solver="xpbd", frames=12, options=XPBDOptions(partitions=parts))
        last[parts] = list(simulate(model, Scene(), settings))[-1]
    assert np.allclose(last[1].welded_positions, last[2].welded_positions, atol=0.02)


def test_slabbed_runs_are_reproducible() -> None:
    model = cloth(24)
    settings = Settings(solver="verlet", frames=6, options=VerletOptions(partitions=2))
    a = list(simulate(model, Scene(), settings))[-1].welded_positions
    b = list(simulate(model, Scene(), settings))[-1].welded_positions
    assert np.array_equal(a, b)


def test_frames_report_rest_and_rest_frame_helper() -> None:
    model = cloth(6)
    frames = list(simulate(model, Scene(gravity=(0, 0, 0)), Settings(solver="xpbd", frames=3)))
    assert all(f.at_rest for f in frames)
    assert [f.rest_frame for f in frames] == [1, 1, 1]
    assert rest_frame(frames) == 1
    moving = Frame(1, 0.0, np.zeros((1, 3)), np.zeros((1, 3)), 1.0, 1.0)
    assert not moving.at_rest and moving.rest_frame is None
    assert rest_frame([*frames, moving]) is None
    assert rest_frame([]) is None


def test_pin_motion_moves_pins_exactly() -> None:
    model = cloth(6)
    pins = np.flatnonzero(model.pinned)
    start = model.rest_positions[pins]

    def motion(t: float) -> np.ndarray:
        return start + np.array([0.5 * t, 0.0, 0.0])

    for name in NAMES:
        frames = list(simulate(model, Scene(pin_motion=motion), Settings(solver=name, frames=6)))
        assert np.array_equal(frames[-1].welded_positions[pins], motion(frames[-1].time))


@pytest.mark.parametrize("rate", [0.0, 5.0])
def test_anchor_damping_decays_relative_velocity_exponentially(rate: float) -> None:
    """The original's damping: a vertex moving away from its anchor (no spring to speak of, no
    air damping) keeps exp(-rate t) of its velocity after t seconds, whatever the step."""
    model = cloth(3)  # a pinned corner: anchors in the world frame
    options = AnchorOptions(anchor_stiffness=1e-12, anchor_damping=rate, damping=0.0)
    solver = make_solver("anchor", options)
    state = State.at_rest(model)
    free = np.flatnonzero(~model.pinned)[0]
    state.velocities[free] = (0.0, 0.3, 0.0)
    control = Control(np.zeros((model.vertex_count, 3)))
    for _ in range(96):
        solver.step(model, state, 1.0 / 96, control)
    assert state.velocities[free, 1] == pytest.approx(0.3 * math.exp(-rate), rel=1e-6)


@pytest.mark.parametrize("solver", ["xpbd", "verlet"])
def test_tethers_let_grips_that_pull_a_cloth_apart_stretch_it_evenly(solver: str) -> None:
    """The grips of `pulled_banner` move apart by 30 % of the cloth's width: no shape keeps every
    vertex within its rest distance along the mesh of both grips, and the tethers held all but
    the row next to one grip, whose springs took the whole stretch (9.4x on a 32 x 20 flag).
    Each vertex's limits now grow by what its two grips' separation asks for
    (`sweep_kernels.release_tethers`): the springs across the cloth share the 1.3x, as they do
    under `implicit` (no tethers)."""
    from pipeline.build import build_simulation
    from pipeline.recipe import parse_recipe

    mesh, text = pulled_banner(solver)
    built = build_simulation(parse_recipe(text), mesh)
    last = list(simulate(built.model, built.scene, built.settings))[-1]
    x = last.welded_positions
    assert x[:, 0].max() - x[:, 0].min() == pytest.approx(1.3, abs=0.01)  # the grips' own spread
    assert last.max_stretch < 1.6
