"""What the fast solver paths must keep: thread-independent results, exact levelling, pins.

The position-based solvers sweep springs in a levelled, partitioned order on a scratch copy
of the vertices, in one compiled call per substep (serial or parallel build). None of that may
change results with the number of Numba threads: a batch worker with one thread and a run
with two must write byte-identical frames, whether the parallel build is asked for or not.
"""

from __future__ import annotations

import numba as nb
import numpy as np
import pytest
from factories import TOP_CORNERS, grid_cloth

from meshdeform.model import SpringModel, State
from meshdeform.scene.base import Force
from meshdeform.simulate import Scene, Settings, simulate
from meshdeform.solvers import Control, Solver, solver_class
from meshdeform.solvers.dispatch import PARALLEL_SUBSTEPS
from meshdeform.solvers.layout import AUTO_PARALLEL_SPRINGS, resolve_parts, spring_layout

two_threads = pytest.mark.skipif(nb.config.NUMBA_NUM_THREADS < 2, reason="needs 2 Numba threads")


def cloth(n: int, plane: str = "xy") -> SpringModel:
    """An n x n cloth hanging from its top corners (`factories.grid_cloth`)."""
    return grid_cloth(n, pins=TOP_CORNERS, plane=plane).model


def run(model: SpringModel, solver: str, threads: int, partitions: int, frames: int = 4) -> np.ndarray:
    before = nb.get_num_threads()
    nb.set_num_threads(threads)
    try:
        options = solver_class(solver).options_class(partitions=partitions)
        settings = Settings(solver=solver, frames=frames, options=options)
        return np.stack([f.welded_positions for f in simulate(model, Scene(), settings)])
    finally:
        nb.set_num_threads(before)


def test_auto_partitions_ignore_the_thread_count(monkeypatch: pytest.MonkeyPatch) -> None:
    for threads in (1, 2, 8):
        monkeypatch.setattr(nb, "get_num_threads", lambda threads=threads: threads)
        assert resolve_parts(0, AUTO_PARALLEL_SPRINGS) == 2
        assert resolve_parts(0, AUTO_PARALLEL_SPRINGS - 1) == 1
        assert resolve_parts(3, 10) == 3


@two_threads
@pytest.mark.parametrize("parallel", ["0", "1"])
@pytest.mark.parametrize("solver", ["xpbd", "verlet"])
@pytest.mark.parametrize("partitions", [0, 1, 2, 3])
def test_results_bit_identical_with_one_or_two_threads(
    solver: str, partitions: int, parallel: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """With parallel substeps asked for, two threads run the parallel build (on 2 or 3 slabs)."""
    monkeypatch.setenv(PARALLEL_SUBSTEPS, parallel)
    model = cloth(20)
    one = run(model, solver, 1, partitions)
    two = run(model, solver, 2, partitions)
    assert one.tobytes() == two.tobytes()
    assert np.isfinite(one).all()


@two_threads
def test_auto_layout_above_the_parallel_threshold_is_thread_independent(monkeypatch: pytest.MonkeyPatch) -> None:
    """A model big enough for two automatic slabs: 1 and 2 threads (the serial and the parallel
    build) give the same bytes."""
    monkeypatch.setenv(PARALLEL_SUBSTEPS, "1")
    n = int(np.ceil(np.sqrt(AUTO_PARALLEL_SPRINGS / 5.6))) + 2
    model = cloth(n)
    assert model.spring_count >= AUTO_PARALLEL_SPRINGS
    lay1 = spring_layout(model, 0)
    assert lay1.parts == 2
    one = run(model, "xpbd", 1, 0, frames=1)
    two = run(model, "xpbd", 2, 0, frames=1)
    assert one.tobytes() == two.tobytes()


@pytest.mark.parametrize("block", [0, 300])
@pytest.mark.parametrize("parts", [1, 2])
def test_levelled_order_sweeps_like_the_sorted_order(parts: int, block: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """Levelling is exact: every vertex meets its springs in the same order as in the sorted order.

    The sorted order is the pin-distance order of `spring_layout` before levelling; a
    Gauss-Seidel sweep only depends on the order in which each vertex sees its springs.
    With levelled blocks (`LEVEL_BLOCK`, here 300 springs so a small cloth has several) a
    spring moves only within its block of the sorted order.
    """
    from meshdeform.solvers import layout
    from meshdeform.solvers.layout import pin_distance

    monkeypatch.setattr(layout, "LEVEL_BLOCK", block)
    model = cloth(24)
    lay = spring_layout(model, parts)
    dist = pin_distance(model)
    group = np.repeat(np.arange(lay.parts + 1), np.diff(lay.offsets))
    lo, hi = np.minimum(lay.a, lay.b), np.maximum(lay.a, lay.b)
    reference = np.empty(lay.a.shape[0], dtype=np.int64)
    reference[np.lexsort((hi, lo, np.minimum(dist[lay.a], dist[lay.b]), group))] = np.arange(lay.a.shape[0])
    stored = np.arange(lay.a.shape[0])
    vertex = np.concatenate([lay.a, lay.b])
    pos_s = np.concatenate([stored, stored])
    pos_r = np.concatenate([reference, reference])
    order = np.lexsort((pos_s, vertex))
    same_vertex = vertex[order][1:] == vertex[order][:-1]
    assert (np.diff(pos_r[order])[same_vertex] > 0).all()
    # and levelling did reorder (consecutive springs are mostly independent)
    assert not np.array_equal(np.argsort(reference), stored)
    if block:
        assert lay.a.shape[0] > 4 * block
        assert np.array_equal(reference // block, stored // block)
    else:  # one block: springs travel further than a block of 300 would let them
        assert np.abs(reference - stored).max() > 300


def test_kernel_numbering_is_a_permutation() -> None:
    model = cloth(16)
    lay = spring_layout(model, 2)
    n = model.vertex_count
    assert np.array_equal(np.sort(lay.vertex_order), np.arange(n))
    assert np.array_equal(lay.vertex_rank[lay.vertex_order], np.arange(n))
    assert np.array_equal(lay.vertex_order[lay.ends["a"]], lay.a)
    assert np.array_equal(lay.vertex_order[lay.ends["b"]], lay.b)


@pytest.mark.parametrize("solver", ["xpbd", "verlet"])
def test_pins_bit_identical_and_run_reproducible(solver: str) -> None:
    model = cloth(12, plane="xz")
    a = run(model, solver, 1, 1, frames=6)
    b = run(model, solver, 1, 1, frames=6)
    assert a.tobytes() == b.tobytes()
    pins = np.flatnonzero(model.pinned)
    assert a[:, pins].tobytes() == np.broadcast_to(model.rest_positions[pins], a[:, pins].shape).tobytes()


class _SubstepOnly(Solver):
    """A solver's `step` behind the default `Solver.advance` (a loop of `step`)."""

    def __init__(self, solver: Solver) -> None:
        super().__init__(solver.options)
        self.inner = solver
        self.name = solver.name
        self.hint = solver.hint

    def step(self, model: SpringModel, state: State, dt: float, control: Control) -> None:
        self.inner.step(model, state, dt, control)


@pytest.mark.parametrize("solver", ["xpbd", "verlet"])
def test_whole_frame_calls_match_the_substep_loop(solver: str) -> None:
    """A gravity-only scene runs each frame as one solver call: same frames as substep by substep."""
    from meshdeform.solvers import make_solver

    model = cloth(20)
    settings = Settings(solver=solver, frames=6)
    framewise = make_solver(solver, settings.options)
    calls: list[int] = []
    advance = framewise.advance
    framewise.advance = lambda *args: calls.append(args[-1]) or advance(*args)
    whole = [f.positions.copy() for f in simulate(model, Scene(), settings, solver=framewise)]
    assert calls == [settings.substeps] * 6
    stepped = [
        f.positions.copy()
        for f in simulate(model, Scene(), settings, solver=_SubstepOnly(make_solver(solver, settings.options)))
    ]
    assert np.abs(whole[-1] - model.rest_positions).max() > 1e-3  # the cloth fell
    assert all(a.tobytes() == b.tobytes() for a, b in zip(whole, stepped, strict=True))


class _NoForce(Force):
    """A force that adds nothing: its presence alone makes simulate step substep by substep."""

    def accumulate(self, model: SpringModel, state: State, time: float, dt: float, out: np.ndarray) -> None:
        pass


@pytest.mark.parametrize("solver", ["implicit", "springs", "anchor"])
def test_default_advance_matches_the_substep_loop(solver: str) -> None:
    """Solvers without their own `advance` run a gravity-only frame through the default one (a
    loop of `step`): the same frames as the substep loop (implicit reads the state's time)."""
    model = cloth(12)
    settings = Settings(solver=solver, frames=4, substeps=3)
    whole = [f.positions.copy() for f in simulate(model, Scene(), settings)]
    stepped = [f.positions.copy() for f in simulate(model, Scene(forces=[_NoForce()]), settings)]
    assert np.abs(whole[-1] - model.rest_positions).max() > 1e-4  # the cloth moved
    assert all(a.tobytes() == b.tobytes() for a, b in zip(whole, stepped, strict=True))
