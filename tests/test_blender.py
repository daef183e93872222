"""A real bake opened in Blender with every importer option and modifier setting at its default:
at every scene frame F the Mesh Cache modifier (PC2, MDD) on the object the caches are for, the
imported USD stage and the imported glTF scene show the OBJ file of frame F as Blender imports it
(benchmarks/blender_check.py), for `up_axis = "y"` (caches on the imported rest OBJ) and `"z"`
(caches on the Z-up mesh the OBJ was exported from, which Blender's OBJ exporter proves).

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


CASES = [(1, "y", "y"), (0, "y", "y"), (7, "y", "y"), (1, "y", "z"), (7, "y", "z"), (1, "z", "default"), (7, "z", "z")]


@pytest.mark.parametrize(("start_frame", "input_up", "up_axis"), CASES)
def test_point_caches_usd_and_gltf_play_in_blender_at_its_defaults_as_the_obj_frames(
    tmp_path: Path, start_frame: int, input_up: str, up_axis: str
) -> None:
    """A Z-up input (`simulation.up = "z"`) is imported as Z up (the OBJ importer's one non-default
    setting); its caches default to its own coordinates, its USD stage is Z up and its glTF Y up."""
    script = ROOT / "benchmarks" / "blender_check.py"
    subprocess.run(
        [sys.executable, str(script), "--make", str(tmp_path), "--start-frame", str(start_frame),
         "--input-up", input_up, "--up-axis", up_axis],
        check=True,
    )  # fmt: skip
    done = subprocess.run([BPY_PYTHON, str(script), "--check", str(tmp_path)], capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
    written = input_up if up_axis == "default" else up_axis
    assert f"input up {input_up}, up_axis {written}, " in done.stdout
    assert f"frame {start_frame} is the rest pose" in done.stdout
    if (input_up, written) == ("y", "z"):
        assert "the Z-up mesh exported by Blender's OBJ exporter" in done.stdout
    for name in ("PC2", "MDD", "USD", "glTF"):
        assert f"{name}: max |difference| to the OBJ of the same scene frame" in done.stdout
