"""PLY reading and writing: every format and type, element order, list handling, round trips."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from checks import refused
from factories import grid_sheet
from shared_meshes import MESHES, needs_meshes

from meshdeform.errors import ExportError, MeshLoadError
from meshdeform.io import PlyWriter, load, read_ply, save, write_ply
from meshdeform.mesh import Mesh, polygons_to_csr

_STRUCT = {"char": "b", "int8": "b", "uchar": "B", "uint8": "B", "short": "h", "int16": "h", "ushort": "H",
           "uint16": "H", "int": "i", "int32": "i", "uint": "I", "uint32": "I", "float": "f", "float32": "f",
           "double": "d", "float64": "d"}  # fmt: skip


def ply_file(fmt: str, elements: list[tuple[str, list[str], list[list]]], newline: str = "\n") -> bytes:
    """A PLY file built independently of the code under test.

    elements: (name, property declarations like "float x" / "list uchar int vertex_indices", rows);
    a row holds one value per scalar and a Python list per list property.
    """
    head = ["ply", f"format {fmt} 1.0", "comment test file"]
    for name, props, rows in elements:
        head.append(f"element {name} {len(rows)}")
        head += [f"property {p}" for p in props]
    head.append("end_header")
    out = newline.join(head).encode() + newline.encode()
    order = "<" if fmt == "binary_little_endian" else ">"
    for _, props, rows in elements:
        for row in rows:
            if fmt == "ascii":
                parts = []
                for value in row:
                    parts += [str(len(value)), *map(str, value)] if isinstance(value, list) else [str(value)]
                out += (" ".join(parts) + newline).encode()
                continue
            for decl, value in zip(props, row, strict=True):
                words = decl.split()
                if words[0] == "list":
                    out += struct.pack(order + _STRUCT[words[1]], len(value))
                    out += struct.pack(order + _STRUCT[words[2]] * len(value), *value)
                else:
                    out += struct.pack(order + _STRUCT[words[0]], value)
    return out


SQUARE_V = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0], [2.0, 0.5, 0.0]]
FORMATS = ["ascii", "binary_little_endian", "binary_big_endian"]


def _write(tmp_path: Path, data: bytes, name: str = "m.ply") -> Path:
    path = tmp_path / name
    path.write_bytes(data)
    return path


# --------------------------------------------------------------------------- real meshes

# file -> V, F, polygon sizes, vertex property names, has normals
REAL_PLY = {
    "bunny.ply": (8171, 16301, {3: 16301}, ["confidence", "intensity"], False),
    "reference.ply": (845, 1610, {3: 1610}, ["red", "green", "blue", "alpha", "color"], False),
    "cube-minimal-custom_props.ply": (8, 6, {4: 6}, ["quality", "index"], True),
    "sphere840.ply": (422, 840, {3: 840}, [], False),
    "platonic_shelf.ply": (50, 50, {3: 32, 4: 6, 5: 12}, [], False),
}


@needs_meshes
@pytest.mark.parametrize("name", sorted(REAL_PLY))
def test_real_ply_counts(name: str) -> None:
    n_v, n_f, sizes, props, normals = REAL_PLY[name]
    mesh = load(MESHES / "real" / name)
    assert mesh.vertex_count == n_v and mesh.face_count == n_f
    values, counts = np.unique(mesh.face_sizes, return_counts=True)
    assert dict(zip(values.tolist(), counts.tolist(), strict=True)) == sizes
    assert list(mesh.vertex_properties) == props
    assert (mesh.normals is not None) == normals
    assert mesh.warnings == ()


@needs_meshes
def test_bunny_extra_properties_and_positions_match_meshio_and_trimesh() -> None:
    meshio = pytest.importorskip("meshio")
    trimesh = pytest.importorskip("trimesh")
    path = MESHES / "real" / "bunny.ply"
    mesh = load(path)
    assert mesh.vertex_properties["confidence"].dtype == np.float32
    theirs = meshio.read(path)
    assert np.array_equal(theirs.point_data["confidence"], mesh.vertex_properties["confidence"])
    assert np.array_equal(theirs.point_data["intensity"], mesh.vertex_properties["intensity"])
    t = trimesh.load(path, process=False)
    assert np.array_equal(t.vertices, mesh.positions)
    assert np.array_equal(t.faces, mesh.face_indices.reshape(-1, 3))


@needs_meshes
def test_reference_colours() -> None:
    trimesh = pytest.importorskip("trimesh")
    path = MESHES / "real" / "reference.ply"
    mesh = load(path)
    color = mesh.vertex_properties["color"]
    assert color.shape == (845, 4) and color.dtype == np.uint8
    assert np.array_equal(color[:, 0], mesh.vertex_properties["red"])
    t = trimesh.load(path, process=False)
    assert np.array_equal(t.visual.vertex_colors, color)
    assert np.array_equal(t.vertices, mesh.positions)


@needs_meshes
def test_custom_props_cube() -> None:
    mesh = load(MESHES / "real" / "cube-minimal-custom_props.ply")
    assert mesh.vertex_properties["index"].tolist() == list(range(8))
    assert mesh.vertex_properties["index"].dtype == np.uint32
    assert mesh.vertex_properties["quality"].dtype == np.float32
    assert mesh.face_properties["faceIndex"].tolist() == list(range(6))
    assert mesh.normals[3].tolist() == [1.0, 0.0, 0.0]
    assert np.array_equal(mesh.face_normal_indices, mesh.face_indices)
    # the face list `texcoords` (u v per corner, as OpenMesh / MeshLab write seams) becomes UVs
    assert mesh.uvs.shape == (24, 2) and mesh.face_uv_indices.tolist() == list(range(24))
    assert mesh.uvs[:2].tolist() == [[1.0, 1.0], [-1.0, -1.0]]


@needs_meshes
def test_platonic_shelf_face_before_vertex() -> None:
    path = MESHES / "real" / "platonic_shelf.ply"
    header = path.read_bytes().split(b"end_header")[0]
    assert header.index(b"element face") < header.index(b"element vertex")
    mesh = load(path)
    assert mesh.polygons()[0].tolist() == [0, 1, 3, 2]
    assert mesh.face_indices.max() == 49
    # the cube (first 8 vertices) has unit edges in the file: check a real value landed right
    edge = np.linalg.norm(mesh.positions[0] - mesh.positions[1])
    assert edge > 0.1


@needs_meshes
def test_sphere840_crlf_ascii() -> None:
    path = MESHES / "real" / "sphere840.ply"
    assert b"end_header\r\n" in path.read_bytes()
    mesh = load(path)
    assert mesh.positions[0].tolist() == [0.0, 0.0, -127.0]
    assert np.allclose(np.linalg.norm(mesh.positions, axis=1), 127, atol=1.5)


# --------------------------------------------------------------------------- handmade files


@pytest.mark.parametrize("fmt", FORMATS)
def test_formats_polygons_and_face_first(tmp_path: Path, fmt: str) -> None:
    faces = [[[0, 1, 2, 3]], [[1, 4, 2]]]
    data = ply_file(
        fmt,
        [
            ("face", ["list uchar int vertex_indices"], faces),
            ("vertex", ["float x", "float y", "float z"], SQUARE_V),
        ],
    )
    mesh = read_ply(_write(tmp_path, data))
    assert mesh.positions.tolist() == SQUARE_V
    assert [p.tolist() for p in mesh.polygons()] == [[0, 1, 2, 3], [1, 4, 2]]


@pytest.mark.parametrize("fmt", FORMATS)
def test_every_type_name(tmp_path: Path, fmt: str) -> None:
    names = ["char", "int8", "uchar", "uint8", "short", "int16", "ushort", "uint16", "int", "int32", "uint",
             "uint32", "float", "float32", "double", "float64"]  # fmt: skip
    props = ["double x", "float32 y", "float64 z"] + [f"{t} p_{t}" for t in names]
    values = [-5, -6, 200, 201, -300, -301, 60000, 60001, -70000, -70001, 4000000000, 4000000001, 0.5, 0.25,
              0.1, 0.2]  # fmt: skip
    rows = [[1.5, 2.5, 3.5, *values], [0.0, 1.0, 0.0, *values], [1.0, 1.0, 1.0, *values]]
    data = ply_file(fmt, [("vertex", props, rows), ("face", ["list ushort uint vertex_index"], [[[0, 1, 2]]])])
    mesh = read_ply(_write(tmp_path, data))
    assert mesh.positions[0].tolist() == [1.5, 2.5, 3.5]
    assert mesh.face_indices.tolist() == [0, 1, 2]
    expected_types = ["int8", "int8", "uint8", "uint8", "int16", "int16", "uint16", "uint16", "int32", "int32",
                      "uint32", "uint32", "float32", "float32", "float64", "float64"]  # fmt: skip
    for t, v, dtype in zip(names, values, expected_types, strict=True):
        prop = mesh.vertex_properties[f"p_{t}"]
        assert prop.dtype == np.dtype(dtype), t
        assert prop[0] == np.asarray(v, dtype=dtype), t


@pytest.mark.parametrize("fmt", FORMATS)
def test_varying_list_lengths_scalars_and_other_lists(tmp_path: Path, fmt: str) -> None:
    """Mixed polygon sizes (the row walk), a face scalar after the list, another list ignored."""
    faces = [[[0, 1, 2, 3], 7, [1.0, 2.0]], [[1, 4, 2], 8, []], [[0, 2, 4], 9, [3.0]]]
    data = ply_file(
        fmt,
        [
            ("vertex", ["float x", "float y", "float z", "list uchar float junk"], [[*v, [1.0]] for v in SQUARE_V]),
            ("face", ["list uchar int vertex_indices", "short tag", "list int float other"], faces),
            ("edge", ["int vertex1", "int vertex2"], [[0, 1], [1, 2]]),
        ],
    )
    mesh = read_ply(_write(tmp_path, data))
    assert [p.tolist() for p in mesh.polygons()] == [[0, 1, 2, 3], [1, 4, 2], [0, 2, 4]]
    assert mesh.face_properties["tag"].tolist() == [7, 8, 9]
    assert mesh.face_properties["tag"].dtype == np.int16
    assert mesh.positions.tolist() == SQUARE_V
    assert "junk" not in mesh.vertex_properties
    assert any("edge" in w for w in mesh.warnings)


def test_uniform_binary_lists_vectorised(tmp_path: Path) -> None:
    n = 2000
    rng = np.random.default_rng(3)
    verts = rng.random((n, 3)).tolist()
    faces = [[rng.integers(0, n, 4).tolist()] for _ in range(3000)]
    data = ply_file("binary_big_endian", [("vertex", ["float x", "float y", "float z"], verts),
                                          ("face", ["list uchar int vertex_indices"], faces)])  # fmt: skip
    mesh = read_ply(_write(tmp_path, data))
    expected = np.array([f[0] for f in faces])
    # consecutive repeats are repaired, so compare the faces the cleanup left alone
    assert mesh.positions.astype(np.float32).tolist() == np.asarray(verts, dtype=np.float32).tolist()
    ok = np.all(expected != np.roll(expected, -1, axis=1), axis=1)
    kept = np.array([p.tolist() for p in mesh.polygons() if len(p) == 4])
    assert np.array_equal(kept, expected[ok])


def test_normals_uvs_and_colour_names(tmp_path: Path) -> None:
    props = ["float x", "float y", "float z", "float nx", "float ny", "float nz", "float s", "float t",
             "uchar red", "uchar green", "uchar blue"]  # fmt: skip
    rows = [[*v, 0.0, 0.0, 1.0, v[0], v[1], 10, 20, 30] for v in SQUARE_V]
    data = ply_file("ascii", [("vertex", props, rows), ("face", ["list uchar int vertex_indices"], [[[0, 1, 2]]])])
    mesh = read_ply(_write(tmp_path, data))
    assert np.array_equal(mesh.normals, np.tile([0.0, 0.0, 1.0], (5, 1)))
    assert mesh.uvs.tolist() == [v[:2] for v in SQUARE_V]
    assert np.array_equal(mesh.face_uv_indices, mesh.face_indices)
    assert mesh.vertex_properties["color"].tolist() == [[10, 20, 30]] * 5
    assert set(mesh.vertex_properties) == {"red", "green", "blue", "color"}


def test_crlf_header_before_binary_body(tmp_path: Path) -> None:
    data = ply_file("binary_little_endian", [("vertex", ["float x", "float y", "float z"], SQUARE_V),
                                             ("face", ["list uchar int vertex_indices"], [[[0, 1, 2]]])],
                    newline="\r\n")  # fmt: skip
    assert read_ply(_write(tmp_path, data)).positions.tolist() == SQUARE_V
    # mixed: LF lines, then CRLF after end_header only (the case that shifts naive readers by a byte)
    mixed = data.replace(b"\r\n", b"\n", data.count(b"\r\n") - 1)
    assert b"\nend_header\r\n" in mixed
    assert read_ply(_write(tmp_path, mixed, "mixed.ply")).positions.tolist() == SQUARE_V


@needs_meshes
def test_truncated_binary_files(tmp_path: Path) -> None:
    data = (MESHES / "real" / "reference.ply").read_bytes()
    for cut in (len(data) - 1, len(data) - 700, data.index(b"end_header") + 11 + 845 * 16 - 3):
        with pytest.raises(MeshLoadError, match=r"element '(vertex|face)'.*(ends early|truncated)"):
            read_ply(_write(tmp_path, data[:cut]))
    grid = grid_sheet(4)
    write_ply(tmp_path / "g.ply", grid)
    whole = (tmp_path / "g.ply").read_bytes()
    with pytest.raises(MeshLoadError, match=r"element 'face'"):
        read_ply(_write(tmp_path, whole[:-5], "cut.ply"))


@pytest.mark.parametrize(
    ("data", "message"),
    [
        (b"", r"empty file"),
        (b"solid cube\n", r"not a PLY file"),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n", r"no end_header"),
        (b"ply\nformat utf8 1.0\nend_header\n", r"line 2: unknown PLY format 'utf8'"),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float128 x\nend_header\n",
         r"line 4: unknown property type 'float128'"),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nelement vertex 1\nproperty float y\n"
         b"end_header\n1\n2\n", r"line 5: a second 'vertex' element"),
        (b"ply\nformat ascii 1.0\nelement vertex two\nend_header\n", r"line 3: element count 'two'"),
        (b"ply\nformat ascii 1.0\nproperty float x\nend_header\n", r"line 3: a property before any element"),
        (b"ply\nelement vertex 0\nend_header\n", r"no 'format' line"),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n",
         r"element 'vertex': no scalar property z"),
        (b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
         b"end_header\n0 0 0\n1 nan 0\n", r"element 'vertex' row 1: non-finite position"),
        (b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
         b"end_header\n0 0 0\n1 abc 0\n", r"element 'vertex' row 1: cannot parse 'abc'"),
        (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
         b"element face 2\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
         b"3 0 1 4143600380\n", r"element 'face' row 1: vertex index 4143600380 out of range \(3 vertices\)"),
        (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
         b"element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1\n",
         r"element 'face' row 0: the list 'vertex_indices' declares 3 values, line 13 holds only 2 after it$"),
        (b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
         b"end_header\n0 0 0\n1 0\n", r"element 'vertex' row 1: line 9 holds 2 values, too few for its properties "
         r"\(x y z\)$"),
        (b"ply\nformat binary_little_endian 1.0\nelement vertex 1000000000000\nproperty float x\n"
         b"property float y\nproperty float z\nend_header\n" + b"\0" * 24,
         r"element 'vertex' row 2: the file ends early"),
        (b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
         b"property float z\nelement face 1000000000\nproperty list uchar int vertex_indices\nend_header\n"
         + b"\0" * 36 + b"\x03" + b"\0" * 12, r"element 'face'.*ends early"),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty uchar x\nproperty uchar y\nproperty uchar z\n"
         b"end_header\n1 2 300\n", r"element 'vertex' row 0: z = 300.0 is not a valid uint8 value"),
    ],
)
def test_errors_name_file_and_place(tmp_path: Path, data: bytes, message: str) -> None:
    refused(_write(tmp_path, data), message, read=read_ply)


def test_vertices_only_loads_with_warning(tmp_path: Path) -> None:
    data = ply_file("ascii", [("vertex", ["float x", "float y", "float z"], SQUARE_V)])
    mesh = read_ply(_write(tmp_path, data))
    assert mesh.vertex_count == 5 and mesh.face_count == 0
    assert any("no 'face' element" in w for w in mesh.warnings)


def test_degenerate_ply_faces_repaired(tmp_path: Path) -> None:
    faces = [[[0, 1, 2]], [[1, 1, 1]], [[0, 1]], [[0, 1, 1, 2]]]
    data = ply_file("ascii", [("vertex", ["float x", "float y", "float z"], SQUARE_V),
                              ("face", ["list uchar int vertex_indices", "uchar tag"],
                               [[f[0], k] for k, f in enumerate(faces)])])  # fmt: skip
    mesh = read_ply(_write(tmp_path, data))
    assert [p.tolist() for p in mesh.polygons()] == [[0, 1, 2], [0, 1, 2]]
    assert mesh.face_properties["tag"].tolist() == [0, 3]
    assert len(mesh.warnings) == 3


# --------------------------------------------------------------------------- writing


def _mixed_mesh() -> Mesh:
    flat, offsets = polygons_to_csr([[0, 1, 2, 3], [1, 4, 2]])
    return Mesh(positions=np.array(SQUARE_V), face_indices=flat, face_offsets=offsets)


@pytest.mark.parametrize("encoding", FORMATS)
def test_round_trip_encodings(tmp_path: Path, encoding: str) -> None:
    mesh = _mixed_mesh()
    pos = mesh.positions + np.array([0.1, 0.2, 1e-3])
    path = tmp_path / "m.ply"
    PlyWriter(mesh, encoding=encoding).write(path, pos)
    assert f"format {encoding} 1.0".encode() in path.read_bytes()[:80]
    back = read_ply(path)
    assert np.array_equal(back.positions, pos.astype(np.float32).astype(np.float64))
    assert [p.tolist() for p in back.polygons()] == [[0, 1, 2, 3], [1, 4, 2]]


def test_double_positions_are_exact(tmp_path: Path) -> None:
    mesh = grid_sheet(5)
    pos = mesh.positions + np.random.default_rng(0).normal(size=mesh.positions.shape)
    for encoding in ("binary_little_endian", "ascii"):
        write_ply(tmp_path / "d.ply", mesh, pos, encoding=encoding, position_type="double")
        assert np.array_equal(read_ply(tmp_path / "d.ply").positions, pos)


@needs_meshes
@pytest.mark.parametrize("name", ["bunny.ply", "reference.ply", "cube-minimal-custom_props.ply", "platonic_shelf.ply"])
def test_real_round_trip_keeps_properties(tmp_path: Path, name: str) -> None:
    mesh = load(MESHES / "real" / name)
    path = tmp_path / name
    save(path, mesh)
    assert path.read_bytes().startswith(b"ply\nformat binary_little_endian 1.0\n")
    back = read_ply(path)
    assert np.array_equal(back.positions, mesh.positions.astype(np.float32))
    assert np.array_equal(back.face_indices, mesh.face_indices)
    assert np.array_equal(back.face_offsets, mesh.face_offsets)
    assert list(back.vertex_properties) == list(mesh.vertex_properties)
    for key, values in mesh.vertex_properties.items():
        assert back.vertex_properties[key].dtype == values.dtype, key
        assert np.array_equal(back.vertex_properties[key], values), key
    for key, values in mesh.face_properties.items():
        assert np.array_equal(back.face_properties[key], values), key
    assert (back.normals is None) == (mesh.normals is None)
    assert (back.uvs is None) == (mesh.uvs is None)
    if mesh.uvs is not None:
        assert np.array_equal(back.uvs[back.face_uv_indices], mesh.uvs[mesh.face_uv_indices].astype(np.float32))


@needs_meshes
def test_custom_props_normals_recomputed(tmp_path: Path) -> None:
    mesh = load(MESHES / "real" / "cube-minimal-custom_props.ply")
    path = tmp_path / "c.ply"
    PlyWriter(mesh).write(path, mesh.positions * 2.0)
    back = read_ply(path)
    # the cube's authored normals are arbitrary test values and its faces wind inwards: the new
    # normals follow the geometry (unit, along the corner's diagonal) on the authored side
    assert np.allclose(np.linalg.norm(back.normals, axis=1), 1.0, atol=1e-6)
    radial = back.positions / np.linalg.norm(back.positions, axis=1, keepdims=True)
    assert np.allclose(np.abs(np.einsum("ij,ij->i", back.normals, radial)), 1.0, atol=1e-6)
    authored_side = np.sign(np.einsum("ij,ij->i", back.normals, mesh.normals))
    assert np.all(authored_side >= 0)


@needs_meshes
def test_uv_seams_written_as_corner_texcoords(tmp_path: Path) -> None:
    mesh = load(MESHES / "real" / "spot_control_mesh.obj")
    path = tmp_path / "spot.ply"
    save(path, mesh)
    assert b"property list uchar float texcoord" in path.read_bytes()[:400]
    back = read_ply(path)
    assert back.vertex_count == 188 and back.face_count == 180
    assert np.allclose(back.uvs[back.face_uv_indices], mesh.uvs[mesh.face_uv_indices], atol=1e-7)


def test_trimesh_and_meshio_read_our_ply(tmp_path: Path) -> None:
    trimesh = pytest.importorskip("trimesh")
    meshio = pytest.importorskip("meshio")
    mesh = grid_sheet(6, 4)
    pos = mesh.positions + 0.125
    path = tmp_path / "g.ply"
    save(path, mesh, pos)
    t = trimesh.load(path, process=False)
    assert np.array_equal(t.vertices, pos.astype(np.float32))
    assert len(t.faces) == 2 * mesh.face_count
    m = meshio.read(path)
    assert np.array_equal(m.points, pos.astype(np.float32))
    assert [(c.type, len(c.data)) for c in m.cells] == [("quad", 15)]
    assert np.array_equal(m.cells[0].data, mesh.face_indices.reshape(-1, 4))
    assert np.allclose(m.point_data["s"], mesh.uvs[:, 0])


def test_writer_rejects_bad_input(tmp_path: Path) -> None:
    mesh = _mixed_mesh()
    with pytest.raises(ExportError, match="encoding"):
        PlyWriter(mesh, encoding="utf8")
    with pytest.raises(ExportError, match="shape"):
        PlyWriter(mesh).write(tmp_path / "x.ply", np.zeros((2, 3)))
    assert not list(tmp_path.iterdir())


def test_obj_colours_written_as_uchar(tmp_path: Path) -> None:
    mesh = _mixed_mesh()
    colors = np.tile([1.0, 0.5, 0.0], (5, 1))
    colored = Mesh(positions=mesh.positions, face_indices=mesh.face_indices, face_offsets=mesh.face_offsets,
                   vertex_properties={"color": colors})  # fmt: skip
    write_ply(tmp_path / "c.ply", colored)
    back = read_ply(tmp_path / "c.ply")
    assert back.vertex_properties["color"].tolist() == [[255, 128, 0]] * 5


def test_nan_colour_is_an_export_error_not_a_black_vertex(tmp_path: Path) -> None:
    mesh = _mixed_mesh()
    colors = np.tile([1.0, 0.5, 0.25], (5, 1))
    colors[3, 2] = np.nan
    colored = Mesh(positions=mesh.positions, face_indices=mesh.face_indices, face_offsets=mesh.face_offsets,
                   vertex_properties={"color": colors})  # fmt: skip
    with pytest.raises(ExportError, match=r"vertex colours, row 3: not finite"):
        write_ply(tmp_path / "c.ply", colored)
    assert not list(tmp_path.iterdir())


def test_clashing_property_names_written_once(tmp_path: Path) -> None:
    mesh = grid_sheet(3)  # per-vertex UVs: written as s, t
    clash = Mesh(positions=mesh.positions, face_indices=mesh.face_indices, face_offsets=mesh.face_offsets,
                 uvs=mesh.uvs, face_uv_indices=mesh.face_uv_indices,
                 vertex_properties={"x": np.arange(9.0), "s": np.zeros(9), "weight": np.arange(9, dtype=np.int16)},
                 face_properties={"vertex_indices": np.zeros(4), "area": np.ones(4, dtype=np.float32)})  # fmt: skip
    write_ply(tmp_path / "c.ply", clash)
    back = read_ply(tmp_path / "c.ply")
    assert np.array_equal(back.positions, mesh.positions)
    assert list(back.vertex_properties) == ["weight"] and back.vertex_properties["weight"].dtype == np.int16
    assert list(back.face_properties) == ["area"]
    assert np.allclose(back.uvs, mesh.uvs)


def test_save_unknown_suffix(tmp_path: Path) -> None:
    with pytest.raises(ExportError, match="unknown mesh file extension"):
        save(tmp_path / "m.stl", grid_sheet(2))
    save(tmp_path / "M.PLY", grid_sheet(2))
    assert load(tmp_path / "M.PLY").face_count == 1
