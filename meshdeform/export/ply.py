"""PLY sequence export: `frames/frame_0001.ply`, ... written by `meshdeform.io.PlyWriter`.

Vertex order, polygons (quads stay quads) and the input's vertex/face properties are kept,
as the PLY writer does for a single file.
"""

from __future__ import annotations

from typing import Any, ClassVar

from meshdeform.export.sequence import FrameSequenceExporter
from meshdeform.mesh import Mesh


class PlyExporter(FrameSequenceExporter):
    """Per-frame PLY files."""

    name: ClassVar[str] = "ply"
    summary: ClassVar[str] = "a PLY file per frame"
    suffix: ClassVar[str] = ".ply"

    def _make_writer(self, mesh: Mesh) -> Any:
        from meshdeform.io import PlyWriter

        return PlyWriter(mesh)
