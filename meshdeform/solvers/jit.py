"""Numba compile options of every solver kernel, in one place so that all kernels compile alike.

`cache=True` keeps the compiled code on disk between runs; `error_model="numpy"` drops the
divide-by-zero checks from the loops; `nogil` lets two jobs of one process (Dask threads) run
kernels at once. FAST allows every fast-math flag; SWEEP all but reassociation, so the serial
and the parallel build of a sweep kernel compute every spring bit for bit alike.
"""

from __future__ import annotations

JIT = {"cache": True, "error_model": "numpy", "nogil": True}
FAST = {**JIT, "fastmath": True}
SWEEP = {**JIT, "fastmath": {"nnan", "ninf", "nsz", "arcp", "contract", "afn"}}
