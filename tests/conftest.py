"""Shared fixtures: the real/broken mesh folders beside the repo, headless rendering, one Numba thread.

Shared builders are plain functions beside this file, imported by name (this folder is on the
path of every test module): tests/factories.py makes cloth grids (`grid_sheet`), their pins by
side or corner (`grid_pins`, `TOP_CORNERS`), their spring models (`grid_cloth`), OBJ files of them
(`write_grid`), slit copies of them (`slit_grid`) and a one-command CLI app (`command_app`);
tests/checks.py holds shared checks (`refused`: a reader's one-line refusal); tests/shared_meshes.py
finds the shared real and broken meshes.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")

from shared_meshes import MESHES

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session")
def shared_meshes() -> Path:
    """../shared/meshes (with real/ and broken/); tests using it skip only when it is absent."""
    if MESHES is None:
        pytest.skip("shared meshes folder not found beside the repo nor at $MESHDEFORM_SHARED_MESHES")
    return MESHES


@pytest.fixture(scope="session")
def samples_dir() -> Path:
    return REPO / "samples"


@pytest.fixture(scope="module")
def one_numba_thread():
    """Tiny meshes: parallel kernels only add thread hand-offs (slow on a busy machine)."""
    import numba

    before = numba.get_num_threads()
    numba.set_num_threads(1)
    yield
    numba.set_num_threads(before)
