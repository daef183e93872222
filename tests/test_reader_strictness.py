"""Reads are exact or refused, non-meshes are named without quoting them, materials stay in their folder,
big polygons cost linear work and nothing non-finite is written (issue #13, "Safe on anyone's files")."""

from __future__ import annotations

import json
import re
import struct
import time
from pathlib import Path

import numpy as np
import pytest
from checks import refused
from factories import grid_sheet
from typer.testing import CliRunner

from meshdeform.errors import ExportError
from meshdeform.export.sequence import copy_material_libraries
from meshdeform.io import load, read_obj, read_ply, save
from meshdeform.io.obj_writer import ObjWriter
from meshdeform.mesh import Mesh
from meshdeform.topology import build_springs
from pipeline.cli import app

runner = CliRunner()
TRIANGLE = "v 0 0 0\nv 1 0 0\nv 0 1 0\n"
PLY_HEAD = (
    b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
    b"element face 1\nproperty list uchar int vertex_indices\nend_header\n"
)
PLY_BODY = b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"


def _file(tmp_path: Path, data: str | bytes, name: str) -> Path:
    path = tmp_path / name
    path.write_bytes(data.encode() if isinstance(data, str) else data)
    return path


def _cli_refuses(path: Path) -> str:
    """`meshdeform inspect path` exits 2 with exactly one stderr line naming the file (no traceback)."""
    result = runner.invoke(app, ["inspect", str(path)])
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {path}: "), result.stderr
    assert "Traceback" not in result.output
    return lines[0]


# --------------------------------------------------------------------------- OBJ numbers and faces


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("v 1_000 2 3\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", r"line 1: cannot parse '1_000' as a number"),
        ("v 1 2 3abc\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", r"line 1: cannot parse '3abc' as a number"),
        ("v 1 2 \u0663\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", r"line 1: cannot parse '\u0663' as a number"),  # Arabic 3
        ("v 0x10 2 3\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", r"line 1: cannot parse '0x10' as a number"),
        # a comment sends the file down the line-by-line path, which must be as strict as the bulk parse
        ("v 1_0 2 3 # c\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", r"line 1: cannot parse '1_0' as a number"),
        (TRIANGLE + "f 1 2 3_0 # c\n", r"line 4: cannot parse face corner '3_0'"),
        (TRIANGLE + "l 1 2_0\n", r"line 4: cannot parse line element"),
        ("v 1 infinity 3\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", r"line 1: non-finite vertex position"),
        ("v 1 2 3 0.5 nan 1\nv 1 0 0 1 1 1\nv 0 1 0 1 1 1\nf 1 2 3\n", r"line 1: non-finite vertex colour"),
        ("v 0 0 0 1 1 1\nv 1 0 0 1 1 1\nv 0 1 0 1 -inf 1\nf 1 2 3\n", r"line 3: non-finite vertex colour"),
        (TRIANGLE + "vt 0 inf\nf 1/1 2/1 3/1\n", r"line 4: non-finite texture coordinate"),
        (TRIANGLE.replace("v 0 1 0", "v 0 1 0 0.5 0.5") + "f 1 2 3\n",
         r"line 3: a vertex line holds 3, 4 \(x y z w\), 6 or 7 \(x y z r g b \[a\]\) numbers, this one has 5"),
        (TRIANGLE + "f 1\nf 2 3\nf 1 1 1\n", r"line 4: no usable face: all 3 faces have fewer than 3 distinct"),
    ],
)  # fmt: skip
def test_obj_values_are_exact_or_refused(tmp_path: Path, text: str, message: str) -> None:
    refused(_file(tmp_path, text, "m.obj"), message)


def test_obj_colours_on_some_lines_give_no_nan_colour(tmp_path: Path) -> None:
    """A colour on one vertex line does not make every other vertex's colour NaN: colours are dropped."""
    mesh = read_obj(_file(tmp_path, "v 0 0 0\nv 1 0 0 0.2 0.4 0.6\nv 0 1 0\nf 1 2 3\n", "m.obj"))
    assert "color" not in mesh.vertex_properties
    assert mesh.warnings == ("dropped all vertex colours: 2 of 3 vertex lines have no colour (first at line 1)",)
    full = read_obj(_file(tmp_path, "v 0 0 0 1 0 0\nv 1 0 0 0.2 0.4 0.6\nv 0 1 0 0 0 1 0.5\nf 1 2 3\n", "c.obj"))
    assert full.vertex_properties["color"].tolist() == [[1, 0, 0], [0.2, 0.4, 0.6], [0, 0, 1]]


def test_obj_c_numbers_still_parse(tmp_path: Path) -> None:
    """Every C decimal form stays readable, on the bulk path and on the line-by-line one (comments)."""
    body = "v +1 -.5e-3 1E+2\nv 5. .25 -0\nv 1e0 2 3\nf 1 2 3\n"
    for text in (body, body.replace("\nf", " # comment\nf")):
        mesh = read_obj(_file(tmp_path, text, "m.obj"))
        assert mesh.positions.tolist() == [[1, -0.0005, 100], [5, 0.25, 0], [1, 2, 3]]


def test_obj_nonfinite_normals_dropped_and_recomputed(tmp_path: Path) -> None:
    mesh = read_obj(_file(tmp_path, TRIANGLE + "vn 0 nan 1\nf 1//1 2//1 3//1\n", "m.obj"))
    assert mesh.normals is None and mesh.face_normal_indices is None
    assert mesh.warnings == ("dropped all normals: 1 of 1 are not finite (first at line 4)",)


# --------------------------------------------------------------------------- PLY rows and bodies


@pytest.mark.parametrize(
    ("body", "message"),
    [
        (b"0 0 0 7\n1 0 0\n0 1 0\n3 0 1 2\n",
         r"element 'vertex' row 0: line 10 holds 1 values more than its properties \(x y z\) take$"),
        (b"0 0 0\n1 0\n0 1 0\n3 0 1 2\n", r"element 'vertex' row 1: line 11 holds 2 values, too few"),
        (b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2 0\n", r"element 'face' row 0: line 13 holds 1 values more"),
        (b"0 0 0\n1 0 0\n0 1 0\n3 0 1\n", r"element 'face' row 0: the list 'vertex_indices' declares 3 values"),
        (b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n3 0 1 2\n",
         r"line 14: more rows than the header declares \(the last element 'face' has 1 rows; 1 rows follow\)$"),
        (b"0 0 0\n1 0 0\n0 1 0\n", r"element 'face' row 0: the file ends early"),
        (b"0 0 0\n1_0 0 0\n0 1 0\n3 0 1 2\n", r"element 'vertex' row 1: cannot parse '1_0' as a number \(line 11\)"),
        (b"0 0 0\n1 0 0\n0 1 0\n1_3 0 1 2\n", r"element 'face' row 0: cannot parse '1_3'"),
        (b"0 0 0\n1 0 0\n0 1 0\n2.5 0 1 2\n", r"element 'face' row 0: list length 2.5 of 'vertex_indices'"),
        (b"0 0 0\n1 0 0\x00\x01\n0 1 0\n3 0 1 2\n", r"byte \d+: binary data in an ascii PLY body"),
    ],
)  # fmt: skip
def test_ply_ascii_rows_are_exact_or_refused(tmp_path: Path, body: bytes, message: str) -> None:
    refused(_file(tmp_path, PLY_HEAD + body, "m.ply"), message)


def test_ply_ascii_blank_lines_crlf_and_the_exact_file_still_load(tmp_path: Path) -> None:
    for body in (PLY_BODY, PLY_BODY.replace(b"\n", b"\r\n"), b"\n" + PLY_BODY.replace(b"\n", b"\n\n") + b"  \n"):
        mesh = read_ply(_file(tmp_path, PLY_HEAD + body, "m.ply"))
        assert mesh.positions.tolist() == [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
        assert mesh.face_indices.tolist() == [0, 1, 2] and mesh.warnings == ()


BINARY_HEAD = PLY_HEAD.replace(b"format ascii", b"format binary_little_endian")
END = len(BINARY_HEAD) + 36 + 13  # 3 vertices of 3 floats, one face of a uchar count and 3 ints


def _binary_ply(extra: bytes = b"", cut: int = 0) -> bytes:
    head = BINARY_HEAD
    body = struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0) + struct.pack("<B3i", 3, 0, 1, 2)
    return head + (body[: len(body) - cut] if cut else body) + extra


@pytest.mark.parametrize(
    ("data", "message"),
    [
        (_binary_ply(b"\x00\x00\x00\x00"),
         rf"byte {END}: 4 bytes after the last element \('face', 1 rows\): the header's counts or types do not match"),
        (_binary_ply(b"\n\n"), rf"byte {END}: 2 bytes after the last element"),
        (_binary_ply(cut=3), r"element 'face' row 0: the file ends early"),
        (_binary_ply(cut=14), r"element 'vertex' row 2: the file ends early: 3 rows of 12 bytes need 36 bytes"),
    ],
)  # fmt: skip
def test_ply_binary_length_must_match_the_header(tmp_path: Path, data: bytes, message: str) -> None:
    refused(_file(tmp_path, data, "m.ply"), message)


@pytest.mark.parametrize("ending", [b"", b"\n", b"\r\n"])
def test_ply_binary_with_one_trailing_line_end_loads(tmp_path: Path, ending: bytes) -> None:
    mesh = read_ply(_file(tmp_path, _binary_ply(ending), "m.ply"))
    assert mesh.face_indices.tolist() == [0, 1, 2] and mesh.warnings == ()


def test_ply_nonfinite_properties_are_refused(tmp_path: Path) -> None:
    head = PLY_HEAD.replace(b"property float z\n", b"property float z\nproperty float quality\n")
    refused(_file(tmp_path, head + b"0 0 0 1\n1 0 0 nan\n0 1 0 1\n3 0 1 2\n", "q.ply"),
             r"element 'vertex' row 1: non-finite quality value")  # fmt: skip
    head = PLY_HEAD.replace(b"property float z\n", b"property float z\nproperty float s\nproperty float t\n")
    refused(_file(tmp_path, head + b"0 0 0 0 0\n1 0 0 1 0\n0 1 0 inf 1\n3 0 1 2\n", "uv.ply"),
             r"element 'vertex' row 2: non-finite texture coordinate value")  # fmt: skip


def test_ply_every_face_malformed_is_refused(tmp_path: Path) -> None:
    head = PLY_HEAD.replace(b"element face 1", b"element face 2")
    refused(_file(tmp_path, head + b"0 0 0\n1 0 0\n0 1 0\n2 0 1\n3 1 1 1\n", "m.ply"),
             r"element 'face': no usable face: all 2 faces have fewer than 3 distinct vertices")  # fmt: skip


def test_ply_element_count_in_c_syntax_only(tmp_path: Path) -> None:
    refused(_file(tmp_path, PLY_HEAD.replace(b"vertex 3", b"vertex 0_3") + PLY_BODY, "m.ply"),
             r"line 3: element count '0_3' is not a whole number")  # fmt: skip


# --------------------------------------------------------------------------- files that are no mesh at all

SECRET = b"SECRET-CONTENT"
NOT_MESHES = {
    "png": b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR" + SECRET,
    "zip": b"PK\x03\x04\x14\x00\x00\x00" + SECRET,
    "random": bytes(np.random.default_rng(7).integers(0, 256, 4096, dtype=np.uint8)) + SECRET,
    "nul": b"v 0 0 0\x00" + SECRET + b"\n",
    "utf16": (SECRET.decode() + " is not a mesh\n").encode("utf-16"),
    "html": b"<html>" + SECRET + b"</html>\n",
}


@pytest.mark.parametrize("kind", sorted(NOT_MESHES))
@pytest.mark.parametrize("suffix", [".obj", ".ply"])
def test_not_a_mesh_is_named_and_never_quoted(tmp_path: Path, kind: str, suffix: str) -> None:
    path = _file(tmp_path, NOT_MESHES[kind], f"{kind}{suffix}")
    message = refused(path)
    said = message.removeprefix(f"{path}: ")
    assert "SECRET" not in said and "IHDR" not in said and "html" not in said and "\\x" not in said
    assert re.search(rf"not an? (text )?{suffix[1:].upper()} file", said)
    assert "SECRET" not in _cli_refuses(path).removeprefix(f"error: {path}: ")


def test_binary_obj_names_the_byte(tmp_path: Path) -> None:
    line = _cli_refuses(_file(tmp_path, NOT_MESHES["zip"], "z.obj"))
    assert line == f"error: {tmp_path / 'z.obj'}: byte 2: not a text OBJ file (binary data)"


# --------------------------------------------------------------------------- through the CLI


@pytest.mark.parametrize(
    ("name", "data", "expected"),
    [
        ("u.obj", "v 1_000 2 3\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "line 1: cannot parse '1_000' as a number"),
        ("f.obj", TRIANGLE + "f 1\nf 2 3\n", "line 4: no usable face: all 2 faces have fewer than 3"),
        ("c.obj", "v 0 0 0 1 1 nan\nv 1 0 0 1 1 1\nv 0 1 0 1 1 1\nf 1 2 3\n", "line 1: non-finite vertex colour"),
        ("r.ply", PLY_HEAD + b"0 0 0 7\n1 0 0\n0 1 0\n3 0 1 2\n", "element 'vertex' row 0: line 10 holds 1 values"),
        ("t.ply", PLY_HEAD + PLY_BODY + b"3 0 1 2\n", "line 14: more rows than the header declares"),
        ("b.ply", _binary_ply(b"\x00" * 8), f"byte {END}: 8 bytes after the last element ('face', 1 rows)"),
    ],
)  # fmt: skip
def test_cli_inspect_refuses_with_one_line(tmp_path: Path, name: str, data: str | bytes, expected: str) -> None:
    path = _file(tmp_path, data, name)
    assert _cli_refuses(path).startswith(f"error: {path}: {expected}")


# --------------------------------------------------------------------------- material libraries


def _cloth_with_libraries(tmp_path: Path, names: str) -> Path:
    folder = tmp_path / "in"
    folder.mkdir(exist_ok=True)
    (folder / "ok.mtl").write_text("newmtl red\nKd 1 0 0\nmap_Kd /etc/hostname\n")
    return _file(folder, f"mtllib {names}\n{TRIANGLE}v 1 1 0\nusemtl red\nf 1 2 4 3\n", "cloth.obj")


def test_mtllib_outside_the_folder_is_warned_about_and_not_copied(tmp_path: Path) -> None:
    outside = tmp_path / "outside.mtl"
    outside.write_text("newmtl secret\n")
    mesh_path = _cloth_with_libraries(tmp_path, f"ok.mtl {outside} ../outside.mtl link.mtl inner.mtl")
    (mesh_path.parent / "link.mtl").symlink_to(outside)  # a link out of the folder
    (mesh_path.parent / "inner.mtl").symlink_to(mesh_path.parent / "ok.mtl")  # a link inside it
    mesh = load(mesh_path)
    assert mesh.warnings == (
        "material libraries outside the mesh's folder are not copied with the frames: "
        f"'{outside}' (an absolute path), '../outside.mtl' (it climbs out of the mesh's folder), "
        "'link.mtl' (a link to outside the mesh's folder)",
    )
    frames = tmp_path / "frames"
    frames.mkdir()
    copied = copy_material_libraries(mesh, frames)
    assert copied == [frames / "ok.mtl", frames / "inner.mtl"]
    assert sorted(p.name for p in frames.iterdir()) == ["inner.mtl", "ok.mtl"]
    assert not (frames / "inner.mtl").is_symlink()  # the file's bytes, not a link
    # texture paths inside the .mtl are kept as written and never followed
    assert (frames / "ok.mtl").read_text() == "newmtl red\nKd 1 0 0\nmap_Kd /etc/hostname\n"


def test_mtllib_warning_reaches_the_report(tmp_path: Path) -> None:
    mesh_path = _cloth_with_libraries(tmp_path, "ok.mtl ../../up.mtl")
    out = tmp_path / "out"
    result = runner.invoke(app, ["simulate", str(mesh_path), "--out", str(out), "--frames", "2", "--quiet"])
    assert result.exit_code == 0, result.output
    report = json.loads((out / "report.json").read_text())
    assert report["warnings"] == [
        "material libraries outside the mesh's folder are not copied with the frames: "
        "'../../up.mtl' (it climbs out of the mesh's folder)"
    ]
    assert sorted(p.name for p in (out / "frames").glob("*.mtl")) == ["ok.mtl"]


# --------------------------------------------------------------------------- big polygons


def _disc(corners: int) -> Mesh:
    angle = np.linspace(0.0, 2 * np.pi, corners, endpoint=False)
    positions = np.stack([np.cos(angle), np.sin(angle), np.zeros(corners)], axis=1)
    return Mesh(positions=positions, face_indices=np.arange(corners), face_offsets=np.array([0, corners]))


def test_polygons_up_to_8_corners_keep_every_diagonal_larger_ones_their_fan() -> None:
    assert build_springs(_disc(8))[1].counts()["shear"] == 8 * 5 // 2
    _, springs = build_springs(_disc(9))
    shear = springs.pairs[springs.kinds == 1]
    assert shear.tolist() == [[0, k] for k in range(2, 8)]  # corner 0 to corners 2 .. k - 2


def test_a_20000_corner_polygon_inspects_in_under_a_second(tmp_path: Path) -> None:
    path = tmp_path / "big.obj"
    save(path, _disc(20_000))
    runner.invoke(app, ["inspect", str(_file(tmp_path, TRIANGLE + "f 1 2 3\n", "warm.obj"))])  # compile kernels
    start = time.perf_counter()
    result = runner.invoke(app, ["inspect", "--json", str(path)])
    elapsed = time.perf_counter() - start
    assert result.exit_code == 0, result.output
    info = json.loads(result.stdout)
    assert info["springs"]["shear"] == 20_000 - 3 and info["polygon_sizes"] == {"20000": 1}
    assert elapsed < 1.0


# --------------------------------------------------------------------------- writers


def test_writers_refuse_nonfinite_values_and_write_nothing(tmp_path: Path) -> None:
    mesh = grid_sheet(3)
    bad = mesh.positions.copy()
    bad[4, 1] = np.nan
    for suffix in (".obj", ".ply"):
        with pytest.raises(ExportError, match=r"vertex positions, row 4: not finite"):
            save(tmp_path / f"f{suffix}", mesh, bad)
    huge = mesh.positions.copy()
    huge[2, 0] = 1e39  # finite as float64, infinite as the PLY's float32
    with pytest.raises(ExportError, match=r"row 2: not finite"):
        save(tmp_path / "h.ply", mesh, huge)
    colours = np.full((mesh.vertex_count, 3), 0.5)
    colours[7, 0] = np.inf
    coloured = Mesh(positions=mesh.positions, face_indices=mesh.face_indices, face_offsets=mesh.face_offsets,
                    vertex_properties={"color": colours})  # fmt: skip
    with pytest.raises(ExportError, match=r"vertex colours, row 7: not finite"):
        ObjWriter(coloured)
    assert not list(tmp_path.iterdir())


def test_a_named_pipe_is_refused_without_being_opened(tmp_path: Path) -> None:
    """Opening a FIFO would wait for a writer for ever: the readers refuse it from its file type."""
    import os

    pipe = tmp_path / "pipe.obj"
    os.mkfifo(pipe)
    refused(pipe, "is a named pipe, not a mesh file")
    assert "is a named pipe" in _cli_refuses(pipe)
    result = runner.invoke(app, ["check", str(pipe)])
    assert result.exit_code == 2 and result.stderr.strip() == f"error: {pipe}: is a named pipe, not a recipe file"


@pytest.mark.parametrize(
    ("text", "line"),
    [("v 0 0 0\nv 1e19 0 0\nv 0 1 0\nf 1 2 3\n", 2), ("# c\nv 0 0 0 # x\nv 0 -2e12 0\nv 0 1 0\nf 1 2 3\n", 3)],
)
def test_obj_coordinates_past_the_limit_are_refused_with_their_line(tmp_path: Path, text: str, line: int) -> None:
    from meshdeform.mesh import MAX_COORDINATE

    message = refused(_file(tmp_path, text, "huge.obj"), f"line {line}: vertex position .* is beyond the limit")
    assert f"{MAX_COORDINATE:g}" in message
    ok = load(_file(tmp_path, f"v 0 0 0\nv {MAX_COORDINATE!r} 0 0\nv 0 1 0\nf 1 2 3\n", "edge.obj"))
    assert ok.positions[1, 0] == MAX_COORDINATE  # the limit itself is a coordinate


def test_ply_coordinates_past_the_limit_are_refused_with_their_row(tmp_path: Path) -> None:
    header = (
        b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        b"property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
    )
    body = struct.pack("<9f", 0, 0, 0, 0, 1e30, 0, 0, 1, 0) + struct.pack("<B3i", 3, 0, 1, 2)
    refused(_file(tmp_path, header + body, "huge.ply"), r"element 'vertex' row 1: position .* beyond the limit")


def test_mtllib_copies_only_material_libraries(tmp_path: Path) -> None:
    """An OBJ inside a home folder naming `.ssh/id_rsa` or `notes.txt` as its material library: not copied."""
    mesh_path = _cloth_with_libraries(tmp_path, "ok.mtl .ssh/id_rsa notes.txt .hidden/lib.mtl")
    for name in (".ssh/id_rsa", "notes.txt", ".hidden/lib.mtl"):
        (mesh_path.parent / name).parent.mkdir(parents=True, exist_ok=True)
        (mesh_path.parent / name).write_text("private\n")
    mesh = load(mesh_path)
    assert len(mesh.warnings) == 1
    for name in (".ssh/id_rsa", "notes.txt", ".hidden/lib.mtl"):
        assert f"'{name}' (not a .mtl file, or in a hidden folder)" in mesh.warnings[0]
    frames = tmp_path / "frames"
    frames.mkdir()
    assert copy_material_libraries(mesh, frames) == [frames / "ok.mtl"]


def test_mtllib_with_a_leading_dot_folder_is_copied(tmp_path: Path) -> None:
    """`mtllib ./name.mtl` (as some exporters write it) names the mesh's own folder: copied, no warning."""
    mesh_path = _cloth_with_libraries(tmp_path, "./ok.mtl")
    mesh = load(mesh_path)
    assert mesh.warnings == ()
    frames = tmp_path / "frames"
    frames.mkdir()
    assert copy_material_libraries(mesh, frames) == [frames / "ok.mtl"]
