"""The up-axis story without Blender (tests/test_blender.py checks the same files in Blender): every
output is in the world its docs name, for a Y-up and a Z-up input (docs/recipes.md, "Up axis").

The expected coordinates come from scipy's rotations about X (a right-handed +-90 degree turn), not
from the exporters' own turn."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from test_gltf import accessor, read_glb
from vat_reader import decode

from meshdeform.export import ExportContext, ExportSession, FrameData, turn_about_x
from meshdeform.mesh import grid_mesh

FPS = 24.0
#: a Y-up world into Blender's Z-up one (+90 degrees about X) and back
Y_TO_Z = Rotation.from_euler("x", 90, degrees=True)
Z_TO_Y = Y_TO_Z.inv()


def read_pc2(path: Path) -> np.ndarray:
    """The samples (S, V, 3) of a PC2 file, read by its published layout: a 32-byte header
    (b"POINTCACHE2\\0", version, points, start, rate, samples) then float32 xyz."""
    data = path.read_bytes()
    points, samples = np.frombuffer(data, "<i4", 1, 16)[0], np.frombuffer(data, "<i4", 1, 28)[0]
    assert data[:12] == b"POINTCACHE2\0"
    return np.frombuffer(data, "<f4", offset=32).reshape(samples, points, 3)


def motion(rest: np.ndarray, k: int, up: int) -> np.ndarray:
    """Frame k of a sheet swinging and falling along `up` (the axis index of the input's up)."""
    pos = rest.copy()
    pos[:, 0] += 0.05 * np.sin(k + pos[:, up] * 3.0)
    pos[:, up] -= 0.01 * k * k
    return pos


def bake(folder: Path, input_up: str, up_axis: str | None, formats: list[str]) -> list[np.ndarray]:
    """A 5 x 4 sheet standing in the input's world (vertical, its up axis `input_up`), 4 frames."""
    sheet = grid_mesh(5, 4, size=(1.0, 0.8))
    if input_up == "z":  # stand it up in a Z-up world
        sheet = replace(sheet, positions=Y_TO_Z.apply(sheet.positions))
    up = 1 if input_up == "y" else 2
    states = [motion(sheet.positions, k, up) for k in range(4)]
    ctx = ExportContext(mesh=sheet, out_dir=folder, fps=FPS, frame_count=3, up_axis=up_axis, input_up=input_up)
    with ExportSession(formats, ctx) as session:
        for k, pos in enumerate(states):
            session.write(FrameData(k, k / FPS, pos))
    return states


@pytest.mark.parametrize("turns", [1, -1, 2, 0])
def test_turn_about_x_is_a_right_handed_quarter_turn(turns: int) -> None:
    points = np.random.default_rng(3).normal(size=(20, 3))
    expected = Rotation.from_euler("x", 90 * turns, degrees=True).apply(points)
    np.testing.assert_allclose(turn_about_x(points, turns), expected, atol=1e-12)
    np.testing.assert_allclose(turn_about_x(turn_about_x(points, turns), -turns), points, atol=1e-12)


@pytest.mark.parametrize(
    ("input_up", "up_axis", "to_cache"),
    [("y", None, None), ("y", "z", Y_TO_Z), ("z", None, None), ("z", "z", None), ("z", "y", Z_TO_Y)],
)
def test_caches_and_usd_are_in_the_world_up_axis_names(
    tmp_path: Path, input_up: str, up_axis: str | None, to_cache: Rotation | None
) -> None:
    from pxr import Usd, UsdGeom

    states = bake(tmp_path, input_up, up_axis, ["pc2", "usd"])
    written = up_axis or input_up
    stage = Usd.Stage.Open(str(tmp_path / "scene.usdc"))
    assert UsdGeom.GetStageUpAxis(stage) == (UsdGeom.Tokens.z if written == "z" else UsdGeom.Tokens.y)
    geom = UsdGeom.Mesh(stage.GetDefaultPrim().GetChildren()[0])
    cache = read_pc2(tmp_path / "cache.pc2")
    for k, state in enumerate(states):
        expected = state if to_cache is None else to_cache.apply(state)
        np.testing.assert_allclose(cache[1 + k], expected, atol=1e-6)  # sample 1 + k: scene frame 1 + k
        np.testing.assert_allclose(np.asarray(geom.GetPointsAttr().Get(Usd.TimeCode(1 + k))), expected, atol=1e-6)


@pytest.mark.parametrize("input_up", ["y", "z"])
@pytest.mark.parametrize("up_axis", [None, "y", "z"])
def test_gltf_and_vat_are_y_up_whatever_up_axis(tmp_path: Path, input_up: str, up_axis: str | None) -> None:
    states = bake(tmp_path, input_up, up_axis, ["gltf", "vat"])
    to_y_up = (lambda p: p) if input_up == "y" else Z_TO_Y.apply
    doc, blob = read_glb(tmp_path / "scene.glb")
    primitive = doc["meshes"][0]["primitives"][0]
    rest = accessor(doc, blob, primitive["attributes"]["POSITION"])[: states[0].shape[0]]
    np.testing.assert_allclose(rest, to_y_up(states[0]), atol=1e-6)
    last = rest + accessor(doc, blob, primitive["targets"][-1]["POSITION"])[: states[0].shape[0]]
    np.testing.assert_allclose(last, to_y_up(states[-1]), atol=1e-6)
    description, positions, _ = decode(tmp_path / "vat")
    step = (np.asarray(description["bounds_max"]) - np.asarray(description["bounds_min"])) / 65535
    for state, decoded in zip(states, positions, strict=True):
        assert np.all(np.abs(decoded - to_y_up(state)) <= step / 2 + 1e-9)
