"""The compile-ahead stand-in (`pipeline.compile_ahead`): a background thread for solvers with
serial kernels and large runs only, that finishes, that a job waits for, and a run beside it
gives the bytes of a run alone."""

from __future__ import annotations

import numpy as np
import pytest
from factories import TOP_CORNERS, grid_cloth, write_grid

from meshdeform.scene import Scene
from meshdeform.scene.colliders import Collider, Plane
from meshdeform.simulate import Settings, simulate
from meshdeform.solvers import SOLVERS, solver_class
from pipeline import compile_ahead


@pytest.mark.parametrize("name", sorted(SOLVERS))
def test_a_stand_in_runs_beside_solvers_without_parallel_builds_only(name: str) -> None:
    assert compile_ahead.start(Settings(solver=name), Scene(), compile_ahead.MIN_VERTICES - 1) is None  # too small
    thread = compile_ahead.start(Settings(solver=name), Scene(), compile_ahead.MIN_VERTICES)
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
    thread = compile_ahead.start(settings, scene, compile_ahead.MIN_VERTICES)
    beside = np.array([f.welded_positions for f in simulate(model, scene, settings)])
    assert thread is not None
    thread.join(timeout=120)
    assert alone.tobytes() == beside.tobytes()


def test_a_job_that_fails_after_starting_the_stand_in_waits_for_it(tmp_path, monkeypatch) -> None:
    """run_job joins the stand-in whatever happens: a process that ended while it still compiled or
    held a factorisation crashed or printed nanobind's leak report on its way out."""
    import threading

    import pipeline.estimate
    from pipeline.estimate import InsufficientDiskSpace
    from pipeline.job import run_job
    from pipeline.recipe import load_recipe

    def no_room(estimated_bytes: int | None, folder) -> None:
        raise InsufficientDiskSpace(f"{folder}: no room (a test)")

    monkeypatch.setattr(pipeline.estimate, "require_disk_space", no_room)
    mesh = write_grid(tmp_path / "sheet.obj", 128, 128)  # compile_ahead.MIN_VERTICES: it gets a stand-in
    with pytest.raises(InsufficientDiskSpace):
        run_job(mesh, load_recipe(None), tmp_path / "out")
    assert not [t for t in threading.enumerate() if t.name == "meshdeform-compile-ahead"]


def test_the_stand_in_s_distant_shapes_are_of_the_kind_they_stand_in_for() -> None:
    """Each collider kind but the plane has a shape far above the stand-in, of that kind: the
    stand-in's ground then runs in the contact pipeline the run's colliders compile."""
    import meshdeform.contact.collider_kernels as ck
    from meshdeform.scene.colliders import collider_kinds

    assert set(compile_ahead._DISTANT) == {ck.SPHERE, ck.CAPSULE, ck.BOX, ck.MESH}
    for kind, shape in compile_ahead._DISTANT.items():
        assert collider_kinds([Collider(shape())]) == {kind}
        assert shape().bounds()[0][1] >= 99.0  # far above the 1 m stand-in
