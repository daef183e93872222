"""The implicit solver's memory: its set-up and first step (the sparse factorisation) take memory
linear in the vertex count, far from what a dense factor of the same matrix would take.

Measured as the growth of the peak resident memory (VmHWM, reset through /proc/self/clear_refs)
of a fresh interpreter over `solver.step` on a cloth built beforehand, after a first solver's step
on the same cloth (its kernels compiled or loaded, the factor's library in memory). Not with
tracemalloc: CHOLMOD allocates its factor in C, outside the allocator tracemalloc follows, so
tracemalloc would be blind to the one part that could go dense. glibc's mmap
threshold is fixed at 128 KiB, so large arrays are mapped and unmapped with their own pages and
the peak is that of the step, not of what the heap kept (the tool's own threshold,
`pipeline.memory`, is 4 MiB: arrays below it would reuse what the first solver's step left in
the heap, and the growth would tell the allocator's state rather than the step's needs).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from meshdeform.solvers.implicit.cholesky import OWN_FACTOR_ROWS

TESTS = Path(__file__).resolve().parent
#: glibc's mmap threshold in the probe (bytes; the module docstring)
MMAP_THRESHOLD = 128 * 1024

#: bytes of peak memory per vertex that set-up and the first step may take. Measured here: 1.4-1.5
#: kB a vertex with CHOLMOD's factor at 9k to 65k vertices, 1.5-1.6 kB with ours at 16k to 65k (a
#: third NumPy: per spring ends, rest length, weight and stiffnesses, the matrix's COO and CSC
#: arrays; the rest the factor, whose fill with a fill-reducing ordering grows like V log V,
#: docs/performance.md). 3 kB leaves nearly twice that. A dense Cholesky factor of the
#: (V, V) matrix holds its lower triangle, 8 V^2 / 2 bytes: 4 V bytes a vertex, 37 kB at 9k
#: vertices, twelve times the bound, and four times as much for twice the vertices.
BYTES_PER_VERTEX = 3000

# Prints the vertex count and the growth of the peak resident memory (bytes) over the first step
# of the implicit solver on an nx x ny cloth (square cells) hanging from its top corners.
PROBE = """
import gc, json, sys
import numpy as np
from factories import TOP_CORNERS, grid_cloth
from meshdeform.model import State
from meshdeform.solvers import Control, make_solver

def status(key):
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) * 1024 for line in f if line.startswith(key + ":"))

def ready(nx, ny):
    model = grid_cloth(nx, ny, pins=TOP_CORNERS, size=(1.0, ny / nx)).model
    control = Control(np.tile([0.0, -9.81, 0.0], (model.vertex_count, 1)))
    return model, make_solver("implicit"), State.at_rest(model), control

# a first solver on the same cloth: every kernel the size takes compiled or loaded, the factor's
# library in memory, the helper thread started; the second's set-up and first step are measured
model, solver, state, control = ready(int(sys.argv[1]), int(sys.argv[2]))
solver.step(model, state, 1.0 / 24.0, control)
del model, solver, state, control
gc.collect()
model, solver, state, control = ready(int(sys.argv[1]), int(sys.argv[2]))
with open("/proc/self/clear_refs", "w") as f:
    f.write("5")  # the peak resident memory (VmHWM) starts again from the current one
before = status("VmRSS")
solver.step(model, state, 1.0 / 24.0, control)
print(json.dumps({"vertices": model.vertex_count, "peak": status("VmHWM") - before}))
"""


def clear_refs_resets_the_peak() -> bool:
    """True where a process may reset its VmHWM (Linux 4.0 and later: /proc/self/clear_refs)."""
    return sys.platform.startswith("linux") and os.access("/proc/self/clear_refs", os.W_OK)


def first_step_peak(nx: int, ny: int) -> tuple[int, int]:
    """(vertices, bytes): the peak memory the implicit solver's first step on an nx x ny cloth
    takes, measured in a fresh interpreter."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_") and k != "GLIBC_TUNABLES"}
    env["PYTHONPATH"] = os.pathsep.join([str(TESTS.parent), str(TESTS), env.get("PYTHONPATH", "")])
    env["MALLOC_MMAP_THRESHOLD_"] = str(MMAP_THRESHOLD)  # read by glibc as the interpreter starts
    probe = subprocess.run([sys.executable, "-c", PROBE, str(nx), str(ny)], capture_output=True, text=True, env=env)
    assert probe.returncode == 0, probe.stderr
    result = json.loads(probe.stdout.splitlines()[-1])
    return result["vertices"], result["peak"]


@pytest.mark.skipif(not clear_refs_resets_the_peak(), reason="needs Linux's VmHWM reset")
@pytest.mark.parametrize(("nx", "factor"), [(96, "CHOLMOD's"), (150, "our own")])
def test_first_step_memory_grows_linearly_with_the_vertex_count(nx: int, factor: str) -> None:
    """nx x nx and nx x 2 nx vertices, with either factor (`cholesky.OWN_FACTOR_ROWS`): twice the
    vertices take about twice the peak, under 2.6x (a factor filling in like V log V takes 2.15x,
    2.1-2.2x measured; one like V^1.5, as without a fill-reducing ordering, 2.8x; a dense one
    4x), and each stays under BYTES_PER_VERTEX a vertex."""
    small_vertices, small = first_step_peak(nx, nx)
    large_vertices, large = first_step_peak(nx, 2 * nx)
    assert large_vertices == 2 * small_vertices == 2 * nx * nx
    assert (small_vertices - 2 >= OWN_FACTOR_ROWS) == (factor == "our own")  # both sizes on the same factor
    assert (large_vertices - 2 >= OWN_FACTOR_ROWS) == (factor == "our own")
    # the measurement sees the step: at least the (V, 3) rhs and solution buffers the solver keeps
    assert small > 2 * 24 * small_vertices
    assert large / small < 2.6, (small, large)
    assert small / small_vertices < BYTES_PER_VERTEX, small
    assert large / large_vertices < BYTES_PER_VERTEX, large
