"""Compile ahead: a job's kernels compiled while the job prepares its run.

A process with an empty Numba cache (a fresh CI runner, container or Dask worker) compiles every
kernel a run uses on first use, seconds of work; meanwhile the job's own
preparation (the solver's set-up and factorisation at the first step, the exporters, the rest
frame) would wait or be waited for. `start` steps a small stand-in cloth with the run's settings in
a background thread, so that the compiling overlaps that preparation: Numba compiles under one
lock, and a kernel the run reaches while the stand-in compiles it is waited for, not compiled
twice. Its results are thrown away; the run's own bytes do not depend on it.

The stand-in is a 4 x 4 sheet lying flat, pinned at two corners, calm where the run's scene is calm
(`meshdeform.simulate.calm`: the same steps a frame, `steps_for`), otherwise lying on a ground
collider (the contact steps and their kernels) with a shape of each other collider kind of the run
far above it (so that the ground runs in the contact pipeline the run compiles), with
self-collision where the run has it. Solvers
that launch Numba's parallel builds (`Solver.parallel_kernels`: xpbd, verlet) get no stand-in:
under Numba's workqueue threading layer two threads must not launch parallel kernels at once.
Nor do runs of fewer than `MIN_VERTICES` vertices: their own set-up is too short to hide the
compiling behind, and with a warm cache the stand-in's steps are only a cost (`benchmarks/startup.py`).

Self-collision's kernels take a run with an empty cache longer than all the others together (about
12 of the 24 s of one frame of a sheet dropped on a sphere), and a collider's contact build 6-10 s;
a thread cannot share that work: Numba compiles under one lock. `start_compiler` starts a second
process instead (`python -m pipeline.compile_ahead SOLVER [--self-collision]`), which compiles
self-collision's kernels where the run has it (`compile_self_collision`: the run reaches them
last) and then steps a stand-in without colliders (the solver's kernels) into Numba's disk cache
(NUMBA_CACHE_DIR, inherited) on the other core, while this process compiles the colliders' builds
first (`compile_colliders`, before the run's first substep): when the run reaches the solver and
self-collision it loads from the cache what the helper has compiled by then (its files are
written whole and renamed into place) and compiles the rest itself. Only where that
can help: self-collision or colliders whose kernels are in neither this process nor the cache, two
cores and two Numba threads for this job (a batch of as many jobs as cores gives each one). The job
stops the helper when it ends.

A large run's own kernels (`Solver.large_kernels`: implicit's Cholesky factor of its own from
`cholesky.OWN_FACTOR_ROWS` vertices, about 3 s to compile) are reached by the first step before
anything else: the `start` thread compiles them first, and where they are not cached the helper
process is started for the solver's step kernels meanwhile.
"""

from __future__ import annotations

import contextlib
import subprocess
import sys
import threading
from collections.abc import Callable
from pathlib import Path

import numba
import numpy as np

from meshdeform.contact import collider_kernels as ck
from meshdeform.contact import self_kernels
from meshdeform.contact.self_collision import SelfCollision
from meshdeform.mesh import grid_mesh
from meshdeform.model import SpringModel, State
from meshdeform.scene import Scene
from meshdeform.scene.colliders import (
    Box,
    Capsule,
    Collider,
    Plane,
    Shape,
    Sphere,
    TriangleMesh,
    collider_kinds,
    share_company,
)
from meshdeform.simulate import Settings, calm, simulate
from meshdeform.solvers import solver_class
from meshdeform.solvers.base import LargeKernels
from meshdeform.solvers.dispatch import HOST, available

__all__ = ["compile_colliders", "compile_self_collision", "start", "start_compiler", "stop_compiler"]

#: vertices along each side of the stand-in sheet (1 m square)
STAND_IN_SIDE = 4
#: the fewest vertices of a run that gets a stand-in (a 128 x 128 sheet)
MIN_VERTICES = 128 * 128
#: a shape of each collider kind but the plane, 100 m above the stand-in (never touched)
_DISTANT: dict[int, Callable[[], Shape]] = {
    ck.SPHERE: lambda: Sphere((0.0, 100.0, 0.0), 0.5),
    ck.CAPSULE: lambda: Capsule((0.0, 100.0, 0.0), (1.0, 100.0, 0.0), 0.5),
    ck.BOX: lambda: Box((0.0, 100.0, 0.0), (1.0, 101.0, 1.0)),
    ck.MESH: lambda: TriangleMesh(
        np.array([[0.0, 100.0, 0.0], [1.0, 100.0, 0.0], [0.0, 101.0, 0.0], [0.0, 100.0, 1.0]]),
        np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]),
    ),
}


def start(settings: Settings, scene: Scene, vertices: int) -> threading.Thread | None:
    """A started background thread stepping the stand-in for `settings` and `scene` of a run of
    `vertices` (welded) vertices (join it before the process ends, so that Numba's cache files
    are complete), or None for a solver with parallel builds or a run under `MIN_VERTICES`."""
    solver = solver_class(settings.solver)
    if solver.parallel_kernels or vertices < MIN_VERTICES:
        return None
    large = solver.large_kernels(vertices)
    thread = threading.Thread(
        target=_compile_ahead,
        args=(settings, calm(scene), scene.self_collision is not None, collider_kinds(scene.constraints), large),
        name="meshdeform-compile-ahead",
        daemon=True,
    )
    thread.start()
    return thread


def _compile_ahead(
    settings: Settings, calm_scene: bool, self_collision: bool, kinds: frozenset[int], large: LargeKernels | None
) -> None:
    """The background thread's work: the solver's kernels for a large run first (`large`, which
    the run's first step reaches before the kernels the stand-in's steps compile), then one
    frame of the stand-in (`_step_stand_in`)."""
    if large is not None:
        with contextlib.suppress(Exception):  # an optimisation only: the run reports its own errors
            large.compile()
    _step_stand_in(settings, calm_scene, self_collision, kinds)


def _step_stand_in(settings: Settings, calm_scene: bool, self_collision: bool, kinds: frozenset[int]) -> None:
    """One frame of the stand-in (module docstring); `kinds`: the run's collider shape kinds,
    each but the plane's given a shape far above the stand-in (`_DISTANT`), so that its ground
    runs in the compiled contact pipeline the run's colliders use (`collider_kernels.contact_kernel`)."""
    side = STAND_IN_SIDE
    pinned = np.zeros(side * side, dtype=bool)
    pinned[[side * (side - 1), side * side - 1]] = True
    model = SpringModel.from_mesh(grid_mesh(side, side, plane="xz"), pinned_input=pinned)
    constraints = [] if calm_scene else _stand_in_colliders(kinds | {ck.PLANE})
    scene = Scene(constraints=constraints, self_collision=SelfCollision() if self_collision else None)
    try:
        for _ in simulate(model, scene, settings.with_frames(1)):
            pass
    except Exception:  # an optimisation only: the run reports its own errors
        return


def _stand_in_colliders(kinds: frozenset[int]) -> list[Collider]:
    """A collider of each shape kind in `kinds`, in kind order: the plane as a ground just below the
    stand-in sheet, the others far above it (`_DISTANT`)."""
    return [
        Collider(Plane((0.0, -0.001, 0.0), (0.0, 1.0, 0.0)) if kind == ck.PLANE else _DISTANT[kind]())
        for kind in sorted(kinds)
    ]


def start_compiler(settings: Settings, scene: Scene, vertices: int) -> subprocess.Popen[bytes] | None:
    """A started process compiling kernels into Numba's disk cache for a run of `settings` and
    `scene` on `vertices` vertices (module docstring): self-collision's where it is on and they
    are not cached, and the solver's where the run's colliders' contact build is not cached
    either (this process then compiles that build first: `compile_colliders`), or the large
    run's kernels (`Solver.large_kernels`) are not (the `start` thread compiles those first);
    None where it cannot help. Stop it with `stop_compiler` when the job ends."""
    kinds = collider_kinds(scene.constraints)
    self_collision = scene.self_collision is not None and not available(self_kernels.vf_candidates)
    colliders = not all(available(ck.contact_kernel(kind, kinds)) for kind in kinds)
    large = solver_class(settings.solver).large_kernels(vertices)
    large_uncached = large is not None and vertices >= MIN_VERTICES and not large.cached()
    if not (self_collision or colliders or large_uncached) or numba.get_num_threads() < 2 or HOST.cores() < 2:
        return None
    # started where this process found the package, whose folder then comes first on the child's
    # `sys.path` (`python -m` puts its working folder there): the same code as this process runs
    root = Path(__file__).resolve().parents[1]
    flags = [SELF_COLLISION_FLAG] if scene.self_collision is not None else []
    return subprocess.Popen(
        [sys.executable, "-m", "pipeline.compile_ahead", settings.solver, *flags],
        cwd=root, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip


def compile_colliders(scene: Scene) -> None:
    """Compiles the contact builds of `scene`'s colliders in this process now, before the run's
    first substep reaches them (while a `start_compiler` process compiles the solver's kernels,
    which the substep reaches first): one substep of a collider of each of the scene's kinds,
    in the same company (`share_company`), on a resting stand-in sheet."""
    kinds = collider_kinds(scene.constraints)
    if not kinds:
        return
    side = STAND_IN_SIDE
    model = SpringModel.from_mesh(grid_mesh(side, side, plane="xz"))
    colliders = _stand_in_colliders(kinds)
    share_company(colliders)
    state = State.at_rest(model)
    dt = 1.0 / 192.0
    for collider in colliders:
        collider.project(model, state, dt, dt)


def stop_compiler(process: subprocess.Popen[bytes]) -> None:
    """Ends a `start_compiler` process still running (its cache files are whole: Numba writes
    each under another name and renames it)."""
    if process.poll() is None:
        process.terminate()
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


#: the `start_compiler` process's argument for a run with self-collision
SELF_COLLISION_FLAG = "--self-collision"


def _compile_in_process(arguments: list[str]) -> None:
    """The `start_compiler` process's work (arguments: the solver's name, then
    `SELF_COLLISION_FLAG` or nothing): self-collision's kernels first where the flag asks for
    them (`compile_self_collision`), then one frame of the stand-in without colliders, with
    self-collision where the flag asks for it (the solver's kernels).

    Self-collision first: a run with colliders compiles their contact build before it reaches its
    solver (`compile_colliders`), and one without reaches its solver at once, so either way the
    run reaches self-collision last, and compiled its solver's kernels itself where the helper
    was still on them; in the other order the run reached self-collision while the helper was
    compiling it and compiled the same kernels beside it (docs/performance.md, "Where a cold
    start stands")."""
    solver, *flags = arguments
    self_collision = SELF_COLLISION_FLAG in flags
    if self_collision:
        compile_self_collision()
    _step_stand_in(Settings(solver=solver), calm_scene=True, self_collision=self_collision, kinds=frozenset())


def compile_self_collision() -> None:
    """Compiles (or loads) self-collision's kernels without a solver: `SelfCollision.project` over
    `SELF_COLLISION_SUBSTEPS` substeps of a stand-in sheet falling freely: the calls a stand-in's
    frame with self-collision makes (`tests/test_compile_ahead.py` checks that its frame then
    compiles none of them anew; the partial searches of a few stray vertices are left to the run)."""
    side = STAND_IN_SIDE
    model = SpringModel.from_mesh(grid_mesh(side, side, plane="xz"))
    state = State.at_rest(model)
    collision = SelfCollision()
    dt = 1.0 / 192.0
    for k in range(1, SELF_COLLISION_SUBSTEPS + 1):
        state.previous[:] = state.positions
        state.velocities[:, 1] = -9.81 * k * dt
        state.positions += state.velocities * dt
        collision.project(model, state, k * dt, dt)


#: substeps of `compile_self_collision`'s falling stand-in (a whole search, then the kept lists)
SELF_COLLISION_SUBSTEPS = 4


if __name__ == "__main__":
    _compile_in_process(sys.argv[1:])
