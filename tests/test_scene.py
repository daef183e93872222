"""The scene's contracts: which forces and constraints follow a tear (`Remappable`), each once."""

from __future__ import annotations

import numpy as np
from factories import grid_cloth

from meshdeform.model import SpringModel, State
from meshdeform.scene import (
    Box,
    Collider,
    Force,
    Impact,
    NearestPinTethers,
    Plane,
    Plasticity,
    Pressure,
    Remappable,
    Scene,
    SoftPins,
    Wind,
    gravity_vector,
)


def test_every_item_with_per_vertex_data_is_remappable_and_listed_once() -> None:
    model = grid_cloth(4).model
    plastic = Plasticity(model, stiffness=10.0, yield_distance=0.01, rate=1.0)
    wind = Wind((1.0, 0.0, 0.0))
    impact = Impact(time=0.0, radius=0.5, strength=1.0, duration=0.1, point=(0, 0, 1))
    pressure = Pressure(model, 10.0)
    tethers = NearestPinTethers(model, np.array([0]))
    soft = SoftPins(np.array([0]), model.rest_positions[:1], 0.5)
    ground = Collider(Plane((0, -1, 0), (0, 1, 0)))
    box = Collider(Box((-1, -1, -1), (1, 1, 1)))
    scene = Scene(forces=[plastic, wind, pressure, impact], constraints=[plastic, tethers, soft, ground, box])
    assert scene.remappables() == [plastic, wind, impact, tethers, soft, ground, box]
    assert not isinstance(pressure, Remappable)


def test_a_force_written_elsewhere_is_remappable_by_its_method() -> None:
    class Drift(Force):  # a Force by subclassing, remappable by its method alone
        def accumulate(self, model: SpringModel, state: State, time: float, dt: float, out: np.ndarray) -> None:
            out[:, 0] += 1.0

        def remap(self, model: SpringModel, index_map: np.ndarray) -> None:
            pass

    class Push(Force):
        def accumulate(self, model: SpringModel, state: State, time: float, dt: float, out: np.ndarray) -> None:
            out[:, 1] += 1.0

    drift, push = Drift(), Push()
    assert Scene(forces=[drift, push]).remappables() == [drift]


def test_default_gravity_points_down_y() -> None:
    assert Scene().gravity == gravity_vector("y") == (0.0, -9.81, 0.0)
