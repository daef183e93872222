"""Pins: keyframes, hard pins following animated targets, soft pins, pin weights from a vertex property."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from factories import grid_sheet

from meshdeform.scene.pins import SOFT_PIN_RATE, Keyframe, Keyframes, SoftPins
from meshdeform.simulate import simulate
from pipeline.build import build_simulation
from pipeline.recipe import parse_recipe

pytestmark = pytest.mark.usefixtures("one_numba_thread")


def test_keyframes_interpolate_hold_and_carry_channels_forward() -> None:
    keys = Keyframes(
        [
            Keyframe(1.0, translate=(0, 0, 0)),
            Keyframe(2.0, translate=(2, 0, 0), scale=(2, 2, 2)),
            Keyframe(3.0, rotate=(0, 0, 90)),  # translate and scale carry forward from the key before
        ],
        pivot=(1, 0, 0),
    )
    p = np.array([[2.0, 0.0, 0.0]])
    np.testing.assert_allclose(keys.apply(p, 0.0), p)  # before the first key: held
    np.testing.assert_allclose(keys.apply(p, 1.5), [[1 + 1 + 1.5, 0, 0]])  # half way: T=1, S=1.5
    np.testing.assert_allclose(keys.apply(p, 3.0), [[1 + 2, 2, 0]], atol=1e-12)  # pivot + T + R(90) * 2 * (1, 0, 0)
    np.testing.assert_allclose(keys.apply(p, 9.0), keys.apply(p, 3.0))  # after the last: held
    q = np.random.default_rng(0).normal(size=(5, 3))
    np.testing.assert_allclose(keys.inverse(keys.apply(q, 2.4), 2.4), q, atol=1e-12)


def test_looping_keyframes_repeat() -> None:
    keys = Keyframes([Keyframe(0.0, rotate=(0, 0, 0)), Keyframe(1.0, rotate=(0, 0, 30))], pivot=(0, 0, 0), loop=True)
    p = np.array([[1.0, 0.0, 0.0]])
    np.testing.assert_allclose(keys.apply(p, 1.25), keys.apply(p, 0.25))


SWING = """
[simulation]
solver = "verlet"
fps = 24
frames = 24
substeps = 4

[[pins]]
select = { box = { min = [0, 0.99, 0], max = [1, 1, 1] }, relative = true }
pivot = [0, 1, 0]
animate = [
  { time = 0.0 },
  { time = 0.5, translate = [0.4, 0, 0] },
  { time = 1.0, translate = [0.4, 0, 0], rotate = [0, 90, 0] },
]
"""


def test_hard_pins_follow_their_animation_exactly() -> None:
    built = build_simulation(parse_recipe(SWING), grid_sheet(6, 5))
    pinned = built.model.pinned_input_mask()
    assert pinned.sum() == 6
    rest = grid_sheet(6, 5).positions[pinned]
    for frame in simulate(built.model, built.scene, built.settings):
        t = frame.time
        shift = 0.4 * min(t / 0.5, 1.0)
        angle = np.deg2rad(90.0 * min(max(t - 0.5, 0.0) / 0.5, 1.0))
        local = rest - [0, 1, 0]
        rotated = np.stack([np.cos(angle) * local[:, 0], local[:, 1], -np.sin(angle) * local[:, 0]], axis=1)
        np.testing.assert_allclose(frame.positions[pinned], rotated + [shift, 1, 0], atol=1e-12)


SOFT = """
[simulation]
solver = "verlet"
fps = 24
frames = 48
substeps = 8
damping = 0.95

[[pins]]
select = {{ box = {{ min = [0, 0, 0], max = [1, 1, 1] }}, relative = true }}
stiffness = {stiffness}
damping = 0.5
{animate}
"""


def test_soft_pin_sags_g_over_k_below_its_target() -> None:
    built = build_simulation(parse_recipe(SOFT.format(stiffness=0.5, animate="")), grid_sheet(5))
    assert not built.model.pinned.any() and isinstance(built.scene.constraints[0], SoftPins)
    frames = list(simulate(built.model, built.scene, built.settings))
    sag = grid_sheet(5).positions[:, 1] - frames[-1].positions[:, 1]
    k = SOFT_PIN_RATE * 0.5 / (1 - 0.5)
    np.testing.assert_allclose(sag, 9.81 / k, rtol=0.05)


def test_soft_pin_follows_its_animated_target_within_the_expected_distance() -> None:
    animate = "animate = [ { time = 0.0 }, { time = 1.0, translate = [0.5, 0, 0] }, { time = 2.0 } ]"
    built = build_simulation(parse_recipe(SOFT.format(stiffness=0.9, animate=animate)), grid_sheet(5))
    pin = built.scene.constraints[0]
    k = SOFT_PIN_RATE * 0.9 / (1 - 0.9)
    worst = 0.0
    for frame in simulate(built.model, built.scene, built.settings):
        gap = np.linalg.norm(frame.welded_positions[pin.indices] - pin.targets(frame.time), axis=1).max()
        worst = max(worst, gap)
    # gravity sag g/k plus the lag of a spring of that stiffness behind a target moving at 0.5 m/s
    assert worst < 2 * 9.81 / k + 0.5 / np.sqrt(k)
    assert worst > 0.5 * 9.81 / k


def test_pin_weights_from_a_vertex_property_scale_the_stiffness() -> None:
    mesh = grid_sheet(4)
    weight = np.zeros(16)
    weight[[0, 1]] = 1.0  # hard
    weight[[2, 3]] = 0.5  # soft
    mesh = replace(mesh, vertex_properties={"pin": weight})
    recipe = parse_recipe(
        "[simulation]\nsolver = 'verlet'\n[[pins]]\nselect = { attribute = { name = 'pin' } }\nweight = 'pin'\n"
    )
    built = build_simulation(recipe, mesh)
    assert np.flatnonzero(built.model.pinned_input_mask()).tolist() == [0, 1]
    soft = built.scene.constraints[0]
    assert sorted(built.model.representative[soft.indices].tolist()) == [2, 3]
    np.testing.assert_allclose(soft.rate, SOFT_PIN_RATE)  # s = 1 * 0.5 -> k = rate * 0.5 / 0.5
