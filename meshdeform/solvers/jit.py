"""Numba compile options of every solver kernel, in one place so that all kernels compile alike.

`cache=True` keeps the compiled code on disk between runs; `error_model="numpy"` drops the
divide-by-zero checks from the loops; `nogil` lets two jobs of one process (Dask threads) run
kernels at once. FAST allows every fast-math flag; SWEEP all but reassociation, so the serial
and the parallel build of a sweep kernel (`serial_and_parallel`) compute every spring bit for
bit alike.
"""

from __future__ import annotations

import types
from collections.abc import Callable

import numba as nb
from numba.core.dispatcher import Dispatcher

JIT = {"cache": True, "error_model": "numpy", "nogil": True}
FAST = {**JIT, "fastmath": True}
SWEEP = {**JIT, "fastmath": {"nnan", "ninf", "nsz", "arcp", "contract", "afn"}}


def serial_and_parallel(kernel: Callable[..., None], **options: object) -> tuple[Dispatcher, Dispatcher]:
    """The serial and the parallel build of `kernel`, a function written with `numba.prange` loops.

    The serial build runs those loops as plain loops, in order; the parallel build splits each
    over Numba's threads. The parallel one compiles a copy of the function named
    `<name>_parallel`, because Numba's disk cache tells functions apart by name and bytecode,
    not by compile options: under one name the two builds would load each other's code.
    """
    name = f"{kernel.__name__}_parallel"
    copy = types.FunctionType(kernel.__code__, kernel.__globals__, name, kernel.__defaults__, kernel.__closure__)
    copy.__qualname__ = name
    copy.__doc__ = kernel.__doc__
    return nb.njit(**options)(kernel), nb.njit(parallel=True, **options)(copy)


@nb.njit(**JIT)
def opaque(value):  # pragma: no cover - compiled
    """`value` (an integer or a bool) as a runtime value. A kernel that compiled code calls with a
    constant argument (`f(x, True)`, `g(i, -1)`) is compiled for that constant (Numba types it
    `Literal`), once per constant and once more for runtime values, and so are the kernels it
    calls in turn; passed through here the argument costs one compile. (`value | value`: an
    operation's result is typed as a plain value, where a returned argument keeps its literal.)"""
    return value | value
