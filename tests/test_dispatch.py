"""Serial or parallel substep builds: same bytes, chunks that split safely, serial unless asked for."""

from __future__ import annotations

import numba as nb
import numpy as np
import pytest
from factories import TOP_CORNERS, grid_cloth

from meshdeform.model import SpringModel, State
from meshdeform.solvers import Control, make_solver, solver_class
from meshdeform.solvers.common import kernel_tethers
from meshdeform.solvers.dispatch import PARALLEL_SUBSTEPS, substep_build
from meshdeform.solvers.layout import chunk_bounds, kernel_chunks, spring_layout
from meshdeform.solvers.verlet import kernels as verlet_kernels
from meshdeform.solvers.xpbd import kernels as xpbd_kernels

two_threads = pytest.mark.skipif(nb.config.NUMBA_NUM_THREADS < 2, reason="needs 2 Numba threads")


@pytest.mark.parametrize(("count", "parts"), [(0, 2), (1, 2), (7, 2), (4096, 2), (10, 3), (5, 8)])
def test_chunk_bounds_cover_the_range_in_order(count: int, parts: int) -> None:
    bounds = chunk_bounds(count, parts)
    assert bounds.dtype == np.uint64 and bounds.shape == (parts + 1,)
    assert bounds[0] == 0 and bounds[-1] == count
    sizes = np.diff(bounds.astype(np.int64))
    assert (sizes >= 0).all() and sizes.max() - sizes.min() <= 1


@pytest.mark.parametrize("parts", [1, 2, 3])
def test_tether_chunks_hold_the_tethers_of_their_vertex_chunk(parts: int) -> None:
    """The thread that predicts a kernel vertex range applies exactly those vertices' tethers."""
    model = cloth(24)
    layout = spring_layout(model, parts)
    tethers = kernel_tethers(model, layout.vertex_rank, 1.0)
    assert tethers.shape[0] > model.vertex_count  # two pins: up to two tethers per vertex
    chunks = kernel_chunks(layout, tethers["v"])
    vertices = chunks.vertices.astype(np.int64)
    bounds = chunks.tethers.astype(np.int64)
    assert vertices[0] == 0 and vertices[-1] == model.vertex_count
    assert bounds[0] == 0 and bounds[-1] == tethers.shape[0]
    for p in range(layout.parts):
        held = tethers["v"][bounds[p] : bounds[p + 1]].astype(np.int64)
        assert ((held >= vertices[p]) & (held < vertices[p + 1])).all()


def test_serial_build_unless_parallel_substeps_are_asked_for(monkeypatch: pytest.MonkeyPatch) -> None:
    """Parallel only when the environment asks, the layout has slabs and Numba threads to run them."""
    serial, parallel = object(), object()
    monkeypatch.setattr(nb, "get_num_threads", lambda: 2)
    monkeypatch.delenv(PARALLEL_SUBSTEPS, raising=False)
    assert substep_build(serial, parallel, 2) is serial
    for value in ("0", "", "yes", "2"):
        monkeypatch.setenv(PARALLEL_SUBSTEPS, value)
        assert substep_build(serial, parallel, 2) is serial
    monkeypatch.setenv(PARALLEL_SUBSTEPS, "1")
    assert substep_build(serial, parallel, 2) is parallel
    assert substep_build(serial, parallel, 3) is parallel
    assert substep_build(serial, parallel, 1) is serial  # one slab: nothing to run side by side
    monkeypatch.setattr(nb, "get_num_threads", lambda: 1)
    assert substep_build(serial, parallel, 2) is serial  # one Numba thread


@pytest.mark.parametrize("name", ["xpbd", "verlet"])
def test_solvers_prepare_with_the_build_asked_for(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """The choice is made when a model is prepared: serial by default, parallel when asked for."""
    model = cloth(24)
    state = State.at_rest(model)
    control = Control(np.zeros((model.vertex_count, 3)))
    monkeypatch.setattr(nb, "get_num_threads", lambda: 2)
    monkeypatch.delenv(PARALLEL_SUBSTEPS, raising=False)
    solver = make_solver(name, solver_class(name).options_class(partitions=2))
    solver.step(model, state, 1e-3, control)
    assert solver.substep is BUILDS[name, "serial"]
    monkeypatch.setenv(PARALLEL_SUBSTEPS, "1")
    solver = make_solver(name, solver_class(name).options_class(partitions=2))
    solver.step(model, state, 1e-3, control)
    assert solver.substep is BUILDS[name, "parallel"]


@pytest.mark.parametrize("name", ["xpbd", "verlet"])
def test_the_two_builds_compile_one_source_under_two_names(name: str) -> None:
    """One kernel source, compiled serially and in parallel, each build under its own name (so
    that Numba's disk cache, which keys by name and bytecode, keeps them apart)."""
    serial, parallel = BUILDS[name, "serial"], BUILDS[name, "parallel"]
    assert serial.py_func.__code__ is parallel.py_func.__code__
    assert serial.py_func.__qualname__ == f"{name}_substep"
    assert parallel.py_func.__qualname__ == f"{name}_substep_parallel"
    assert not serial.targetoptions.get("parallel") and parallel.targetoptions.get("parallel")


def cloth(n: int) -> SpringModel:
    """An n x n cloth hanging from its top corners (`factories.grid_cloth`)."""
    return grid_cloth(n, pins=TOP_CORNERS).model


#: (solver, build) -> its substep kernel
BUILDS = {
    ("xpbd", "serial"): xpbd_kernels.xpbd_substep,
    ("xpbd", "parallel"): xpbd_kernels.xpbd_substep_parallel,
    ("verlet", "serial"): verlet_kernels.verlet_substep,
    ("verlet", "parallel"): verlet_kernels.verlet_substep_parallel,
}


def advance(name: str, build: str, steps: int = 30, per_call: int = 1) -> np.ndarray:
    """Positions after `steps` substeps, `per_call` at a time, forcing the serial or the parallel build."""
    model = cloth(24)
    solver = make_solver(name, solver_class(name).options_class(partitions=2))
    state = State.at_rest(model)
    control = Control(np.tile(np.array([0.0, -9.81, 0.0]), (model.vertex_count, 1)))
    dt = 1.0 / 24 / 20
    solver.step(model, state, dt, control)  # prepares (serial: nothing asks for the parallel build)
    assert solver.layout.parts == 2 and solver.tethers.shape[0] > 0
    solver.substep = BUILDS[name, build]  # from now on this build
    for _ in range(steps // per_call):
        solver.advance(model, state, dt, control, per_call)
    return np.concatenate([state.positions, state.velocities, state.previous])


@two_threads
@pytest.mark.parametrize("name", ["xpbd", "verlet"])
def test_parallel_build_gives_the_serial_bytes(name: str) -> None:
    serial = advance(name, "serial")
    parallel = advance(name, "parallel")
    assert np.isfinite(serial).all()
    assert serial.tobytes() == parallel.tobytes()
    # and the cloth did move (a test of nothing would pass too)
    assert np.abs(serial[: serial.shape[0] // 3] - cloth(24).rest_positions).max() > 1e-4


@two_threads
@pytest.mark.parametrize("build", ["serial", "parallel"])
@pytest.mark.parametrize("name", ["xpbd", "verlet"])
def test_whole_frame_calls_give_the_bytes_of_single_substeps(name: str, build: str) -> None:
    """`advance(..., count)` keeps the vertices in the scratch between substeps: same bytes as
    `count` separate steps (positions, velocities and previous positions)."""
    single = advance(name, build, steps=30, per_call=1)
    frames = advance(name, build, steps=30, per_call=6)
    assert np.isfinite(single).all()
    assert single.tobytes() == frames.tobytes()
    assert np.abs(single[: single.shape[0] // 3] - cloth(24).rest_positions).max() > 1e-4
