"""OBJ reading and writing: real meshes, handmade edge cases, round trips through trimesh / meshio."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from checks import refused
from factories import grid_sheet
from shared_meshes import MESHES, needs_meshes

from meshdeform.errors import ExportError, MeshLoadError
from meshdeform.io import MESH_SUFFIXES, ObjWriter, load, read_obj, save, write_obj
from meshdeform.mesh import Mesh, polygons_to_csr


def _write(tmp_path: Path, text: str | bytes, name: str = "m.obj", encoding: str = "utf-8") -> Path:
    path = tmp_path / name
    path.write_bytes(text if isinstance(text, bytes) else text.encode(encoding))
    return path


def _sizes(mesh: Mesh) -> dict[int, int]:
    values, counts = np.unique(mesh.face_sizes, return_counts=True)
    return {int(v): int(c) for v, c in zip(values, counts, strict=True)}


CUBE = """\
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 0 0 1
v 1 0 1
v 1 1 1
v 0 1 1
f 1 4 3 2
f 5 6 7 8
f 1 2 6 5
f 2 3 7 6
f 3 4 8 7
f 4 1 5 8
"""


# --------------------------------------------------------------------------- real meshes

# file -> V, F, polygon sizes {corners: count}, #vt, #vn, groups (None = no check), has colour
REAL_OBJ = {
    "spot_triangulated.obj": (2930, 5856, {3: 5856}, 3225, None, {}, False),
    "spot_control_mesh.obj": (188, 180, {3: 4, 4: 160, 5: 16}, 267, None, {}, False),
    "teapot.obj": (3644, 6320, {3: 6320}, None, None, {}, False),
    "suzanne.obj": (507, 500, {3: 32, 4: 468}, None, 507, {}, False),
    "quadknot.obj": (1440, 1440, {4: 1440}, 3, 1440, {}, True),
    "tube.obj": (128, 120, {3: 120}, 128, 128, {"0": 0, "1": 120}, False),
    "rabbit.obj": (644, 678, {3: 176, 4: 496, 16: 6}, None, 732, None, False),
    "concave.obj": (10, 7, {4: 5, 5: 2}, None, 7, {"Plane": 7}, False),
}


@needs_meshes
@pytest.mark.parametrize("name", sorted(REAL_OBJ))
def test_real_obj_counts(name: str) -> None:
    n_v, n_f, sizes, n_vt, n_vn, groups, colour = REAL_OBJ[name]
    mesh = load(MESHES / "real" / name)
    assert mesh.vertex_count == n_v
    assert mesh.face_count == n_f
    assert _sizes(mesh) == sizes
    assert (None if mesh.uvs is None else len(mesh.uvs)) == n_vt
    assert (None if mesh.normals is None else len(mesh.normals)) == n_vn
    if groups is not None:
        assert {k: len(v) for k, v in mesh.groups.items()} == groups
    assert ("color" in mesh.vertex_properties) == colour
    assert mesh.warnings == ()
    assert np.isfinite(mesh.positions).all()
    assert mesh.face_indices.min() >= 0 and mesh.face_indices.max() < n_v


@needs_meshes
def test_rabbit_objects_and_groups() -> None:
    mesh = load(MESHES / "real" / "rabbit.obj")
    objects = [t.split(None, 1)[1] for _, t in mesh.statements if t.startswith("o ")]
    g_names = [t.split(None, 1)[1] for _, t in mesh.statements if t.startswith("g ")]
    assert len(objects) == 9 and len(g_names) == 9
    assert set(mesh.groups) == set(objects) | set(g_names)
    # every face is in exactly one object and one g group; the objects partition the faces
    all_faces = np.concatenate([mesh.groups[o] for o in objects])
    assert np.array_equal(np.sort(all_faces), np.arange(mesh.face_count))
    for o, g in zip(objects, g_names, strict=True):
        assert np.array_equal(mesh.groups[o], mesh.groups[g])
    counts = [c for c, t in mesh.statements if t.startswith("o ")]
    assert counts == sorted(counts) and counts[0] == 0


@needs_meshes
def test_quadknot_crlf_and_colours_match_file() -> None:
    path = MESHES / "real" / "quadknot.obj"
    assert b"\r\n" in path.read_bytes()
    mesh = load(path)
    first = next(line for line in path.read_text().splitlines() if line.startswith("v "))
    values = [float(x) for x in first.split()[1:]]
    assert mesh.positions[0].tolist() == values[:3]
    assert mesh.vertex_properties["color"][0].tolist() == values[3:6]
    assert mesh.vertex_properties["color"].shape == (1440, 3)


@needs_meshes
@pytest.mark.parametrize("name", ["teapot.obj", "suzanne.obj", "concave.obj", "rabbit.obj"])
def test_positions_match_trimesh(name: str) -> None:
    trimesh = pytest.importorskip("trimesh")
    path = MESHES / "real" / name
    ours = load(path)
    theirs = trimesh.load(path, process=False, force="mesh")
    if theirs.vertices.shape == ours.positions.shape:
        assert np.array_equal(theirs.vertices, ours.positions)
    # trimesh triangulates: same number of triangles as our polygons fan out into
    assert len(theirs.faces) == len(ours.triangles)


# --------------------------------------------------------------------------- handmade reading


def test_polygons_and_vertex_order_kept(tmp_path: Path) -> None:
    mesh = read_obj(_write(tmp_path, CUBE + "v 5 5 5\nf 1 2 3 4 9\n"))
    assert mesh.vertex_count == 9
    assert mesh.positions[8].tolist() == [5.0, 5.0, 5.0]
    assert _sizes(mesh) == {4: 6, 5: 1}
    assert mesh.polygons()[0].tolist() == [0, 3, 2, 1]
    assert mesh.polygons()[-1].tolist() == [0, 1, 2, 3, 8]


@pytest.mark.parametrize(
    ("encoding", "bom"),
    [("utf-16-le", b"\xff\xfe"), ("utf-16-be", b"\xfe\xff"), ("utf-8", b"\xef\xbb\xbf"), ("utf-16-le", b"")],
)
def test_text_encodings(tmp_path: Path, encoding: str, bom: bytes) -> None:
    text = "# café\ng grüße\n" + CUBE.replace("\n", "\r\n")
    mesh = read_obj(_write(tmp_path, bom + text.encode(encoding)))
    assert mesh.vertex_count == 8 and mesh.face_count == 6
    assert list(mesh.groups) == ["grüße"]


def test_latin1_fallback(tmp_path: Path) -> None:
    mesh = read_obj(_write(tmp_path, ("usemtl pâte\n" + CUBE).encode("latin-1")))
    assert mesh.face_count == 6
    assert mesh.statements[0][1] == "usemtl pâte"
    assert any("Latin-1" in w for w in mesh.warnings)


def test_crlf_cr_tabs_comments_blank_lines_continuation(tmp_path: Path) -> None:
    text = (
        "# header comment\r\n"
        "   \r\n"
        "v\t0 0 0 # trailing comment\r\n"
        "  v 1 0 0\r\n"
        "v 1 1 \\\r\n"
        "  0\r\n"
        "\tv 0 1 0\r"
        "f 1 2 \\\n"
        "3 4 # quad\n"
        "f\t1\t2\t3\n"
    )
    mesh = read_obj(_write(tmp_path, text))
    assert mesh.positions.tolist() == [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]
    assert [p.tolist() for p in mesh.polygons()] == [[0, 1, 2, 3], [0, 1, 2]]


def test_continuation_keeps_line_numbers(tmp_path: Path) -> None:
    text = "v 0 0 \\\n0\nv 1 0 0\nv 0 1 0\nf 1 2 \\\n3\nf 1 2 7\n"
    with pytest.raises(MeshLoadError, match=r"line 7: face index 7 out of range \(3 vertices\)"):
        read_obj(_write(tmp_path, text))


def test_negative_indices_in_all_slots(tmp_path: Path) -> None:
    text = (
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvn 0 0 1\n"
        "f -3/-3/-1 -2/-2/-1 -1/-1/-1\n"
        "v 0 1 0\nvt 0 1\nvn 0 0 -1\n"
        "f -4/-4/-2 -2/-2/-1 -1/-1/-1\n"
    )
    mesh = read_obj(_write(tmp_path, text))
    assert [p.tolist() for p in mesh.polygons()] == [[0, 1, 2], [0, 2, 3]]
    assert mesh.face_uv_indices.tolist() == [0, 1, 2, 0, 2, 3]
    assert mesh.face_normal_indices.tolist() == [0, 0, 0, 0, 1, 1]


def test_all_corner_patterns(tmp_path: Path) -> None:
    base = "v 0 0 0\nv 1 0 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvn 0 0 1\n"
    m1 = read_obj(_write(tmp_path, base + "f 1 2 3\n", "a.obj"))
    m2 = read_obj(_write(tmp_path, base + "f 1/1 2/2 3/3\n", "b.obj"))
    m3 = read_obj(_write(tmp_path, base + "f 1//1 2//1 3//1\n", "c.obj"))
    m4 = read_obj(_write(tmp_path, base + "f 1/3/1 2/2/1 3/1/1\n", "d.obj"))
    assert m1.uvs is None and m1.normals is None
    assert m2.face_uv_indices.tolist() == [0, 1, 2] and m2.normals is None
    assert m3.uvs is None and m3.face_normal_indices.tolist() == [0, 0, 0]
    assert m4.face_uv_indices.tolist() == [2, 1, 0] and m4.face_normal_indices.tolist() == [0, 0, 0]
    for m in (m1, m2, m3, m4):
        assert m.face_indices.tolist() == [0, 1, 2]


def test_vertex_w_colours_and_vt_widths(tmp_path: Path) -> None:
    """Colours on only some vertex lines are dropped (with a warning), never made up as NaN."""
    text = "v 0 0 0 1\nv 1 0 0 0.5 0.25 0.125\nv 1 1 0\nvt 0.5\nvt 0.1 0.2 0.3\nf 1/1 2/2 3/2\n"
    mesh = read_obj(_write(tmp_path, text))
    assert mesh.positions.tolist() == [[0, 0, 0], [1, 0, 0], [1, 1, 0]]
    assert "color" not in mesh.vertex_properties
    assert mesh.uvs.tolist() == [[0.5, 0, 0], [0.1, 0.2, 0.3]]
    assert mesh.warnings == ("dropped all vertex colours: 2 of 3 vertex lines have no colour (first at line 1)",)
    every = read_obj(_write(tmp_path, "v 0 0 0 1 1 1\nv 1 0 0 0.5 0.25 0.125 1\nv 1 1 0 0 0 0\nf 1 2 3\n", "b.obj"))
    assert every.vertex_properties["color"].tolist() == [[1, 1, 1], [0.5, 0.25, 0.125], [0, 0, 0]]


def test_polylines(tmp_path: Path) -> None:
    mesh = read_obj(_write(tmp_path, "v 0 0 0\nv 1 0 0\nv 2 0 0\nl 1 2 3\nl 3/1 -3\nl 2\n"))
    assert mesh.face_count == 0 and mesh.line_count == 2
    assert mesh.line_indices.tolist() == [0, 1, 2, 2, 0]
    assert mesh.line_offsets.tolist() == [0, 3, 5]
    assert any("line elements with fewer than 2" in w for w in mesh.warnings)


def test_groups_and_statements(tmp_path: Path) -> None:
    text = (
        "mtllib a.mtl\no thing\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
        "g left both\nusemtl red\nf 1 2 3\ns 1\nf 1 3 4\ng right\nusemtl blue\nf 1 2 4\ng\nf 2 3 4\n"
    )
    mesh = read_obj(_write(tmp_path, text))
    assert {k: v.tolist() for k, v in mesh.groups.items()} == {
        "thing": [0, 1, 2, 3],
        "left": [0, 1],
        "both": [0, 1],
        "right": [2],
    }
    assert mesh.statements == (
        (0, "mtllib a.mtl"),
        (0, "o thing"),
        (0, "g left both"),
        (0, "usemtl red"),
        (1, "s 1"),
        (2, "g right"),
        (2, "usemtl blue"),
        (3, "g"),
    )


def test_uv_seams_kept(tmp_path: Path) -> None:
    # a strip of two quads whose UVs are cut along the middle edge
    text = (
        "v 0 0 0\nv 1 0 0\nv 2 0 0\nv 0 1 0\nv 1 1 0\nv 2 1 0\n"
        "vt 0 0\nvt 1 0\nvt 0 1\nvt 1 1\nvt 0 0\nvt 1 0\nvt 0 1\nvt 1 1\n"
        "f 1/1 2/2 5/4 4/3\nf 2/5 3/6 6/8 5/7\n"
    )
    mesh = read_obj(_write(tmp_path, text))
    assert mesh.vertex_count == 6 and len(mesh.uvs) == 8
    assert mesh.face_uv_indices.tolist() == [0, 1, 3, 2, 4, 5, 7, 6]


def test_mixed_uv_presence_drops_uvs_with_warning(tmp_path: Path) -> None:
    text = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nf 1/1 2/1 3/1\nf 1 3 4\n"
    mesh = read_obj(_write(tmp_path, text))
    assert mesh.face_count == 2 and mesh.uvs is None and mesh.face_uv_indices is None
    assert any("dropped all UV references" in w and "line 7" in w for w in mesh.warnings)


def test_unsupported_and_unknown_statements_warn(tmp_path: Path) -> None:
    mesh = read_obj(_write(tmp_path, "vp 0.5\np 1\nfoo bar\n" + CUBE))
    assert mesh.face_count == 6
    assert any("unsupported" in w and "vp" in w for w in mesh.warnings)
    assert any("unknown statements" in w and "line 3" in w for w in mesh.warnings)


def test_degenerate_polygons_repaired(tmp_path: Path) -> None:
    text = CUBE + "f 1 1 1\nf 1 2 1\nf 1 2 2 3\nf 1 2 1 2\nf 1 2\n"
    mesh = read_obj(_write(tmp_path, text))
    assert mesh.face_count == 7
    assert mesh.polygons()[-1].tolist() == [0, 1, 2]
    text_w = " | ".join(mesh.warnings)
    assert "dropped 3 degenerate polygons" in text_w and "line 15" in text_w
    assert "dropped 1 face with fewer than 3 vertices (first at line 19)" in text_w
    assert "removed repeated consecutive vertices from 1 polygon (first at line 17)" in text_w


def test_vertices_only_loads_with_warning(tmp_path: Path) -> None:
    mesh = read_obj(_write(tmp_path, "v 0 0 0\nv 1 0 0\n"))
    assert mesh.vertex_count == 2 and mesh.face_count == 0
    assert any("only vertices" in w for w in mesh.warnings)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 0\n", r"line 4: face index 0 \(OBJ indices start at 1\)"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", r"line 4: face index 4 out of range \(3 vertices\)"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -4\n", r"line 4: face index -4 out of range"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1 2/1 3/x\n", r"line 4: cannot parse face corner '3/x'"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3.5\n", r"line 4: cannot parse face corner '3.5'"),
        ("v 0 0 0\nv 1 zero 0\n", r"line 2: cannot parse 'zero' as a number"),
        ("v 0 0 0\nv 1 0\n", r"line 2: a vertex needs 3 coordinates, this one has 2"),
        ("v 0 0 0\nv 1 inf 0\n", r"line 2: non-finite vertex position"),
        ("v 0 0 0\nv 1 1.#QNAN 0\n", r"line 2: non-finite vertex position"),
        ("v 0 0 0\nvn 1 0\n", r"line 2: a normal \(vn\) needs 3 values"),
        ("v 0 0 0\nl 1 5\n", r"line 2: line element index 5 out of range \(1 vertices\)"),
        ("# only a comment\n\n", r"no vertices, faces or lines"),
        ("<html><body>not a mesh</body></html>\n", r"line 1: not an OBJ file"),
        ("v 0 0 0\nv 1 0 0\x00\x01\x02\nf 1 2 3\n", r"byte 15: not a text OBJ file \(binary data\)$"),
        ("   \n\t\n", r"only whitespace"),
    ],
)
def test_errors_are_one_line_with_path_and_line(tmp_path: Path, text: str, message: str) -> None:
    refused(_write(tmp_path, text), message, read=read_obj)


def test_missing_directory_and_unknown_extension(tmp_path: Path) -> None:
    with pytest.raises(MeshLoadError, match="no such file"):
        load(tmp_path / "nope.obj")
    with pytest.raises(MeshLoadError, match="no such file"):
        read_obj(tmp_path / "nope.obj")
    with pytest.raises(MeshLoadError, match="is a directory"):
        load(tmp_path)
    folder = tmp_path / "folder.obj"
    folder.mkdir()
    with pytest.raises(MeshLoadError, match="is a directory"):
        load(folder)
    (tmp_path / "m.stl").write_text("solid x\n")
    with pytest.raises(MeshLoadError, match=r"unknown mesh file extension \('\.stl'\)"):
        load(tmp_path / "m.stl")
    with pytest.raises(MeshLoadError, match="no extension"):
        load(tmp_path / "mesh")


def test_suffix_is_case_insensitive(tmp_path: Path) -> None:
    assert MESH_SUFFIXES == (".obj", ".ply")
    assert load(_write(tmp_path, CUBE, "CUBE.OBJ")).face_count == 6


# --------------------------------------------------------------------------- writing


def _deform(positions: np.ndarray, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return positions + rng.normal(scale=0.01, size=positions.shape) * np.array([1.0, 1e-7, 1e5])


def test_write_read_exact_float64_round_trip(tmp_path: Path) -> None:
    mesh = grid_sheet(7, 5)
    pos = _deform(mesh.positions)
    pos[0] = [1e-300, -0.0, 123456789.123456789]
    path = tmp_path / "out.obj"
    write_obj(path, mesh, pos)
    back = read_obj(path)
    assert back.positions.dtype == np.float64
    assert np.array_equal(back.positions, pos)
    assert np.array_equal(back.face_indices, mesh.face_indices)
    assert np.array_equal(back.face_offsets, mesh.face_offsets)
    assert np.array_equal(back.uvs, mesh.uvs)
    assert np.array_equal(back.face_uv_indices, mesh.face_uv_indices)
    assert _sizes(back) == {4: 24}


@needs_meshes
@pytest.mark.parametrize("name", sorted(REAL_OBJ))
def test_real_round_trip_keeps_everything(tmp_path: Path, name: str) -> None:
    mesh = load(MESHES / "real" / name)
    pos = _deform(mesh.positions, 1)
    path = tmp_path / name
    ObjWriter(mesh).write(path, pos)
    back = read_obj(path)
    assert np.array_equal(back.positions, pos)
    assert np.array_equal(back.face_indices, mesh.face_indices)
    assert np.array_equal(back.face_offsets, mesh.face_offsets)
    for a, b in ((back.uvs, mesh.uvs), (back.face_uv_indices, mesh.face_uv_indices)):
        assert (a is None) == (b is None)
        if a is not None:
            assert np.array_equal(a, b)
    assert (back.normals is None) == (mesh.normals is None)
    if mesh.normals is not None:
        # recomputed normals, one per (position, input normal): two corners share an output normal
        # exactly when they sit at one position and their input normals agree (docs/recipes.md, Normals)
        _, position = np.unique(mesh.positions, axis=0, return_inverse=True)
        unit = mesh.normals / np.linalg.norm(mesh.normals, axis=1, keepdims=True)
        _, direction = np.unique(np.round(unit, 4), axis=0, return_inverse=True)
        corners = np.stack([position.ravel()[mesh.face_indices], direction.ravel()[mesh.face_normal_indices]], axis=1)
        _, expected = np.unique(corners, axis=0, return_inverse=True)
        pairs = np.unique(np.stack([expected.ravel(), back.face_normal_indices], axis=1), axis=0)
        assert len(pairs) == len(np.unique(expected)) == len(np.unique(back.face_normal_indices))
        assert np.allclose(np.linalg.norm(back.normals, axis=1), 1.0, atol=1e-5)
    assert back.statements == mesh.statements
    assert {k: v.tolist() for k, v in back.groups.items()} == {k: v.tolist() for k, v in mesh.groups.items()}
    if "color" in mesh.vertex_properties:
        assert np.array_equal(back.vertex_properties["color"], mesh.vertex_properties["color"])


@needs_meshes
@pytest.mark.parametrize("name", ["rabbit.obj", "tube.obj", "spot_control_mesh.obj", "suzanne.obj"])
def test_our_output_reads_in_trimesh(tmp_path: Path, name: str) -> None:
    trimesh = pytest.importorskip("trimesh")
    mesh = load(MESHES / "real" / name)
    path = tmp_path / name
    save(path, mesh)
    scene_or_mesh = trimesh.load(path, process=False, group_material=False)
    loaded = scene_or_mesh.to_mesh() if hasattr(scene_or_mesh, "to_mesh") else scene_or_mesh
    assert len(loaded.faces) == len(mesh.triangles)
    if mesh.uvs is None and mesh.normals is None:
        assert np.array_equal(loaded.vertices, mesh.positions)


def test_trimesh_and_meshio_read_written_grid(tmp_path: Path) -> None:
    trimesh = pytest.importorskip("trimesh")
    meshio = pytest.importorskip("meshio")
    mesh = grid_sheet(6, 4)
    pos = _deform(mesh.positions)
    path = tmp_path / "grid.obj"
    save(path, mesh, pos)
    t = trimesh.load(path, process=False)
    assert np.array_equal(t.vertices, pos)
    assert len(t.faces) == 2 * mesh.face_count
    assert t.visual.uv.shape == (24, 2)
    m = meshio.read(path)
    assert np.array_equal(m.points, pos)
    assert [(c.type, len(c.data)) for c in m.cells] == [("quad", 15)]
    assert np.array_equal(m.cells[0].data, mesh.face_indices.reshape(-1, 4))


def test_negative_input_indices_written_absolute(tmp_path: Path) -> None:
    text = "v 0 0 0\nv 1 0 0\nv 1 1 0\nvn 0 0 1\nf -3//-1 -2//-1 -1//-1\n"
    mesh = read_obj(_write(tmp_path, text))
    out = tmp_path / "out.obj"
    write_obj(out, mesh)
    faces = [line for line in out.read_text().splitlines() if line.startswith("f ")]
    assert faces == ["f 1//1 2//2 3//3"]  # the shared normal becomes one per vertex (normal_layout)


def test_writer_replays_statements_between_faces(tmp_path: Path) -> None:
    text = "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\ng a\nusemtl 100%\nf 1 2 3\ng b\nf 1 3 2\nl 1 2\n"
    mesh = read_obj(_write(tmp_path, text))
    out = tmp_path / "out.obj"
    write_obj(out, mesh)
    lines = [line for line in out.read_text().splitlines() if not line.startswith(("#", "v "))]
    assert lines == ["mtllib m.mtl", "g a", "usemtl 100%", "f 1 2 3", "g b", "f 1 3 2", "l 1 2"]


def test_writer_recomputes_a_shared_normal_per_vertex(tmp_path: Path) -> None:
    # a flat square: two triangles sharing one normal, authored as +z; the frame has a normal
    # per vertex (each the same here: the square stays flat), corners indexing their vertex's
    text = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//1 3//1\nf 1//1 3//1 4//1\n"
    mesh = read_obj(_write(tmp_path, text))
    rotated = mesh.positions[:, [0, 2, 1]] * np.array([1, -1, 1])  # the xy plane turned into xz
    out = tmp_path / "out.obj"
    ObjWriter(mesh).write(out, rotated)
    back = read_obj(out)
    assert back.normals.shape == (4, 3)
    assert np.allclose(back.normals, [0, -1, 0])
    assert back.face_normal_indices.tolist() == mesh.face_indices.tolist()


def test_writer_checks_shape_and_leaves_no_partial_files(tmp_path: Path) -> None:
    mesh = grid_sheet(3)
    writer = ObjWriter(mesh)
    with pytest.raises(ExportError, match="shape"):
        writer.write(tmp_path / "bad.obj", np.zeros((4, 3)))
    assert list(tmp_path.iterdir()) == []
    writer.write(tmp_path / "sub" / "frame_0001.obj", mesh.positions)
    assert [p.name for p in (tmp_path / "sub").iterdir()] == ["frame_0001.obj"]


def test_writer_frames_differ_only_in_vertex_lines(tmp_path: Path) -> None:
    polys = [[0, 1, 2, 3], [1, 4, 2]]
    flat, offsets = polygons_to_csr(polys)
    mesh = Mesh(positions=np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0.0]]),
                face_indices=flat, face_offsets=offsets)  # fmt: skip
    writer = ObjWriter(mesh)
    writer.write(tmp_path / "a.obj", mesh.positions)
    writer.write(tmp_path / "b.obj", mesh.positions + 1.5)
    a = (tmp_path / "a.obj").read_text().splitlines()
    b = (tmp_path / "b.obj").read_text().splitlines()
    assert len(a) == len(b)
    changed = [x for x, y in zip(a, b, strict=True) if x != y]
    assert len(changed) == 5 and all(x.startswith("v ") for x in changed)
    assert read_obj(tmp_path / "b.obj").polygons()[1].tolist() == [1, 4, 2]


def test_random_binary_bytes_are_refused(tmp_path: Path) -> None:
    data = np.random.default_rng(5).integers(0, 256, size=4000, dtype=np.uint8).tobytes()
    with pytest.raises(MeshLoadError, match=r"binary data|not an OBJ file|cannot parse"):
        load(_write(tmp_path, data, "noise.obj"))


def test_big_grid_loads_in_bulk(tmp_path: Path) -> None:
    """Guards the bulk paths (no per-line Python for v / vt / f): 90k vertices, well under a second
    on an idle machine; the bound only catches a fall back to line-by-line parsing."""
    import time

    mesh = grid_sheet(300)
    path = tmp_path / "grid.obj"
    save(path, mesh)
    start = time.perf_counter()
    back = load(path)
    elapsed = time.perf_counter() - start
    assert np.array_equal(back.positions, mesh.positions) and np.array_equal(back.face_indices, mesh.face_indices)
    assert elapsed < 8.0


@needs_meshes
def test_bulk_and_line_by_line_paths_agree(monkeypatch: pytest.MonkeyPatch) -> None:
    """The NumPy bulk parse and the slow line-by-line parse give the same mesh for every real OBJ."""
    import meshdeform.io.obj as obj_module

    names = sorted(REAL_OBJ) + ["negative_indices.obj", "cube-minimal-degenerated.obj", "box-incomplete-normals.obj"]
    paths = [MESHES / ("real" if n in REAL_OBJ else "broken") / n for n in names]
    fast = [read_obj(p) for p in paths]
    monkeypatch.setattr(obj_module, "_parse_all", lambda data, dtype: None)
    slow = [read_obj(p) for p in paths]
    for name, a, b in zip(names, fast, slow, strict=True):
        for field in ("positions", "face_indices", "face_offsets", "uvs", "face_uv_indices", "normals",
                      "face_normal_indices"):  # fmt: skip
            x, y = getattr(a, field), getattr(b, field)
            assert (x is None) == (y is None), (name, field)
            if x is not None:
                assert np.array_equal(x, y, equal_nan=True), (name, field)
        assert a.vertex_properties.keys() == b.vertex_properties.keys(), name
        for key, values in a.vertex_properties.items():
            assert np.array_equal(values, b.vertex_properties[key]), (name, key)
        assert a.statements == b.statements and a.warnings == b.warnings, name


def test_interleaved_lines_many_runs(tmp_path: Path) -> None:
    """Thousands of alternating v / f runs (each triangle right after its vertices)."""
    lines = []
    for k in range(3000):
        lines += [f"v {k} 0 0", f"v {k} 1 0", f"v {k} 0 1", "f -3 -2 -1", f"# triangle {k}"]
    mesh = read_obj(_write(tmp_path, "\n".join(lines)))
    assert mesh.vertex_count == 9000 and mesh.face_count == 3000
    assert np.array_equal(mesh.face_indices, np.arange(9000))
    assert mesh.positions[-1].tolist() == [2999.0, 0.0, 1.0]
