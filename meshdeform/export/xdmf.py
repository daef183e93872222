"""XDMF time series through meshio: `scene.xdmf`, for ParaView, VisIt and meshio readers.

Written with `meshio.xdmf.TimeSeriesWriter`: the mesh grid holds the topology and the rest
positions, and each time step carries point data `displacement` (rest + displacement = the
frame's positions, which is what meshio's time-series reader gives back; it replaces a frame
array of the same name) plus the frame's own arrays (`strain`, `velocity`, `pinned`, ...).
Each step also gets its own `Geometry` (the deformed float32 positions) so ParaView animates
the shape without a Warp By Vector filter; ParaView also lists meshio's static mesh grid as a
second block, named "rest" here (hide it).

Data are inline XML (`data_format="XML"`): meshio's HDF5 variant needs h5py, which is not a
dependency, and writes its `.h5` relative to the working directory. meshio builds the whole
XML document in memory and writes it at close, so for very long bakes prefer `vtk` or `usd`.
Polygons with more than four corners are fan-triangulated (meshio's XDMF has no n-gon cells);
the series has one fixed mesh, so a changed topology (tearing) is refused.
"""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from meshdeform.atomic import atomic_path
from meshdeform.export.base import BaseExporter, ExportContext, FrameData
from meshdeform.mesh import Mesh, fan_triangulate

FILE_NAME = "scene.xdmf"
#: characters of one number in the inline XML (measured: about 13 on a cloth grid)
XDMF_NUMBER_CHARS = 16
_XINCLUDE = "{http://www.w3.org/2003/XInclude}include"


def meshio_cells(mesh: Mesh) -> list[tuple[str, np.ndarray]]:
    """meshio cell blocks: triangles and quads as they are, larger polygons fan-triangulated.

    Polylines become line segments, but only when the mesh has no polygons (meshio cannot
    write lines inside a mixed XDMF topology).
    """
    sizes = mesh.face_sizes
    blocks: list[tuple[str, np.ndarray]] = []
    corner_size = np.repeat(sizes, sizes)
    for kind, k in (("triangle", 3), ("quad", 4)):
        corners = mesh.face_indices[corner_size == k]
        if corners.size:
            blocks.append((kind, corners.reshape(-1, k).astype(np.int64)))
    big = sizes > 4
    if big.any():
        keep = np.repeat(big, sizes)
        sub_offsets = np.concatenate([[0], np.cumsum(sizes[big])])
        tris = fan_triangulate(mesh.face_indices[keep], sub_offsets)
        if blocks and blocks[0][0] == "triangle":
            blocks[0] = ("triangle", np.concatenate([blocks[0][1], tris]))
        else:
            blocks.insert(0, ("triangle", tris))
    if not blocks and mesh.line_count:
        seg_sizes = np.diff(mesh.line_offsets)
        starts = np.arange(mesh.line_indices.shape[0])
        last = np.zeros(mesh.line_indices.shape[0], dtype=bool)
        last[mesh.line_offsets[1:][seg_sizes > 0] - 1] = True
        a = starts[~last]
        blocks.append(("line", np.stack([mesh.line_indices[a], mesh.line_indices[a + 1]], axis=1)))
    return blocks


def _xdmf_array(value: np.ndarray) -> np.ndarray:
    value = np.asarray(value)
    if value.dtype.kind == "f":
        return value.astype(np.float32)
    return value.astype(np.int32)


class XdmfExporter(BaseExporter):
    """Builds the meshio time series frame by frame and writes `scene.xdmf` at close."""

    name: ClassVar[str] = "xdmf"
    summary: ClassVar[str] = "XDMF time series (ParaView, VisIt)"
    supports_topology_change: ClassVar[bool] = False
    topology_message: ClassVar[str] = "the XDMF time series has one fixed mesh"

    @classmethod
    def estimated_bytes(cls, mesh: Mesh, frames: int) -> int | None:
        """Inline XML text: geometry, displacement (3 each), strain and pinned per vertex per step; the
        rest positions and the cells once."""
        v, corners = mesh.vertex_count, int(mesh.face_indices.shape[0])
        return int(XDMF_NUMBER_CHARS * (8 * v * frames + 3 * v + corners))

    def _open(self, ctx: ExportContext) -> None:
        from meshio.xdmf import TimeSeriesWriter

        self._stack = contextlib.ExitStack()
        tmp = self._stack.enter_context(atomic_path(ctx.out_dir / FILE_NAME))
        self._series: Any = TimeSeriesWriter(tmp, data_format="XML")
        self._series.__enter__()
        self._series.mesh_name = "rest"  # the domain-level grid ParaView also lists, named for what it is
        self._series.write_points_cells(np.asarray(ctx.mesh.positions, dtype=np.float64), meshio_cells(ctx.mesh))

    def _write(self, ctx: ExportContext, frame: FrameData, mesh: Mesh, positions: np.ndarray) -> None:
        series = self._series
        data = {k: _xdmf_array(v) for k, v in frame.point_data.items()}
        data["displacement"] = _xdmf_array(positions - ctx.mesh.positions)  # ours: rest + this = positions
        series.write_data(float(frame.time), point_data=data)
        grid = list(series.collection)[-1]
        include = grid.find(_XINCLUDE)
        if include is not None:  # topology shared, geometry per step
            include.set("xpointer", f'xpointer(//Grid[@Name="{series.mesh_name}"]/*[self::Topology])')
        series.points(grid, np.ascontiguousarray(positions, dtype=np.float32))
        geometry = grid[-1]
        grid.remove(geometry)
        grid.insert(1, geometry)

    def _close(self, ctx: ExportContext) -> list[Path]:
        self._series.__exit__(None, None, None)
        self._stack.close()
        return [ctx.out_dir / FILE_NAME]

    def _abort(self) -> None:
        err = RuntimeError("export aborted")
        self._stack.__exit__(type(err), err, None)
