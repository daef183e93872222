"""The streaming exporter contract shared by every output format.

An exporter is opened once per run with an `ExportContext`, receives the frames one by one as
`FrameData` and is closed (finalised) at the end, so a long bake never has to hold every frame
in memory where the format allows it. Files appear under their final names only when they are
complete (`meshdeform.atomic`); `abort()` removes everything the exporter wrote in this run, so
an interrupted export leaves nothing that looks finished.
"""

from __future__ import annotations

import contextlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Protocol, runtime_checkable

import numpy as np

from meshdeform.errors import ExportError
from meshdeform.mesh import Mesh

if TYPE_CHECKING:
    from meshdeform.export.results import ResultReading

#: accepted values of `ExportContext.up_axis`
UP_AXES = ("y", "z")
#: bytes per vertex per frame of the point data a run hands its exporters (`FrameData.point_data`:
#: strain and displacement float32, pinned uint8), for the estimates of the formats that write it
POINT_DATA_BYTES = 4 + 4 + 1


@dataclass(frozen=True)
class ExportContext:
    """What every exporter needs to know before the first frame.

    mesh: the input mesh (topology, UVs, groups, input vertex order; its positions are the rest pose).
    out_dir: the result folder; each format writes its fixed file names inside it.
    fps: frames per second of the sequence (USD timeCodesPerSecond, MDD times, npz `fps`).
    start_frame: the scene frame of the rest pose (frame index 0): frame index k is scene frame
        `start_frame + k`, the state k / fps seconds after the start (`scene_frame`), as Blender's
        own cloth cache numbers them. File names, cache samples and USD time codes use it.
    input_up: the input's up axis ("y", as OBJ files are, or "z": the recipe's `simulation.up`);
        the world the solver ran in.
    up_axis: the world point caches and USD are written in ("y" or "z"); None: `input_up` (the
        input's coordinates unchanged). From a Y-up input "z" turns them into Blender's Z-up
        world, (x, y, z) -> (x, -z, y); from a Z-up input "y" turns them back. glTF and VAT are
        always written Y up (`to_y_up`), OBJ/PLY/NPZ/VTK always in the input's coordinates.
        None for start_frame means the default.
    frame_count: the number of simulated frames (after the rest pose), when known (file-name
        padding; otherwise 4 digits).
    """

    mesh: Mesh
    out_dir: Path
    fps: float
    start_frame: int = 1
    up_axis: str | None = None
    frame_count: int | None = None
    input_up: str = "y"

    def __post_init__(self) -> None:
        object.__setattr__(self, "out_dir", Path(self.out_dir))
        # None means "the default", so callers can pass optional recipe values straight through
        object.__setattr__(self, "input_up", "y" if self.input_up is None else str(self.input_up).lower())
        object.__setattr__(self, "up_axis", self.input_up if self.up_axis is None else str(self.up_axis).lower())
        object.__setattr__(self, "start_frame", 1 if self.start_frame is None else int(self.start_frame))
        for axis in (self.input_up, self.up_axis):
            if axis not in UP_AXES:
                raise ExportError(f"up axis must be one of {', '.join(UP_AXES)}, not {axis!r}")
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise ExportError(f"fps must be a positive number, not {self.fps!r}")

    def scene_frame(self, index: int) -> int:
        """The scene frame of frame index `index` (0: the rest pose)."""
        return self.start_frame + int(index)

    @property
    def output_turns(self) -> int:
        """Quarter turns about X from the input's world to `up_axis`'s (`quarter_turns`)."""
        return quarter_turns(self.input_up, str(self.up_axis))

    def to_output_world(self, points: np.ndarray) -> np.ndarray:
        """Points or normals (..., 3) of the run in the world of the point caches and USD."""
        return turn_about_x(points, self.output_turns)

    def to_y_up(self, points: np.ndarray) -> np.ndarray:
        """Points or normals (..., 3) of the run in a Y-up world (glTF by specification, VAT)."""
        return turn_about_x(points, quarter_turns(self.input_up, "y"))

    @property
    def last_scene_frame(self) -> int | None:
        """The scene frame of the run's last frame, when the frame count is known."""
        return None if self.frame_count is None else self.scene_frame(self.frame_count)


@dataclass(frozen=True)
class FrameData:
    """One frame handed to the exporters.

    index: frame index, 0 for the rest pose, k for the state after k frames (scene frame
        `ExportContext.scene_frame(index)`, which file names, samples and time codes use).
    time: seconds since the start of the simulation (index / fps).
    positions: (V, 3) positions in the input vertex layout (of `mesh` when that is given).
    mesh: the new mesh when the topology changed at this frame (tearing), else None; it stays
        in force for the following frames until another one arrives.
    point_data: per-vertex arrays for formats that carry them (vtk, xdmf, npz), by convention
        "strain" (V,) stretch ratio (1 = rest length), "velocity" (V, 3), "pinned" (V,) uint8.
    subframes: (time in s, positions (V, 3)) of the states between the frame before and this
        one, in time order, for formats that write motion-blur samples (USD); usually empty.
    """

    index: int
    time: float
    positions: np.ndarray
    mesh: Mesh | None = None
    point_data: Mapping[str, np.ndarray] = field(default_factory=dict)
    subframes: tuple[tuple[float, np.ndarray], ...] = ()


@runtime_checkable
class Exporter(Protocol):
    """A streaming writer of one output format."""

    name: ClassVar[str]
    #: what the format writes, in one line (the command line's help lists it)
    summary: ClassVar[str]
    supports_topology_change: ClassVar[bool]

    def open(self, ctx: ExportContext) -> None: ...

    def write(self, frame: FrameData) -> None: ...

    def close(self) -> list[Path]: ...

    def abort(self) -> None: ...


def uvs_have_seams(mesh: Mesh) -> bool:
    """Whether the mesh's UVs are per corner (seams) rather than one per vertex: the PLY writer then
    writes per-face texcoord lists instead of vertex columns, and VTK has no per-vertex TCoords."""
    if mesh.uvs is None or mesh.face_uv_indices is None:
        return False
    per_vertex = mesh.uvs.shape[0] == mesh.vertex_count and np.array_equal(mesh.face_uv_indices, mesh.face_indices)
    return not per_vertex


def frame_file_name(number: int, last_number: int | None, suffix: str, stem: str = "frame_") -> str:
    """`frame_0001.obj` for (scene) frame `number`: 4-digit zero padding, more digits when the
    sequence's last number (`last_number`, when known) has more."""
    width = max(4, len(str(last_number))) if last_number else 4
    return f"{stem}{number:0{width}d}{suffix}"


def leading_samples(ctx: ExportContext, first_index: int) -> int:
    """How many copies of the first frame a point cache writes before it, so that its sample k is
    scene frame k: Blender's Mesh Cache modifier at its default settings (Frame time mode, Frame
    Start 0) plays sample F at scene frame F, and Blender's own MDD exporter writes an extra rest
    sample in the same way. The copies cost `start_frame` samples: a run that starts at frame
    1001 writes 1001 of them (set the modifier's Frame Start to the start frame instead and
    they are never shown, but they are always written so that the defaults work)."""
    return max(ctx.scene_frame(first_index), 0)


def quarter_turns(source: str, target: str) -> int:
    """Quarter turns about X that take a `source`-up world to a `target`-up one, as `turn_about_x`
    counts them: 0 for the same axis, +1 from Y up to Z up, -1 from Z up to Y up."""
    return {("y", "z"): 1, ("z", "y"): -1}.get((source, target), 0)


def turn_about_x(points: np.ndarray, turns: int) -> np.ndarray:
    """Points or normals (..., 3) turned by `turns` quarter turns about +X: +1 maps (x, y, z) to
    (x, -z, y) (a Y-up world into Blender's Z-up one, as its OBJ exporter's inverse), -1 back to
    (x, z, -y); 0 returns `points` itself."""
    turns = int(turns) % 4
    if turns == 0:
        return points
    points = np.asarray(points)
    x, y, z = points[..., 0], points[..., 1], points[..., 2]
    if turns == 1:
        return np.stack([x, -z, y], axis=-1)
    if turns == 3:
        return np.stack([x, z, -y], axis=-1)
    return np.stack([x, -y, -z], axis=-1)


class BaseExporter:
    """Common bookkeeping: open/closed state, frame order, shape checks and cleanup on abort.

    Subclasses implement `_open`, `_write` and `_close` (returning the finished files) and may
    override `_abort` to drop temporary files; files they finish during the run are listed in
    `self._written` so that `abort()` can remove them. They also declare what the rest of the tool
    reads from the registry: `name`, `summary`, `supports_topology_change`, `estimated_bytes` and
    `reading`.
    """

    name: ClassVar[str] = ""
    summary: ClassVar[str] = ""
    supports_topology_change: ClassVar[bool] = False
    #: a point cache whose sample k is scene frame k (`leading_samples` copies before the first frame)
    pads_to_scene_frame_zero: ClassVar[bool] = False
    #: `FrameData.subframes` become samples of their own (USD motion blur), each as large as a frame's
    writes_subframes: ClassVar[bool] = False
    #: the reason given when a frame changes the topology and the format cannot follow
    topology_message: ClassVar[str] = "this format needs a fixed topology"

    def __init__(self, **options: Any) -> None:
        if options:
            raise ExportError(f"{self.name}: unknown option(s) {', '.join(sorted(options))}")
        self._ctx: ExportContext | None = None
        self._mesh: Mesh | None = None
        self._written: list[Path] = []
        self._made_dirs: list[Path] = []
        self._count = 0
        self._last_index: int | None = None

    @classmethod
    def estimated_bytes(cls, mesh: Mesh, frames: int) -> int | None:
        """About how many bytes this format writes for `frames` frames of `mesh` (exact or on the high
        side; `meshdeform check` prints it and a run whose outputs would not fit on the disk is refused
        before it starts), or None when the format cannot tell (it is then left out of the estimate).
        A format with recipe options (`[output.<format>]`, `OutputSpec.exporter_options`) also takes
        them, as keyword arguments (usd)."""
        return None

    @classmethod
    def reading(cls, **options: Any) -> ResultReading | None:
        """How previews read this format back, from a result folder or from a run's frames in memory
        (its reader and `ReadBack`, beside the writer), or None when they cannot (the format is then
        never searched for). `options`: the run's `[output.<format>]` options, for a format whose
        file names depend on them (usd's `ascii`); none for a folder searched without a recipe."""
        return None

    # -- public protocol -------------------------------------------------------------------
    def open(self, ctx: ExportContext) -> None:
        """Start a run: remember the context, create folders, open streams."""
        if self._ctx is not None:
            raise ExportError(f"{self.name}: exporter is already open")
        self._ctx = ctx
        self._mesh = ctx.mesh
        self._written = []
        self._made_dirs = []
        self._count = 0
        self._last_index = None
        try:
            ctx.out_dir.mkdir(parents=True, exist_ok=True)
            self._open(ctx)
        except BaseException as exc:
            with contextlib.suppress(Exception):
                self._abort()
            self._ctx = None
            if isinstance(exc, OSError):
                raise ExportError(f"{self.name}: cannot open output in {ctx.out_dir}: {exc}") from exc
            raise

    def write(self, frame: FrameData) -> None:
        """Add one frame; checks order, topology and shapes before handing it to the format."""
        ctx = self._require_open()
        if self._last_index is not None and frame.index <= self._last_index:
            raise ExportError(
                f"{self.name}: frames must arrive in increasing order (frame {frame.index} after {self._last_index})"
            )
        if frame.mesh is not None:
            if not self.supports_topology_change:
                from meshdeform.export.registry import topology_following  # the registry imports this module

                raise ExportError(
                    f"{self.name}: {self.topology_message}; the mesh topology changed at frame {frame.index} "
                    f"(tearing). Export {topology_following()} instead, or turn tearing off"
                )
            self._mesh = frame.mesh
        mesh = self._mesh
        assert mesh is not None
        positions = np.asarray(frame.positions)
        if positions.shape != (mesh.vertex_count, 3):
            raise ExportError(
                f"{self.name}: frame {frame.index} has positions of shape {positions.shape}, "
                f"expected ({mesh.vertex_count}, 3)"
            )
        try:
            self._write(ctx, frame, mesh, positions)
        except OSError as exc:
            raise ExportError(f"{self.name}: cannot write frame {frame.index}: {exc}") from exc
        self._count += 1
        self._last_index = frame.index

    def close(self) -> list[Path]:
        """Finalise: write headers/indexes, rename complete files into place; returns the files."""
        ctx = self._require_open()
        if self._count == 0:
            self.abort()
            raise ExportError(f"{self.name}: no frames were written")
        try:
            finished = self._close(ctx)
        except BaseException:
            self.abort()
            raise
        self._ctx = None
        return finished

    def abort(self) -> None:
        """Give up: close streams, delete temporary files and every file written in this run."""
        if self._ctx is None:
            return
        with contextlib.suppress(Exception):
            self._abort()
        folders = {path.parent for path in self._written} | set(self._made_dirs)
        for path in self._written:
            with contextlib.suppress(OSError):
                path.unlink()
        for folder in folders - {self._ctx.out_dir}:  # frames/, vtk/: only if now empty
            with contextlib.suppress(OSError):
                folder.rmdir()
        self._written = []
        self._ctx = None

    # -- for subclasses ----------------------------------------------------------------------
    @property
    def frames_written(self) -> int:
        return self._count

    def _make_dir(self, folder: Path) -> Path:
        """Create a sub-folder of the output; `abort()` removes it again if it is left empty."""
        if not folder.is_dir():
            folder.mkdir(parents=True, exist_ok=True)
            self._made_dirs.append(folder)
        return folder

    def _require_open(self) -> ExportContext:
        if self._ctx is None:
            raise ExportError(f"{self.name}: exporter is not open")
        return self._ctx

    def _open(self, ctx: ExportContext) -> None:
        pass

    def _write(self, ctx: ExportContext, frame: FrameData, mesh: Mesh, positions: np.ndarray) -> None:
        raise NotImplementedError

    def _close(self, ctx: ExportContext) -> list[Path]:
        raise NotImplementedError

    def _abort(self) -> None:
        pass


class StreamedFile:
    """A file written through a temporary name: `finish()` renames it into place, `discard()` deletes it."""

    def __init__(self, target: Path) -> None:
        from meshdeform.atomic import atomic_path

        self.target = target
        self._stack = contextlib.ExitStack()
        self.path = self._stack.enter_context(atomic_path(target))
        self.handle = self._stack.enter_context(open(self.path, "wb"))  # noqa: SIM115

    def finish(self) -> Path:
        self._stack.close()
        return self.target

    def discard(self) -> None:
        err = ExportError("export aborted")
        self._stack.__exit__(type(err), err, None)
