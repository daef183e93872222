"""Serial or parallel substep builds: same bytes, chunks that split safely, the picker's choice."""

from __future__ import annotations

import sys
from collections.abc import Callable

import numba as nb
import numpy as np
import pytest
from factories import TOP_CORNERS, grid_cloth

from meshdeform.errors import MeshdeformError
from meshdeform.model import SpringModel, State
from meshdeform.solvers import Control, make_solver, solver_class
from meshdeform.solvers.common import kernel_tethers
from meshdeform.solvers.dispatch import PARALLEL_SUBSTEPS, PickerSettings, SubstepPicker, requested_mode
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
    tethers = kernel_tethers(model, layout.vertex_rank, 1.0).records
    assert tethers.shape[0] > model.vertex_count  # two pins: up to two tethers per vertex
    chunks = kernel_chunks(layout, tethers["v"])
    vertices = chunks.vertices.astype(np.int64)
    bounds = chunks.tethers.astype(np.int64)
    assert vertices[0] == 0 and vertices[-1] == model.vertex_count
    assert bounds[0] == 0 and bounds[-1] == tethers.shape[0]
    for p in range(layout.parts):
        held = tethers["v"][bounds[p] : bounds[p + 1]].astype(np.int64)
        assert ((held >= vertices[p]) & (held < vertices[p + 1])).all()


# -- the choice: a fake machine whose clock the fake kernels advance ------------------------------

#: seconds per substep: the serial build; the parallel one on idle cores and with one core busy
SERIAL, PARALLEL_IDLE, PARALLEL_BUSY = 1e-3, 0.5e-3, 2e-3
#: the picker's schedule scaled to the fake kernels (10 substeps a window)
FAST = PickerSettings(window=0.01, call=0.004, first_trial=0.05, first_trial_cold=0.5, interval=0.1, max_interval=0.8)


class FakeMachine:
    """Two cores and a clock that only the fake kernels advance (by `cost` seconds per substep).

    busy: another process holds one core (the parallel build then runs at PARALLEL_BUSY, and no
    core is idle). fast_start: the first substeps of the parallel build after the serial one
    ran cost PARALLEL_IDLE even when busy (a thread that slept gets a core at once).
    idle_known: False stands for a machine without /proc/stat.
    """

    def __init__(self, busy: bool = False, idle_known: bool = True, cores: float = 2.0, fast_start: int = 0) -> None:
        self.now = 0.0
        self.idle_seconds = 0.0
        self.busy = busy
        self.idle_known = idle_known
        self.core_count = cores
        self.fast_start = fast_start
        self.calls: list[tuple[str, int]] = []
        self._fast_left = fast_start

    def clock(self) -> float:
        return self.now

    def idle(self) -> float | None:
        return self.idle_seconds if self.idle_known else None

    def cores(self) -> float:
        return self.core_count

    def cost(self, build: str) -> float:
        if build == "serial":
            self._fast_left = self.fast_start
            return SERIAL
        if self.busy and self._fast_left > 0:
            self._fast_left -= 1
            return PARALLEL_IDLE
        return PARALLEL_BUSY if self.busy else PARALLEL_IDLE

    def kernel(self, build: str, compute: Callable[..., None] | None = None) -> Callable[..., None]:
        """A build that runs `compute` (if any) and advances the clock by its cost."""

        def run(*args: object) -> None:
            count = int(args[-1])  # type: ignore[call-overload]
            if compute is not None:
                compute(*args)
            self.calls.append((build, count))
            seconds = sum(self.cost(build) for _ in range(count))
            threads = 1 if build == "serial" else 2
            free = max(0.0, self.core_count - threads - (1.0 if self.busy else 0.0))
            self.idle_seconds += free * seconds
            self.now += seconds

        return run


def fake_picker(machine: FakeMachine, parts: int = 2) -> SubstepPicker:
    return SubstepPicker(machine.kernel("serial"), machine.kernel("parallel"), parts, 1000, machine, FAST)


def drive(picker: SubstepPicker, machine: FakeMachine, until: float, count: int = 22) -> None:
    """Frames of `count` substeps until the fake clock reaches `until` seconds."""
    while machine.now < until:
        picker(None, count)


@pytest.fixture
def auto(monkeypatch: pytest.MonkeyPatch) -> None:
    """The picker in charge (no override) and two Numba threads in this thread."""
    monkeypatch.delenv(PARALLEL_SUBSTEPS, raising=False)
    monkeypatch.setattr(nb, "get_num_threads", lambda: 2)


def test_idle_cores_take_the_parallel_build_after_the_first_stretch(auto: None) -> None:
    machine = FakeMachine()
    picker = fake_picker(machine)
    # the parallel build is not compiled (a plain function): the long wait before its first trial
    drive(picker, machine, FAST.first_trial_cold * 0.9)
    assert picker.build == "serial" and picker.substeps["parallel"] == 0
    drive(picker, machine, 3.0)
    assert picker.build == "parallel" and picker.switches == 1
    # the later trials (serial again) kept it; most of the run was parallel
    assert picker.substeps["parallel"] > 3 * picker.substeps["serial"]
    assert sum(n for _, n in machine.calls) == picker.substeps["serial"] + picker.substeps["parallel"]


def test_a_parallel_build_already_compiled_is_tried_sooner(auto: None) -> None:
    machine = FakeMachine()
    parallel = machine.kernel("parallel")
    parallel.signatures = ["compiled"]  # type: ignore[attr-defined]  # what `available` reads of a dispatcher
    picker = SubstepPicker(machine.kernel("serial"), parallel, 2, 1000, machine, FAST)
    drive(picker, machine, FAST.first_trial_cold * 0.9)
    assert picker.build == "parallel"


def test_a_busy_core_keeps_the_serial_build_without_trying_the_other(auto: None) -> None:
    machine = FakeMachine(busy=True)
    picker = fake_picker(machine)
    drive(picker, machine, 5.0)
    assert picker.build == "serial" and picker.substeps["parallel"] == 0


def test_without_idle_figures_trials_decide_and_grow_apart(auto: None) -> None:
    """No /proc/stat: the parallel build is tried on a busy machine, found slower and kept out;
    the intervals between trials double, so trials cost little of a long run."""
    machine = FakeMachine(busy=True, idle_known=False)
    picker = fake_picker(machine)
    drive(picker, machine, 20.0)
    assert picker.build == "serial" and picker.switches == 0
    assert 0 < picker.substeps["parallel"] < 0.02 * picker.substeps["serial"]


def test_short_fast_starts_of_the_parallel_build_do_not_fool_the_trials(auto: None) -> None:
    """A parallel call right after serial ones runs fast even with a core busy; sustained, it is
    slow. Trials time whole windows, so the serial build stays."""
    machine = FakeMachine(busy=True, idle_known=False, fast_start=3)
    picker = fake_picker(machine)
    drive(picker, machine, 10.0)
    assert picker.build == "serial" and picker.switches == 0


def test_the_choice_follows_the_machine_and_switches_back(auto: None) -> None:
    machine = FakeMachine()
    picker = fake_picker(machine)
    drive(picker, machine, 2.0)
    assert picker.build == "parallel"
    machine.busy = True  # another process takes a core
    started = machine.now
    drive(picker, machine, started + 0.2)
    assert picker.build == "serial" and picker.switches == 2  # within a few windows
    drive(picker, machine, started + 3.0)
    assert picker.build == "serial"
    machine.busy = False  # the core is free again
    drive(picker, machine, machine.now + 2 * FAST.max_interval)
    assert picker.build == "parallel" and picker.switches == 3


def test_a_small_gain_is_not_worth_a_switch(auto: None, monkeypatch: pytest.MonkeyPatch) -> None:
    """Hysteresis: a parallel build only 5 % faster (less than the margin) never takes over."""
    monkeypatch.setattr(sys.modules[__name__], "PARALLEL_IDLE", SERIAL * 0.95)
    machine = FakeMachine(idle_known=False)
    picker = fake_picker(machine)
    drive(picker, machine, 10.0)
    assert picker.switches == 0 and picker.build == "serial"


def test_trials_split_calls_into_chunks_of_the_same_substeps(auto: None) -> None:
    """In a trial a frame's substeps are run as chunks of at most `call` seconds, in order,
    adding up to the substeps asked for; outside trials a frame is one call."""
    machine = FakeMachine()
    picker = fake_picker(machine)
    drive(picker, machine, 3.0)
    counts = [n for _, n in machine.calls]
    assert max(counts) == 22 and min(counts) <= int(FAST.call / SERIAL)
    assert sum(counts) % 22 == 0


def test_one_core_one_slab_or_one_thread_keep_the_serial_build(auto: None, monkeypatch: pytest.MonkeyPatch) -> None:
    for machine, parts in ((FakeMachine(cores=1.0), 2), (FakeMachine(cores=1.5), 2), (FakeMachine(), 1)):
        picker = fake_picker(machine, parts)
        drive(picker, machine, 3.0)
        assert picker.substeps["parallel"] == 0
    monkeypatch.setattr(nb, "get_num_threads", lambda: 1)
    machine = FakeMachine()
    picker = fake_picker(machine)
    drive(picker, machine, 3.0)
    assert picker.substeps["parallel"] == 0


def test_the_environment_forces_a_build(monkeypatch: pytest.MonkeyPatch) -> None:
    """MESHDEFORM_PARALLEL_SUBSTEPS=0 / 1 force the serial / the parallel build whatever the
    machine (the parallel one only with slabs and threads); another value is an error."""
    monkeypatch.setattr(nb, "get_num_threads", lambda: 2)
    monkeypatch.setenv(PARALLEL_SUBSTEPS, "0")
    machine = FakeMachine()  # idle: the picker would go parallel
    picker = fake_picker(machine)
    drive(picker, machine, 3.0)
    assert picker.substeps["parallel"] == 0
    monkeypatch.setenv(PARALLEL_SUBSTEPS, "1")
    machine = FakeMachine(busy=True)  # busy: the picker would stay serial
    picker = fake_picker(machine)
    drive(picker, machine, 3.0)
    assert picker.substeps["serial"] == 0 and {n for _, n in machine.calls} == {22}
    machine = FakeMachine()
    picker = fake_picker(machine, parts=1)
    drive(picker, machine, 1.0)
    assert picker.substeps["parallel"] == 0
    monkeypatch.setattr(nb, "get_num_threads", lambda: 1)
    picker = fake_picker(machine)
    drive(picker, machine, 2.0)
    assert picker.substeps["parallel"] == 0
    for value in ("yes", "2", "true"):
        monkeypatch.setenv(PARALLEL_SUBSTEPS, value)
        with pytest.raises(MeshdeformError, match=PARALLEL_SUBSTEPS):
            requested_mode()
    for value, mode in (("", "auto"), (" AUTO ", "auto"), ("0", "serial"), ("1", "parallel")):
        monkeypatch.setenv(PARALLEL_SUBSTEPS, value)
        assert requested_mode() == mode


@pytest.mark.parametrize("name", ["xpbd", "verlet"])
def test_solvers_keep_one_picker_over_their_models(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """A solver prepares its picker with its two builds and keeps it for the next model; the
    override is read at each preparation."""
    monkeypatch.setattr(nb, "get_num_threads", lambda: 2)
    monkeypatch.setenv(PARALLEL_SUBSTEPS, "1")
    solver = make_solver(name, solver_class(name).options_class(partitions=2))
    model = cloth(24)
    solver.step(model, State.at_rest(model), 1e-3, Control(np.zeros((model.vertex_count, 3))))
    picker = solver.substep
    assert isinstance(picker, SubstepPicker)
    assert picker.kernels == {"serial": BUILDS[name, "serial"], "parallel": BUILDS[name, "parallel"]}
    assert picker.build == "parallel" and picker.substeps["parallel"] == 1
    monkeypatch.setenv(PARALLEL_SUBSTEPS, "0")
    other = cloth(25)
    solver.step(other, State.at_rest(other), 1e-3, Control(np.zeros((other.vertex_count, 3))))
    assert solver.substep is picker and picker.build == "serial" and picker.substeps["serial"] == 1


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


def advance(
    name: str,
    build: str | Callable[[object], SubstepPicker],
    steps: int = 30,
    per_call: int = 1,
    between_calls: Callable[[], None] = lambda: None,
) -> np.ndarray:
    """Positions, velocities and previous positions after `steps` substeps, `per_call` at a time,
    with the serial or the parallel build forced, or with the picker `build(solver)` returns."""
    model = cloth(24)
    solver = make_solver(name, solver_class(name).options_class(partitions=2))
    state = State.at_rest(model)
    control = Control(np.tile(np.array([0.0, -9.81, 0.0]), (model.vertex_count, 1)))
    dt = 1.0 / 24 / 20
    solver.step(model, state, dt, control)  # prepares (serial: nothing asks for the parallel build)
    assert solver.layout.parts == 2 and solver.tethers.shape[0] > 0
    solver.substep = BUILDS[name, build] if isinstance(build, str) else build(solver)  # from now on
    for _ in range(steps // per_call):
        solver.advance(model, state, dt, control, per_call)
        between_calls()
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


@two_threads
@pytest.mark.parametrize("name", ["xpbd", "verlet"])
def test_a_run_that_switches_builds_mid_way_gives_the_serial_bytes(name: str, auto: None) -> None:
    """The real builds under a picker on a fake machine whose second core comes and goes: the
    picker switches back and forth, splits calls into chunks in its trials, and the run ends with
    the bytes of the serial build alone."""
    serial = advance(name, "serial", steps=240, per_call=6)
    machine = FakeMachine()
    settings = PickerSettings(window=0.005, call=0.002, first_trial=0.01, first_trial_cold=0.01, interval=0.02)

    builds = (machine.kernel(build, BUILDS[name, build]) for build in ("serial", "parallel"))
    picker = SubstepPicker(*builds, 2, 1000, machine, settings)

    def between_calls() -> None:
        machine.busy = int(machine.now / 0.05) % 2 == 1

    switched = advance(name, lambda _: picker, steps=240, per_call=6, between_calls=between_calls)
    assert picker.switches >= 3 and min(picker.substeps.values()) > 40
    assert min(n for _, n in machine.calls) < 6  # trials ran chunks
    assert switched.tobytes() == serial.tobytes()
