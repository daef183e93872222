"""The compile-ahead stand-in (`pipeline.compile_ahead`): a background thread for solvers with
serial kernels only, that finishes, and a run beside it gives the bytes of a run alone."""

from __future__ import annotations

import numpy as np
import pytest
from factories import TOP_CORNERS, grid_cloth

from meshdeform.scene import Scene
from meshdeform.scene.colliders import Collider, Plane
from meshdeform.simulate import Settings, simulate
from meshdeform.solvers import SOLVERS, solver_class
from pipeline import compile_ahead


@pytest.mark.parametrize("name", sorted(SOLVERS))
def test_a_stand_in_runs_beside_solvers_without_parallel_builds_only(name: str) -> None:
    thread = compile_ahead.start(Settings(solver=name), Scene())
    if solver_class(name).parallel_kernels:  # xpbd, verlet: never two launchers of parallel kernels
        assert thread is None
    else:
        assert thread is not None
        thread.join(timeout=120)
        assert not thread.is_alive()


def test_a_run_beside_the_stand_in_gives_the_bytes_of_a_run_alone() -> None:
    model = grid_cloth(12, pins=TOP_CORNERS, plane="xz").model
    ground = Collider(Plane((0.0, -0.4, 0.0), (0.0, 1.0, 0.0)), friction=0.3)
    scene, settings = Scene(constraints=[ground]), Settings(frames=12)
    alone = np.array([f.welded_positions for f in simulate(model, scene, settings)])
    thread = compile_ahead.start(settings, scene)
    beside = np.array([f.welded_positions for f in simulate(model, scene, settings)])
    assert thread is not None
    thread.join(timeout=120)
    assert alone.tobytes() == beside.tobytes()
