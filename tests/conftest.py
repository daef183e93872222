"""Shared fixtures: the real/broken mesh folders beside the repo, headless rendering, a fresh Numba cache."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")

REPO = Path(__file__).resolve().parents[1]
SHARED_MESHES = Path(os.environ.get("MESHDEFORM_SHARED_MESHES", REPO.parent / "shared" / "meshes"))


@pytest.fixture(scope="session")
def shared_meshes() -> Path:
    """../shared/meshes (with real/ and broken/); tests using it skip only when it is absent."""
    if not SHARED_MESHES.is_dir():
        pytest.skip(f"shared meshes folder not found at {SHARED_MESHES}")
    return SHARED_MESHES


@pytest.fixture(scope="session")
def samples_dir() -> Path:
    return REPO / "samples"
