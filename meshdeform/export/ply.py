"""PLY sequence export: `frames/frame_0001.ply`, ... written by `meshdeform.io.PlyWriter`.

Vertex order, polygons (quads stay quads) and the input's vertex/face properties are kept,
as the PLY writer does for a single file.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from meshdeform.export.base import uvs_have_seams
from meshdeform.export.results import ResultReading
from meshdeform.export.sequence import FrameSequenceExporter, frame_files_reading
from meshdeform.mesh import Mesh


def _vertex_channels(mesh: Mesh) -> int:
    """Extra per-vertex columns a PLY frame carries (properties, normals, per-vertex UVs)."""
    n = 0
    for values in mesh.vertex_properties.values():
        shape = np.shape(values)
        n += int(np.prod(shape[1:])) if len(shape) > 1 else 1
    if mesh.normals is not None:
        n += 3
    if mesh.uvs is not None and not uvs_have_seams(mesh):
        n += 2
    return n


class PlyExporter(FrameSequenceExporter):
    """Per-frame PLY files."""

    name: ClassVar[str] = "ply"
    summary: ClassVar[str] = "a PLY file per frame"
    suffix: ClassVar[str] = ".ply"

    @classmethod
    def estimated_bytes(cls, mesh: Mesh, frames: int) -> int | None:
        """Binary frames: float32 x y z, 4 bytes per extra column, uchar count + int32 indices per face."""
        corners = int(mesh.face_indices.shape[0])
        per_frame = 512 + mesh.vertex_count * 4 * (3 + _vertex_channels(mesh)) + mesh.face_count + 4 * corners
        if uvs_have_seams(mesh):
            per_frame += mesh.face_count + 8 * corners  # per-corner texcoord lists
        return int(per_frame * frames)

    @classmethod
    def reading(cls, **options: Any) -> ResultReading | None:
        """`frames/`, searched once with obj's; previews of a run read .ply frames when it writes no .obj."""
        return frame_files_reading(20, cls.suffix)

    def _make_writer(self, mesh: Mesh) -> Any:
        from meshdeform.io import PlyWriter

        return PlyWriter(mesh)
