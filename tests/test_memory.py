"""pipeline.memory: with the mmap threshold fixed, a freed large array no longer makes later
arrays of several MiB come from the heap (where their memory stays with the process)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from pipeline.memory import MALLOC_ENVIRONMENT, MMAP_THRESHOLD

glibc = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc malloc only")

# Frees a 16 MiB array (glibc then raises its threshold to 16 MiB unless it is fixed), allocates
# an 8 MiB one and reports by how much that grew the bytes in mmapped blocks (mallinfo2: hblkhd).
PROBE = """
import ctypes, json, sys
import numpy as np
if sys.argv[1] == "tuned":
    from pipeline.memory import tune_malloc
    assert tune_malloc()
class Info(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in ("arena", "ordblks", "smblks", "hblks", "hblkhd",
                                               "usmblks", "fsmblks", "uordblks", "fordblks", "keepcost")]
libc = ctypes.CDLL("libc.so.6")
libc.mallinfo2.restype = Info
big = np.ones(2 ** 21)
del big
before = libc.mallinfo2().hblkhd
small = np.ones(2 ** 20)
print(json.dumps({"mmapped": libc.mallinfo2().hblkhd - before, "small": small.nbytes}))
"""


def probe(mode: str, env: dict[str, str] | None = None) -> dict:
    """Run PROBE in a fresh interpreter ("tuned" calls tune_malloc first) with `env` added."""
    # without any malloc setting from outside (Dask sets MALLOC_TRIM_THRESHOLD_ in its parent process)
    run_env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_") and k != "GLIBC_TUNABLES"}
    run_env.update(env or {})
    out = subprocess.run(
        [sys.executable, "-c", PROBE, mode], capture_output=True, text=True, check=True, env=run_env
    ).stdout
    return json.loads(out.splitlines()[-1])


@glibc
def test_tuned_process_serves_an_8_mib_array_by_mmap_after_a_large_one_was_freed() -> None:
    untuned = probe("plain")
    tuned = probe("tuned")
    assert untuned["mmapped"] < untuned["small"]  # the dynamic threshold moved it to the heap
    assert tuned["mmapped"] >= tuned["small"] > MMAP_THRESHOLD


@glibc
def test_child_environment_sets_the_same_threshold() -> None:
    child = probe("plain", env=MALLOC_ENVIRONMENT)
    assert child["mmapped"] >= child["small"]
