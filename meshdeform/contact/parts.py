"""Self-collision's per-pair and per-query kernels in parts, on two threads at once.

- `search_in_parts`: the searches of `self_kernels` (`vf_candidates`, `ee_candidates`) report their
  pairs query by query, so the pairs of the first part of the queries followed by those of the
  next parts are the pairs of one call over all of them, in the same order.
- `by_rows`: a kernel whose work is row by row over pair lists (`proximity_sides`,
  `colliding_pairs`: each row read and written alone) gives, over consecutive parts of its lists,
  the rows of one call; rows updated in place are views of the caller's arrays.
- `ee_candidates_in_cells` reports its pairs bucket by bucket, so its buckets split the same way.
So a split never changes a result, whatever the thread count or which thread ran which part. The
kernels are compiled with `nogil` (`solvers.jit.JIT`): the calling thread and a pool thread take
the parts in turn, `PARTS` of them (more parts than threads, so that a thread whose parts are
quick takes more: the queries of a pile are far from alike).

Splitting pays only where a kernel is long next to handing work to a thread (tens of
microseconds): `MIN_QUERIES` queries or `MIN_ROWS` rows or more; and only with two Numba threads
or more in the thread that prepares the model (a batch gives each job its share of the cores;
the `MESHDEFORM_PARALLEL_SUBSTEPS=0` pin asks for one), and while `ThreadPicker` measures two
faster than one. Figures in docs/performance.md.
"""

from __future__ import annotations

import functools
import itertools
import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np

from meshdeform.solvers.dispatch import requested_mode

#: a search with fewer queries runs in one call
MIN_QUERIES = 512
#: a per-pair kernel over fewer rows (all its lists together) runs in one call
MIN_ROWS = 2048
#: how many parts a split kernel runs in (taken in turn by two threads)
PARTS = 8

_pool: ThreadPoolExecutor | None = None
_pool_pid = 0  # the process that made `_pool`: a forked child has none of its threads
_pool_lock = threading.Lock()


def _worker() -> ThreadPoolExecutor:
    """The pool whose thread takes parts beside the caller (made on first use in each process;
    shared by every split, so two jobs in threads of one process each get a pool thread)."""
    global _pool, _pool_pid
    with _pool_lock:
        if _pool is None or _pool_pid != os.getpid():
            _pool = ThreadPoolExecutor(max_workers=2, thread_name_prefix="meshdeform-search")
            _pool_pid = os.getpid()
        return _pool


class ThreadPicker:
    """How many threads the split kernels use now: two where measured faster, else one.

    With another process on one of the two cores, splitting can run slower than one thread (the
    contact scenes of benchmarks/contact.py with a busy loop beside them: 2-5 %;
    docs/performance.md, "Two threads or one, by measurement"), and only measuring tells the two
    machines apart. The caller times comparable pieces of
    work (`timed`: self-collision's contact of one substep; over a window of several substeps, the
    whole searches of the pair lists every few substeps included, alike from window to window);
    every `interval` pieces a trial runs `window` of them at the count in use, `window` at the
    other and `window` at the first again, and the other count is kept when its window's seconds beat
    both windows around it by `margin` (noise does not flip it back and forth; sums, not medians: the
    dear pieces, the whole searches, are a few of each window's). Without a switch the
    interval doubles, up to `max_interval`. Neither count changes a result (module docstring):
    only the speed.

    most: the threads allowed (`search_threads`); clock: seconds (tests pass a fake)."""

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
        if len(self._times) == 3 * self.window:
            self._decide()
        return result

    def _decide(self) -> None:
        w = self.window
        first, other, last = (sum(self._times[k * w : (k + 1) * w]) for k in range(3))
        if other < (1.0 - self.margin) * min(first, last):
            self.threads = 3 - self.threads
            self.switches += 1
            self._gap = self.interval
        else:
            self._gap = min(2 * self._gap, self.max_interval)
        self._times = []
        self._trial_at = self._count + self._gap


def search_threads() -> int:
    """How many threads a search may use, read in the thread that prepares a model: 2 where
    Numba has two threads or more there and substeps are not pinned to the serial build, else 1."""
    if requested_mode() == "serial":
        return 1
    return 2 if numba.get_num_threads() >= 2 else 1


def _take(parts: list[Callable[[], tuple]], results: list, counter: itertools.count) -> None:
    """Run parts in turn, the next one not taken yet each time (`next` on a count is atomic)."""
    while (index := next(counter)) < len(parts):
        results[index] = parts[index]()


def _joined(parts: list[Callable[[], tuple[np.ndarray, ...]]]) -> tuple[np.ndarray, ...]:
    """Every part run by this thread and a pool thread, whichever is free; their outputs joined
    in part order."""
    results: list = [None] * len(parts)
    counter = itertools.count()
    helper = _worker().submit(_take, parts, results, counter)
    _take(parts, results, counter)
    helper.result()
    return tuple(np.concatenate(pieces) for pieces in zip(*results, strict=True))


def _bounds(length: int, parts: int) -> list[tuple[int, int]]:
    """`parts` consecutive ranges (start, stop) covering 0..length, alike in size."""
    cuts = [length * k // parts for k in range(parts + 1)]
    return list(itertools.pairwise(cuts))


def search_in_parts(
    search: Callable[..., tuple[np.ndarray, ...]],
    before: tuple,
    queries: np.ndarray,
    after: tuple,
    capacity: int,
    threads: int,
) -> tuple[np.ndarray, ...]:
    """`search(*before, queries, *after, capacity)`, its queries (Q,) split in `PARTS` parts run
    on two threads where `threads` >= 2 and Q >= MIN_QUERIES; the arrays it returns, the parts'
    joined (the same arrays as one call: module docstring). capacity: the expected pair count."""
    if threads < 2 or queries.shape[0] < MIN_QUERIES:
        return search(*before, queries, *after, capacity)
    share = capacity // PARTS
    parts = [
        functools.partial(search, *before, queries[start:stop], *after, share)
        for start, stop in _bounds(queries.shape[0], PARTS)
    ]
    return _joined(parts)


def by_rows(
    kernel: Callable[..., tuple[np.ndarray, ...]],
    groups: tuple[tuple[np.ndarray, ...], ...],
    threads: int,
) -> tuple[np.ndarray, ...]:
    """`kernel(*arrays of every group)`, each group's arrays (rows along axis 0, alike in length
    within a group) split in `PARTS` consecutive parts, where `threads` >= 2 and the groups hold
    MIN_ROWS rows or more together: the kernel's per-row outputs (one per group's rows, in its
    return order) joined (the same arrays as one call: module docstring)."""
    rows = sum(group[0].shape[0] for group in groups)
    if threads < 2 or rows < MIN_ROWS:
        return kernel(*(array for group in groups for array in group))
    ranges = [_bounds(group[0].shape[0], PARTS) for group in groups]
    parts = [
        functools.partial(
            kernel,
            *(
                array[spans[part][0] : spans[part][1]]
                for group, spans in zip(groups, ranges, strict=True)
                for array in group
            ),
        )
        for part in range(PARTS)
    ]
    return _joined(parts)
