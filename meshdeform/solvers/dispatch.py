"""Which build of a substep kernel runs: the serial one, unless parallel substeps are asked for.

verlet and xpbd compile each substep kernel twice, a serial and a parallel build, and both
compute bit for bit the same result (the slabs of a `SpringLayout` share no vertex, the vertex
and tether chunks of `layout.KernelChunks` split only element-wise work): the build decides the
speed, never the output. The parallel build runs the slabs on one Numba thread each; it pays
only on cores nothing else is using, which a run cannot know beforehand nor tell reliably from
timing a few short calls (docs/performance.md, "Serial or parallel substeps"). So the serial
build is the default, and the parallel one runs only where it is asked for:

- `PARALLEL_SUBSTEPS` (MESHDEFORM_PARALLEL_SUBSTEPS=1 in the environment, read when a solver
  prepares a model: batch workers inherit it), and
- the layout has more than one slab (`partitions`, see `layout.resolve_parts`), and
- Numba has more than one thread in the thread that prepares the model
  (`numba.get_num_threads()`: NUMBA_NUM_THREADS, or `numba.set_num_threads` in that thread;
  the batch sizes it per worker). The parallel build uses at most one thread per slab.

The choice is made once per prepared model (a run, and again after a tear), never while it
runs. Neither the thread count nor the choice changes a result: only `partitions` does.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import TypeVar

import numba as nb

#: the environment variable that asks for the parallel build ("1": yes; anything else: no)
PARALLEL_SUBSTEPS = "MESHDEFORM_PARALLEL_SUBSTEPS"

Kernel = TypeVar("Kernel", bound=Callable[..., None])


def parallel_requested() -> bool:
    """Whether the environment asks for parallel substeps (`PARALLEL_SUBSTEPS` is "1")."""
    return os.environ.get(PARALLEL_SUBSTEPS, "").strip() == "1"


def substep_build(serial: Kernel, parallel: Kernel, parts: int) -> Kernel:
    """The build to run on a layout of `parts` slabs: `parallel` when it is requested, there is
    more than one slab and Numba has more than one thread here (see the module docstring);
    otherwise `serial`. Both take the same arguments and give the same bytes."""
    if parts > 1 and parallel_requested() and nb.get_num_threads() > 1:
        return parallel
    return serial
