"""Shared part of the per-frame mesh exporters (OBJ, PLY): `frames/frame_0001.<suffix>`, ...

Each frame is written by the mesh writers of `meshdeform.io` (input vertex order, polygons, UVs,
groups and properties kept; normals recomputed per frame when the input had them), atomically.
The file number is the scene frame (`ExportContext.scene_frame`: the rest pose at `start_frame`,
then one a frame), zero padded to 4 digits, or more when the last one has more digits. A changed
topology (tearing) simply switches the writer to the new mesh from that frame on.
`read_frame_files` reads the frames back (`meshdeform.export.results`); `frame_files_reading` is
the reading both formats declare.
"""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from meshdeform.atomic import atomic_path
from meshdeform.export.base import BaseExporter, ExportContext, FrameData, frame_file_name
from meshdeform.export.results import (
    FrameItem,
    LazyFrames,
    ReadBack,
    ResultFrames,
    ResultReading,
    numbered_files,
    prefer_input,
)
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
        target = self._folder / frame_file_name(ctx.scene_frame(frame.index), ctx.last_scene_frame, self.suffix)
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


def _same_polygons(frame: Mesh, base: Mesh) -> bool:
    """Whether a loaded OBJ/PLY frame has the base's vertex count and polygons."""
    return (
        frame.vertex_count == base.vertex_count
        and np.array_equal(frame.face_offsets, base.face_offsets)
        and np.array_equal(frame.face_indices, base.face_indices)
    )


def read_frame_files(root: Path, input_mesh: Mesh | None) -> ResultFrames | None:
    """The `frames/*.obj` or `frames/*.ply` files of a result folder (the suffix of the lowest-numbered
    file; the input mesh is the base when the first frame has its vertex count), or None."""
    from meshdeform.io import load

    files = numbered_files(root / FOLDER, (".obj", ".ply"))
    if not files:
        return None
    suffix = files[0][1].suffix.lower()
    files = [(n, p) for n, p in files if p.suffix.lower() == suffix]
    base = prefer_input(load(files[0][1]), input_mesh)
    return ResultFrames(
        base,
        LazyFrames([p for _, p in files], base, load, _same_polygons),
        [n for n, _ in files],
        f"{FOLDER}/*{suffix}",
    )


class FrameFilesReadBack(ReadBack):
    """`read_frame_files` for a run's frames in memory: OBJ positions exact (shortest round-trip text),
    PLY float32 and without polylines (PLY has none); a frame whose topology is not the base's is a Mesh
    as the file holds it, new on every access as a loaded file is."""

    def __init__(self, ctx: ExportContext, suffix: str) -> None:
        super().__init__(ctx)
        self.source = f"{FOLDER}/*{suffix}"
        self._obj = suffix == ".obj"
        self._same: tuple[Mesh | None, bool] = (None, False)

    def keep(self, positions: np.ndarray) -> np.ndarray:
        return np.array(positions, dtype=np.float64 if self._obj else np.float32)

    def _as_read(self, mesh: Mesh, kept: np.ndarray) -> Mesh:
        """The frame's file loaded: its positions, polygons and (OBJ) polylines."""
        read = Mesh(positions=kept.astype(np.float64), face_indices=mesh.face_indices, face_offsets=mesh.face_offsets)
        return replace(read, line_indices=mesh.line_indices, line_offsets=mesh.line_offsets) if self._obj else read

    def start(self, frame: FrameData, mesh: Mesh, kept: np.ndarray) -> Mesh:
        same_count = mesh.vertex_count == self.ctx.mesh.vertex_count
        self.base = self.ctx.mesh if same_count else self._as_read(mesh, kept)
        return self.base

    def item(self, mesh: Mesh, kept: np.ndarray) -> FrameItem:
        base = self.base
        assert base is not None
        if self._same[0] is not mesh:  # as read_frame_files compares a loaded frame with the base
            same = (
                mesh.vertex_count == base.vertex_count
                and np.array_equal(mesh.face_offsets, base.face_offsets)
                and np.array_equal(mesh.face_indices, base.face_indices)
            )
            self._same = (mesh, same)
        return kept.astype(np.float64) if self._same[1] else self._as_read(mesh, kept)


def _read_any_frame_files(root: Path, input_mesh: Mesh | None, turns: int | None) -> ResultFrames | None:
    return read_frame_files(root, input_mesh)


def frame_files_reading(priority: int, suffix: str) -> ResultReading:
    """The `ResultReading` of the per-frame files of `suffix`: one reader of `frames/` for every suffix
    (a folder is read as the suffix of its lowest-numbered file), and the `FrameFilesReadBack` of `suffix`."""
    return ResultReading(
        priority=priority,
        looks_for=f"{FOLDER}/*.obj|ply",
        read=_read_any_frame_files,
        read_back=lambda ctx: FrameFilesReadBack(ctx, suffix),
    )
