"""`meshdeform.contact.parts`: kernels split in parts over two threads give one call's result,
and keep working in a process forked after the split's pool thread was made."""

from __future__ import annotations

import multiprocessing

import numpy as np
import pytest

from meshdeform.contact import parts
from meshdeform.solvers import threads


def _doubled(values: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A row-by-row kernel stand-in over two lists, one updated in place."""
    rows += 1
    return 2 * values, rows.copy()


def test_parts_joined_in_order_are_one_call() -> None:
    """A per-query search and a row-by-row kernel split in parts give one call's arrays, and the
    row kernel's in-place updates reach the caller's array (the real searches and kernels:
    tests/test_self_collision.py::test_searches_split_over_two_threads_give_the_same_bytes)."""
    queries = np.arange(3000)
    one = parts.search_in_parts(lambda q, c: (q * q,), (), queries, (), 0, 1)
    split = parts.search_in_parts(lambda q, c: (q * q,), (), queries, (), 0, 2)
    assert np.array_equal(one[0], split[0])
    values, rows = np.arange(5000.0), np.zeros(2500, dtype=np.int64)
    doubled, updated = parts.by_rows(_doubled, ((values,), (rows,)), 2)
    assert np.array_equal(doubled, 2 * np.arange(5000.0)) and np.array_equal(updated, np.ones(2500))
    assert np.all(rows == 1)  # the parts were views of the caller's array


def _child(connection) -> None:
    result = parts.search_in_parts(lambda q, c: (q * q,), (), np.arange(4000), (), 0, 2)[0]
    connection.send(int(result.sum()))


@pytest.mark.skipif("fork" not in multiprocessing.get_all_start_methods(), reason="no fork on this platform")
def test_a_forked_process_gets_a_pool_of_its_own() -> None:
    """A library user forking after a split ran (multiprocessing's default on Linux) must not
    inherit the parent's pool: its thread does not exist in the child, and a part handed to it
    would never run (the child hung before)."""
    parts.search_in_parts(lambda q, c: (q * q,), (), np.arange(4000), (), 0, 2)  # the parent's pool
    context = multiprocessing.get_context("fork")
    receive, send = context.Pipe(duplex=False)
    child = context.Process(target=_child, args=(send,))
    child.start()
    child.join(30)
    hung = child.is_alive()
    if hung:
        child.kill()
    assert not hung, "the forked process hung on the parent's pool"
    assert receive.recv() == int((np.arange(4000) ** 2).sum())


class _FakeClock:
    """Seconds that a stand-in search moves on by its cost at the thread count it ran with."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def _searches(picker: threads.ThreadPicker, clock: _FakeClock, cost: dict[int, float], count: int) -> list[int]:
    """`count` pieces of work through the picker; the thread count each ran with."""
    used = []

    def search(threads: int) -> int:
        clock.now += cost[threads]
        used.append(threads)
        return threads

    for _ in range(count):
        assert picker.timed(search) == used[-1]
    return used


def test_the_thread_picker_drops_the_second_thread_where_it_is_slower() -> None:
    """Another process on one core: splitting is slower than one thread, and after its first
    trial the picker runs one thread; it tried the other count in the trial's middle window only."""
    clock = _FakeClock()
    picker = threads.ThreadPicker(2, window=5, interval=40, clock=clock)
    used = _searches(picker, clock, {1: 1.0, 2: 1.3}, 40 + 15 + 10)
    assert used[:40] == [2] * 40 and used[40:45] == [2] * 5 and used[45:50] == [1] * 5 and used[50:55] == [2] * 5
    assert picker.threads == 1 and picker.switches == 1 and used[55:] == [1] * 10


def test_the_thread_picker_keeps_two_threads_where_they_are_faster_and_tries_less_often() -> None:
    """Each trial of the slower count stops once it cannot win: 3 pieces of 1.0 s reach 0.95 of the
    first window's 5 x 0.6 s."""
    clock = _FakeClock()
    picker = threads.ThreadPicker(2, window=5, interval=40, clock=clock)
    used = _searches(picker, clock, {1: 1.0, 2: 0.6}, 40 + 8 + 80 + 8 + 10)
    assert picker.threads == 2 and picker.switches == 0
    assert used[40:45] == [2] * 5 and used[45:48] == [1] * 3 and used[48:133] == [2] * 85  # decided early
    assert used[133:136] == [1] * 3  # the second trial starts 80 pieces after the first ended
    assert used.count(1) == 6


def test_the_thread_picker_keeps_one_thread_when_one_is_all_it_may_use() -> None:
    clock = _FakeClock()
    picker = threads.ThreadPicker(1, clock=clock)
    assert set(_searches(picker, clock, {1: 1.0, 2: 0.1}, 200)) == {1}
