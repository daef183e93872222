"""Which build of a substep kernel runs, the serial or the parallel one: the faster on the machine now.

verlet and xpbd compile each substep kernel twice, a serial and a parallel build, and both
compute bit for bit the same result (the slabs of a `SpringLayout` share no vertex, the vertex
and tether chunks of `layout.KernelChunks` split only element-wise work), and a call of `count`
substeps gives the bytes of `count` calls of one: the build and the way a frame's substeps are
split into calls decide the speed, never the output. The parallel build runs the slabs on one
Numba thread each. On cores nothing else uses it runs about twice as fast as the serial one; with
another process on one of them, at half the speed or less; and a few short calls cannot tell
the two cases apart (a thread that slept gets a core at once: docs/performance.md, "Serial or
parallel substeps"). So `SubstepPicker` measures sustained work while the run goes on:

- It runs one build (the serial one first) and from time to time a *trial*: a window of the
  build it runs, a window of the other, a window of the first again, each `window` seconds of
  kernel time, the calls of all three split alike into chunks of at most `call` seconds (the
  same bytes as whole calls). It switches when the other build's seconds per substep beat those
  of the two windows around it by `margin` (hysteresis: noise does not flip it back and forth).
- The parallel build is tried only where it can run: more than one slab, more than one Numba
  thread in the thread that prepares the model, two or more cores for the process (its CPU
  affinity and cgroup quota); and only once the run has spent `first_trial` seconds in substeps
  (`first_trial_cold` when the parallel build is neither compiled in this process nor in Numba's
  disk cache: compiling it takes seconds a short run never wins back); and, where the machine's
  idle time is known (Linux /proc/stat), only after a window over which `idle_cores` cores were
  idle (with every core busy it cannot gain).
- After a trial that kept the build the next comes `interval` seconds of substeps later, the
  interval doubling up to `max_interval`; after a switch, `interval` later. While the parallel
  build runs, a window `slowdown` slower than the rate it was chosen at (another process took a
  core) starts a trial at once, so the run goes back to the serial build within a second or two.

`PARALLEL_SUBSTEPS` in the environment overrides the picker: "0" always the serial build, "1"
always the parallel one where it can run (slabs and threads), unset or "auto" the picker; it is
read when a solver prepares a model (batch workers inherit it). Numba threads: the count in the
thread that prepares the model (`numba.get_num_threads()`: NUMBA_NUM_THREADS, or
`numba.set_num_threads` in that thread; the batch gives each worker cores // jobs); the parallel
build uses at most one thread per slab. Neither the thread count, nor the build, nor a switch
in the middle of a run changes a result: only `partitions` does (tests/test_dispatch.py).
"""

from __future__ import annotations

import logging
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal, Protocol

import numba as nb

from meshdeform.errors import MeshdeformError

#: the environment variable that overrides the picker: "0" serial, "1" parallel, "auto" (or unset) the picker
PARALLEL_SUBSTEPS = "MESHDEFORM_PARALLEL_SUBSTEPS"

Build = Literal["serial", "parallel"]
Mode = Literal["serial", "parallel", "auto"]
#: the values of `PARALLEL_SUBSTEPS`, lower-cased, and the mode each asks for
MODES: dict[str, Mode] = {"0": "serial", "1": "parallel", "": "auto", "auto": "auto"}

log = logging.getLogger(__name__)


def requested_mode() -> Mode:
    """The mode `PARALLEL_SUBSTEPS` asks for; MeshdeformError for a value that is none of `MODES`."""
    value = os.environ.get(PARALLEL_SUBSTEPS, "").strip().lower()
    if value not in MODES:
        raise MeshdeformError(f"{PARALLEL_SUBSTEPS}={value!r}: expected 0 (serial), 1 (parallel) or auto")
    return MODES[value]


@dataclass(frozen=True)
class PickerSettings:
    """When and how `SubstepPicker` measures; times are seconds of kernel time (the picker's calls).

    window: one measurement window. call: at most this long a call in a trial (the substeps of a
    call are split into chunks; at least one substep a chunk). margin: the other build switches in
    when its seconds per substep are below (1 - margin) times those of the build that runs.
    first_trial / first_trial_cold: kernel time before the first trial of the parallel build when
    it is compiled or cached / when it must be compiled. interval, max_interval: between trials.
    idle_cores: idle cores (machine-wide, over the last window) needed to try the parallel build.
    slowdown: a window of the parallel build this much slower than its rate when chosen starts a trial.
    """

    window: float = 0.25
    call: float = 0.02
    margin: float = 0.1
    first_trial: float = 1.0
    first_trial_cold: float = 20.0
    interval: float = 5.0
    max_interval: float = 80.0
    idle_cores: float = 0.5
    slowdown: float = 0.25


class Machine(Protocol):
    """What the picker reads of the machine (a fake in the tests)."""

    def clock(self) -> float:
        """Seconds, monotonic: the picker times its kernel calls with it."""
        ...

    def idle(self) -> float | None:
        """Idle core-seconds of the whole machine since a fixed origin; None where unknown."""
        ...

    def cores(self) -> float:
        """Cores this process may run on at once (affinity mask, CPU quota)."""
        ...


class HostMachine:
    """The machine this process runs on: `time.perf_counter`, /proc/stat, affinity and cgroup quota."""

    def clock(self) -> float:
        return time.perf_counter()

    def idle(self) -> float | None:
        """Idle plus iowait time of all cores (first line of /proc/stat, in clock ticks), in seconds."""
        try:
            with open("/proc/stat", "rb") as f:
                fields = f.readline().split()
            return (int(fields[4]) + int(fields[5])) / os.sysconf("SC_CLK_TCK")
        except (OSError, ValueError, IndexError):
            return None

    def cores(self) -> float:
        count: float = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
        try:  # cgroup v2 quota: "max 100000" or "<quota> <period>"
            with open("/sys/fs/cgroup/cpu.max") as f:
                quota, period = f.read().split()[:2]
            if quota != "max":
                count = min(count, int(quota) / int(period))
        except (OSError, ValueError):
            pass
        return count


HOST = HostMachine()


def available(kernel: Callable[..., None]) -> bool:
    """Whether `kernel` (a Numba dispatcher) needs no compiling: compiled in this process, or an
    overload for the current source in Numba's disk cache. (Reads Numba's cache index, a private
    part of Numba: anything unexpected counts as not available.)"""
    if getattr(kernel, "signatures", None):
        return True
    try:
        return bool(kernel._cache._cache_file._load_index())  # type: ignore[attr-defined]
    except Exception:
        return False


@dataclass
class Tally:
    """Kernel seconds and substeps of a stretch of calls."""

    seconds: float = 0.0
    substeps: int = 0

    def add(self, seconds: float, substeps: int) -> None:
        self.seconds += seconds
        self.substeps += substeps

    @property
    def per_substep(self) -> float:
        return self.seconds / self.substeps if self.substeps else math.inf


class SubstepPicker:
    """Runs a substep kernel as `picker(*args, count)`, with the build that is faster now (module docstring).

    serial, parallel: the two builds (same arguments, same bytes; the last argument is the
    substep count). parts: the layout's slab count. machine, settings: what it measures with
    (tests pass fakes). After a run: `build` (the build in use), `switches`, and per build the
    `seconds` and `substeps` it ran.
    """

    def __init__(
        self,
        serial: Callable[..., None],
        parallel: Callable[..., None],
        parts: int,
        work: int = 0,
        machine: Machine | None = None,
        settings: PickerSettings | None = None,
    ) -> None:
        self.kernels: dict[Build, Callable[..., None]] = {"serial": serial, "parallel": parallel}
        self.machine = machine if machine is not None else HOST
        self.settings = settings if settings is not None else PickerSettings()
        self.build: Build = "serial"
        self.switches = 0
        self.seconds: dict[Build, float] = {"serial": 0.0, "parallel": 0.0}
        self.substeps: dict[Build, int] = {"serial": 0, "parallel": 0}
        self._cores = self.machine.cores()
        self._elapsed = 0.0  # kernel seconds, both builds
        self._interval = self.settings.interval
        self._next_trial = 0.0
        self._warm: set[Build] = set()
        self._work = -1
        self.follow(parts, work)

    def follow(self, parts: int, work: int = 0) -> None:
        """A model was prepared: `parts` slabs, `work` a size (springs + vertices); measurements
        restart when the slab count changes or the size by more than 10 %."""
        self.mode = requested_mode()
        self.threads = nb.get_num_threads()
        can_run = parts > 1 and self.threads > 1
        self.auto = self.mode == "auto" and can_run and self._cores >= 2
        if self.mode != "auto":
            self.build = "parallel" if self.mode == "parallel" and can_run else "serial"
        elif not self.auto:
            self.build = "serial"
        if self._work < 0 or parts != self._parts or abs(work - self._work) > 0.1 * max(self._work, 1):
            self._reset()
            if self._work < 0:  # the first model: when to try the parallel build first
                ready = available(self.kernels["parallel"])
                self._next_trial = self.settings.first_trial if ready else self.settings.first_trial_cold
        self._parts = parts
        self._work = work

    def _reset(self) -> None:
        self._trial: list[Tally] | None = None
        self._window = Tally()
        self._window_start = (self.machine.clock(), self.machine.idle())
        self._idle_cores: float | None = None
        self._reference: float | None = None
        self._per_substep: float | None = None

    def __call__(self, *args: object) -> None:
        *head, count = args
        count = int(count)  # type: ignore[call-overload]
        if not self.auto or count <= 0:
            self._run(self.build, head, count)
            return
        while count > 0:
            if self._trial is None and not self._trial_due():
                seconds = self._run(self.build, head, count)
                if seconds is not None:
                    self._observe(seconds, count)
                return
            if self._trial is None:
                self._trial = [Tally(), Tally(), Tally()]
            count -= self._trial_chunk(head, count)

    # -- running and measuring -------------------------------------------------------------

    def _run(self, build: Build, head: list[object], count: int) -> float | None:
        """`count` substeps with `build`; its kernel seconds, or None for the build's first call
        here (compiling or loading it, its threads starting), which no measurement counts."""
        start = self.machine.clock()
        self.kernels[build](*head, count)
        seconds = self.machine.clock() - start
        self.seconds[build] += seconds
        self.substeps[build] += count
        if build not in self._warm:
            self._warm.add(build)
            return None
        self._elapsed += seconds
        return seconds

    def _observe(self, seconds: float, count: int) -> None:
        """A call outside trials: closes a window every `window` seconds (idle cores; slowdown)."""
        self._per_substep = seconds / count
        self._window.add(seconds, count)
        if self._window.seconds < self.settings.window:
            return
        now, idle = self.machine.clock(), self.machine.idle()
        then, idle_then = self._window_start
        if idle is not None and idle_then is not None and now > then:
            self._idle_cores = (idle - idle_then) / (now - then)
        slow = self._reference is not None and self._window.per_substep > self._reference * (1 + self.settings.slowdown)
        if self.build == "parallel" and slow:
            log.debug(
                "parallel substeps %.3g ms, chosen at %.3g ms: trial now",
                1e3 * self._window.per_substep,
                1e3 * (self._reference or 0.0),
            )
            self._next_trial = self._elapsed
        self._window = Tally()
        self._window_start = (now, idle)

    def _trial_due(self) -> bool:
        if self._elapsed < self._next_trial:
            return False
        if self.build == "serial" and self._idle_cores is not None:
            return self._idle_cores >= self.settings.idle_cores
        return True

    def _trial_chunk(self, head: list[object], count: int) -> int:
        """One chunk of the trial under way; the substeps it ran."""
        trial = self._trial
        assert trial is not None
        phase = next(i for i, tally in enumerate(trial) if tally.seconds < self.settings.window)
        build = self.build if phase != 1 else other(self.build)
        per_substep = self._per_substep or self.settings.call
        chunk = max(1, min(count, int(self.settings.call / per_substep)))
        seconds = self._run(build, head, chunk)
        if seconds is None:
            return chunk
        trial[phase].add(seconds, chunk)
        if phase == 2 and trial[2].seconds >= self.settings.window:
            self._decide(trial)
        return chunk

    def _decide(self, trial: list[Tally]) -> None:
        """The end of a trial: switch if the other build beat the windows around it by `margin`."""
        current = Tally(trial[0].seconds + trial[2].seconds, trial[0].substeps + trial[2].substeps).per_substep
        challenger = trial[1].per_substep
        tried = other(self.build)
        figures = (tried, 1e3 * challenger, self.build, 1e3 * current)
        if challenger < current * (1 - self.settings.margin):
            log.debug("%s %.3g ms/substep beat %s %.3g ms: switching", *figures)
            self.build = tried
            self.switches += 1
            self._interval = self.settings.interval
            self._reference = challenger
        else:
            log.debug("%s %.3g ms/substep against %s %.3g ms: kept", *figures)
            self._interval = min(2 * self._interval, self.settings.max_interval)
            self._reference = current
        self._next_trial = self._elapsed + self._interval
        self._trial = None
        self._window = Tally()
        self._window_start = (self.machine.clock(), self.machine.idle())


def other(build: Build) -> Build:
    return "parallel" if build == "serial" else "serial"


def substep_picker(
    serial: Callable[..., None], parallel: Callable[..., None], parts: int, work: int, previous: object = None
) -> SubstepPicker:
    """The picker for a newly prepared model: `previous` (a solver's last one) when it runs these
    builds, told of the new layout (it keeps what it learnt of the machine); else a new one."""
    if isinstance(previous, SubstepPicker) and previous.kernels["serial"] is serial:
        previous.follow(parts, work)
        return previous
    return SubstepPicker(serial, parallel, parts, work)
