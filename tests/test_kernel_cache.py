"""Numba's disk cache of the kernels follows every source file they are compiled from
(`meshdeform.solvers.jit.key_cache_on_package`): an edit of a called module alone recompiles its
callers, which Numba's own check (the caller's file only) missed."""

from __future__ import annotations

import importlib
import os
import pkgutil
import subprocess
import sys
import textwrap
from pathlib import Path

from numba.core.dispatcher import Dispatcher

import meshdeform
from meshdeform.solvers import jit

CALLER = """
from pathlib import Path

import numba as nb

from meshdeform.solvers.jit import JIT, key_cache_on_package

key_cache_on_package(Path(__file__).parent)

from cached_pkg.callee import value  # noqa: E402


@nb.njit(**JIT)
def caller():
    return value() + 100
"""


def _run(folder: Path) -> str:
    """caller() in a fresh process, with the package under `folder` and its own Numba cache there."""
    path = os.pathsep.join([str(folder), *sys.path])
    env = {**os.environ, "PYTHONPATH": path, "NUMBA_CACHE_DIR": str(folder / "cache")}
    code = "import cached_pkg.caller as c; print(c.caller())"
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout


def test_a_caller_cached_on_disk_is_compiled_again_when_only_its_callee_changed(tmp_path: Path) -> None:
    """A kernel calling a kernel of another module, both cached on disk: after the callee's module
    alone is edited, a new process runs the new callee (Numba alone handed back the cached
    caller with the old callee compiled into it)."""
    package = tmp_path / "cached_pkg"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "caller.py").write_text(CALLER)
    callee = "import numba as nb\n\n\n@nb.njit(cache=True)\ndef value():\n    return {}\n"
    (package / "callee.py").write_text(callee.format(1))
    assert _run(tmp_path).strip() == "101"
    assert _run(tmp_path).strip() == "101"  # from the cache
    assert any((tmp_path / "cache").rglob("*.nbi"))
    (package / "callee.py").write_text(callee.format(2) + textwrap.dedent("""
        # an edit elsewhere in the file
    """))
    assert _run(tmp_path).strip() == "102"


def test_every_cached_kernel_of_the_package_is_keyed_on_its_whole_source() -> None:
    """Every Numba kernel of meshdeform that caches on disk found a locator keyed on the package's
    source: each module defining kernels imports `meshdeform.solvers.jit` before it defines them."""
    package = Path(meshdeform.__file__).parent
    kernels = 0
    for module_info in pkgutil.walk_packages([str(package)], "meshdeform."):
        module = importlib.import_module(module_info.name)
        for value in vars(module).values():
            if isinstance(value, Dispatcher) and value.__module__ == module.__name__ and value._cache is not None:
                locator = getattr(value._cache, "_impl", None)
                locator = getattr(locator, "locator", None) or getattr(locator, "_locator", None)
                assert getattr(type(locator), "keyed_root", None) == jit.PACKAGE, value
                kernels += 1
    assert kernels > 100
