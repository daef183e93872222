"""Every file in shared/meshes/broken has a decided outcome, and no input crashes the readers.

Decision table: what `meshdeform.load` does with each file, and why (checked by DECISIONS below).

file                                    outcome                                           why
invalid-relative-vertex-index.obj       MeshLoadError "line 1: face index -4 out of      no vertices at all: nothing
                                        range (relative index, 0 vertices ...)"          the face could refer to
issue-140-zero-face-idx.obj             MeshLoadError "line 16: face index 0 (OBJ        0 in the v slot is a broken
                                        indices start at 1)"                             exporter (0 only in vt / vn
                                                                                         slots would drop those)
invalid-face-definition.obj             MeshLoadError "line 15: no usable face: all 2    every face is malformed:
                                        faces have fewer than 3 distinct vertices"       loading the points alone
                                                                                         would hide the breakage
test-nan.obj                            MeshLoadError "line 12: non-finite vertex        positions must be finite:
                                        position"                                        nan, inf, 1.#IND alike
malformed.obj                           MeshLoadError "line 23: face index 12 out of     a missing vertex cannot be
                                        range (8 vertices)"                              guessed
empty.obj                               MeshLoadError "empty file"                       nothing to load
crash-30d6...ply                        MeshLoadError "no end_header: the header is      the header breaks off into
                                        truncated or corrupted (binary data on line 7)"  binary data
payload_JVN42386607.ply                 MeshLoadError "line 6: a second 'vertex'         ambiguous; refused before
                                        element"                                         any row is read
cube_binary_header_with_RN_newline.ply  loads: 8 V, 12 F, no warning                     CRLF after end_header is
                                                                                         consumed whole
negative_indices.obj                    loads: 8 V, 6 quads, UVs and normals             relative indices are valid
cube-minimal-degenerated.obj            loads: 12 triangles; warnings "dropped 2          `2 2 2`, `2 8 2` dropped;
                                        degenerate polygons ..." and "removed repeated   `2 6 8 8 2` -> `2 6 8`
                                        consecutive vertices from 1 polygon"
box-incomplete-normals.obj              loads: 6 quads with UVs, no normals; warning     20 of 24 normal references
                                        "dropped all normal references"                  dangle; normals are
                                                                                         recomputed anyway
box.nonmanifold.obj                     loads: 8 V, 13 F, no warning                     non-manifold edges are the
                                                                                         topology builder's business
box.duplicates-nonmanifold.obj          loads: 12 V, 7 F, no warning                     duplicates are welded by
                                                                                         the topology, layout kept
nancolor.obj                            MeshLoadError "line 7: non-finite vertex         nothing non-finite is
                                        colour"                                          read (or written)
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from checks import one_line_about, refused
from shared_meshes import MESHES

from meshdeform.errors import MeshLoadError
from meshdeform.io import load
from meshdeform.mesh import Mesh

pytestmark = pytest.mark.skipif(MESHES is None, reason="shared test meshes not found")

CRASH = "crash-30d6d0f7c529b3b66b4131700b7a4580cd7082df.ply"

# file -> ("error", message regex) | ("load", V, F, [warning substrings])
DECISIONS: dict[str, tuple] = {
    "invalid-relative-vertex-index.obj": ("error", r"line 1: face index -4 out of range"),
    "issue-140-zero-face-idx.obj": ("error", r"line 16: face index 0 \(OBJ indices start at 1\)"),
    "invalid-face-definition.obj": (
        "error", r"line 15: no usable face: all 2 faces have fewer than 3 distinct vertices"
    ),
    "test-nan.obj": ("error", r"line 12: non-finite vertex position"),
    "malformed.obj": ("error", r"line 23: face index 12 out of range \(8 vertices\)"),
    "empty.obj": ("error", r"empty file"),
    CRASH: ("error", r"no end_header: the header is truncated or corrupted \(binary data on line 7\)"),
    "payload_JVN42386607.ply": ("error", r"line 6: a second 'vertex' element"),
    "cube_binary_header_with_RN_newline.ply": ("load", 8, 12, []),
    "negative_indices.obj": ("load", 8, 6, []),
    "cube-minimal-degenerated.obj": (
        "load", 8, 12,
        ["dropped 2 degenerate polygons with fewer than 3 distinct vertices (first at line 28)",
         "removed repeated consecutive vertices from 1 polygon (first at line 26)"],
    ),
    "box-incomplete-normals.obj": ("load", 8, 6, ["dropped all normal references: 20 of 24 face corners"]),
    "box.nonmanifold.obj": ("load", 8, 13, []),
    "box.duplicates-nonmanifold.obj": ("load", 12, 7, []),
    "nancolor.obj": ("error", r"line 7: non-finite vertex colour"),
}  # fmt: skip


def test_every_broken_file_has_a_decision() -> None:
    assert sorted(p.name for p in (MESHES / "broken").iterdir()) == sorted(DECISIONS)


@pytest.mark.parametrize("name", sorted(DECISIONS))
def test_broken_file_outcome(name: str) -> None:
    path = MESHES / "broken" / name
    decision = DECISIONS[name]
    if decision[0] == "error":
        refused(path, decision[1])
        return
    _, n_v, n_f, expected_warnings = decision
    mesh = load(path)
    assert (mesh.vertex_count, mesh.face_count) == (n_v, n_f)
    assert len(mesh.warnings) == len(expected_warnings)
    for expected in expected_warnings:
        assert any(expected in w for w in mesh.warnings), (expected, mesh.warnings)
    assert np.isfinite(mesh.positions).all()
    assert mesh.face_indices.size == 0 or (mesh.face_indices.min() >= 0 and mesh.face_indices.max() < n_v)


def test_degenerated_cube_details() -> None:
    mesh = load(MESHES / "broken" / "cube-minimal-degenerated.obj")
    assert set(mesh.face_sizes.tolist()) == {3}
    assert [1, 5, 7] in [p.tolist() for p in mesh.polygons()]  # `2 6 8 8 2`, 0-based and repaired
    assert mesh.face_normal_indices.shape == mesh.face_indices.shape
    assert mesh.groups["cube"].tolist() == list(range(12))


def test_incomplete_normals_keep_uvs() -> None:
    mesh = load(MESHES / "broken" / "box-incomplete-normals.obj")
    assert mesh.normals is None and mesh.face_normal_indices is None
    assert len(mesh.uvs) == 20 and mesh.face_uv_indices.shape == (24,)


def test_negative_indices_resolved() -> None:
    mesh = load(MESHES / "broken" / "negative_indices.obj")
    # `f -8/-13/-6 -4/-12/-6 -2/-12/-6 -6/-11/-6` after 8 v, 14 vt, 6 vn
    assert mesh.polygons()[0].tolist() == [0, 4, 6, 2]
    assert mesh.face_uv_indices[:4].tolist() == [1, 2, 2, 3]
    assert mesh.face_normal_indices[:4].tolist() == [0, 0, 0, 0]


def _variants(data: bytes, seed: int) -> list[bytes]:
    """Truncations and byte corruptions of a file: the inputs a fuzzer would try first."""
    rng = np.random.default_rng(seed)
    if not data:
        return [b"", b" ", b"\x00"]
    out = [data[:n] for n in sorted({0, 1, 3, len(data) // 7, len(data) // 2, len(data) - 1, len(data) - 17})]
    for _ in range(6):
        corrupt = bytearray(data)
        for k in rng.integers(0, len(data), size=max(1, len(data) // 500)):
            corrupt[k] = int(rng.integers(0, 256))
        out.append(bytes(corrupt))
    out.append(data.replace(b" ", b"  \t"))
    out.append(data + b"\x00\xff" * 16)
    return out


@pytest.mark.parametrize("folder", ["real", "broken"])
def test_fuzzed_inputs_load_or_raise_mesh_load_error(tmp_path: Path, folder: str) -> None:
    """Never a traceback, never a hang: either a Mesh or a one-line MeshLoadError."""
    for k, source in enumerate(sorted((MESHES / folder).iterdir())):
        data = source.read_bytes()
        if len(data) > 250_000:
            data = data[:250_000]
        for j, variant in enumerate(_variants(data, k)):
            path = tmp_path / f"v{k}_{j}{source.suffix}"
            path.write_bytes(variant)
            start = time.perf_counter()
            try:
                mesh = load(path)
            except MeshLoadError as exc:
                one_line_about(path, exc)
            else:
                assert isinstance(mesh, Mesh)
                assert np.isfinite(mesh.positions).all()
                if mesh.face_indices.size:
                    assert mesh.face_indices.min() >= 0 and mesh.face_indices.max() < mesh.vertex_count
                assert np.all(np.diff(mesh.face_offsets) >= 3)
            assert time.perf_counter() - start < 10, f"{source.name} variant {j} took too long"


def test_every_real_file_loads_cleanly() -> None:
    names = sorted(p.name for p in (MESHES / "real").iterdir())
    assert len(names) == 13
    for name in names:
        mesh = load(MESHES / "real" / name)
        assert mesh.warnings == (), name
        assert mesh.vertex_count > 0 and mesh.face_count > 0, name
