"""OBJ sequence export: `frames/frame_0001.obj`, ... written by `meshdeform.io.ObjWriter`.

Vertex order, polygons (quads stay quads), UVs, groups, materials statements and polylines
are the input's; normals are recomputed per frame when the input had normals, per vertex and split
where the input has hard edges (`meshdeform.geometry.normal_layout`). The `.mtl`
files the input names are copied beside the frames so the materials still resolve.

The size estimate (`ObjExporter.estimated_bytes`) counts the text of each line; a coordinate is
written as the shortest round trip of a float64 (`%r`), up to 17 digits plus sign, point and
exponent, taken as 20 characters.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from meshdeform.export.base import ExportContext
from meshdeform.export.results import ResultReading
from meshdeform.export.sequence import FrameSequenceExporter, copy_material_libraries, frame_files_reading
from meshdeform.geometry import normal_layout
from meshdeform.mesh import Mesh

#: characters of one OBJ coordinate as `%r` writes a simulated float64 (sign, 17 digits, point: 19-20)
OBJ_COORDINATE_CHARS = 20
#: characters of one OBJ normal component (`%.7g`: sign, 7 digits, point, maybe an exponent)
OBJ_NORMAL_CHARS = 12


def _digits(values: np.ndarray) -> int:
    """Total decimal digits of non-negative integers (vectorised)."""
    v = np.asarray(values, dtype=np.int64)
    if v.size == 0:
        return 0
    return int(np.sum(np.floor(np.log10(np.maximum(v, 1))).astype(np.int64) + 1))


def obj_frame_bytes(mesh: Mesh) -> int:
    """Bytes of one OBJ frame: `v` lines (x y z [r g b]), `vt`, `vn`, faces with their index pattern, lines."""
    has_uvs = mesh.uvs is not None and mesh.face_uv_indices is not None
    has_normals = mesh.normals is not None and mesh.face_normal_indices is not None
    channels = 6 if "color" in mesh.vertex_properties else 3
    size = 128 + sum(len(text) + 1 for _, text in mesh.statements)
    size += mesh.vertex_count * (2 + channels * (1 + OBJ_COORDINATE_CHARS))
    corners = int(mesh.face_indices.shape[0])
    size += 2 * mesh.face_count + corners + _digits(mesh.face_indices + 1)  # "f" + "\n", a space per corner
    if has_uvs:
        size += int(mesh.uvs.shape[0]) * (3 + 2 * (1 + OBJ_COORDINATE_CHARS))
        size += corners + _digits(mesh.face_uv_indices + 1)  # "/" + index
    if has_normals:  # in the layout the writer uses: a normal per (welded vertex, input normal)
        layout = normal_layout(mesh)
        size += int(layout.input_normal.shape[0]) * (3 + 3 * (1 + OBJ_NORMAL_CHARS))
        size += corners * (1 if has_uvs else 2) + _digits(layout.corner_normal + 1)
    if mesh.line_count:
        size += 2 * mesh.line_count + int(mesh.line_indices.shape[0]) + _digits(mesh.line_indices + 1)
    return size


class ObjExporter(FrameSequenceExporter):
    """Per-frame OBJ files."""

    name: ClassVar[str] = "obj"
    summary: ClassVar[str] = "an OBJ file per frame"
    suffix: ClassVar[str] = ".obj"

    @classmethod
    def estimated_bytes(cls, mesh: Mesh, frames: int) -> int | None:
        """`obj_frame_bytes` per frame."""
        return int(obj_frame_bytes(mesh) * frames)

    @classmethod
    def reading(cls, **options: Any) -> ResultReading | None:
        """`frames/` first of all (a run writing obj and ply previews its .obj files)."""
        return frame_files_reading(10, cls.suffix)

    def _make_writer(self, mesh: Mesh) -> Any:
        from meshdeform.io import ObjWriter

        return ObjWriter(mesh)

    def _open(self, ctx: ExportContext) -> None:
        super()._open(ctx)
        self._written.extend(copy_material_libraries(ctx.mesh, self._folder))
