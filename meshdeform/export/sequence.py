"""Shared part of the per-frame mesh exporters (OBJ, PLY): `frames/frame_0001.<suffix>`, ...

Each frame is written by the mesh writers of `meshdeform.io` (input vertex order, polygons, UVs,
groups and properties kept; normals recomputed per frame when the input had them), atomically.
The file number is the frame number (from 1), zero padded to 4 digits, or more when the run has
more than 9999 frames and `frame_count` says so. A changed topology (tearing) simply switches
the writer to the new mesh from that frame on.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from meshdeform.atomic import atomic_path
from meshdeform.export.base import BaseExporter, ExportContext, FrameData, frame_file_name
from meshdeform.io.obj import material_libraries
from meshdeform.mesh import Mesh

FOLDER = "frames"


class FrameSequenceExporter(BaseExporter):
    """One mesh file per frame in `frames/`, written by the `meshdeform.io` writer for `suffix`."""

    suffix: ClassVar[str] = ""
    supports_topology_change: ClassVar[bool] = True

    def _make_writer(self, mesh: Mesh) -> Any:
        raise NotImplementedError

    def _open(self, ctx: ExportContext) -> None:
        self._folder = self._make_dir(ctx.out_dir / FOLDER)
        self._writer_mesh: Mesh | None = None
        self._writer: Any = None
        self._extras: list[Path] = []

    def _write(self, ctx: ExportContext, frame: FrameData, mesh: Mesh, positions: np.ndarray) -> None:
        if self._writer_mesh is not mesh:
            self._writer = self._make_writer(mesh)
            self._writer_mesh = mesh
        target = self._folder / frame_file_name(frame.index, ctx.frame_count, self.suffix)
        self._writer.write(target, positions)
        self._written.append(target)

    def _close(self, ctx: ExportContext) -> list[Path]:
        return list(self._written)


def copy_material_libraries(mesh: Mesh, folder: Path) -> list[Path]:
    """Copy the OBJ's material libraries beside the frames so `mtllib` still resolves.

    Only libraries inside the mesh's folder are copied (`meshdeform.io.obj.material_libraries`:
    absolute names, `..` and links out of the folder are refused; the reader has already put
    them in `Mesh.warnings`, so they appear in the report). The copy reads the resolved file,
    never a link, and texture paths inside the .mtl are left as they are and not followed.
    """
    libraries, _ = material_libraries(mesh.source, mesh.statements)
    copied = []
    for library in libraries:
        target = folder / library.name
        with atomic_path(target) as tmp:
            shutil.copyfile(library.path, tmp, follow_symlinks=False)
        copied.append(target)
    return copied
