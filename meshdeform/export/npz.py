"""NPZ export for Python users: every frame's positions in one array plus the topology.

`positions.npz` holds `positions` (frames, vertices, 3) float32 in the input layout and
coordinates (row 0: the rest pose), `times` (frames,) seconds, `frames` (frames,) scene frame
numbers (`start_frame` for the rest pose), `fps`, `start_frame`,
the polygons in CSR (`face_indices`, `face_offsets`), `rest_positions` (vertices, 3) and, for
each point-data array the frames carried, `point_<name>` (frames, vertices, ...), e.g.
`point_strain`. Frames are streamed into anonymous spool files and zipped at close (NumPy
copies a memory-mapped array in chunks), so memory stays flat however long the bake.

    data = np.load("positions.npz"); data["positions"][frame - data["start_frame"]]

The array needs a fixed vertex count: a frame with a changed topology (tearing) is refused.
`read_npz_result` reads it back (`meshdeform.export.results`).
"""

from __future__ import annotations

import tempfile
from dataclasses import replace
from pathlib import Path
from typing import IO, Any, ClassVar

import numpy as np

from meshdeform.atomic import atomic_open
from meshdeform.errors import ExportError
from meshdeform.export.base import POINT_DATA_BYTES, BaseExporter, ExportContext, FrameData
from meshdeform.export.results import ReadBack, ResultFrames, ResultReading, prefer_input
from meshdeform.mesh import Mesh

FILE_NAME = "positions.npz"


class _Spool:
    """Frames of one array appended to an anonymous temporary file."""

    def __init__(self, out_dir: Path, name: str, dtype: np.dtype, shape: tuple[int, ...]) -> None:
        self.handle: IO[bytes] = tempfile.TemporaryFile(dir=out_dir, prefix=f".{name}.", suffix=".spool")  # noqa: SIM115
        self.dtype = dtype
        self.shape = shape

    def append(self, array: np.ndarray) -> None:
        self.handle.write(np.ascontiguousarray(array, dtype=self.dtype).tobytes())

    def view(self, frames: int) -> np.ndarray:
        self.handle.flush()
        if frames * int(np.prod(self.shape)) == 0:
            return np.zeros((frames, *self.shape), dtype=self.dtype)
        return np.memmap(self.handle, dtype=self.dtype, mode="r", shape=(frames, *self.shape))


def _spool_dtype(array: np.ndarray) -> np.dtype:
    if array.dtype.kind == "f":
        return np.dtype(np.float32)
    if array.dtype.kind == "b":
        return np.dtype(np.uint8)
    return array.dtype


class NpzExporter(BaseExporter):
    """Streams positions and point data into spools; writes `positions.npz` at close."""

    name: ClassVar[str] = "npz"
    summary: ClassVar[str] = "NumPy arrays of every frame"
    supports_topology_change: ClassVar[bool] = False
    topology_message: ClassVar[str] = "the npz positions array needs a fixed vertex count"

    @classmethod
    def estimated_bytes(cls, mesh: Mesh, frames: int) -> int | None:
        """float32 positions and point data per frame, time and number per frame, topology and rest
        positions once, and the zip's own records."""
        v, f, corners = mesh.vertex_count, mesh.face_count, int(mesh.face_indices.shape[0])
        return int(4096 + (12 + POINT_DATA_BYTES) * v * frames + 16 * frames + 8 * (corners + f + 1) + 24 * v)

    @classmethod
    def reading(cls, **options: Any) -> ResultReading | None:
        return ResultReading(
            priority=30,
            looks_for=FILE_NAME,
            read=lambda root, input_mesh, turns: read_npz_result(root, input_mesh),
            read_back=NpzReadBack,
        )

    def _open(self, ctx: ExportContext) -> None:
        self._spools: dict[str, _Spool] = {
            "positions": _Spool(ctx.out_dir, "positions", np.dtype(np.float32), (ctx.mesh.vertex_count, 3))
        }
        self._times: list[float] = []
        self._frames: list[int] = []

    def _write(self, ctx: ExportContext, frame: FrameData, mesh: Mesh, positions: np.ndarray) -> None:
        data = {f"point_{k}": np.asarray(v) for k, v in frame.point_data.items()}
        if self.frames_written == 0:
            for key, value in data.items():
                if value.shape[:1] != (mesh.vertex_count,):
                    raise ExportError(
                        f"npz: point data {key[6:]!r} of frame {frame.index} has shape {value.shape}, "
                        f"expected ({mesh.vertex_count}, ...)"
                    )
                self._spools[key] = _Spool(ctx.out_dir, key, _spool_dtype(value), value.shape)
        elif set(data) != set(self._spools) - {"positions"}:
            raise ExportError(f"npz: frame {frame.index} carries other point data than the first frame")
        self._spools["positions"].append(positions)
        for key, value in data.items():
            spool = self._spools[key]
            if value.shape != spool.shape:
                raise ExportError(
                    f"npz: point data {key[6:]!r} of frame {frame.index} has shape {value.shape}, "
                    f"expected {spool.shape}"
                )
            spool.append(value)
        self._times.append(float(frame.time))
        self._frames.append(ctx.scene_frame(frame.index))

    def _close(self, ctx: ExportContext) -> list[Path]:
        n = len(self._times)
        arrays: dict[str, np.ndarray] = {key: spool.view(n) for key, spool in self._spools.items()}
        mesh = ctx.mesh
        arrays.update(
            times=np.asarray(self._times, dtype=np.float64),
            frames=np.asarray(self._frames, dtype=np.int64),
            fps=np.float64(ctx.fps),
            start_frame=np.int64(ctx.start_frame),
            face_indices=np.asarray(mesh.face_indices, dtype=np.int64),
            face_offsets=np.asarray(mesh.face_offsets, dtype=np.int64),
            rest_positions=np.asarray(mesh.positions, dtype=np.float64),
        )
        if mesh.line_count:
            arrays.update(line_indices=mesh.line_indices, line_offsets=mesh.line_offsets)
        target = ctx.out_dir / FILE_NAME
        with atomic_open(target, "wb") as out:
            np.savez(out, **arrays)
        del arrays
        self._close_spools()
        return [target]

    def _close_spools(self) -> None:
        for spool in self._spools.values():
            spool.handle.close()

    def _abort(self) -> None:
        self._close_spools()


def read_npz_result(root: Path, input_mesh: Mesh | None) -> ResultFrames | None:
    """The frames of a result folder's `positions.npz` (with its fps, `point_pinned` of the first frame and
    `point_strain` when it has them), or None when there is none."""
    path = root / FILE_NAME
    if not path.is_file():
        return None
    with np.load(path) as data:
        positions = np.asarray(data["positions"], dtype=np.float64)
        numbers = [int(n) for n in data["frames"]] if "frames" in data else list(range(1, len(positions) + 1))
        rest = np.asarray(data["rest_positions"]) if "rest_positions" in data else positions[0]
        base = Mesh(positions=rest, face_indices=data["face_indices"], face_offsets=data["face_offsets"])
        if "line_indices" in data:
            base = replace(base, line_indices=data["line_indices"], line_offsets=data["line_offsets"])
        found = ResultFrames(prefer_input(base, input_mesh), list(positions), numbers, path.name)
        found.fps = float(data["fps"]) if "fps" in data else None
        if "point_pinned" in data:
            found.pinned = np.asarray(data["point_pinned"][0]).astype(bool)
        if "point_strain" in data:
            found.strain = list(np.asarray(data["point_strain"], dtype=np.float64))
    return found


def _as_spooled(value: np.ndarray) -> np.ndarray:
    """A point-data array as `positions.npz` holds it (floats as float32, bools as uint8)."""
    value = np.asarray(value)
    return value.astype(_spool_dtype(value))


class NpzReadBack(ReadBack):
    """`read_npz_result` for a run's frames in memory: float32 positions and point data, the run's fps,
    the first frame's pinned flags; the npz's own rest mesh has the input's vertex count, so the input
    is the base."""

    source = FILE_NAME

    def start(self, frame: FrameData, mesh: Mesh, kept: np.ndarray) -> Mesh:
        self.base = self.ctx.mesh
        self.fps = float(self.ctx.fps)  # the npz's `fps`
        if "pinned" in frame.point_data:
            self.pinned = _as_spooled(frame.point_data["pinned"]).astype(bool)
        return self.base

    def strain(self, frame: FrameData) -> np.ndarray | None:
        if "strain" not in frame.point_data:
            return None
        return np.asarray(_as_spooled(frame.point_data["strain"]), dtype=np.float64)
