"""Process memory: large arrays go back to the operating system as soon as they are freed.

glibc's malloc serves requests above a threshold (128 KiB at start) with their own mmap, which
`free` returns at once; but each time such a block is freed it raises the threshold (up to
32 MiB), so afterwards arrays of up to that size come from the heap, whose freed space the
process keeps. A run builds and drops many such arrays (spring topology, solver set-up, a
sparse factorisation), and the kept space shows up as peak memory.

The tool owns its processes, so it fixes the threshold: `tune_malloc` in the CLI process and
in every job (so process-pool and Dask workers too), `MALLOC_ENVIRONMENT` for processes it
starts. Elsewhere (musl, macOS, Windows) both do nothing. The engine (`meshdeform`) leaves
the allocator alone: a library should not change its host process's malloc.

The threshold is 4 MiB, not glibc's initial 128 KiB: every fresh mmapped array costs a page
fault per 4 KiB page when it is first written, and a run's set-up and frames make many arrays
of a few hundred KiB to a few MiB ((V, 3) positions are 1.5 MiB at 65 536 vertices); at 4 MiB
they come from the heap at the same peak memory (the figures: docs/performance.md, "The mmap
threshold").
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

#: bytes from which glibc serves an allocation by mmap, kept fixed (module docstring)
MMAP_THRESHOLD = 4 * 1024 * 1024
#: glibc's mallopt parameter number for the mmap threshold
_M_MMAP_THRESHOLD = -3
#: the same setting for a child process, read by glibc at its start
MALLOC_ENVIRONMENT = {"MALLOC_MMAP_THRESHOLD_": str(MMAP_THRESHOLD)}

_tuned = False


def tune_malloc() -> bool:
    """Fix glibc's mmap threshold at MMAP_THRESHOLD in this process; True if it was set."""
    global _tuned
    if _tuned:
        return True
    if not sys.platform.startswith("linux"):
        return False
    name = ctypes.util.find_library("c") or "libc.so.6"
    try:
        libc = ctypes.CDLL(name)
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc (musl has no mallopt)
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    _tuned = bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD))
    return _tuned
