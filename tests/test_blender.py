"""A real bake opened in Blender with every importer option and modifier setting at its default:
at every scene frame F the Mesh Cache modifier (PC2, MDD) on the imported rest-pose OBJ and the
imported USD stage show the OBJ file of frame F as Blender imports it (benchmarks/blender_check.py).

Blender runs as the `bpy` module in a venv of its own (it is never a dependency of meshdeform):
name its Python in MESHDEFORM_BPY_PYTHON (`python3.11 -m venv V && V/bin/pip install bpy numpy`).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BPY_PYTHON = os.environ.get("MESHDEFORM_BPY_PYTHON")

pytestmark = pytest.mark.skipif(not BPY_PYTHON, reason="MESHDEFORM_BPY_PYTHON names no Python with bpy")


@pytest.mark.parametrize("start_frame", [1, 0, 7])
def test_point_caches_and_usd_play_in_blender_at_its_defaults_as_the_obj_frames(
    tmp_path: Path, start_frame: int
) -> None:
    script = ROOT / "benchmarks" / "blender_check.py"
    subprocess.run(
        [sys.executable, str(script), "--make", str(tmp_path), "--start-frame", str(start_frame)], check=True
    )
    done = subprocess.run([BPY_PYTHON, str(script), "--check", str(tmp_path)], capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
    assert f"frame {start_frame} is the rest pose" in done.stdout
    for name in ("PC2", "MDD", "USD"):
        assert f"{name}: max |difference| to the OBJ of the same scene frame" in done.stdout
