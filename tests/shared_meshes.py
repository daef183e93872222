"""Where the public real/broken test meshes live: ../shared/meshes beside the repo, or $MESHDEFORM_SHARED_MESHES.

Module-level (not only a fixture) because several test modules parametrize over the files in it.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest


def find_shared_meshes() -> Path | None:
    """The shared meshes folder, or None when it is absent (tests using it then skip)."""
    here = Path(__file__).resolve().parents[2] / "shared" / "meshes"
    if here.is_dir():
        return here
    env = os.environ.get("MESHDEFORM_SHARED_MESHES")
    return Path(env) if env and Path(env).is_dir() else None


MESHES = find_shared_meshes()
needs_meshes = pytest.mark.skipif(MESHES is None, reason="shared test meshes not found")
