"""Self-collision's per-pair and per-query kernels over two halves at once, on two threads.

- `in_halves`: the searches of `self_kernels` (`vf_candidates`, `ee_candidates`) report their
  pairs query by query, so the pairs of the first half of the queries followed by those of the
  second half are the pairs of one call over all of them, in the same order.
- `by_rows`: a kernel whose work is row by row over pair lists (`proximity_sides`,
  `colliding_pairs`: each row read and written alone) gives, over the first halves of its lists
  and then the second halves, the rows of one call; rows updated in place are views of the
  caller's arrays.
So a split never changes a result, whatever the thread count. The kernels are compiled with
`nogil` (`solvers.jit.JIT`), so the second half runs on a pool thread while the calling thread
runs the first.

Splitting pays only where a kernel is long next to handing work to a thread (tens of
microseconds): `MIN_QUERIES` queries or `MIN_ROWS` rows or more; and only with two Numba threads
or more in the thread that prepares the model (a batch gives each job its share of the cores;
the `MESHDEFORM_PARALLEL_SUBSTEPS=0` pin asks for one). Figures in docs/performance.md.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np

from meshdeform.solvers.dispatch import requested_mode

#: a search with fewer queries runs in one call
MIN_QUERIES = 512
#: a per-pair kernel over fewer rows (all its lists together) runs in one call
MIN_ROWS = 2048

_pool: ThreadPoolExecutor | None = None
_pool_lock = threading.Lock()


def _worker() -> ThreadPoolExecutor:
    """The pool thread that runs second halves (made on first use; shared by every search)."""
    global _pool
    with _pool_lock:
        if _pool is None:
            _pool = ThreadPoolExecutor(max_workers=2, thread_name_prefix="meshdeform-search")
        return _pool


def search_threads() -> int:
    """How many threads a search may use, read in the thread that prepares a model: 2 where
    Numba has two threads or more there and substeps are not pinned to the serial build, else 1."""
    if requested_mode() == "serial":
        return 1
    return 2 if numba.get_num_threads() >= 2 else 1


def in_halves(
    search: Callable[..., tuple[np.ndarray, ...]],
    before: tuple,
    queries: np.ndarray,
    after: tuple,
    capacity: int,
    threads: int,
) -> tuple[np.ndarray, ...]:
    """`search(*before, queries, *after, capacity)`, its queries (Q,) split in two halves run at
    once where `threads` >= 2 and Q >= MIN_QUERIES; the arrays it returns, the halves' joined
    (the same arrays as one call: module docstring). capacity: the expected pair count."""
    if threads < 2 or queries.shape[0] < MIN_QUERIES:
        return search(*before, queries, *after, capacity)
    half = queries.shape[0] // 2
    second = _worker().submit(search, *before, queries[half:], *after, capacity // 2)
    first = search(*before, queries[:half], *after, capacity // 2)
    return tuple(np.concatenate([a, b]) for a, b in zip(first, second.result(), strict=True))


def by_rows(
    kernel: Callable[..., tuple[np.ndarray, ...]],
    groups: tuple[tuple[np.ndarray, ...], ...],
    threads: int,
) -> tuple[np.ndarray, ...]:
    """`kernel(*arrays of every group)`, each group's arrays (rows along axis 0, alike in length
    within a group) split at the group's half, where `threads` >= 2 and the groups hold MIN_ROWS
    rows or more together: the kernel's per-row outputs (one per group's rows, in its return
    order) joined (the same arrays as one call: module docstring)."""
    rows = sum(group[0].shape[0] for group in groups)
    if threads < 2 or rows < MIN_ROWS:
        return kernel(*(array for group in groups for array in group))
    halves = [group[0].shape[0] // 2 for group in groups]
    first = [array[:half] for group, half in zip(groups, halves, strict=True) for array in group]
    second = [array[half:] for group, half in zip(groups, halves, strict=True) for array in group]
    later = _worker().submit(kernel, *second)
    done = kernel(*first)
    return tuple(np.concatenate([a, b]) for a, b in zip(done, later.result(), strict=True))
