"""glTF export: Khronos glTF-Validator, a reader written from the GLB layout, and Blender's importer.

The reader below parses the GLB container and accessors with `struct`/`json` from the glTF 2.0
specification, not from the writer: positions per frame are the rest POSITION plus the delta of the
morph target whose one-hot weight the animation sets at that frame's time.
"""

from __future__ import annotations

import json
import os
import shutil
import struct
import subprocess
import textwrap
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from factories import grid_sheet

from meshdeform.errors import ExportError
from meshdeform.export import ExportContext, ExportSession, FrameData
from meshdeform.export.gltf import GltfExporter
from meshdeform.mesh import Mesh

FPS = 24.0
FRAMES = 7  # the rest pose and 6 more
BPY_PYTHON = os.environ.get("MESHDEFORM_BPY_PYTHON")
VALIDATOR_DIR = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "meshdeform-tests" / "gltf-validator"


def motion(mesh: Mesh, k: int) -> np.ndarray:
    pos = mesh.positions.copy()
    pos[:, 2] += 0.3 * np.sin(pos[:, 0] * 4.0 + 0.7 * k) * pos[:, 1]
    pos[:, 1] -= 0.02 * k * k
    return pos


def run(
    mesh: Mesh, out: Path, frames: int = FRAMES, fps: float = FPS, formats: tuple[str, ...] = ("gltf",), **ctx
) -> list[np.ndarray]:
    states = [motion(mesh, k) for k in range(frames)]
    context = ExportContext(mesh=mesh, out_dir=out, fps=fps, frame_count=frames - 1, **ctx)
    with ExportSession(list(formats), context) as session:
        for k, pos in enumerate(states):
            session.write(FrameData(k, k / fps, pos))
    return states


def seamed(mesh: Mesh) -> Mesh:
    """The grid with per-corner UVs: each face's corners get UVs of their own (every vertex split)."""
    corners = mesh.face_indices.shape[0]
    uvs = np.stack([np.arange(corners) / corners, np.linspace(0, 1, corners)], axis=1)
    return replace(mesh, uvs=uvs, face_uv_indices=np.arange(corners, dtype=np.int64))


def read_glb(path: Path) -> tuple[dict, bytes]:
    data = path.read_bytes()
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    assert (magic, version, length) == (b"glTF", 2, len(data))
    json_length, json_type = struct.unpack_from("<I4s", data, 12)
    assert json_type == b"JSON" and json_length % 4 == 0
    doc = json.loads(data[20 : 20 + json_length])
    bin_offset = 20 + json_length
    bin_length, bin_type = struct.unpack_from("<I4s", data, bin_offset)
    assert bin_type == b"BIN\0"
    return doc, data[bin_offset + 8 : bin_offset + 8 + bin_length]


def accessor(doc: dict, blob: bytes, index: int) -> np.ndarray:
    acc = doc["accessors"][index]
    view = doc["bufferViews"][acc["bufferView"]]
    dtype = {5126: np.float32, 5125: np.uint32, 5123: np.uint16}[acc["componentType"]]
    width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3}[acc["type"]]
    item = np.dtype(dtype).itemsize * width
    stride = view.get("byteStride", item)
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    rows = [np.frombuffer(blob, dtype, width, start + i * stride) for i in range(acc["count"])]
    return np.array(rows).reshape(acc["count"], width) if width > 1 else np.array(rows).reshape(-1)


def glb_frames(folder: Path) -> list[np.ndarray]:
    """Positions of every frame of `scene.glb` (glTF vertex order), as the animation plays them at
    the key times: rest + sum_t weight_t(time) * delta_t."""
    doc, blob = read_glb(folder / "scene.glb")
    prim = doc["meshes"][0]["primitives"][0]
    rest = accessor(doc, blob, prim["attributes"]["POSITION"]).astype(np.float32)
    if "animations" not in doc:
        return [rest]
    deltas = np.array([accessor(doc, blob, t["POSITION"]) for t in prim.get("targets", [])], dtype=np.float32)
    sampler = doc["animations"][0]["samplers"][0]
    times = accessor(doc, blob, sampler["input"])
    weights = accessor(doc, blob, sampler["output"]).reshape(len(times), len(deltas))
    return [rest + np.tensordot(w, deltas, axes=1).astype(np.float32) for w in weights]


def test_the_glb_plays_every_frame_at_its_time_within_float32(tmp_path: Path) -> None:
    mesh = grid_sheet(6, 4)
    states = run(mesh, tmp_path)
    doc, blob = read_glb(tmp_path / "scene.glb")
    times = accessor(doc, blob, doc["animations"][0]["samplers"][0]["input"])
    np.testing.assert_allclose(times, np.arange(FRAMES) / FPS, rtol=1e-7)
    frames = glb_frames(tmp_path)
    assert len(frames) == FRAMES
    for k, positions in enumerate(frames):
        assert positions.shape == (mesh.vertex_count, 3)  # no seams: one glTF vertex per input vertex
        np.testing.assert_allclose(positions, states[k], rtol=0, atol=4e-7 * (1 + np.abs(states[k]).max()))
    # the triangles cover each quad of the grid: 2 per quad, corners from the input's faces
    indices = accessor(doc, blob, doc["meshes"][0]["primitives"][0]["indices"]).reshape(-1, 3)
    assert indices.shape[0] == 2 * mesh.face_count
    assert set(indices.ravel()) == set(mesh.face_indices)


def test_seams_copy_vertices_after_the_input_ones_and_name_their_source(tmp_path: Path) -> None:
    mesh = seamed(grid_sheet(4, 3))
    states = run(mesh, tmp_path)
    doc, _ = read_glb(tmp_path / "scene.glb")
    source = np.concatenate([np.arange(mesh.vertex_count), doc["meshes"][0]["extras"]["seamSource"]])
    assert source.size == mesh.face_indices.shape[0]  # every corner has its own UV
    for k, positions in enumerate(glb_frames(tmp_path)):
        np.testing.assert_allclose(positions, states[k][source], rtol=0, atol=1e-6)


def test_a_tearing_run_is_refused_and_leaves_nothing(tmp_path: Path) -> None:
    mesh = grid_sheet(4, 3)
    torn = replace(mesh, positions=np.vstack([mesh.positions, mesh.positions[:1]]))
    context = ExportContext(mesh=mesh, out_dir=tmp_path, fps=FPS)
    with pytest.raises(ExportError, match="fixed topology"), ExportSession(["gltf"], context) as session:
        session.write(FrameData(0, 0.0, mesh.positions))
        session.write(FrameData(1, 1 / FPS, torn.positions, mesh=torn))
    assert [p for p in tmp_path.rglob("*") if p.is_file()] == []


def validator() -> Path:
    """The Khronos glTF-Validator npm package in a cache folder (installed on first use)."""
    if shutil.which("node") is None or shutil.which("npm") is None:
        pytest.skip("node/npm is not installed: cannot run the Khronos glTF-Validator")
    package = VALIDATOR_DIR / "node_modules" / "gltf-validator"
    if not package.is_dir():
        VALIDATOR_DIR.mkdir(parents=True, exist_ok=True)
        done = subprocess.run(
            ["npm", "install", "--prefix", str(VALIDATOR_DIR), "gltf-validator"], capture_output=True, text=True
        )
        if done.returncode != 0:
            pytest.skip(f"npm could not install gltf-validator (no network?): {done.stderr[-300:]}")
    return package


def validate(package: Path, glb: Path) -> dict:
    """The `issues` of the validator's report on `glb` (printed: pytest -s shows them)."""
    script = textwrap.dedent(
        """
        const validator = require(process.argv[1]);
        const buf = require("fs").readFileSync(process.argv[2]);
        validator.validateBytes(new Uint8Array(buf)).then((report) => {
            console.log(JSON.stringify(report.issues));
        }, (error) => { console.error(error); process.exit(2); });
        """
    )
    done = subprocess.run(["node", "-e", script, str(package), str(glb)], capture_output=True, text=True, check=True)
    issues = json.loads(done.stdout)
    print(json.dumps(issues, indent=1))
    return issues


@pytest.mark.parametrize("kind", ["grid", "seams", "rest only"])
def test_the_khronos_validator_finds_no_error(tmp_path: Path, kind: str) -> None:
    package = validator()
    mesh = grid_sheet(5, 4)
    run(seamed(mesh) if kind == "seams" else mesh, tmp_path, frames=1 if kind == "rest only" else FRAMES)
    issues = validate(package, tmp_path / "scene.glb")
    assert issues["numErrors"] == 0, issues["messages"]
    assert issues["numWarnings"] == 0, issues["messages"]


@pytest.mark.parametrize("kind", ["grid", "seams"])
def test_the_khronos_validator_finds_no_error_in_the_vat_mesh(tmp_path: Path, kind: str) -> None:
    package = validator()
    mesh = grid_sheet(5, 4)
    run(seamed(mesh) if kind == "seams" else mesh, tmp_path, formats=("vat",))
    issues = validate(package, tmp_path / "vat" / "mesh.glb")
    assert issues["numErrors"] == 0, issues["messages"]
    assert issues["numWarnings"] == 0, issues["messages"]


BLENDER_SCRIPT = """
import json, math, sys
import bpy
import numpy as np
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.import_scene.gltf(filepath=sys.argv[-2])
scene = bpy.context.scene
obj = next(o for o in scene.objects if o.type == "MESH")
fps = scene.render.fps / scene.render.fps_base
out = {"fps": fps, "start": scene.frame_start, "end": scene.frame_end, "frames": []}
for k in range(int(sys.argv[-4])):
    frame = k / float(sys.argv[-3]) * fps  # the scene frame of glTF time k / our fps
    scene.frame_set(math.floor(frame), subframe=frame - math.floor(frame))
    mesh = obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).to_mesh()
    co = np.empty(len(mesh.vertices) * 3)
    mesh.vertices.foreach_get("co", co)
    out["frames"].append(co.reshape(-1, 3).tolist())
json.dump(out, open(sys.argv[-1], "w"))
"""


@pytest.mark.skipif(not BPY_PYTHON, reason="MESHDEFORM_BPY_PYTHON names no Python with bpy")
@pytest.mark.parametrize(("fps", "kind"), [(24.0, "grid"), (30.0, "grid"), (24.0, "seams")])
def test_blender_imports_every_frame_at_our_positions(tmp_path: Path, fps: float, kind: str) -> None:
    """Blender (5.0) keys glTF time t at scene frame t * its own fps (24, not changed by the import),
    from frame 0: our frame index k is at Blender frame k * 24 / fps (a subframe when fps is not 24)."""
    mesh = seamed(grid_sheet(5, 4)) if kind == "seams" else grid_sheet(5, 4)
    states = run(mesh, tmp_path, fps=fps)
    extras = read_glb(tmp_path / "scene.glb")[0]["meshes"][0]["extras"]
    source = np.concatenate([np.arange(mesh.vertex_count), extras.get("seamSource", [])]).astype(int)
    script = tmp_path / "read.py"
    script.write_text(BLENDER_SCRIPT)
    result = tmp_path / "blender.json"
    done = subprocess.run(
        [BPY_PYTHON, str(script), "--", str(FRAMES), str(fps), str(tmp_path / "scene.glb"), str(result)],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    got = json.loads(result.read_text())
    print("Blender scene:", {k: got[k] for k in ("fps", "start", "end")})
    assert len(got["frames"]) == FRAMES
    for k, ours in enumerate(states):
        ours = ours[source]  # Blender keeps the glTF vertices, seam copies included, in their order
        z_up = np.stack([ours[:, 0], -ours[:, 2], ours[:, 1]], axis=1)
        np.testing.assert_allclose(np.asarray(got["frames"][k]), z_up, rtol=0, atol=1e-6)


@pytest.mark.parametrize("kind", ["grid", "seams"])
def test_the_size_estimate_is_on_the_high_side_and_close(tmp_path: Path, kind: str) -> None:
    mesh = seamed(grid_sheet(12, 9)) if kind == "seams" else grid_sheet(12, 9)
    run(mesh, tmp_path, frames=30)
    actual = (tmp_path / "scene.glb").stat().st_size
    estimate = GltfExporter.estimated_bytes(mesh, 30)
    assert actual <= estimate <= 1.3 * actual + 8192


def polygons() -> Mesh:
    """A triangle, a quad and a convex pentagon in the z = 0 plane, and a loose vertex (no face)."""
    positions = np.array(
        [[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [3, 0, 0], [3, 1, 0], [2, 1, 0],
         [4, 0, 0], [5, 0, 0], [5.5, 1, 0], [4.5, 2, 0], [3.8, 1, 0], [9, 9, 9]],
        dtype=np.float64,
    )  # fmt: skip
    faces = np.array([0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11], dtype=np.int64)
    return Mesh(positions=positions, face_indices=faces, face_offsets=np.array([0, 3, 7, 12], dtype=np.int64))


def test_polygons_are_fanned_into_triangles_covering_their_area(tmp_path: Path) -> None:
    mesh = polygons()
    run(mesh, tmp_path, frames=2)
    doc, blob = read_glb(tmp_path / "scene.glb")
    indices = accessor(doc, blob, doc["meshes"][0]["primitives"][0]["indices"]).reshape(-1, 3)
    assert indices.shape == (1 + 2 + 3, 3)
    rest = mesh.positions
    # per polygon, the triangles' areas add up to the shoelace area of the polygon, and all face +z
    cross = np.cross(rest[indices[:, 1]] - rest[indices[:, 0]], rest[indices[:, 2]] - rest[indices[:, 0]])
    assert np.all(cross[:, 2] > 0)
    shoelace = []
    for a, b in zip(mesh.face_offsets[:-1], mesh.face_offsets[1:], strict=True):
        x, y = rest[mesh.face_indices[a:b], 0], rest[mesh.face_indices[a:b], 1]
        shoelace.append(0.5 * (x @ np.roll(y, -1) - y @ np.roll(x, -1)))
    areas = 0.5 * cross[:, 2]
    np.testing.assert_allclose([areas[:1].sum(), areas[1:3].sum(), areas[3:].sum()], shoelace, rtol=1e-12)
    assert mesh.vertex_count - 1 not in indices  # the loose vertex stays a vertex, in no triangle
    assert len(glb_frames(tmp_path)[0]) == mesh.vertex_count


def test_the_khronos_validator_accepts_polygons_and_a_loose_vertex(tmp_path: Path) -> None:
    package = validator()
    run(polygons(), tmp_path, frames=3)
    assert validate(package, tmp_path / "scene.glb")["numErrors"] == 0
