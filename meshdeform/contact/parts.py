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
faster than one (`meshdeform.solvers.threads`: the pool and the measured choice). Figures in
docs/performance.md.
"""

from __future__ import annotations

import functools
import itertools
from collections.abc import Callable

import numpy as np

from meshdeform.solvers.threads import helper_pool

#: a search with fewer queries runs in one call
MIN_QUERIES = 512
#: a per-pair kernel over fewer rows (all its lists together) runs in one call
MIN_ROWS = 2048
#: how many parts a split kernel runs in (taken in turn by two threads)
PARTS = 8

def _take(parts: list[Callable[[], tuple]], results: list, counter: itertools.count) -> None:
    """Run parts in turn, the next one not taken yet each time (`next` on a count is atomic)."""
    while (index := next(counter)) < len(parts):
        results[index] = parts[index]()


def _joined(parts: list[Callable[[], tuple[np.ndarray, ...]]]) -> tuple[np.ndarray, ...]:
    """Every part run by this thread and a pool thread, whichever is free; their outputs joined
    in part order."""
    results: list = [None] * len(parts)
    counter = itertools.count()
    helper = helper_pool().submit(_take, parts, results, counter)
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
