"""Vertex animation textures: decoded with only `vat.json` and VTK's PNG reader (`vat_reader`), the
textures give back every frame's positions within the 16-bit quantisation and unit normals close to
trimesh's; the textures are truly 16-bit; a tearing run is refused and leaves nothing."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
import trimesh
from factories import grid_sheet
from scipy.spatial import cKDTree
from vat_reader import decode, png_header

from meshdeform.errors import ExportError
from meshdeform.export import ExportContext, ExportSession, FrameData
from meshdeform.mesh import Mesh

FPS = 30.0


def billow(mesh: Mesh, index: int) -> np.ndarray:
    """Frame `index` of a sheet billowing out of its plane and drifting in x (V, 3), metres."""
    pos = mesh.positions.copy()
    t = index / FPS
    pos[:, 2] = 0.3 * np.sin(3.0 * pos[:, 0] + 5.0 * t) * np.cos(2.0 * pos[:, 1] - t)
    pos[:, 0] += 0.1 * t
    return pos


def run(mesh: Mesh, out: Path, count: int, frames: list[FrameData] | None = None, **ctx) -> list[np.ndarray]:
    """Export `count` frames of `billow` (index 0, the rest pose, first) as vat; the positions handed over."""
    frames = frames or [FrameData(i, i / FPS, billow(mesh, i)) for i in range(count)]
    with ExportSession(["vat"], ExportContext(mesh=mesh, out_dir=out, fps=FPS, frame_count=count, **ctx)) as s:
        for frame in frames:
            s.write(frame)
    return [f.positions for f in frames]


@pytest.mark.parametrize(("nx", "ny"), [(9, 6), (70, 60)])  # 60 and 4331 vertices: one row per frame
def test_decoding_reproduces_every_frame_within_half_a_quantisation_step(tmp_path: Path, nx: int, ny: int) -> None:
    mesh = grid_sheet(nx, ny, size=(2.0, 1.5))
    sent = run(mesh, tmp_path, 7, start_frame=10)
    info, positions, _ = decode(tmp_path / "vat")
    assert (info["frames"], info["vertices"], info["fps"], info["start_frame"]) == (7, mesh.vertex_count, FPS, 10)
    assert info["rows_per_frame"] == -(-mesh.vertex_count // info["width"])
    everything = np.concatenate(sent)
    low, high = np.asarray(info["bounds_min"]), np.asarray(info["bounds_max"])
    np.testing.assert_allclose(low, everything.min(axis=0), rtol=0, atol=1e-12)  # no axis is flat here
    np.testing.assert_allclose(high, everything.max(axis=0), rtol=0, atol=1e-12)
    half_step = (high - low) / 65535 / 2 + 1e-12
    assert len(positions) == len(sent)
    for decoded, expected in zip(positions, sent, strict=True):
        assert np.all(np.abs(decoded - expected) <= half_step)


def test_a_run_written_from_a_later_frame_names_its_scene_frames_and_is_byte_identical_twice(tmp_path: Path) -> None:
    mesh = grid_sheet(8, 5)
    frames = [FrameData(i, i / FPS, billow(mesh, i)) for i in range(3, 7)]  # [output] frames = [4, 7]
    for out in ("a", "b"):
        run(mesh, tmp_path / out, 4, frames)
    info, positions, _ = decode(tmp_path / "a" / "vat")
    assert (info["frames"], info["first_scene_frame"], info["scene_frames"]) == (4, 4, [4, 5, 6, 7])
    half_step = (np.asarray(info["bounds_max"]) - np.asarray(info["bounds_min"])) / 65535 / 2 + 1e-12
    assert all(np.all(np.abs(p - f.positions) <= half_step) for p, f in zip(positions, frames, strict=True))
    for path in (tmp_path / "a" / "vat").iterdir():
        assert path.read_bytes() == (tmp_path / "b" / "vat" / path.name).read_bytes(), path.name


def test_a_large_mesh_wraps_onto_several_rows_per_frame(tmp_path: Path) -> None:
    mesh = grid_sheet(100, 90)  # 9191 vertices: wider than any one texture row allowed
    sent = run(mesh, tmp_path, 3)
    info, positions, _ = decode(tmp_path / "vat")
    assert info["rows_per_frame"] >= 2 and info["width"] * info["rows_per_frame"] >= mesh.vertex_count
    assert png_header(tmp_path / "vat" / info["position_texture"])[:2] == (
        info["width"],
        info["rows_per_frame"] * info["frames"],
    )
    half_step = (np.asarray(info["bounds_max"]) - np.asarray(info["bounds_min"])) / 65535 / 2 + 1e-12
    for decoded, expected in zip(positions, sent, strict=True):
        assert np.all(np.abs(decoded - expected) <= half_step)


def test_normals_decode_to_unit_vectors_close_to_trimeshs_vertex_normals(tmp_path: Path) -> None:
    mesh = grid_sheet(25, 20, triangles=True)
    sent = run(mesh, tmp_path, 5)
    _, _, normals = decode(tmp_path / "vat")
    faces = mesh.face_indices.reshape(-1, 3)
    for decoded, positions in zip(normals, sent, strict=True):
        np.testing.assert_allclose(np.linalg.norm(decoded, axis=1), 1.0, atol=3e-5)  # 16-bit rounding
        reference = trimesh.Trimesh(positions, faces, process=False).vertex_normals
        # trimesh weights faces by corner angle, meshdeform by area: on a smooth sheet they nearly agree
        assert np.min(np.sum(decoded * reference, axis=1)) > np.cos(np.radians(3.0))


def test_the_textures_are_16_bit_rgb_and_the_json_names_them(tmp_path: Path) -> None:
    mesh = grid_sheet(6, 4)
    run(mesh, tmp_path, 4)
    folder = tmp_path / "vat"
    info = json.loads((folder / "vat.json").read_text())
    for key in ("position_texture", "normal_texture"):
        width, height, depth, colour = png_header(folder / info[key])
        assert (width, height, depth, colour) == (info["width"], 4 * info["rows_per_frame"], 16, 2)  # RGB
    assert sorted(p.name for p in folder.iterdir()) == sorted(
        ["vat.json", info["mesh"], info["mesh_gltf"], info["position_texture"], info["normal_texture"]]
    )


def obj_vertex_uvs(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(V, 3) positions and (V, 2) the UV each vertex's corners use, read from the OBJ text (`v`, `vt`,
    `f v/vt`); every corner of a vertex must name the same `vt`."""
    lines = path.read_text().splitlines()
    vertices = np.array([[float(t) for t in line.split()[1:4]] for line in lines if line.startswith("v ")])
    texcoords = np.array([[float(t) for t in line.split()[1:3]] for line in lines if line.startswith("vt ")])
    uv = np.full((len(vertices), 2), np.nan)
    for line in (line for line in lines if line.startswith("f ")):
        for corner in line.split()[1:]:
            v, t = (int(i) - 1 for i in corner.split("/")[:2])
            assert np.isnan(uv[v, 0]) or np.array_equal(uv[v], texcoords[t])
            uv[v] = texcoords[t]
    return vertices, uv


def test_the_mesh_uvs_point_at_each_vertexs_texel_centre(tmp_path: Path) -> None:
    mesh = grid_sheet(100, 90)
    run(mesh, tmp_path, 2)
    folder = tmp_path / "vat"
    info = json.loads((folder / "vat.json").read_text())
    vertices, uv = obj_vertex_uvs(folder / "mesh.obj")
    np.testing.assert_allclose(vertices, mesh.positions, atol=1e-12)  # input order, rest pose
    width, height = info["width"], info["rows_per_frame"] * info["frames"]
    # back to texels in image rows (row 0 at the top, UV origin bottom-left): x = u * width, y = (1 - v) * height
    x, y = uv[:, 0] * width - 0.5, (1.0 - uv[:, 1]) * height - 0.5
    v = np.arange(mesh.vertex_count)
    np.testing.assert_allclose(x, v % width, atol=1e-4)
    np.testing.assert_allclose(y, v // width, atol=1e-4)
    np.testing.assert_allclose(np.asarray(info["uv2"]), uv, atol=1e-6)


def test_a_still_flat_sheet_widens_its_zero_range_axis_and_says_so(tmp_path: Path) -> None:
    mesh = grid_sheet(5, 4)  # in the xy plane: z is 0 at every frame
    frames = [FrameData(i, i / FPS, mesh.positions + [0.0, -0.01 * i, 0.0]) for i in range(3)]
    run(mesh, tmp_path, 3, frames)
    info, positions, _ = decode(tmp_path / "vat")
    assert info["bounds_widened"] == ["z"] and info["bounds_max"][2] > info["bounds_min"][2]
    for decoded, frame in zip(positions, frames, strict=True):
        np.testing.assert_allclose(decoded, frame.positions, rtol=0, atol=1.6e-5)


def test_a_torn_frame_is_refused_and_nothing_is_left(tmp_path: Path) -> None:
    mesh = grid_sheet(5, 4)
    torn = Mesh(np.vstack([mesh.positions, mesh.positions[:1]]), mesh.face_indices, mesh.face_offsets)
    frames = [FrameData(0, 0.0, mesh.positions), FrameData(1, 1 / FPS, torn.positions, mesh=torn)]
    with pytest.raises(ExportError, match="vertex animation textures need a fixed vertex count"):
        run(mesh, tmp_path, 2, frames)
    assert list(tmp_path.iterdir()) == []


def read_glb(path: Path) -> dict[str, np.ndarray]:
    """The first primitive's attributes and indices of a binary glTF, from the published layout (12-byte
    header, a JSON chunk, a BIN chunk; accessors of float32 VEC2/VEC3 and uint32 SCALAR)."""
    data = path.read_bytes()
    magic, version, total = struct.unpack("<4sII", data[:12])
    assert (magic, version, total) == (b"glTF", 2, len(data))
    json_length, kind = struct.unpack("<I4s", data[12:20])
    assert kind == b"JSON"
    document = json.loads(data[20 : 20 + json_length])
    bin_start = 20 + json_length
    bin_length, kind = struct.unpack("<I4s", data[bin_start : bin_start + 8])
    assert kind == b"BIN\0"
    blob = data[bin_start + 8 : bin_start + 8 + bin_length]
    primitive = document["meshes"][0]["primitives"][0]
    wanted = {**primitive["attributes"], "indices": primitive["indices"]}
    out = {}
    for name, index in wanted.items():
        accessor = document["accessors"][index]
        view = document["bufferViews"][accessor["bufferView"]]
        dtype = {5126: "<f4", 5125: "<u4"}[accessor["componentType"]]
        width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3}[accessor["type"]]
        chunk = blob[view["byteOffset"] : view["byteOffset"] + view["byteLength"]]
        out[name] = np.frombuffer(chunk, dtype=dtype).reshape(accessor["count"], width).squeeze()
    return out


@pytest.mark.parametrize("triangles", [False, True])
def test_the_gltf_mesh_carries_the_input_uvs_and_the_vat_uvs_as_its_second_set(tmp_path: Path, triangles: bool) -> None:
    mesh = grid_sheet(12, 9, triangles=triangles)
    run(mesh, tmp_path, 3)
    folder = tmp_path / "vat"
    info = json.loads((folder / "vat.json").read_text())
    glb = read_glb(folder / info["mesh_gltf"])
    # each glTF vertex is an input vertex: found by its position
    distance, source = cKDTree(mesh.positions).query(glb["POSITION"])
    assert np.max(distance) < 1e-6
    width, height = info["width"], info["height"]
    # glTF UVs have their origin top-left: v_gltf * height - 0.5 is the image row
    np.testing.assert_allclose(glb["TEXCOORD_1"][:, 0] * width - 0.5, source % width, atol=1e-3)
    np.testing.assert_allclose(glb["TEXCOORD_1"][:, 1] * height - 0.5, source // width, atol=1e-3)
    per_vertex = np.empty((mesh.vertex_count, 2))
    per_vertex[mesh.face_indices] = mesh.uvs[mesh.face_uv_indices, :2]  # the sheet has one UV per vertex
    np.testing.assert_allclose(
        glb["TEXCOORD_0"], np.column_stack([per_vertex[source, 0], 1 - per_vertex[source, 1]]), atol=1e-6
    )
    # the triangles cover the sheet's area once, facing as the input's polygons
    tri = glb["POSITION"][glb["indices"].reshape(-1, 3)].astype(np.float64)
    area = 0.5 * np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    np.testing.assert_allclose(area.sum(axis=0), [0.0, 0.0, 1.0], atol=1e-6)


def test_a_uv_seam_splits_the_gltf_vertex_and_both_copies_point_at_its_texel(tmp_path: Path) -> None:
    # two quads sharing the edge of vertices 1 and 4; the right quad's UV island is apart (a seam there)
    positions = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0], [1, 1, 0], [2, 1, 0]], dtype=np.float64)
    faces = np.array([0, 1, 4, 3, 1, 2, 5, 4])
    uvs = np.array([[0, 0], [0.4, 0], [0.4, 1], [0, 1], [0.6, 0], [1, 0], [1, 1], [0.6, 1]], dtype=np.float64)
    mesh = Mesh(positions, faces, np.array([0, 4, 8]), uvs=uvs, face_uv_indices=np.arange(8))
    run(mesh, tmp_path, 2, [FrameData(i, i / FPS, positions + [0, 0, 0.1 * i]) for i in range(2)])
    info = json.loads((tmp_path / "vat" / "vat.json").read_text())
    glb = read_glb(tmp_path / "vat" / info["mesh_gltf"])
    assert glb["POSITION"].shape == (8, 3)  # vertices 1 and 4 twice, once per UV island
    source = cKDTree(positions).query(glb["POSITION"])[1]
    np.testing.assert_array_equal(np.bincount(source), [1, 2, 1, 1, 2, 1])
    # as scene.glb: the input's vertices first, in its order, then the copies, each's input vertex listed
    np.testing.assert_array_equal(source[:6], np.arange(6))
    data = (tmp_path / "vat" / info["mesh_gltf"]).read_bytes()
    document = json.loads(data[20 : 20 + struct.unpack("<I", data[12:16])[0]])
    assert document["meshes"][0]["extras"]["seamSource"] == source[6:].tolist()
    np.testing.assert_allclose(glb["TEXCOORD_1"][:, 0] * info["width"] - 0.5, source, atol=1e-3)
    expected = sorted((u, 1 - v) for u, v in uvs)
    np.testing.assert_allclose(sorted(map(tuple, glb["TEXCOORD_0"].astype(np.float64))), expected, atol=1e-7)
