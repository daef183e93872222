"""VTK export for ParaView: per-frame `vtk/frame_0001.vtp` files and a `scene.pvd` collection.

Each `.vtp` holds the frame's polygons (quads stay quads, polylines as lines), float32 points
and point data: every array the frame carried (`strain`, `velocity`, `pinned`, ...), the
`displacement` (V, 3) from the rest pose while the topology is the input's (it replaces a frame
array of that name), and `TCoords` when the UVs are per vertex (no seams). Open `scene.pvd` in
ParaView to get the time series. The topology may change between frames (tearing): every file
carries its own. `read_vtk_result` reads the frames back (`meshdeform.export.results`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar
from xml.sax.saxutils import quoteattr

import numpy as np

from meshdeform.atomic import atomic_path, write_text_atomic
from meshdeform.errors import MeshLoadError
from meshdeform.export.base import (
    POINT_DATA_BYTES,
    BaseExporter,
    ExportContext,
    FrameData,
    frame_file_name,
    uvs_have_seams,
)
from meshdeform.export.results import FrameItem, LazyFrames, ReadBack, ResultFrames, ResultReading, numbered_files
from meshdeform.mesh import Mesh

FOLDER = "vtk"
COLLECTION_NAME = "scene.pvd"


def _cell_array(indices: np.ndarray, offsets: np.ndarray) -> Any:
    from vtkmodules.util.numpy_support import numpy_to_vtk
    from vtkmodules.vtkCommonCore import VTK_ID_TYPE
    from vtkmodules.vtkCommonDataModel import vtkCellArray

    cells = vtkCellArray()
    cells.SetData(
        numpy_to_vtk(np.ascontiguousarray(offsets, dtype=np.int64), deep=True, array_type=VTK_ID_TYPE),
        numpy_to_vtk(np.ascontiguousarray(indices, dtype=np.int64), deep=True, array_type=VTK_ID_TYPE),
    )
    return cells


def vertex_uvs(mesh: Mesh) -> np.ndarray | None:
    """Per-vertex UVs (V, 2) when every corner of a vertex uses the same UV (no seams), else None."""
    if mesh.uvs is None or mesh.face_uv_indices is None or mesh.face_indices.size == 0:
        return None
    uv_index = np.asarray(mesh.face_uv_indices)
    if uv_index.shape != mesh.face_indices.shape or (uv_index < 0).any():
        return None
    corner_uv = np.asarray(mesh.uvs, dtype=np.float64)[uv_index, :2]
    per_vertex = np.zeros((mesh.vertex_count, 2))
    per_vertex[mesh.face_indices] = corner_uv
    if not np.allclose(per_vertex[mesh.face_indices], corner_uv):
        return None
    return per_vertex


def polydata_from_mesh(mesh: Mesh, positions: np.ndarray | None = None) -> Any:
    """A `vtkPolyData` of the mesh's polygons and polylines (no point data), float32 points."""
    from vtkmodules.util.numpy_support import numpy_to_vtk
    from vtkmodules.vtkCommonCore import vtkPoints
    from vtkmodules.vtkCommonDataModel import vtkPolyData

    pts = np.ascontiguousarray(mesh.positions if positions is None else positions, dtype=np.float32)
    points = vtkPoints()
    points.SetData(numpy_to_vtk(pts, deep=True))
    poly = vtkPolyData()
    poly.SetPoints(points)
    if mesh.face_count:
        poly.SetPolys(_cell_array(mesh.face_indices, mesh.face_offsets))
    if mesh.line_count:
        poly.SetLines(_cell_array(mesh.line_indices, mesh.line_offsets))
    return poly


def set_point_array(poly: Any, name: str, values: np.ndarray) -> None:
    """Attach (or replace) a named point-data array, floats as float32."""
    from vtkmodules.util.numpy_support import numpy_to_vtk

    values = np.asarray(values)
    if values.dtype.kind == "f":
        values = values.astype(np.float32, copy=False)
    elif values.dtype.kind == "b":
        values = values.astype(np.uint8)
    array = numpy_to_vtk(np.ascontiguousarray(values), deep=True)
    array.SetName(name)
    poly.GetPointData().AddArray(array)


def pvd_text(entries: list[tuple[float, str]]) -> str:
    """The ParaView collection file listing (time, relative file) pairs."""
    lines = [
        '<?xml version="1.0"?>',
        '<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">',
        "  <Collection>",
    ]
    lines += [f'    <DataSet timestep="{t!r}" group="" part="0" file={quoteattr(f)}/>' for t, f in entries]
    lines += ["  </Collection>", "</VTKFile>", ""]
    return "\n".join(lines)


class VtkExporter(BaseExporter):
    """Writes one `.vtp` per frame as it comes and the `.pvd` collection at close."""

    name: ClassVar[str] = "vtk"
    summary: ClassVar[str] = "a VTK file per frame and a ParaView collection"
    supports_topology_change: ClassVar[bool] = True

    @classmethod
    def estimated_bytes(cls, mesh: Mesh, frames: int) -> int | None:
        """Appended data per frame: float32 points, displacement (V, 3) and point data as written (zlib
        keeps about that of simulated floats), int64 cells at half (they compress well), XML, and a
        line of the collection per frame."""
        v, corners = mesh.vertex_count, int(mesh.face_indices.shape[0])
        per_frame = 2048 + v * (12 + 12 + POINT_DATA_BYTES) + 4 * (corners + mesh.face_count)
        if mesh.uvs is not None and not uvs_have_seams(mesh):
            per_frame += 8 * v  # TCoords
        return int(per_frame * frames + 256 * frames)

    @classmethod
    def reading(cls, **options: Any) -> ResultReading | None:
        """The `.vtp` frames; their first frame's `pinned` array also serves the frames other readers find."""
        return ResultReading(
            priority=50,
            looks_for=f"{FOLDER}/*.vtp",
            read=lambda root, input_mesh, turns: read_vtk_result(root, input_mesh),
            read_back=VtkReadBack,
            folder_pinned=vtp_pinned,
            frame_pinned=first_frame_pinned,
        )

    def __init__(self, *, compress: bool = True, **options: Any) -> None:
        super().__init__(**options)
        self.compress = compress

    def _open(self, ctx: ExportContext) -> None:
        from vtkmodules.vtkIOXML import vtkXMLPolyDataWriter

        self._make_dir(ctx.out_dir / FOLDER)
        self._entries: list[tuple[float, str]] = []
        self._poly_mesh: Mesh | None = None
        self._writer = vtkXMLPolyDataWriter()
        self._writer.SetDataModeToAppended()
        self._writer.EncodeAppendedDataOff()
        if self.compress:
            self._writer.SetCompressorTypeToZLib()
        else:
            self._writer.SetCompressorTypeToNone()

    def _write(self, ctx: ExportContext, frame: FrameData, mesh: Mesh, positions: np.ndarray) -> None:
        from vtkmodules.util.numpy_support import numpy_to_vtk

        if self._poly_mesh is not mesh:  # first frame or a new topology: rebuild the cells
            self._poly = polydata_from_mesh(mesh, positions)
            self._poly_mesh = mesh
            self._uvs = vertex_uvs(mesh)
        else:
            self._poly.GetPoints().SetData(numpy_to_vtk(np.ascontiguousarray(positions, dtype=np.float32), deep=True))
            self._poly.GetPoints().Modified()
        poly = self._poly
        pd = poly.GetPointData()
        for name in [pd.GetArrayName(i) for i in range(pd.GetNumberOfArrays())]:
            pd.RemoveArray(name)
        for key, value in frame.point_data.items():
            set_point_array(poly, key, value)
        if mesh is ctx.mesh:  # the vector (for Warp By Vector) replaces a frame array of that name
            set_point_array(poly, "displacement", positions - ctx.mesh.positions)
        if self._uvs is not None:
            set_point_array(poly, "TCoords", self._uvs)
            pd.SetActiveTCoords("TCoords")
        rel = f"{FOLDER}/{frame_file_name(ctx.scene_frame(frame.index), ctx.last_scene_frame, '.vtp')}"
        target = ctx.out_dir / rel
        with atomic_path(target) as tmp:
            self._writer.SetFileName(str(tmp))
            self._writer.SetInputData(poly)
            if self._writer.Write() != 1:
                raise OSError(f"VTK could not write {target}")
        self._written.append(target)
        self._entries.append((float(frame.time), rel))

    def _close(self, ctx: ExportContext) -> list[Path]:
        target = ctx.out_dir / COLLECTION_NAME
        write_text_atomic(target, pvd_text(self._entries))
        return [*self._written, target]


def read_vtp(path: Path) -> Mesh:
    """A `.vtp` file's points, polygons and polylines as a Mesh (point data is not read)."""
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkIOXML import vtkXMLPolyDataReader

    reader = vtkXMLPolyDataReader()
    reader.SetFileName(str(path))
    reader.Update()
    poly = reader.GetOutput()
    if poly is None or poly.GetPoints() is None:
        raise MeshLoadError(f"{path}: cannot read the VTK PolyData file")
    polys, lines = poly.GetPolys(), poly.GetLines()
    return Mesh(
        positions=vtk_to_numpy(poly.GetPoints().GetData()).astype(np.float64),
        face_indices=vtk_to_numpy(polys.GetConnectivityArray()).astype(np.int64),
        face_offsets=vtk_to_numpy(polys.GetOffsetsArray()).astype(np.int64),
        line_indices=vtk_to_numpy(lines.GetConnectivityArray()).astype(np.int64),
        line_offsets=vtk_to_numpy(lines.GetOffsetsArray()).astype(np.int64),
        source=path,
    )


def _same_cells(frame: Mesh, base: Mesh) -> bool:
    """Whether a read `.vtp` frame has the base's vertex count and polygon corners."""
    return frame.vertex_count == base.vertex_count and np.array_equal(frame.face_indices, base.face_indices)


def read_vtk_result(root: Path, input_mesh: Mesh | None) -> ResultFrames | None:
    """The `vtk/*.vtp` frames of a result folder (the input mesh is the base when the first frame has its
    polygons), or None when there are none."""
    files = numbered_files(root / FOLDER, (".vtp",))
    if not files:
        return None
    first = read_vtp(files[0][1])
    base = first
    if input_mesh is not None and np.array_equal(input_mesh.face_indices, first.face_indices):
        base = input_mesh
    return ResultFrames(
        base, LazyFrames([p for _, p in files], base, read_vtp, _same_cells), [n for n, _ in files], f"{FOLDER}/*.vtp"
    )


def vtp_pinned(root: Path, n: int) -> np.ndarray | None:
    """The `pinned` point array of a result folder's first `.vtp` frame as an (n,) mask (None when there is
    no such frame or array, or it is not n long)."""
    files = numbered_files(root / FOLDER, (".vtp",))
    if not files:
        return None
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkIOXML import vtkXMLPolyDataReader

    reader = vtkXMLPolyDataReader()
    reader.SetFileName(str(files[0][1]))
    reader.Update()
    array = reader.GetOutput().GetPointData().GetArray("pinned")
    if array is None:
        return None
    mask = vtk_to_numpy(array).astype(bool)
    return mask if mask.shape == (n,) else None


class VtkReadBack(ReadBack):
    """`read_vtk_result` for a run's frames in memory: float32 points; a frame whose polygons are not the
    base's is a Mesh as its `.vtp` holds it, new on every access as a read file is."""

    source = f"{FOLDER}/*.vtp"

    def __init__(self, ctx: ExportContext) -> None:
        super().__init__(ctx)
        self._same: tuple[Mesh | None, bool] = (None, False)

    def _as_read(self, mesh: Mesh, kept: np.ndarray) -> Mesh:
        """The frame's `.vtp` read (`read_vtp`)."""
        return Mesh(
            positions=kept.astype(np.float64),
            face_indices=np.asarray(mesh.face_indices, dtype=np.int64),
            face_offsets=np.asarray(mesh.face_offsets, dtype=np.int64),
            line_indices=np.asarray(mesh.line_indices, dtype=np.int64),
            line_offsets=np.asarray(mesh.line_offsets, dtype=np.int64),
        )

    def start(self, frame: FrameData, mesh: Mesh, kept: np.ndarray) -> Mesh:
        same = np.array_equal(self.ctx.mesh.face_indices, mesh.face_indices)
        self.base = self.ctx.mesh if same else self._as_read(mesh, kept)
        return self.base

    def item(self, mesh: Mesh, kept: np.ndarray) -> FrameItem:
        base = self.base
        assert base is not None
        if self._same[0] is not mesh:  # as read_vtk_result compares a read frame with the base
            same = mesh.vertex_count == base.vertex_count and np.array_equal(mesh.face_indices, base.face_indices)
            self._same = (mesh, same)
        return kept.astype(np.float64) if self._same[1] else self._as_read(mesh, kept)


def first_frame_pinned(frame: FrameData, n: int) -> np.ndarray | None:
    """`vtp_pinned` for a run's first frame in memory: its `pinned` point data as an (n,) mask, or None."""
    if "pinned" not in frame.point_data:
        return None
    mask = np.asarray(frame.point_data["pinned"]).astype(bool)
    return mask if mask.shape == (n,) else None
