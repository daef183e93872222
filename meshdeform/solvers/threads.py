"""Two threads for kernels that split their work: the pool thread beside the caller, the measured
choice of one or two, and two calls run beside each other.

Users: self-collision's searches and per-pair kernels (`meshdeform.contact.parts`) and the implicit
solver's energy and coarse Hessian over two slabs (`meshdeform.solvers.implicit`). The kernels they
hand over are compiled with `nogil` (`jit.JIT`); splitting never changes a result, only the speed.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numba

from meshdeform.solvers.dispatch import requested_mode

_pool: ThreadPoolExecutor | None = None
_pool_pid = 0  # the process that made `_pool`: a forked child has none of its threads
_pool_lock = threading.Lock()


def helper_pool() -> ThreadPoolExecutor:
    """The pool whose thread takes parts beside the caller (made on first use in each process;
    shared by every split, so two jobs in threads of one process each get a pool thread)."""
    global _pool, _pool_pid
    with _pool_lock:
        if _pool is None or _pool_pid != os.getpid():
            _pool = ThreadPoolExecutor(max_workers=2, thread_name_prefix="meshdeform-split")
            _pool_pid = os.getpid()
        return _pool


class ThreadPicker:
    """How many threads the split kernels use now: two where measured faster, else one.

    With another process on one of the two cores, splitting can run slower than one thread (the
    contact scenes of benchmarks/contact.py with a busy loop beside them: 2-5 %;
    docs/performance.md, "Two threads or one, by measurement"), and only measuring tells the two
    machines apart. The caller times comparable pieces of
    work (`timed`: self-collision's contact of one substep, over a window of several substeps the
    whole searches of the pair lists every few substeps included, alike from window to window; the
    implicit solver's steps);
    every `interval` pieces a trial runs `window` of them at the count in use, `window` at the
    other and `window` at the first again, and the other count is kept when its window's seconds beat
    both windows around it by `margin` (noise does not flip it back and forth; sums, not medians: the
    dear pieces, the whole searches, are a few of each window's). A trial ends early, keeping
    the count in use, once the other count's pieces so far took longer than that margin allows
    (its window can no longer win: a slow count is not run to the window's end). Without a switch
    the interval doubles, up to `max_interval`. Neither count changes a result (module docstring):
    only the speed.

    most: the threads allowed (`split_threads`); clock: seconds (tests pass a fake)."""

    def __init__(
        self,
        most: int,
        window: int = 15,
        margin: float = 0.1,
        interval: int = 120,
        max_interval: int = 960,
        clock: Callable[[], float] = time.perf_counter,
    ) -> None:
        self.most = most
        self.threads = most
        self.window, self.margin = window, margin
        self.interval, self.max_interval = interval, max_interval
        self.clock = clock
        self.switches = 0
        self._gap = interval  # pieces of work from one trial to the next
        self._count = 0  # pieces so far
        self._trial_at = interval  # the piece a trial starts at
        self._times: list[float] = []  # the trial's seconds so far, window by window

    def current(self) -> int:
        """The threads the next kernel call uses: during a trial's middle window the other count."""
        if self.most < 2:
            return 1
        step = self._count - self._trial_at
        if self.window <= step < 2 * self.window:
            return 3 - self.threads  # the other of 1 and 2
        return self.threads

    def timed(self, search: Callable[[int], object]) -> object:
        """`search(threads)`, a piece of work at the count `current` gives, timed when a trial runs."""
        threads = self.current()
        step = self._count - self._trial_at
        if self.most < 2 or step < 0:
            self._count += 1
            return search(threads)
        start = self.clock()
        result = search(threads)
        self._times.append(self.clock() - start)
        self._count += 1
        timed = len(self._times)
        if timed == 3 * self.window:
            self._decide()
        elif self.window < timed < 2 * self.window and sum(self._times[self.window :]) >= (1.0 - self.margin) * sum(
            self._times[: self.window]
        ):  # the other count's window already took too long to win: the trial is decided
            self._next_trial(min(2 * self._gap, self.max_interval))
        return result

    def _decide(self) -> None:
        w = self.window
        first, other, last = (sum(self._times[k * w : (k + 1) * w]) for k in range(3))
        if other < (1.0 - self.margin) * min(first, last):
            self.threads = 3 - self.threads
            self.switches += 1
            self._next_trial(self.interval)
        else:  # the count in use kept: the next trial twice as far off
            self._next_trial(min(2 * self._gap, self.max_interval))

    def _next_trial(self, gap: int) -> None:
        """The trial ended: the next one starts `gap` pieces from now."""
        self._gap = gap
        self._times = []
        self._trial_at = self._count + gap


def split_threads() -> int:
    """How many threads a split kernel may use, read in the thread that prepares a model: 2 where
    Numba has two threads or more there and substeps are not pinned to the serial build, else 1."""
    if requested_mode() == "serial":
        return 1
    return 2 if numba.get_num_threads() >= 2 else 1


def beside(first: Callable[[], object], second: Callable[[], object]) -> tuple[object, object]:
    """(first(), second()): `first` on the pool thread while this thread runs `second`. Each must
    be a `nogil` kernel call writing nothing the other reads or writes."""
    helper = helper_pool().submit(first)
    second_result = second()
    return helper.result(), second_result
