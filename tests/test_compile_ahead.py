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
from meshdeform.solvers.implicit import cholesky
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


@pytest.mark.parametrize("vertices", [256 * 256, cholesky.OWN_FACTOR_ROWS - 1])
def test_a_large_implicit_run_s_thread_compiles_its_factor_s_kernels_first(vertices: int, monkeypatch) -> None:
    """From `cholesky.OWN_FACTOR_ROWS` vertices the implicit solver factorises with its own
    Cholesky factor, whose kernels the run's first step reaches first: the thread compiles them
    before its stand-in's frame; below, not at all."""
    calls: list[str] = []
    monkeypatch.setattr(cholesky, "compile_kernels", lambda: calls.append("factor"))
    stepped = compile_ahead._step_stand_in
    monkeypatch.setattr(compile_ahead, "_step_stand_in", lambda *args: (calls.append("stand-in"), stepped(*args)))
    thread = compile_ahead.start(Settings(solver="implicit", frames=1), Scene(), vertices)
    assert thread is not None
    thread.join()
    assert calls == (["factor", "stand-in"] if vertices >= cholesky.OWN_FACTOR_ROWS else ["stand-in"])


def test_the_factor_s_kernels_compile_on_a_split_matrix() -> None:
    """`cholesky.compile_kernels` runs every kernel `kernels_cached` asks the cache for, the
    separator's included (its 6 x 6 grid is split in two halves and a separator)."""
    cholesky.compile_kernels()
    assert all(kernel.signatures for kernel in cholesky.KERNELS)
    assert cholesky.kernels_cached()


def test_the_stand_in_s_distant_shapes_are_of_the_kind_they_stand_in_for() -> None:
    """Each collider kind but the plane has a shape far above the stand-in, of that kind: the
    stand-in's ground then runs in the contact pipeline the run's colliders compile."""
    import meshdeform.contact.collider_kernels as ck
    from meshdeform.scene.colliders import collider_kinds

    assert set(compile_ahead._DISTANT) == {ck.SPHERE, ck.CAPSULE, ck.BOX, ck.MESH}
    for kind, shape in compile_ahead._DISTANT.items():
        assert collider_kinds([Collider(shape())]) == {kind}
        assert shape().bounds()[0][1] >= 99.0  # far above the 1 m stand-in


def _self_collision_scene() -> Scene:
    from meshdeform.contact.self_collision import SelfCollision

    return Scene(self_collision=SelfCollision())


def test_a_compiler_process_starts_only_where_it_can_help(monkeypatch) -> None:
    """Self-collision on or colliders, their kernels neither compiled nor cached, two cores and
    two Numba threads."""
    import numba

    monkeypatch.setattr(compile_ahead, "available", lambda kernel: False)
    monkeypatch.setattr(compile_ahead.HOST, "cores", lambda: 2.0)
    monkeypatch.setattr(numba, "get_num_threads", lambda: 2)
    assert compile_ahead.start_compiler(Settings(), Scene(), 100) is None  # neither self-collision nor colliders
    # a large implicit run whose own factor's kernels are not cached: the helper compiles the
    # step's kernels while this process's thread compiles the factor's (`start`)
    monkeypatch.setattr(cholesky, "kernels_cached", lambda: False)
    process = compile_ahead.start_compiler(Settings(solver="implicit"), Scene(), 256 * 256)
    assert process is not None
    compile_ahead.stop_compiler(process)
    assert compile_ahead.start_compiler(Settings(solver="implicit"), Scene(), cholesky.OWN_FACTOR_ROWS - 1) is None
    monkeypatch.setattr(cholesky, "kernels_cached", lambda: True)
    assert compile_ahead.start_compiler(Settings(solver="implicit"), Scene(), 256 * 256) is None
    process = compile_ahead.start_compiler(Settings(), Scene(constraints=[Collider(Plane((0, 0, 0), (0, 1, 0)))]), 100)
    assert process is not None  # the solver's kernels, while this process compiles the ground's
    compile_ahead.stop_compiler(process)
    assert process.poll() is not None
    monkeypatch.setattr(numba, "get_num_threads", lambda: 1)  # a batch job's share: one core
    assert compile_ahead.start_compiler(Settings(), _self_collision_scene(), 100) is None
    monkeypatch.setattr(numba, "get_num_threads", lambda: 2)
    monkeypatch.setattr(compile_ahead.HOST, "cores", lambda: 1.0)
    assert compile_ahead.start_compiler(Settings(), _self_collision_scene(), 100) is None
    monkeypatch.setattr(compile_ahead.HOST, "cores", lambda: 2.0)
    monkeypatch.setattr(compile_ahead, "available", lambda kernel: True)  # a warm cache
    assert compile_ahead.start_compiler(Settings(), _self_collision_scene(), 100) is None


def test_the_compiler_process_fills_an_empty_cache_with_self_collision_s_kernels(tmp_path, monkeypatch) -> None:
    """The process, started on an empty NUMBA_CACHE_DIR, ends by itself having written
    self-collision's search kernels there (the files a run started next loads instead of compiling)."""
    import numba

    cache = tmp_path / "numba-cache"
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(cache))
    monkeypatch.setattr(compile_ahead, "available", lambda kernel: False)
    monkeypatch.setattr(compile_ahead.HOST, "cores", lambda: 2.0)
    monkeypatch.setattr(numba, "get_num_threads", lambda: 2)
    process = compile_ahead.start_compiler(Settings(), _self_collision_scene(), 100)
    assert process is not None
    assert process.wait(timeout=300) == 0
    written = {path.name.rsplit("-", 1)[0] for path in cache.rglob("*.nbi")}  # "module.function-line.py311.nbi"
    searches = {"self_kernels.vf_candidates", "self_kernels.ee_candidates_in_cells", "self_kernels.project_proximity"}
    assert searches <= written, sorted(written)


def test_a_job_stops_a_compiler_process_still_running(tmp_path, monkeypatch) -> None:
    """run_job ends the compiling process when the run is done (its cache files are whole)."""
    import subprocess
    import sys

    from pipeline.job import run_job
    from pipeline.recipe import load_recipe

    started: list[subprocess.Popen[bytes]] = []

    def sleeper(settings, scene, vertices) -> subprocess.Popen[bytes]:
        process = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
        started.append(process)
        return process

    monkeypatch.setattr(compile_ahead, "start_compiler", sleeper)
    run_job(write_grid(tmp_path / "sheet.obj", 6, 6), load_recipe(None), tmp_path / "out")
    assert len(started) == 1 and started[0].poll() is not None


def test_colliders_compiled_ahead_are_the_builds_the_run_calls() -> None:
    """`compile_colliders` compiles each collider kind's contact build, in the scene's company, with
    the signature the run's substeps call: the run compiles none of its own."""
    import meshdeform.contact.collider_kernels as ck
    from meshdeform.scene.colliders import Box

    model = grid_cloth(8, plane="xz", size=1.0, centred=True, offset=(0.0, 0.2, 0.0)).model
    ground = Collider(Plane((0.0, 0.0, 0.0), (0.0, 1.0, 0.0)), friction=0.3)
    bar = Collider(Box((-0.6, 0.1, -0.02), (0.6, 0.12, 0.02)), friction=0.3)
    scene = Scene(constraints=[ground, bar])
    compile_ahead.compile_colliders(scene)
    compiled = set(ck.contact_box.signatures)
    assert compiled
    for _ in simulate(model, scene, Settings(frames=3)):
        pass
    assert set(ck.contact_box.signatures) == compiled
    assert ck.contact_kernel(ck.PLANE, ground.company) is ck.contact_box


_SELF_COLLISION_FIRST = """
import importlib, json
from numba.core.registry import CPUDispatcher
from meshdeform.simulate import Settings
from pipeline import compile_ahead

def signatures():
    out = {}
    for name in ("meshdeform.contact.self_kernels", "meshdeform.contact.broad_phase"):
        for key, kernel in vars(importlib.import_module(name)).items():
            if isinstance(kernel, CPUDispatcher):
                out[name + "." + key] = sorted(map(str, kernel.signatures))
    return out

compile_ahead.compile_self_collision()
first = signatures()
compile_ahead._step_stand_in(Settings(solver="implicit"), True, True, frozenset())
print(json.dumps([first, signatures()]))
"""


def test_the_helper_s_self_collision_pass_compiles_what_a_stand_in_s_frame_runs() -> None:
    """`compile_ahead.compile_self_collision` (the helper process's first work where a run has
    self-collision) reaches every self-collision and broad-phase kernel, in the argument types,
    that a stand-in's frame with self-collision then runs: the frame adds no signature. In a
    fresh interpreter, whose dispatchers hold only what it ran (compiled or loaded from the
    cache), not what earlier tests here did."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    root = Path(compile_ahead.__file__).resolve().parents[1]
    done = subprocess.run(
        [sys.executable, "-c", _SELF_COLLISION_FIRST], cwd=root, capture_output=True, text=True, timeout=600, check=True
    )
    first, after = json.loads(done.stdout.strip().splitlines()[-1])
    assert sum(map(len, first.values())) >= 10  # the search, proximity and continuous check ran
    assert {name: sigs for name, sigs in after.items() if sigs != first.get(name, [])} == {}
