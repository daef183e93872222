"""OBJ sequence export: `frames/frame_0001.obj`, ... written by `meshdeform.io.ObjWriter`.

Vertex order, polygons (quads stay quads), UVs, groups, materials statements and polylines
are the input's; normals are recomputed per frame when the input had normals. The `.mtl`
files the input names are copied beside the frames so the materials still resolve.
"""

from __future__ import annotations

from typing import Any, ClassVar

from meshdeform.export.base import ExportContext
from meshdeform.export.sequence import FrameSequenceExporter, copy_material_libraries
from meshdeform.mesh import Mesh


class ObjExporter(FrameSequenceExporter):
    """Per-frame OBJ files."""

    name: ClassVar[str] = "obj"
    summary: ClassVar[str] = "an OBJ file per frame"
    suffix: ClassVar[str] = ".obj"

    def _make_writer(self, mesh: Mesh) -> Any:
        from meshdeform.io import ObjWriter

        return ObjWriter(mesh)

    def _open(self, ctx: ExportContext) -> None:
        super()._open(ctx)
        self._written.extend(copy_material_libraries(ctx.mesh, self._folder))
