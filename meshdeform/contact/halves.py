"""A candidate search over its queries in two halves at once, on two threads.

The searches of `self_kernels` (`vf_candidates`, `ee_candidates`) report their pairs query by
query, so the pairs of the first half of the queries followed by those of the second half are
the pairs of one call over all of them, in the same order: the split never changes a result,
whatever the thread count. The kernels are compiled with `nogil` (`solvers.jit.JIT`), so the
second half runs on a pool thread while the calling thread runs the first.

Splitting pays only where a search is long next to handing work to a thread (tens of
microseconds): `MIN_QUERIES` queries or more; and only with two Numba threads or more in the
thread that prepares the model (a batch gives each job its share of the cores; the
`MESHDEFORM_PARALLEL_SUBSTEPS=0` pin asks for one). Figures in docs/performance.md.
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
