"""MDD (LightWave point cache, read by Blender's Mesh Cache modifier) export: one big-endian file.

Layout (DESIGN.md section 5): `int32 num_frames`, `int32 num_points`, `float32 times[num_frames]`
(seconds), then exactly `num_frames` blocks of `num_points * 3` float32. Block k is scene frame k:
the first frame written (the rest pose at `start_frame`, frame index 0) is preceded by copies of
itself for scene frames 0 .. start_frame - 1 (`base.leading_samples`), and the times are scene
frame / fps, so Blender's Mesh Cache modifier at its defaults ("Frame" time mode, Frame Start 0)
and in "Time" mode both show at scene frame F the OBJ file of frame F.
The header's size depends on the frame count, so positions are streamed into an anonymous
temporary file and the cache is composed (header + times + blocks) at close.

Point caches need a fixed vertex count: a frame with a changed topology (tearing) is refused.
`read_mdd_result` reads it back on the input mesh (`meshdeform.export.results`).
"""

from __future__ import annotations

import shutil
import struct
import tempfile
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from meshdeform.atomic import atomic_open
from meshdeform.export.base import BaseExporter, ExportContext, FrameData, leading_samples
from meshdeform.export.results import (
    PointCacheReadBack,
    ResultFrames,
    ResultReading,
    point_cache_frames,
    require_input_mesh,
)
from meshdeform.mesh import Mesh

FILE_NAME = "cache.mdd"
MDD_HEADER = struct.Struct(">ii")  # num_frames, num_points: 8 bytes, big-endian
MDD_FLOAT = ">f4"  # the times (seconds) and the x y z of every point: big-endian float32


def mdd_bytes(frames: int, points: int) -> int:
    """The size of an MDD file: the header, a float32 time per frame, float32 x y z per point per frame."""
    return MDD_HEADER.size + 4 * frames + 12 * points * frames


def mdd_time(ctx: ExportContext, index: int) -> float:
    """The scene time in seconds of frame index `index` in the MDD times: scene frame / fps."""
    return ctx.scene_frame(index) / ctx.fps


class MddExporter(BaseExporter):
    """Streams frames into a spool file and writes `cache.mdd` at close."""

    name: ClassVar[str] = "mdd"
    summary: ClassVar[str] = "MDD point cache (LightWave, Blender)"
    supports_topology_change: ClassVar[bool] = False
    pads_to_scene_frame_zero: ClassVar[bool] = True
    topology_message: ClassVar[str] = "point caches need a fixed vertex count"

    @classmethod
    def estimated_bytes(cls, mesh: Mesh, frames: int) -> int | None:
        """Exact: frame count, point count, a float32 time per frame, float32 x y z per vertex per frame."""
        return int(mdd_bytes(frames, mesh.vertex_count))

    @classmethod
    def reading(cls, **options: Any) -> ResultReading | None:
        return ResultReading(priority=70, looks_for=FILE_NAME, read=read_mdd_result, read_back=MddReadBack)

    def _open(self, ctx: ExportContext) -> None:
        self._spool = tempfile.TemporaryFile(dir=ctx.out_dir, prefix=".cache.mdd.", suffix=".spool")  # noqa: SIM115
        self._times: list[float] = []

    def _write(self, ctx: ExportContext, frame: FrameData, mesh: Mesh, positions: np.ndarray) -> None:
        data = np.ascontiguousarray(ctx.to_output_world(positions), dtype=MDD_FLOAT)
        if not self._times:  # the first frame also fills the samples of scene frames 0 .. it - 1
            lead = leading_samples(ctx, frame.index)
            for k in range(lead):
                self._spool.write(data.tobytes())
                self._times.append(k / ctx.fps)
        self._spool.write(data.tobytes())
        self._times.append(mdd_time(ctx, frame.index))

    def _close(self, ctx: ExportContext) -> list[Path]:
        target = ctx.out_dir / FILE_NAME
        with atomic_open(target, "wb") as out:
            out.write(MDD_HEADER.pack(len(self._times), ctx.mesh.vertex_count))
            out.write(np.asarray(self._times, dtype=MDD_FLOAT).tobytes())
            self._spool.seek(0)
            shutil.copyfileobj(self._spool, out, 1 << 20)
        self._spool.close()
        return [target]

    def _abort(self) -> None:
        self._spool.close()


def read_mdd(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read an MDD file: positions (frames, points, 3) float32 and times (frames,) in seconds.

    Raises MeshLoadError when the size does not match the header.
    """
    from meshdeform.errors import MeshLoadError

    path = Path(path)
    with open(path, "rb") as handle:
        head = handle.read(MDD_HEADER.size)
        if len(head) != MDD_HEADER.size:
            raise MeshLoadError(f"{path}: too short for an MDD header")
        frames, points = MDD_HEADER.unpack(head)
        if frames < 0 or points < 0:
            raise MeshLoadError(f"{path}: not an MDD point cache")
        times = np.fromfile(handle, dtype=MDD_FLOAT, count=frames)
        data = np.fromfile(handle, dtype=MDD_FLOAT)
    if times.size != frames or data.size != frames * points * 3:
        raise MeshLoadError(f"{path}: size does not match the header ({frames} frames of {points} points)")
    return data.reshape(frames, points, 3).astype(np.float32), times.astype(np.float64)


def mdd_fps(times: np.ndarray) -> float | None:
    """The frame rate of an MDD's times (seconds, as read): None for fewer than two or non-increasing times."""
    if times.size >= 2 and times[1] > times[0]:
        return float(1.0 / (times[1] - times[0]))
    return None


def read_mdd_result(root: Path, input_mesh: Mesh | None, turns: int | None) -> ResultFrames | None:
    """The frames of a result folder's `cache.mdd` on the input mesh (`point_cache_frames`: every sample,
    sample k numbered the first time's scene frame (first time * fps, 0 as ours are written) + k; fps
    from its first two times), or None when there is none; MeshLoadError when there is one but no input
    mesh."""
    path = root / FILE_NAME
    if not path.is_file():
        return None
    mesh = require_input_mesh(root, input_mesh)
    positions, times = read_mdd(path)
    fps = mdd_fps(times)
    first = float(times[0]) * fps if fps is not None else 0.0
    number = round(first) if abs(first - round(first)) < 1e-3 else 0
    return point_cache_frames(path, positions, mesh, turns, fps=fps, first_number=number)


class MddReadBack(PointCacheReadBack):
    """`read_mdd_result` for a run's frames in memory: the fps from the cache's first two float32 times,
    those of the copies before the first frame (`leading_samples`, at k / fps) when there are any."""

    source = FILE_NAME

    def __init__(self, ctx: ExportContext) -> None:
        super().__init__(ctx)
        self._times: list[float] = []

    def add(self, frame: FrameData, mesh: Mesh) -> None:
        if len(self._times) >= 2:
            return
        if not self._times:  # the samples the exporter writes before the first frame
            self._times = [k / self.ctx.fps for k in range(min(leading_samples(self.ctx, frame.index), 2))]
        self._times = [*self._times, mdd_time(self.ctx, frame.index)][:2]
        self.fps = mdd_fps(np.asarray(self._times, dtype=MDD_FLOAT).astype(np.float64))
