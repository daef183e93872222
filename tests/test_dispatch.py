"""Serial or parallel substep builds: same bytes, chunks that split safely, a picker that measures."""

from __future__ import annotations

import time

import numba as nb
import numpy as np
import pytest

from meshdeform.mesh import grid_mesh
from meshdeform.model import SpringModel, State
from meshdeform.solvers import Control, dispatch, make_solver, solver_class
from meshdeform.solvers.common import kernel_tethers
from meshdeform.solvers.dispatch import KernelPicker, chunk_bounds
from meshdeform.solvers.layout import kernel_chunks, spring_layout
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


def test_picker_runs_the_faster_build_and_measures_again(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(nb, "get_num_threads", lambda: 2)
    monkeypatch.setattr(dispatch, "PROBE_EVERY", 60)
    monkeypatch.setattr(dispatch, "PROBE_AGAIN", 12)
    calls: list[str] = []
    slow = {"serial": 0.004, "parallel": 0.0}

    def build(name: str):
        def run() -> None:
            calls.append(name)
            time.sleep(slow[name])

        return run

    def probes(count: int) -> list[int]:
        """Make `count` calls; the indices of those that start a probe."""
        starts = []
        for k in range(count):
            if picker._phase == 0:
                starts.append(k)
            picker()
        return starts

    probe = 2 * (dispatch.PROBE_CALLS + 1)
    picker = KernelPicker(build("serial"), build("parallel"), parallel_ok=True)
    # parallel faster: one probe, then the parallel build until the next probe PROBE_EVERY calls on
    assert probes(60) == [0]
    assert calls[:probe].count("serial") == calls[:probe].count("parallel") == probe // 2
    assert set(calls[probe:60]) == {"parallel"} and picker.uses_parallel
    # the machine changes: the next probe picks the serial build and probes again soon,
    # 12 calls later, then 24, 48 and at most PROBE_EVERY while serial keeps winning
    slow.update(serial=0.0, parallel=0.004)
    calls.clear()
    assert probes(12 + 24 + 48 + 60 + 1) == [0, 12, 36, 84, 144]
    assert not picker.uses_parallel
    assert set(calls[probe:12]) == {"serial"}
    # it changes back: the short period finds the parallel build again within PROBE_AGAIN calls
    picker = KernelPicker(build("serial"), build("parallel"), parallel_ok=True)
    slow.update(serial=0.0, parallel=0.004)
    probes(probe)
    assert not picker.uses_parallel
    slow.update(serial=0.004, parallel=0.0)
    probes(2 * dispatch.PROBE_AGAIN)
    assert picker.uses_parallel


def test_picker_without_parallel_runs_serial_only(monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[str] = []
    picker = KernelPicker(lambda: calls.append("s"), lambda: calls.append("p"), parallel_ok=False)
    for _ in range(20):
        picker()
    assert calls == ["s"] * 20 and not picker.uses_parallel
    # one Numba thread: no parallel build either, whatever the layout allows
    monkeypatch.setattr(nb, "get_num_threads", lambda: 1)
    picker = KernelPicker(lambda: calls.append("s"), lambda: calls.append("p"), parallel_ok=True)
    calls.clear()
    for _ in range(20):
        picker()
    assert calls == ["s"] * 20


def cloth(n: int) -> SpringModel:
    mesh = grid_mesh(n, n, plane="xy")
    pinned = np.zeros(n * n, dtype=bool)
    pinned[[n * (n - 1), n * n - 1]] = True
    return SpringModel.from_mesh(mesh, pinned_input=pinned)


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
    solver.step(model, state, dt, control)  # prepares; the picker's first call is serial
    assert solver.layout.parts == 2 and solver.tethers.shape[0] > 0
    kernel = BUILDS[name, build]
    solver.substep = KernelPicker(kernel, kernel, parallel_ok=False)  # always this build
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


def test_picker_probes_on_single_calls_then_hands_out_its_choice(monkeypatch: pytest.MonkeyPatch) -> None:
    """`probing` is true exactly for the probe's calls; `call_chosen` runs the winner and counts."""
    monkeypatch.setattr(nb, "get_num_threads", lambda: 2)
    monkeypatch.setattr(dispatch, "PROBE_EVERY", 40)
    calls: list[str] = []

    def build(name: str, seconds: float):
        def run() -> None:
            calls.append(name)
            time.sleep(seconds)

        return run

    picker = KernelPicker(build("serial", 0.004), build("parallel", 0.0), parallel_ok=True)
    probe_length = 2 * (dispatch.PROBE_CALLS + 1)
    flags = []
    for _ in range(probe_length):
        flags.append(picker.probing)
        picker()
    assert flags == [True] * probe_length and not picker.probing
    with pytest.raises(RuntimeError):
        KernelPicker(build("serial", 0.0), build("parallel", 0.0), parallel_ok=True).call_chosen()
    calls.clear()
    for _ in range(40 - probe_length):
        picker.call_chosen()
    assert calls == ["parallel"] * (40 - probe_length)
    assert picker.probing  # the next probe is due after PROBE_EVERY calls in all


def test_whole_frame_calls_count_their_substeps_towards_the_next_probe(monkeypatch: pytest.MonkeyPatch) -> None:
    """A frame of 22 substeps in one call brings the next probe 22 calls closer, so probes come
    as often (in simulated time) as when every substep is its own call."""
    monkeypatch.setattr(nb, "get_num_threads", lambda: 2)
    monkeypatch.setattr(dispatch, "PROBE_EVERY", 100)
    counts: list[int] = []

    def build(seconds: float):
        def run(count: int) -> None:
            counts.append(count)
            time.sleep(seconds * count)

        return run

    picker = KernelPicker(build(0.001), build(0.0), parallel_ok=True)
    frames_until_probe = 0
    while True:  # the first probe runs on single substeps
        picker.call_substeps(22)
        if not picker.probing:
            break
    assert set(counts) == {1}
    counts.clear()
    while not picker.probing:
        picker.call_substeps(22)
        frames_until_probe += 1
    assert set(counts) == {22}
    # the first frame made 22 single calls (the probe, then the chosen build); each later frame
    # counts 22 calls, and a period has 100 calls in all
    assert frames_until_probe == -(-(100 - 22) // 22)
