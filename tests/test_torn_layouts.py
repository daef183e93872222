"""After a tear the position-based solvers derive the new spring order from the old one.

Sorting a fresh layout costs about 20 substeps of work at 128 x 128; a tearing run may change
topology every frame. The inherited layout must keep what the kernels rely on: every spring
once, slabs that share no vertex, kernel numbering consistent with the spring ends. And the
per-spring records and reused buffers must not change any result.
"""

from __future__ import annotations

import numpy as np
import pytest

from meshdeform.mesh import grid_mesh
from meshdeform.model import SpringModel, State
from meshdeform.simulate import Scene, Settings, simulate
from meshdeform.solvers import Control, common, make_solver, solver_class
from meshdeform.solvers.layout import SpringLayout, inherited_layout, spring_layout
from meshdeform.tearing import Tearer, TearRegion, TearSettings

N = 32  # 32 x 32 has more springs than AUTO_PARALLEL_SPRINGS: two slabs and a separator


def pulled_apart() -> tuple[SpringModel, Scene]:
    """A cloth held at its left and right edges pulled apart; it may tear in a middle band."""
    from meshdeform.scene.pins import HardPinMotion, Keyframe, Keyframes

    mesh = grid_mesh(N, N)
    x = mesh.positions[:, 0]
    left, right = x < 1e-9, x > 1 - 1e-9
    model = SpringModel.from_mesh(mesh, pinned_input=left | right)
    band = (x > 0.3) & (x < 0.7)
    apart = [
        (np.flatnonzero(side), Keyframes([Keyframe(0.0, (0, 0, 0)), Keyframe(1.0, (s * 0.6, 0, 0))], (0, 0, 0)))
        for side, s in ((left, -1), (right, 1))
    ]
    tearer = Tearer(mesh, model, TearSettings.from_regions(model, [TearRegion(mask=band, max_stretch=1.3)]))
    return model, Scene(pin_motion=HardPinMotion(model, apart), tearing=tearer)


def check_layout(lay: SpringLayout, model: SpringModel) -> None:
    """What the kernels rely on: a permutation of the springs, slabs sharing no vertex, ends in kernel numbering."""
    springs = np.asarray(model.springs, dtype=np.int64)
    assert np.array_equal(np.sort(lay.order), np.arange(springs.shape[0]))
    assert np.array_equal(lay.a, springs[lay.order, 0]) and np.array_equal(lay.b, springs[lay.order, 1])
    assert np.array_equal(lay.rest, np.asarray(model.rest_lengths)[lay.order])
    assert np.array_equal(np.sort(lay.vertex_order), np.arange(model.vertex_count))
    assert np.array_equal(lay.vertex_rank[lay.vertex_order], np.arange(model.vertex_count))
    assert np.array_equal(lay.vertex_order[lay.ends["a"]], lay.a)
    assert np.array_equal(lay.vertex_order[lay.ends["b"]], lay.b)
    assert lay.offsets[0] == 0 and lay.offsets[-1] == springs.shape[0] and (np.diff(lay.offsets) >= 0).all()
    owner = np.full(model.vertex_count, -1)
    for p in range(lay.parts):
        lo, hi = lay.offsets[p], lay.offsets[p + 1]
        touched = np.unique(np.concatenate([lay.a[lo:hi], lay.b[lo:hi]]))
        assert (owner[touched] == -1).all(), f"slab {p} shares a vertex with an earlier slab"
        owner[touched] = p


@pytest.mark.parametrize("solver", ["xpbd", "verlet"])
def test_torn_models_inherit_their_layout(solver: str, monkeypatch: pytest.MonkeyPatch) -> None:
    built: list[SpringModel] = []
    inherited: list[tuple[SpringLayout, SpringModel]] = []
    fresh = common.spring_layout

    def counting_fresh(model: SpringModel, parts: int) -> SpringLayout:
        built.append(model)
        return fresh(model, parts)

    def recording_inherited(previous, model, index_map, parent):
        lay = inherited_layout(previous, model, index_map, parent)
        assert lay is not None, "a torn model did not descend from its predecessor"
        # every spring sits where its parent sat: parents' places in the previous order ascend
        place = np.empty_like(previous.order)
        place[previous.order] = np.arange(previous.order.shape[0])
        assert (np.diff(place[np.asarray(parent)[lay.order]]) >= 0).all()
        inherited.append((lay, model))
        return lay

    monkeypatch.setattr(common, "spring_layout", counting_fresh)
    monkeypatch.setattr(common, "inherited_layout", recording_inherited)
    model, scene = pulled_apart()
    settings = Settings(solver=solver, frames=20, substeps=8, options=solver_class(solver).options_class(tethers=None))
    frames = list(simulate(model, scene, settings))
    assert frames[-1].pieces >= 2 and len(inherited) >= 2
    assert built == [model]  # only the untorn model was sorted afresh
    assert inherited[0][0].parts == 2
    for lay, torn in inherited:
        check_layout(lay, torn)


def test_a_model_not_descending_from_the_layout_is_refused() -> None:
    model = SpringModel.from_mesh(grid_mesh(8, 8))
    lay = spring_layout(model, 0)
    same = np.arange(model.vertex_count)
    parent = np.arange(model.spring_count)
    assert inherited_layout(lay, model, same, parent) is not None
    assert inherited_layout(lay, model, same, np.roll(parent, 1)) is None  # springs joining other vertices
    assert inherited_layout(lay, model, same[::-1].copy(), parent) is None  # kept vertices renumbered


@pytest.mark.parametrize("solver", ["xpbd", "verlet"])
def test_buffers_kept_from_a_larger_model_change_nothing(solver: str) -> None:
    """A solver reuses its scratch and records across models: stale contents must never be read."""
    big = SpringModel.from_mesh(grid_mesh(40, 40))
    small_mesh = grid_mesh(30, 30)
    pinned = np.zeros(small_mesh.vertex_count, dtype=bool)
    pinned[[870, 899]] = True
    small = SpringModel.from_mesh(small_mesh, pinned_input=pinned)
    dt = 1.0 / 24 / 8

    def run(instance: object, model: SpringModel) -> bytes:
        state = State.at_rest(model)
        control = Control(np.tile([0.0, -9.81, 0.0], (model.vertex_count, 1)))
        for _ in range(8):
            instance.step(model, state, dt, control)
        return state.positions.tobytes() + state.velocities.tobytes()

    used = make_solver(solver)
    big_state = State.at_rest(big)
    big_state.positions += 0.01 * np.random.default_rng(5).standard_normal(big_state.positions.shape)
    used.step(big, big_state, dt, Control(np.zeros((big.vertex_count, 3))))
    assert run(used, small) == run(make_solver(solver), small)
