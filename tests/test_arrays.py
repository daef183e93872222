"""The fast integer helpers must order exactly as NumPy's reference functions do."""

from __future__ import annotations

import numpy as np
import pytest

from meshdeform.arrays import argsort_int, dense_rank, lexsort_int


@pytest.mark.parametrize("high", [3, 1000, 2**40])
def test_lexsort_int_matches_np_lexsort(high: int) -> None:
    rng = np.random.default_rng(7)
    keys = tuple(rng.integers(0, high, size=5000) for _ in range(3))
    # few distinct values (high = 3) make many ties: stability decides their order
    np.testing.assert_array_equal(lexsort_int(keys), np.lexsort(keys))


def test_lexsort_int_falls_back_for_negative_or_wide_keys() -> None:
    rng = np.random.default_rng(8)
    wide = (rng.integers(0, 2**40, size=200), rng.integers(0, 2**40, size=200))
    negative = (rng.integers(-5, 5, size=200), rng.integers(0, 3, size=200))
    for keys in (wide, negative):
        np.testing.assert_array_equal(lexsort_int(keys), np.lexsort(keys))
    assert lexsort_int((np.zeros(0, dtype=np.int64),)).shape == (0,)


def test_argsort_int_is_stable() -> None:
    values = np.array([3, 1, 3, 0, 1, 3])
    np.testing.assert_array_equal(argsort_int(values), np.argsort(values, kind="stable"))


def test_dense_rank_keeps_order_and_ties() -> None:
    values = np.array([0.5, -1.0, 0.5, 2.0, -1.0, 0.25])
    rank = dense_rank(values)
    np.testing.assert_array_equal(rank, [2, 0, 2, 3, 0, 1])
    rng = np.random.default_rng(9)
    x = rng.integers(0, 50, size=1000).astype(float)
    r = dense_rank(x)
    np.testing.assert_array_equal(np.sign(x[:, None] - x[None, :]), np.sign(r[:, None] - r[None, :]))
    assert dense_rank(np.zeros(0)).shape == (0,)
