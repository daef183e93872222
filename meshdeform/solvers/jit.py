"""Numba compile options of every kernel, in one place so that all kernels compile alike, and the
disk cache they compile into.

`cache=True` keeps the compiled code on disk between runs; `error_model="numpy"` drops the
divide-by-zero checks from the loops; `nogil` lets two jobs of one process (Dask threads) run
kernels at once. FAST allows every fast-math flag; SWEEP all but reassociation, so the serial
and the parallel build of a sweep kernel (`serial_and_parallel`) compute every spring bit for
bit alike.

The cache: Numba checks a cached kernel against its own source file only, yet a kernel that calls
kernels of other modules has their code compiled into it. After an edit of those modules alone (a
`git pull` in the README's editable install) the cache handed back the caller with the old callee
inside: a pair search kept a grid rule that the grid no longer followed and visited 10^27 cells.
So every meshdeform kernel's cache is keyed on its own file and on a digest of every source file
of the package (`package_digest`, `key_cache_on_package`, run on import of this module, which
every module with kernels imports before it defines them): any change compiles them all afresh.
"""

from __future__ import annotations

import hashlib
import types
from collections.abc import Callable
from pathlib import Path

import numba as nb
from numba.core import caching
from numba.core.dispatcher import Dispatcher

#: the package whose source keys its kernels' cache
PACKAGE = Path(__file__).resolve().parent.parent


def package_digest(root: Path = PACKAGE) -> bytes:
    """SHA-256 of every .py file under `root` (relative path and contents, in sorted order)."""
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(path.relative_to(root).as_posix().encode() + b"\0")
        digest.update(path.read_bytes())
    return digest.digest()


def key_cache_on_package(root: Path = PACKAGE) -> None:
    """Key the Numba disk cache of every kernel defined in a file under `root` on `package_digest`
    as well as on its own file (the module docstring): Numba's source-file cache locators are
    replaced by subclasses whose source stamp holds both, for those files alone. Kernels defined
    before the call keep their locator; a second call for the same root does nothing. Numba's
    locators are a private part of Numba: where they are not as expected, nothing changes."""
    impl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl", None)
    backed = getattr(caching, "_SourceFileBackedLocatorMixin", None)
    classes = getattr(impl, "_locator_classes", None)
    if backed is None or not isinstance(classes, list):
        return
    root = root.resolve()
    if any(getattr(cls, "keyed_root", None) == root for cls in classes):
        return
    digest = package_digest(root)

    def keyed(base: type) -> type:
        def get_source_stamp(self: object) -> object:
            stamp = base.get_source_stamp(self)
            inside = Path(self._py_file).resolve().is_relative_to(root)  # type: ignore[attr-defined]
            return (stamp, digest) if inside else stamp

        return type(base.__name__, (base,), {"get_source_stamp": get_source_stamp, "keyed_root": root})

    impl._locator_classes = [keyed(cls) if issubclass(cls, backed) else cls for cls in classes]


key_cache_on_package()

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
