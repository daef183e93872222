"""Exporters round-trip through independent readers: meshio, trimesh, pxr, and reference PC2/MDD readers.

The PC2 and MDD readers below are written from the published byte layouts (DESIGN.md section 5),
not from our writer, so a layout mistake cannot cancel itself out.
"""

from __future__ import annotations

import json
import re
import struct
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import meshio
import numpy as np
import pytest
import trimesh
import vat_reader
from factories import grid_sheet
from test_gltf import glb_frames

from meshdeform.errors import ExportError
from meshdeform.export import (
    EXPORTERS,
    BaseExporter,
    ExportContext,
    ExportSession,
    FrameData,
    frame_file_name,
    make_exporter,
)
from meshdeform.geometry import vertex_normals
from meshdeform.mesh import Mesh

NX, NY, FRAMES, FPS = 7, 5, 6, 24.0


def wave(mesh: Mesh, index: int) -> np.ndarray:
    """A travelling sine wave through the sheet plus a sag: every frame differs."""
    pos = mesh.positions.copy()
    t = index / FPS
    pos[:, 2] = 0.2 * np.sin(pos[:, 0] * 5.0 + t * 7.0) * pos[:, 1]
    pos[:, 1] -= 0.05 * t * (1.0 - pos[:, 1])
    return pos


def point_data(mesh: Mesh, pos: np.ndarray) -> dict[str, np.ndarray]:
    return {
        "strain": 1.0 + 0.01 * np.arange(mesh.vertex_count, dtype=np.float64),
        "velocity": np.tile([0.5, -1.0, 0.25], (mesh.vertex_count, 1)),
        "pinned": (mesh.positions[:, 1] > 0.99).astype(np.uint8),
    }


def frames_of(mesh: Mesh, count: int = FRAMES) -> list[FrameData]:
    """`count` frames as a run hands them over: frame index i - 1 (0: the first, a run's rest pose,
    at scene frame start_frame) holds wave(mesh, i), so scene frame start_frame + i - 1 does."""
    out = []
    for i in range(1, count + 1):
        pos = wave(mesh, i)
        out.append(FrameData(index=i - 1, time=(i - 1) / FPS, positions=pos, point_data=point_data(mesh, pos)))
    return out


def export(
    formats: list[str], mesh: Mesh, out: Path, frames: list[FrameData] | None = None, options=None, **ctx
) -> dict[str, list[Path]]:
    frames = frames_of(mesh) if frames is None else frames
    context = ExportContext(mesh=mesh, out_dir=out, fps=FPS, frame_count=len(frames), **ctx)
    with ExportSession(formats, context, options) as session:
        for frame in frames:
            session.write(frame)
    return session.outputs


@pytest.fixture
def mesh() -> Mesh:
    return grid_sheet(NX, NY)


def visible_files(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file())


# ---------------------------------------------------------------------------------------------
# registry and naming


def test_every_exporter_module_is_registered_and_unknown_names_are_refused() -> None:
    """Each exporter class of a meshdeform.export module (a named BaseExporter) is in EXPORTERS under
    its name, with a summary for the help; unknown names and options are refused."""
    import importlib
    import pkgutil

    import meshdeform.export as package

    defined = {
        cls.name: cls
        for info in pkgutil.iter_modules(package.__path__)
        for cls in vars(importlib.import_module(f"{package.__name__}.{info.name}")).values()
        if isinstance(cls, type) and issubclass(cls, BaseExporter) and cls.name and cls.__module__.endswith(info.name)
    }
    assert defined == EXPORTERS
    for name, cls in EXPORTERS.items():
        exporter = make_exporter(name.upper())
        assert exporter.name == name and isinstance(exporter, cls) and cls.summary
    with pytest.raises(ExportError, match=r"unknown export format 'fbx'.*obj.*pc2.*usd"):
        make_exporter("fbx")
    with pytest.raises(ExportError, match="unknown option"):
        make_exporter("pc2", colour="red")


def test_frame_file_names_are_padded_to_four_digits_or_more() -> None:
    assert frame_file_name(1, 120, ".obj") == "frame_0001.obj"
    assert frame_file_name(9999, 9999, ".obj") == "frame_9999.obj"
    assert frame_file_name(7, 12000, ".ply") == "frame_00007.ply"
    assert frame_file_name(3, None, ".vtp") == "frame_0003.vtp"


def test_context_rejects_bad_axis_and_fps(mesh: Mesh, tmp_path: Path) -> None:
    with pytest.raises(ExportError, match="up axis"):
        ExportContext(mesh=mesh, out_dir=tmp_path, fps=24, up_axis="x")
    with pytest.raises(ExportError, match="fps"):
        ExportContext(mesh=mesh, out_dir=tmp_path, fps=0)


# ---------------------------------------------------------------------------------------------
# OBJ / PLY


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # trimesh's UV code on a material-less OBJ
def test_obj_frames_round_trip_through_meshio_and_trimesh(mesh: Mesh, tmp_path: Path) -> None:
    outputs = export(["obj"], mesh, tmp_path)
    files = outputs["obj"]
    assert [p.name for p in files] == [f"frame_{i:04d}.obj" for i in range(1, FRAMES + 1)]
    assert all(p.parent == tmp_path / "frames" for p in files)
    for i, path in enumerate(files, start=1):
        expected = wave(mesh, i)
        m = meshio.read(path)
        np.testing.assert_allclose(m.points, expected, rtol=0, atol=1e-6)
        assert [c.type for c in m.cells] == ["quad"]  # quads stay quads
        np.testing.assert_array_equal(m.cells[0].data.ravel(), mesh.face_indices)
        np.testing.assert_allclose(m.point_data["obj:vt"], mesh.uvs, atol=1e-9)
        t = trimesh.load(path, process=False, maintain_order=True)
        np.testing.assert_allclose(t.vertices, expected, rtol=0, atol=1e-6)
        assert len(t.faces) == 2 * mesh.face_count  # trimesh triangulates the quads


def test_obj_keeps_groups_and_recomputes_normals_per_frame(tmp_path: Path) -> None:
    base = grid_sheet(5, 4)
    n_faces = base.face_count
    mesh = replace(
        base,
        normals=vertex_normals(base),
        face_normal_indices=base.face_indices.copy(),
        statements=((0, "o sheet"), (0, "g left"), (n_faces // 2, "g right")),
        groups={"left": np.arange(n_faces // 2), "right": np.arange(n_faces // 2, n_faces)},
    )
    export(["obj"], mesh, tmp_path, frames_of(mesh, 3))
    text = (tmp_path / "frames" / "frame_0003.obj").read_text()
    assert "g left" in text and "g right" in text and "o sheet" in text
    vn = np.array([[float(x) for x in line.split()[1:]] for line in text.splitlines() if line.startswith("vn ")])
    np.testing.assert_allclose(vn, vertex_normals(mesh, wave(mesh, 3)), atol=1e-6)
    assert not np.allclose(vn, vertex_normals(mesh), atol=1e-3)  # they moved with the cloth
    faces = [line for line in text.splitlines() if line.startswith("f ")]
    assert len(faces) == n_faces and all(len(f.split()) == 5 for f in faces)
    assert all(f.split()[1].count("/") == 2 for f in faces)  # v/vt/vn kept


def test_ply_frames_round_trip_through_meshio_and_trimesh(mesh: Mesh, tmp_path: Path) -> None:
    files = export(["ply"], mesh, tmp_path)["ply"]
    assert files[0] == tmp_path / "frames" / "frame_0001.ply"
    for i, path in enumerate(files, start=1):
        expected = wave(mesh, i).astype(np.float32)
        m = meshio.read(path)
        np.testing.assert_allclose(m.points, expected, rtol=1e-6, atol=1e-7)
        assert [c.type for c in m.cells] == ["quad"]
        t = trimesh.load(path, process=False)
        np.testing.assert_allclose(t.vertices, expected, rtol=1e-6, atol=1e-7)


# ---------------------------------------------------------------------------------------------
# point caches, read back with readers written from the published layouts


def read_pc2(path: Path) -> tuple[dict, np.ndarray]:
    data = path.read_bytes()
    magic, version, points, start, rate, samples = struct.unpack("<12siiffi", data[:32])
    assert len(data) == 32 + 12 * points * samples
    pos = np.frombuffer(data, dtype="<f4", offset=32).reshape(samples, points, 3)
    return {"magic": magic, "version": version, "points": points, "start": start, "rate": rate}, pos


def read_mdd(path: Path) -> tuple[np.ndarray, np.ndarray]:
    data = path.read_bytes()
    frames, points = struct.unpack(">ii", data[:8])
    assert len(data) == 8 + 4 * frames + 12 * points * frames  # exactly F blocks
    times = np.frombuffer(data, dtype=">f4", count=frames, offset=8)
    pos = np.frombuffer(data, dtype=">f4", offset=8 + 4 * frames).reshape(frames, points, 3)
    return times, pos


def test_pc2_matches_the_published_layout(mesh: Mesh, tmp_path: Path) -> None:
    export(["pc2"], mesh, tmp_path, start_frame=10)
    header, pos = read_pc2(tmp_path / "cache.pc2")
    # sample k is scene frame k (Blender's Mesh Cache defaults): the first frame, at start frame 10,
    # is also written for scene frames 0 .. 9 before it
    assert header == {"magic": b"POINTCACHE2\0", "version": 1, "points": mesh.vertex_count, "start": 0.0, "rate": 1.0}
    expected = np.stack([wave(mesh, 1)] * 10 + [wave(mesh, i) for i in range(1, FRAMES + 1)]).astype(np.float32)
    np.testing.assert_array_equal(pos, expected)


def test_mdd_matches_the_published_layout(mesh: Mesh, tmp_path: Path) -> None:
    export(["mdd"], mesh, tmp_path)
    times, pos = read_mdd(tmp_path / "cache.mdd")
    # block k is scene frame k: the first frame (start frame 1) also fills scene frame 0
    np.testing.assert_allclose(times, np.arange(0, FRAMES + 1) / FPS, rtol=1e-7)  # scene seconds
    expected = np.stack([wave(mesh, 1)] + [wave(mesh, i) for i in range(1, FRAMES + 1)]).astype(np.float32)
    np.testing.assert_array_equal(pos, expected)


def test_mdd_times_follow_the_start_frame(mesh: Mesh, tmp_path: Path) -> None:
    export(["mdd"], mesh, tmp_path, start_frame=1001)
    times, _ = read_mdd(tmp_path / "cache.mdd")
    np.testing.assert_allclose(times, np.arange(0, 1001 + FRAMES) / FPS, rtol=1e-7)


def test_point_cache_readers_read_what_the_exporters_wrote(mesh: Mesh, tmp_path: Path) -> None:
    from meshdeform.export.mdd import read_mdd as our_read_mdd
    from meshdeform.export.pc2 import read_pc2 as our_read_pc2

    export(["pc2", "mdd"], mesh, tmp_path, start_frame=3)
    positions, start, rate = our_read_pc2(tmp_path / "cache.pc2")
    assert (positions.shape, start, rate) == ((3 + FRAMES, mesh.vertex_count, 3), 0.0, 1.0)
    np.testing.assert_array_equal(positions, our_read_mdd(tmp_path / "cache.mdd")[0])


def test_point_caches_convert_to_blender_z_up(mesh: Mesh, tmp_path: Path) -> None:
    export(["pc2", "mdd"], mesh, tmp_path, up_axis="z")
    p = wave(mesh, 1)  # sample 1: scene frame 1, the first frame
    blender = np.stack([p[:, 0], -p[:, 2], p[:, 1]], axis=1).astype(np.float32)
    np.testing.assert_array_equal(read_pc2(tmp_path / "cache.pc2")[1][1], blender)
    np.testing.assert_array_equal(read_mdd(tmp_path / "cache.mdd")[1][1], blender)


def test_pc2_needs_consecutive_frames(mesh: Mesh, tmp_path: Path) -> None:
    frames = frames_of(mesh, 3)
    with pytest.raises(ExportError, match="consecutive"):
        export(["pc2"], mesh, tmp_path, [frames[0], frames[2]])
    assert visible_files(tmp_path) == []


# ---------------------------------------------------------------------------------------------
# USD


@pytest.mark.parametrize("ascii_", [False, True])
def test_usd_stage_has_topology_once_and_time_sampled_points(mesh: Mesh, tmp_path: Path, ascii_: bool) -> None:
    from pxr import Usd, UsdGeom

    outputs = export(["usd"], mesh, tmp_path, options={"usd": {"ascii": ascii_}}, start_frame=1001)
    path = outputs["usd"][0]
    assert path.name == ("scene.usda" if ascii_ else "scene.usdc")
    stage = Usd.Stage.Open(str(path))
    assert stage.GetTimeCodesPerSecond() == FPS
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (1001, 1000 + FRAMES)
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    geom = UsdGeom.Mesh(stage.GetDefaultPrim().GetChildren()[0])
    assert geom.GetFaceVertexCountsAttr().GetNumTimeSamples() == 0
    assert list(geom.GetFaceVertexCountsAttr().Get()) == [4] * mesh.face_count
    assert list(geom.GetFaceVertexIndicesAttr().Get()) == mesh.face_indices.tolist()
    assert geom.GetPointsAttr().GetTimeSamples() == [float(1000 + i) for i in range(1, FRAMES + 1)]
    for i in range(1, FRAMES + 1):
        code = Usd.TimeCode(1000 + i)
        expected = wave(mesh, i)
        pts = np.asarray(geom.GetPointsAttr().Get(code))
        np.testing.assert_allclose(pts, expected, rtol=1e-6, atol=1e-7)
        extent = np.asarray(geom.GetExtentAttr().Get(code))
        np.testing.assert_allclose(extent, [expected.min(axis=0), expected.max(axis=0)], rtol=1e-6, atol=1e-7)
        normals = np.asarray(geom.GetNormalsAttr().Get(code))
        np.testing.assert_allclose(normals, vertex_normals(mesh, expected), atol=1e-6)
    st = UsdGeom.PrimvarsAPI(geom).GetPrimvar("st")
    assert st.GetInterpolation() == UsdGeom.Tokens.faceVarying
    np.testing.assert_allclose(np.asarray(st.ComputeFlattened()), mesh.uvs[mesh.face_uv_indices], atol=1e-7)


def test_usd_z_up_converts_points_and_sets_the_axis(mesh: Mesh, tmp_path: Path) -> None:
    from pxr import Usd, UsdGeom

    export(["usd"], mesh, tmp_path, up_axis="z")
    stage = Usd.Stage.Open(str(tmp_path / "scene.usdc"))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    geom = UsdGeom.Mesh(stage.GetDefaultPrim().GetChildren()[0])
    p = wave(mesh, 1)
    np.testing.assert_allclose(
        np.asarray(geom.GetPointsAttr().Get(Usd.TimeCode(1))), np.stack([p[:, 0], -p[:, 2], p[:, 1]], 1), atol=1e-6
    )


def test_usd_writes_polylines_as_basis_curves(tmp_path: Path) -> None:
    from pxr import Usd, UsdGeom

    pos = np.stack([np.linspace(0, 1, 6), np.ones(6), np.zeros(6)], axis=1)
    rope = Mesh(
        positions=pos,
        face_indices=np.zeros(0, np.int64),
        face_offsets=np.zeros(1, np.int64),
        line_indices=np.arange(6),
        line_offsets=np.array([0, 6]),
    )
    frames = [FrameData(i, i / FPS, pos + [0, -0.1 * (i + 1), 0]) for i in (0, 1)]
    export(["usd", "vtk"], rope, tmp_path, frames)
    stage = Usd.Stage.Open(str(tmp_path / "scene.usdc"))
    curves = UsdGeom.BasisCurves(stage.GetPrimAtPath("/Root/mesh_lines"))
    assert list(curves.GetCurveVertexCountsAttr().Get()) == [6]
    np.testing.assert_allclose(np.asarray(curves.GetPointsAttr().Get(Usd.TimeCode(2))), frames[1].positions, atol=1e-6)
    vtp = read_with_vtk(tmp_path / "vtk" / "frame_0002.vtp")
    assert vtp.n_lines == 1 and vtp.lines.tolist() == [6, 0, 1, 2, 3, 4, 5]


# ---------------------------------------------------------------------------------------------
# VTK, XDMF, NPZ


def read_with_vtk(path: Path):
    """A .vtp or .ply file read by VTK's own readers (via PyVista): meshio reads .vtu but not .vtp, and
    PLY frames of a torn mesh that trimesh (unused vertices) and meshio (per-corner UVs) cannot."""
    import pyvista as pv

    return pv.read(path)


def test_vtk_collection_of_vtp_frames_with_point_data(mesh: Mesh, tmp_path: Path) -> None:
    outputs = export(["vtk"], mesh, tmp_path)
    assert tmp_path / "scene.pvd" in outputs["vtk"]
    root = ET.parse(tmp_path / "scene.pvd").getroot()
    entries = [(float(d.get("timestep")), d.get("file")) for d in root.iter("DataSet")]
    assert entries == [((i - 1) / FPS, f"vtk/frame_{i:04d}.vtp") for i in range(1, FRAMES + 1)]
    for i in range(1, FRAMES + 1):
        m = read_with_vtk(tmp_path / "vtk" / f"frame_{i:04d}.vtp")
        expected = wave(mesh, i)
        np.testing.assert_allclose(m.points, expected, rtol=1e-6, atol=1e-7)
        assert m.n_cells == m.n_faces == mesh.face_count
        np.testing.assert_array_equal(m.faces.reshape(-1, 5)[:, 0], 4)  # quads stay quads
        np.testing.assert_array_equal(m.faces.reshape(-1, 5)[:, 1:].ravel(), mesh.face_indices)
        pd = point_data(mesh, expected)
        np.testing.assert_allclose(m.point_data["strain"], pd["strain"], rtol=1e-6)
        np.testing.assert_allclose(m.point_data["velocity"], pd["velocity"], rtol=1e-6)
        np.testing.assert_array_equal(m.point_data["pinned"], pd["pinned"])
        np.testing.assert_allclose(m.point_data["displacement"], expected - mesh.positions, atol=1e-6)
        np.testing.assert_allclose(m.active_texture_coordinates, mesh.uvs, atol=1e-7)


def test_xdmf_time_series_reads_back_through_meshio(mesh: Mesh, tmp_path: Path) -> None:
    export(["xdmf"], mesh, tmp_path)
    with meshio.xdmf.TimeSeriesReader(tmp_path / "scene.xdmf") as reader:
        rest, cells = reader.read_points_cells()
        np.testing.assert_allclose(rest, mesh.positions)
        assert [c.type for c in cells] == ["quad"]
        np.testing.assert_array_equal(cells[0].data.ravel(), mesh.face_indices)
        assert reader.num_steps == FRAMES
        for k in range(FRAMES):
            t, pd, _ = reader.read_data(k)
            assert t == pytest.approx(k / FPS)
            expected = wave(mesh, k + 1)
            np.testing.assert_allclose(rest + pd["displacement"], expected, rtol=0, atol=2e-7)
            np.testing.assert_allclose(pd["strain"], point_data(mesh, expected)["strain"], rtol=1e-6)
    # each step also carries its own deformed geometry, for ParaView
    text = (tmp_path / "scene.xdmf").read_text()
    assert text.count("<Geometry") == FRAMES + 1


def test_xdmf_fan_triangulates_ngons() -> None:
    from meshdeform.export.xdmf import meshio_cells

    pos = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 1], [1, 1, 0], [0, 1, 0], [3, 3, 3], [4, 3, 3], [4, 4, 3]], float)
    mesh = Mesh(positions=pos, face_indices=np.array([0, 1, 2, 3, 4, 5, 6, 7]), face_offsets=np.array([0, 5, 8]))
    blocks = dict(meshio_cells(mesh))
    assert sorted(blocks) == ["triangle"]
    assert blocks["triangle"].tolist() == [[5, 6, 7], [0, 1, 2], [0, 2, 3], [0, 3, 4]]


def test_npz_holds_positions_topology_and_point_data(mesh: Mesh, tmp_path: Path) -> None:
    export(["npz"], mesh, tmp_path, start_frame=5)
    with np.load(tmp_path / "positions.npz") as data:
        assert data["positions"].shape == (FRAMES, mesh.vertex_count, 3)
        assert data["positions"].dtype == np.float32
        expected = np.stack([wave(mesh, i) for i in range(1, FRAMES + 1)]).astype(np.float32)
        np.testing.assert_array_equal(data["positions"], expected)
        np.testing.assert_array_equal(data["face_indices"], mesh.face_indices)
        np.testing.assert_array_equal(data["face_offsets"], mesh.face_offsets)
        assert float(data["fps"]) == FPS and int(data["start_frame"]) == 5
        np.testing.assert_array_equal(data["frames"], np.arange(5, 5 + FRAMES))  # scene frames from the start
        assert data["point_velocity"].shape == (FRAMES, mesh.vertex_count, 3)
        assert data["point_pinned"].dtype == np.uint8


# ---------------------------------------------------------------------------------------------
# every registered format, read back by code that is not meshdeform's

ALL = list(EXPORTERS)
FOLLOWING = [name for name, cls in EXPORTERS.items() if cls.supports_topology_change]
FIXED = [name for name, cls in EXPORTERS.items() if not cls.supports_topology_change]


def trimesh_frames(paths: list[Path]) -> list[np.ndarray]:
    return [np.asarray(trimesh.load(p, process=False, maintain_order=True).vertices) for p in paths]


def usd_frames(folder: Path) -> list[np.ndarray]:
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(folder / "scene.usdc"))
    points = UsdGeom.Mesh(stage.GetDefaultPrim().GetChildren()[0]).GetPointsAttr()
    return [np.asarray(points.Get(Usd.TimeCode(t))) for t in points.GetTimeSamples()]


def vtk_frames(folder: Path) -> list[np.ndarray]:
    collection = ET.parse(folder / "scene.pvd").getroot()
    return [np.asarray(read_with_vtk(folder / entry.get("file")).points) for entry in collection.iter("DataSet")]


def xdmf_frames(folder: Path) -> list[np.ndarray]:
    with meshio.xdmf.TimeSeriesReader(folder / "scene.xdmf") as reader:
        rest, _ = reader.read_points_cells()
        return [rest + reader.read_data(k)[1]["displacement"] for k in range(reader.num_steps)]


def npz_frames(folder: Path) -> list[np.ndarray]:
    with np.load(folder / "positions.npz") as data:
        return list(data["positions"])


#: format -> the positions of every frame of a result folder, as an independent reader reads them
INDEPENDENT_READERS: dict[str, Callable[[Path], list[np.ndarray]]] = {
    "obj": lambda folder: trimesh_frames(sorted((folder / "frames").glob("*.obj"))),
    "ply": lambda folder: [np.asarray(read_with_vtk(p).points) for p in sorted((folder / "frames").glob("*.ply"))],
    # sample k of a point cache is scene frame k: the frames from the start frame (1) on
    "pc2": lambda folder: list(read_pc2(folder / "cache.pc2")[1][1:]),
    "mdd": lambda folder: list(read_mdd(folder / "cache.mdd")[1][1:]),
    "usd": usd_frames,
    "vtk": vtk_frames,
    "xdmf": xdmf_frames,
    "npz": npz_frames,
    "gltf": glb_frames,  # frame index k at glTF time k / fps; the grid has no UV seams
    "vat": lambda folder: vat_reader.decode(folder / "vat")[1],
}


def reader_tolerance(name: str, folder: Path) -> np.ndarray | float:
    """How far an independent reader's positions may be from those written: 1e-6 m (float32, text), and
    for vat half its 16-bit quantisation step per axis over the bounds `vat.json` states."""
    if name != "vat":
        return 1e-6
    info = json.loads((folder / "vat" / "vat.json").read_text())
    return (np.asarray(info["bounds_max"]) - np.asarray(info["bounds_min"])) / 65535 / 2 + 1e-12


def torn(mesh: Mesh) -> Mesh:
    """The grid with its first quad cut loose: vertex 0 duplicated as a new last vertex."""
    positions = np.vstack([mesh.positions, mesh.positions[:1]])
    faces = mesh.face_indices.copy()
    faces[0] = mesh.vertex_count
    return replace(mesh, positions=positions, face_indices=faces, face_uv_indices=mesh.face_uv_indices)


def torn_run(mesh: Mesh) -> list[FrameData]:
    """Four frames: the cloth tears at frame 3 (the torn mesh given with it), the loose corner 0.3 m off."""
    frames = frames_of(mesh, 2)
    moved = np.vstack([wave(mesh, 3), wave(mesh, 3)[:1] + [0.0, 0.0, 0.3]])
    frames.append(FrameData(2, 2 / FPS, moved, mesh=torn(mesh)))
    frames.append(FrameData(3, 3 / FPS, moved + 0.01))
    return frames


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # trimesh's UV code on a material-less OBJ
@pytest.mark.parametrize("name", ALL)
def test_every_format_writes_frames_an_independent_reader_reads(mesh: Mesh, tmp_path: Path, name: str) -> None:
    assert name in INDEPENDENT_READERS, f"{name}: add a reader that is not meshdeform's to INDEPENDENT_READERS"
    export([name], mesh, tmp_path)
    frames = INDEPENDENT_READERS[name](tmp_path)
    assert len(frames) == FRAMES
    atol = reader_tolerance(name, tmp_path)
    for i, positions in enumerate(frames, start=1):
        assert np.all(np.abs(positions - wave(mesh, i)) <= atol), name


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
@pytest.mark.parametrize("name", FOLLOWING)
def test_every_format_that_follows_a_tear_writes_the_torn_frames(mesh: Mesh, tmp_path: Path, name: str) -> None:
    run = torn_run(mesh)
    export([name], mesh, tmp_path, run)
    frames = INDEPENDENT_READERS[name](tmp_path)
    assert [len(f) for f in frames] == [mesh.vertex_count] * 2 + [mesh.vertex_count + 1] * 2
    np.testing.assert_allclose(frames[-1], run[-1].positions, rtol=0, atol=1e-6)


@pytest.mark.parametrize("name", FIXED)
def test_every_fixed_topology_format_refuses_a_torn_frame_and_leaves_nothing(
    mesh: Mesh, tmp_path: Path, name: str
) -> None:
    with pytest.raises(ExportError, match=re.escape(EXPORTERS[name].topology_message)):
        export([name], mesh, tmp_path, torn_run(mesh)[:3])
    assert "fixed" in EXPORTERS[name].topology_message
    assert visible_files(tmp_path) == []


# ---------------------------------------------------------------------------------------------
# streaming, atomicity, topology changes


def test_nothing_looks_finished_until_close_and_abort_leaves_nothing(mesh: Mesh, tmp_path: Path) -> None:
    closed = export(ALL, mesh, tmp_path / "closed", frames_of(mesh, 3))
    finished_names = {p.name for paths in closed.values() for p in paths if p.parent == tmp_path / "closed"}
    assert len(finished_names) >= len(FIXED)  # every single-file format's file, the VTK collection, ...
    out = tmp_path / "aborted"
    session = ExportSession(ALL, ExportContext(mesh=mesh, out_dir=out, fps=FPS, frame_count=FRAMES)).open()
    for frame in frames_of(mesh, 3):
        session.write(frame)
    assert not finished_names & {p.name for p in out.iterdir()}
    session.abort()
    assert visible_files(out) == []  # no frames, no temporary files, no spools
    assert list(out.iterdir()) == []  # not even the empty frames/ and vtk/ folders


def test_an_exception_mid_run_aborts_every_exporter(mesh: Mesh, tmp_path: Path) -> None:
    ctx = ExportContext(mesh=mesh, out_dir=tmp_path, fps=FPS)
    with pytest.raises(KeyboardInterrupt), ExportSession(ALL, ctx) as session:
        for frame in frames_of(mesh, 2):
            session.write(frame)
        raise KeyboardInterrupt
    assert visible_files(tmp_path) == []


def test_a_session_made_before_its_folder_opens_on_it_and_closes_inside_its_block(mesh: Mesh, tmp_path: Path) -> None:
    """As run_job uses it: formats checked first, opened on a staging folder made later, closed inside the
    block (timed, files used); an exception after that still removes the finished files."""
    with pytest.raises(ExportError, match="unknown export format"):
        ExportSession(["obj", "blend"])
    session = ExportSession(["obj", "pc2"])
    with pytest.raises(ExportError, match="no export context"):
        session.open()
    out = tmp_path / "stage"
    with session.open(ExportContext(mesh=mesh, out_dir=out, fps=FPS, frame_count=2)):
        for frame in frames_of(mesh, 2):
            session.write(frame)
        session.close()
        assert sorted(p.relative_to(out).as_posix() for p in session.files) == [
            "cache.pc2",
            "frames/frame_0001.obj",
            "frames/frame_0002.obj",
        ]
    assert all(p.is_file() for p in session.files)  # the block ended normally: kept, not closed twice
    again = ExportSession(["obj", "pc2"])
    with pytest.raises(KeyboardInterrupt), again.open(ExportContext(mesh=mesh, out_dir=tmp_path / "b", fps=FPS)):
        again.write(frames_of(mesh, 1)[0])
        again.close()
        raise KeyboardInterrupt
    assert visible_files(tmp_path / "b") == [] and again.files == []


def test_abort_reaches_every_exporter_when_one_fails(mesh: Mesh, tmp_path: Path, monkeypatch) -> None:
    session = ExportSession(["obj", "pc2"], ExportContext(mesh=mesh, out_dir=tmp_path, fps=FPS)).open()
    session.write(frames_of(mesh, 1)[0])

    def broken() -> None:
        raise RuntimeError("abort failed")

    monkeypatch.setattr(session.exporters["obj"], "abort", broken)
    session.abort()
    assert [p.name for p in tmp_path.iterdir()] == ["frames"]  # pc2 aborted all the same: no cache, no temporary


@pytest.mark.parametrize("name", ALL)
def test_close_without_frames_is_an_error(mesh: Mesh, tmp_path: Path, name: str) -> None:
    exporter = make_exporter(name)
    exporter.open(ExportContext(mesh=mesh, out_dir=tmp_path, fps=FPS))
    with pytest.raises(ExportError, match="no frames"):
        exporter.close()
    assert list(tmp_path.iterdir()) == []


def test_frames_must_increase_and_match_the_vertex_count(mesh: Mesh, tmp_path: Path) -> None:
    exporter = make_exporter("npz")
    exporter.open(ExportContext(mesh=mesh, out_dir=tmp_path, fps=FPS))
    frames = frames_of(mesh, 2)
    exporter.write(frames[1])
    with pytest.raises(ExportError, match="increasing order"):
        exporter.write(frames[0])
    with pytest.raises(ExportError, match=r"shape \(3, 3\)"):
        exporter.write(FrameData(5, 1.0, np.zeros((3, 3))))
    exporter.abort()


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_obj_usd_vtk_follow_a_topology_change(mesh: Mesh, tmp_path: Path) -> None:
    from pxr import Usd, UsdGeom

    frames = torn_run(mesh)
    moved = frames[2].positions
    export(["obj", "usd", "vtk"], mesh, tmp_path, frames)
    assert meshio.read(tmp_path / "frames" / "frame_0002.obj").points.shape[0] == mesh.vertex_count
    m3 = trimesh.load(tmp_path / "frames" / "frame_0003.obj", process=False, maintain_order=True)
    np.testing.assert_allclose(m3.vertices, moved, atol=1e-9)
    assert m3.faces[0, 0] == mesh.vertex_count
    assert read_with_vtk(tmp_path / "vtk" / "frame_0004.vtp").n_points == mesh.vertex_count + 1
    stage = Usd.Stage.Open(str(tmp_path / "scene.usdc"))
    geom = UsdGeom.Mesh(stage.GetDefaultPrim().GetChildren()[0])
    indices = geom.GetFaceVertexIndicesAttr()
    assert indices.GetTimeSamples() == [1.0, 3.0]
    assert indices.Get(Usd.TimeCode(2))[0] == 0 and indices.Get(Usd.TimeCode(4))[0] == mesh.vertex_count
    assert len(geom.GetPointsAttr().Get(Usd.TimeCode(4))) == mesh.vertex_count + 1


def test_export_the_sample_flag_with_groups_to_every_format(samples_dir: Path, tmp_path: Path) -> None:
    from meshdeform.io import load

    flag = load(samples_dir / "meshes" / "flag.obj")
    frames = frames_of(flag, 3)
    outputs = export(ALL, flag, tmp_path, frames)
    assert list(outputs) == ALL and all(paths and all(p.is_file() for p in paths) for paths in outputs.values())
    back = load(tmp_path / "frames" / "frame_0002.obj")
    assert sorted(back.groups) == sorted(flag.groups)
    np.testing.assert_allclose(back.positions, frames[1].positions)
    assert not [p for p in tmp_path.rglob(".*")]  # no temporary files left


def test_obj_copies_the_material_library_beside_the_frames(tmp_path: Path) -> None:
    from meshdeform.io import load

    source = tmp_path / "in"
    source.mkdir()
    (source / "cloth.mtl").write_text("newmtl red\nKd 1 0 0\n")
    (source / "cloth.obj").write_text("mtllib cloth.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nusemtl red\nf 1 2 3 4\n")
    mesh = load(source / "cloth.obj")
    out = tmp_path / "out"
    outputs = export(["obj"], mesh, out, frames_of(mesh, 2))
    assert out / "frames" / "cloth.mtl" in outputs["obj"]
    assert (out / "frames" / "cloth.mtl").read_text() == "newmtl red\nKd 1 0 0\n"
    text = (out / "frames" / "frame_0002.obj").read_text()
    assert "mtllib cloth.mtl" in text and "usemtl red" in text


# Two threads of one fresh process open their first USD stages at the same moment, as two jobs
# in one Dask worker do: without `start_usd` USD's first-use initialisation deadlocks in about
# half of such processes.
USD_RACE = """
import os, sys, tempfile, threading
from meshdeform.export.usd import start_usd
folder = tempfile.mkdtemp()
barrier = threading.Barrier(2)
def job(i):
    barrier.wait()
    start_usd()
    from pxr import Usd
    Usd.Stage.CreateNew(os.path.join(folder, f"scene{i}.usda")).Save()
threads = [threading.Thread(target=job, args=(i,)) for i in range(2)]
for t in threads:
    t.start()
for t in threads:
    t.join()
print(sorted(os.listdir(folder)))
"""


def test_two_threads_opening_their_first_usd_stages_do_not_deadlock() -> None:
    import subprocess
    import sys

    for _ in range(4):
        done = subprocess.run([sys.executable, "-c", USD_RACE], capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, done.stderr
        assert done.stdout.strip() == "['scene0.usda', 'scene1.usda']"


def test_each_reader_reads_back_its_own_files_only(mesh: Mesh, tmp_path: Path) -> None:
    """Every kind of files a preview reads (`checks.reader_kinds`), written alone: its reader finds the frames and
    names files that are there, every other reader finds nothing; no reader finds frames in an empty
    folder nor in one of the formats no preview reads."""
    from checks import reader_kinds

    kinds = dict(reader_kinds())
    unread = [name for name in ALL if not any(name in formats for formats in kinds.values())]
    folders = {source: tmp_path / formats[0] for source, formats in kinds.items()}
    for source, folder in folders.items():
        export(list(kinds[source]), mesh, folder)
    for folder in (tmp_path / "none", tmp_path / "unread"):
        folder.mkdir()
    if unread:
        export(unread, mesh, tmp_path / "unread")
    for source, folder in folders.items():
        found = source.read(folder, mesh, 0)
        assert found is not None and list(folder.glob(found.source))
        # scene frames 1 .. FRAMES (the default start frame 1); a point cache also holds sample 0,
        # its copy of the first frame (sample k is scene frame k)
        assert found.from_frame(1).numbers == list(range(1, FRAMES + 1))
        assert found.numbers[0] in (0, 1)
        assert found.base is mesh  # the input mesh: same vertex count (and polygons for vtk)
        np.testing.assert_allclose(np.asarray(found.from_frame(1).frames[FRAMES - 1]), wave(mesh, FRAMES), atol=1e-6)
        for elsewhere in [*(f for s, f in folders.items() if s is not source), tmp_path / "none", tmp_path / "unread"]:
            assert source.read(elsewhere, mesh, 0) is None, (kinds[source], elsewhere.name)
