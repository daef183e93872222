"""Recomputed normals of the OBJ / PLY frames follow the surface (issue 18 item 3).

The frames are parsed here by hand and their normals compared with area-weighted normals
computed in this file from the frame's own positions and polygons, so a layout mistake in the
writer cannot cancel itself out.
"""

from __future__ import annotations

from pathlib import Path

import meshio
import numpy as np
from typer.testing import CliRunner

from meshdeform.export import ExportContext, ExportSession, FrameData
from meshdeform.io import ObjWriter, PlyWriter, load
from pipeline.cli import app


def parse_obj(path: Path) -> tuple[np.ndarray, np.ndarray, list[list[tuple[int, int]]]]:
    """Positions (V, 3), normals (N, 3) and polygons as lists of (vertex, normal) 0-based indices."""
    v, vn, faces = [], [], []
    for line in path.read_text().splitlines():
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "v":
            v.append([float(x) for x in parts[1:4]])
        elif parts[0] == "vn":
            vn.append([float(x) for x in parts[1:4]])
        elif parts[0] == "f":
            corners = [c.split("/") for c in parts[1:]]
            faces.append([(int(c[0]) - 1, int(c[2]) - 1) for c in corners])
    return np.array(v), np.array(vn), faces


def face_area_vector(pos: np.ndarray, face: list[int]) -> np.ndarray:
    """Twice the vector area of a polygon: the sum of its fan triangles' cross products."""
    p = pos[face]
    return sum(np.cross(p[k] - p[0], p[k + 1] - p[0]) for k in range(1, len(face) - 1))


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def angles_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles (degrees) between rows, by atan2 (arccos loses precision near 0)."""
    a, b = unit(a), unit(b)
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.einsum("ij,ij->i", a, b)))


def flat_plane_obj(path: Path, n: int = 9) -> None:
    """An n x n vertex plane in the xz plane written as Blender writes it: one shared `vn 0 1 0`."""
    xs = np.linspace(0.0, 1.0, n).tolist()
    lines = [f"v {x!r} 0 {z!r}" for z in xs for x in xs]
    lines += [f"vt {x!r} {z!r}" for z in xs for x in xs]
    lines.append("vn -0.0000 1.0000 -0.0000")
    for j in range(n - 1):
        for i in range(n - 1):
            a = j * n + i + 1
            quad = [a, a + n, a + n + 1, a + 1]  # counter-clockwise seen from +y
            lines.append("f " + " ".join(f"{q}/{q}/1" for q in quad))
    path.write_text("\n".join(lines) + "\n")


def worst_vertex_angle(path: Path) -> float:
    """Largest angle (degrees) between a corner's written normal and the area-weighted normal
    of its vertex computed from the frame's positions."""
    pos, vn, faces = parse_obj(path)
    expected = np.zeros_like(pos)
    for face in faces:
        area = face_area_vector(pos, [c[0] for c in face])
        for vertex, _ in face:
            expected[vertex] += area
    corners = [c for face in faces for c in face]
    written = vn[[c[1] for c in corners]]
    return float(angles_deg(written, expected[[c[0] for c in corners]]).max())


def test_a_single_shared_normal_becomes_per_vertex_normals_in_simulated_frames(tmp_path: Path) -> None:
    source = tmp_path / "plane.obj"
    flat_plane_obj(source)
    out = tmp_path / "out"
    result = CliRunner().invoke(
        app,
        ["simulate", str(source), "--out", str(out), "--frames", "8", "--pin", "box:-0.01,-1,0.99,1.01,1,1.01",
         "--quiet"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    frames = sorted((out / "frames").glob("frame_*.obj"))
    assert len(frames) == 9
    last_pos, last_vn, _ = parse_obj(frames[-1])
    assert np.ptp(last_pos[:, 1]) > 0.05  # the cloth really bent
    assert len(last_vn) == len(last_pos)  # a normal per vertex, not one for all
    for path in frames:
        assert worst_vertex_angle(path) < 1.0, path.name


def cube(tmp_path: Path) -> Path:
    """A unit cube of 8 vertices and 6 face normals: every vertex on three hard edges."""
    path = tmp_path / "cube.obj"
    v = [(x, y, z) for x in (0, 1) for y in (0, 1) for z in (0, 1)]
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    normals = [(-1, 0, 0), (1, 0, 0), (0, -1, 0), (0, 1, 0), (0, 0, -1), (0, 0, 1)]
    lines = [f"v {x} {y} {z}" for x, y, z in v] + [f"vn {x} {y} {z}" for x, y, z in normals]
    lines += ["f " + " ".join(f"{q + 1}//{k + 1}" for q in quad) for k, quad in enumerate(quads)]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_hard_edges_of_the_input_stay_hard_in_deformed_frames(tmp_path: Path) -> None:
    mesh = load(cube(tmp_path))
    shear = np.array([[1.0, 0.4, 0.0], [0.0, 1.3, 0.2], [0.3, 0.0, 0.8]])  # faces stay planar
    moved = mesh.positions @ shear.T + [0.5, -1.0, 2.0]
    frame = tmp_path / "frame.obj"
    ObjWriter(mesh).write(frame, moved)
    pos, vn, faces = parse_obj(frame)
    np.testing.assert_array_equal(pos, moved)
    assert len(vn) == 24  # a normal per (vertex, face): 8 vertices on 3 faces each
    for face in faces:
        expected = unit(face_area_vector(pos, [c[0] for c in face]))
        written = vn[[c[1] for c in face]]
        assert angles_deg(written, np.tile(expected, (len(face), 1))).max() < 1e-4


def test_smooth_input_keeps_smooth_normals_and_seams_stay_smooth(tmp_path: Path) -> None:
    """Per-vertex normals on a bent sheet whose middle column is split (a UV seam: two vertices
    at one position, each side with its own copy, same normal value): the frame is smooth
    across the seam, every corner's normal the area-weighted normal of its position."""
    n = 7
    xs = np.linspace(0.0, 1.0, n).tolist()
    grid = [(x, y) for y in xs for x in xs]
    seam = [k for k, (x, _) in enumerate(grid) if x == xs[3]]
    v = grid + [grid[k] for k in seam]
    copy = {k: len(grid) + i for i, k in enumerate(seam)}
    lines = [f"v {x!r} {y!r} 0" for x, y in v] + [f"vt {x!r} {y!r}" for x, y in v]
    lines += ["vn 0 0 1" for _ in v]
    for j in range(n - 1):
        for i in range(n - 1):
            a = j * n + i
            quad = [a, a + 1, a + n + 1, a + n]
            if i >= 3:  # right of the seam: use the copies
                quad = [copy.get(q, q) for q in quad]
            lines.append("f " + " ".join(f"{q + 1}/{q + 1}/{q + 1}" for q in quad))
    source = tmp_path / "seam.obj"
    source.write_text("\n".join(lines) + "\n")
    mesh = load(source)
    bent = mesh.positions.copy()
    bent[:, 2] = 0.3 * np.sin(3.0 * bent[:, 0]) + 0.2 * bent[:, 1] ** 2
    frame = tmp_path / "frame.obj"
    ObjWriter(mesh).write(frame, bent)
    pos, vn, faces = parse_obj(frame)
    # independent: area-weighted normals per position (the seam copies welded)
    keys = {tuple(p): i for i, p in enumerate(map(tuple, pos))}
    welded = np.array([keys[tuple(p)] for p in pos])
    expected = np.zeros_like(pos)
    for face in faces:
        area = face_area_vector(pos, [c[0] for c in face])
        for vertex, _ in face:
            expected[welded[vertex]] += area
    corners = [c for face in faces for c in face]
    written = vn[[c[1] for c in corners]]
    assert angles_deg(written, expected[welded[[c[0] for c in corners]]]).max() < 1e-4
    assert len(vn) == n * n  # one normal per position


def test_ply_frames_of_a_seam_split_sheet_are_smooth_across_the_seam(tmp_path: Path) -> None:
    """A PLY (normals per vertex) whose middle column is split into two vertices at one position:
    both copies get the area-weighted normal of the position, from the faces of both sides."""
    n = 6
    xs = np.linspace(0.0, 1.0, n).tolist()
    grid = [(x, y) for y in xs for x in xs]
    seam = [k for k, (x, _) in enumerate(grid) if x == xs[2]]
    v = grid + [grid[k] for k in seam]
    copy = {k: len(grid) + i for i, k in enumerate(seam)}
    faces = []
    for j in range(n - 1):
        for i in range(n - 1):
            a = j * n + i
            quad = [a, a + 1, a + n + 1, a + n]
            faces.append([copy.get(q, q) for q in quad] if i >= 2 else quad)
    header = ["ply", "format ascii 1.0", f"element vertex {len(v)}", "property float x", "property float y",
              "property float z", "property float nx", "property float ny", "property float nz",
              f"element face {len(faces)}", "property list uchar int vertex_indices", "end_header"]  # fmt: skip
    body = [f"{x!r} {y!r} 0 0 0 1" for x, y in v] + ["4 " + " ".join(map(str, f)) for f in faces]
    source = tmp_path / "seam.ply"
    source.write_text("\n".join(header + body) + "\n")
    mesh = load(source)
    bent = mesh.positions.copy()
    bent[:, 2] = 0.4 * np.sin(2.5 * bent[:, 0]) * (1.0 + bent[:, 1])
    frame = tmp_path / "frame.ply"
    PlyWriter(mesh).write(frame, bent)
    m = meshio.read(frame)
    written = np.stack([m.point_data[c] for c in ("nx", "ny", "nz")], axis=1)
    pos = np.asarray(m.points, dtype=np.float64)
    welded = np.array(list(range(len(grid))) + seam)  # each copy -> its grid vertex
    expected = np.zeros_like(pos)
    for face in faces:
        expected[welded[face]] += face_area_vector(pos, face)
    assert angles_deg(written, expected[welded]).max() < 1e-4  # float32 normals and positions


def test_nearly_equal_input_normals_are_one_distinct_ones_split(tmp_path: Path) -> None:
    """Two triangles of a square meet along the diagonal (vertices 1 and 3). Their input normals
    differing in the 6th decimal count as one (4 written, one per vertex); 0.01 rad apart they
    are a hard edge (the two diagonal vertices get one normal per side: 6)."""
    counts = []
    for second in ("0.000001 0 1", "0.01 0 1"):
        text = f"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvn 0 0 1\nvn {second}\nf 1//1 2//1 3//1\nf 1//2 3//2 4//2\n"
        source = tmp_path / "square.obj"
        source.write_text(text)
        frame = tmp_path / "frame.obj"
        ObjWriter(load(source)).write(frame)
        counts.append(len(parse_obj(frame)[1]))
    assert counts == [4, 6]


def test_usd_keeps_the_hard_edges_as_face_varying_normals(tmp_path: Path) -> None:
    from pxr import Usd, UsdGeom

    mesh = load(cube(tmp_path))
    shear = np.array([[1.0, 0.4, 0.0], [0.0, 1.3, 0.2], [0.3, 0.0, 0.8]])
    frames = [FrameData(index=k, time=k / 24.0, positions=mesh.positions @ (shear * (1 + k)).T) for k in range(3)]
    context = ExportContext(mesh=mesh, out_dir=tmp_path / "out", fps=24.0, frame_count=len(frames))
    with ExportSession(["usd"], context, None) as session:
        for frame in frames:
            session.write(frame)
    stage = Usd.Stage.Open(str(tmp_path / "out" / "scene.usdc"))
    geom = UsdGeom.Mesh(stage.GetDefaultPrim().GetChildren()[0])
    assert geom.GetNormalsInterpolation() == UsdGeom.Tokens.faceVarying
    counts = np.asarray(geom.GetFaceVertexCountsAttr().Get())
    indices = np.asarray(geom.GetFaceVertexIndicesAttr().Get())
    for code in geom.GetPointsAttr().GetTimeSamples():
        pts = np.asarray(geom.GetPointsAttr().Get(code), dtype=np.float64)
        normals = np.asarray(geom.GetNormalsAttr().Get(code), dtype=np.float64)
        assert normals.shape == (indices.shape[0], 3)
        start = 0
        for count in counts.tolist():
            face = indices[start : start + count].tolist()
            expected = np.tile(unit(face_area_vector(pts, face)), (count, 1))
            assert angles_deg(normals[start : start + count], expected).max() < 1e-3  # float32
            start += count
