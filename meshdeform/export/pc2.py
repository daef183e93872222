"""PC2 (Point Cache 2) export: one little-endian file read by Blender's Mesh Cache modifier, Maya, 3ds Max.

Layout (DESIGN.md section 5): a 32-byte header `char[12] "POINTCACHE2\\0"`, `int32 version = 1`,
`int32 num_points`, `float32 start_frame`, `float32 sample_rate = 1.0`, `int32 num_samples`, then
`num_samples * num_points * 3` float32 (x, y, z). Frames are streamed straight into the file
(under a temporary name) and the header is patched with the sample count at close.

Blender's Mesh Cache modifier plays PC2 in "Frame" mode as sample = scene frame - Frame Start and
ignores the header's start frame (benchmarks/blender_check.py). So that its defaults (Frame Start
0) show at scene frame F the OBJ file of frame F, sample k is scene frame k: the first frame
written (the rest pose at `start_frame`) is preceded by copies of itself for scene frames
0 .. start_frame - 1 (`base.leading_samples`), and the header's start frame is 0.

Point caches need a fixed vertex count: a frame with a changed topology (tearing) is refused.
`read_pc2_result` reads it back on the input mesh (`meshdeform.export.results`).
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from meshdeform.errors import ExportError
from meshdeform.export.base import (
    BaseExporter,
    ExportContext,
    FrameData,
    StreamedFile,
    leading_samples,
)
from meshdeform.export.results import (
    PointCacheReadBack,
    ResultFrames,
    ResultReading,
    point_cache_frames,
    require_input_mesh,
)
from meshdeform.mesh import Mesh

PC2_MAGIC = b"POINTCACHE2\0"
PC2_HEADER = struct.Struct("<12siiffi")  # 32 bytes
PC2_FLOAT = "<f4"  # the x y z of every point: little-endian float32
FILE_NAME = "cache.pc2"


def pc2_bytes(samples: int, points: int) -> int:
    """The size of a PC2 file: the 32-byte header, then float32 x y z per point per sample."""
    return PC2_HEADER.size + 12 * points * samples


def pc2_header(num_points: int, start_frame: float, num_samples: int, sample_rate: float = 1.0) -> bytes:
    """The 32-byte PC2 header."""
    return PC2_HEADER.pack(PC2_MAGIC, 1, num_points, float(start_frame), float(sample_rate), num_samples)


class Pc2Exporter(BaseExporter):
    """Streams frames into `cache.pc2`; frames must be consecutive (one sample per frame)."""

    name: ClassVar[str] = "pc2"
    summary: ClassVar[str] = "PC2 point cache (Blender, Maya, 3ds Max)"
    supports_topology_change: ClassVar[bool] = False
    pads_to_scene_frame_zero: ClassVar[bool] = True
    topology_message: ClassVar[str] = "point caches need a fixed vertex count"

    @classmethod
    def estimated_bytes(cls, mesh: Mesh, frames: int) -> int | None:
        """Exact: the 32-byte header, float32 x y z per vertex per frame."""
        return int(pc2_bytes(frames, mesh.vertex_count))

    @classmethod
    def reading(cls, **options: Any) -> ResultReading | None:
        return ResultReading(priority=60, looks_for=FILE_NAME, read=read_pc2_result, read_back=Pc2ReadBack)

    def _open(self, ctx: ExportContext) -> None:
        self._file = StreamedFile(ctx.out_dir / FILE_NAME)
        self._file.handle.write(pc2_header(ctx.mesh.vertex_count, 0.0, 0))
        self._samples = 0

    def _write(self, ctx: ExportContext, frame: FrameData, mesh: Mesh, positions: np.ndarray) -> None:
        if self._last_index is not None and frame.index != self._last_index + 1:
            raise ExportError(
                f"pc2: frames must be consecutive (one sample per frame): frame {frame.index} after {self._last_index}"
            )
        data = np.ascontiguousarray(ctx.to_output_world(positions), dtype=PC2_FLOAT)
        repeats = 1 + (leading_samples(ctx, frame.index) if self._samples == 0 else 0)
        for _ in range(repeats):  # the first frame also fills the samples of scene frames 0 .. it - 1
            self._file.handle.write(data.tobytes())
        self._samples += repeats

    def _close(self, ctx: ExportContext) -> list[Path]:
        handle = self._file.handle
        handle.seek(0)
        handle.write(pc2_header(ctx.mesh.vertex_count, 0.0, self._samples))
        return [self._file.finish()]

    def _abort(self) -> None:
        self._file.discard()


def read_pc2(path: str | Path) -> tuple[np.ndarray, float, float]:
    """Read a PC2 file: positions (samples, points, 3) float32, start frame, sample rate.

    Raises MeshLoadError when the header is not a PC2 header or the size does not match it.
    """
    from meshdeform.errors import MeshLoadError

    path = Path(path)
    with open(path, "rb") as handle:
        head = handle.read(PC2_HEADER.size)
        if len(head) != PC2_HEADER.size:
            raise MeshLoadError(f"{path}: too short for a PC2 header")
        magic, _version, points, start, rate, samples = PC2_HEADER.unpack(head)
        if magic != PC2_MAGIC or points < 0 or samples < 0:
            raise MeshLoadError(f"{path}: not a PC2 point cache")
        data = np.fromfile(handle, dtype=PC2_FLOAT)
    if data.size != points * samples * 3:
        raise MeshLoadError(f"{path}: {data.size} floats, the header promises {points * samples * 3}")
    return data.reshape(samples, points, 3), float(start), float(rate)


def read_pc2_result(root: Path, input_mesh: Mesh | None, turns: int | None) -> ResultFrames | None:
    """The frames of a result folder's `cache.pc2` on the input mesh (`point_cache_frames`: every sample,
    sample k numbered the header's start frame + k, scene frame k as ours are written), or None when
    there is none; MeshLoadError when there is one but no input mesh."""
    path = root / FILE_NAME
    if not path.is_file():
        return None
    mesh = require_input_mesh(root, input_mesh)
    positions, start, _ = read_pc2(path)
    first = round(start) if np.isfinite(start) else 0
    return point_cache_frames(path, positions, mesh, turns, fps=None, first_number=first)


class Pc2ReadBack(PointCacheReadBack):
    """`read_pc2_result` for a run's frames in memory (no fps: PC2 has a sample rate, not one)."""

    source = FILE_NAME
