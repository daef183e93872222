"""Reading a result folder's frames back: what every format's reader returns, and their shared helpers.

Each format module that can be read back has its reader beside its writer (`sequence.read_frame_files`
for `frames/*.obj|ply`, `npz.read_npz_result`, `usd.read_usd_result`, `vtk.read_vtk_result`,
`pc2.read_pc2_result`, `mdd.read_mdd_result`): given the folder and the input mesh (or None), it
returns the frames it found as `ResultFrames`, or None when the folder holds none of its files. Beside
each reader, a `ReadBack` gives what it would read for a run's frames still in memory (previews of a
run). The exporter class declares both, and where they come in the search, as a `ResultReading`
(`BaseExporter.reading`); `meshdeform.preview.results` searches the registry's in priority order.

Frame numbers are scene frames (`ExportContext.scene_frame`: the rest pose at `start_frame`, then one a
frame): the per-frame files' numbers, npz `frames`, USD time codes, and a point cache's sample index (PC2
from its header's start frame, 0 as ours write it; sample k is scene frame k). Point caches also hold
copies of their first frame for the scene frames before it (`base.leading_samples`); their readers return
those samples too (the files do not say where the run's frames begin), `ResultFrames.from_frame` drops
them, as `meshdeform.preview.results.open_result` does with the first frame the run's report names.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from meshdeform.errors import MeshLoadError
from meshdeform.export.base import ExportContext, FrameData, quarter_turns, turn_about_x
from meshdeform.mesh import Mesh

#: a frame read back: positions (V, 3) in the base mesh's layout, or a Mesh when its topology differs
FrameItem = np.ndarray | Mesh

_NUMBER = re.compile(r"(\d+)$")


class LazyFrames(Sequence[FrameItem]):
    """A result's frames read one file at a time: a frame is its positions (V, 3) when
    `same_topology(frame, base)`, else its own Mesh (the mesh changed: tearing).

    paths: the frame files in frame order; read: file -> Mesh (the format's reader).
    """

    def __init__(
        self, paths: list[Path], base: Mesh, read: Callable[[Path], Mesh], same_topology: Callable[[Mesh, Mesh], bool]
    ) -> None:
        self.paths = paths
        self.base = base
        self.read = read
        self.same_topology = same_topology

    def __len__(self) -> int:
        return len(self.paths)

    def __getitem__(self, k: int) -> FrameItem:  # type: ignore[override]
        frame = self.read(self.paths[k])
        return frame.positions if self.same_topology(frame, self.base) else frame


class FramesFrom(Sequence[Any]):
    """The items of a sequence from position `skip` on, read from it on each access (a lazy loader stays lazy)."""

    def __init__(self, items: Sequence[Any], skip: int) -> None:
        self.items = items
        self.skip = max(int(skip), 0)

    def __len__(self) -> int:
        return max(len(self.items) - self.skip, 0)

    def __getitem__(self, k: int) -> Any:  # type: ignore[override]
        if not -len(self) <= k < len(self):
            raise IndexError(k)
        return self.items[self.skip + (k % len(self))]


@dataclass
class ResultFrames:
    """The frames one reader found in a result folder.

    base: the mesh the frames are in (topology; its positions are the rest pose).
    frames: per frame a `FrameItem`, possibly read lazily from disk on each access.
    numbers: the frames' scene frame numbers, increasing (module docstring). source: what was read,
        e.g. "frames/*.obj", "cache.pc2".
    fps / pinned ((V,) bool) / strain (per frame (V,) stretch ratios): when the files carry them.
    """

    base: Mesh
    frames: Sequence[FrameItem]
    numbers: list[int]
    source: str
    fps: float | None = None
    pinned: np.ndarray | None = None
    strain: Sequence[np.ndarray] | None = None

    def from_frame(self, first: int) -> ResultFrames:
        """The frames numbered `first` or later (a point cache's copies before the run's first frame
        dropped); itself when none is before. Base, source, fps and pinned mask are kept."""
        skip = sum(1 for n in self.numbers if n < first)
        if skip == 0:
            return self
        strain = None if self.strain is None else FramesFrom(self.strain, skip)
        return replace(self, frames=FramesFrom(self.frames, skip), numbers=self.numbers[skip:], strain=strain)


def numbered_files(folder: Path, suffixes: Sequence[str]) -> list[tuple[int, Path]]:
    """(number, path) of the files in `folder` with one of `suffixes` whose stem ends in a number, sorted;
    hidden files are skipped (temporary files of a writer)."""
    found: list[tuple[int, Path]] = []
    if not folder.is_dir():
        return found
    for path in folder.iterdir():
        if path.name.startswith(".") or path.suffix.lower() not in suffixes:
            continue
        match = _NUMBER.search(path.stem)
        if match:
            found.append((int(match.group(1)), path))
    return sorted(found)


def prefer_input(base: Mesh, input_mesh: Mesh | None) -> Mesh:
    """The input mesh (rest pose, UVs, groups) when it matches the frames' vertex count."""
    return input_mesh if input_mesh is not None and input_mesh.vertex_count == base.vertex_count else base


#: the quarter turns about X a point cache or USD stage can have been written with from the input
#: (`ExportContext.output_turns`): none, from a Y-up input to Z up, from a Z-up input to Y up
CACHE_TURNS = (0, 1, -1)


def restore_input_world(points: np.ndarray, turns: int) -> np.ndarray:
    """Undo `ExportContext.to_output_world`: points (..., 3) written with `turns` quarter turns back
    in the input's coordinates."""
    return turn_about_x(points, -turns)


def detect_turns(first: np.ndarray, rest: np.ndarray) -> int:
    """The quarter turns (`CACHE_TURNS`) a point cache's first frame (V, 3) was written with: the ones
    whose undoing puts it closest to the rest pose (the first frame is close to rest)."""
    errors = [float(np.abs(restore_input_world(first, t) - rest).mean()) for t in CACHE_TURNS]
    return CACHE_TURNS[int(np.argmin(errors))]


def turns_for(up_axis: str | None, input_up: str = "y") -> int | None:
    """The quarter turns of outputs written in `up_axis` from a `input_up` input; None when unknown."""
    return None if up_axis is None else quarter_turns(input_up, up_axis)


def point_cache_frames(
    path: Path,
    positions: np.ndarray,
    input_mesh: Mesh,
    turns: int | None,
    fps: float | None,
    first_number: int = 0,
) -> ResultFrames:
    """The frames of a point cache (`positions` (F, V, 3) as stored) on the input mesh's topology, every
    sample (leading copies included), numbered `first_number` + sample index (the scene frame).

    `turns`: the quarter turns about X the cache was written with (`ExportContext.output_turns`);
    None: `detect_turns`.
    """
    if positions.shape[1:] != (input_mesh.vertex_count, 3):
        raise MeshLoadError(f"{path}: {positions.shape[1]} points, the input mesh has {input_mesh.vertex_count}")
    if turns is None:
        turns = detect_turns(positions[0], input_mesh.positions)
    frames = list(restore_input_world(positions.astype(np.float64), turns))
    numbers = list(range(first_number, first_number + len(frames)))
    return ResultFrames(input_mesh, frames, numbers, path.name, fps=fps)


def require_input_mesh(root: Path, input_mesh: Mesh | None) -> Mesh:
    """The input mesh a point cache needs for its topology (MeshLoadError naming the folder without one)."""
    if input_mesh is None:
        raise MeshLoadError(
            f"{root}: point caches hold no topology, and the input mesh (report.json 'input') is missing"
        )
    return input_mesh


class ReadBack:
    """What a format's reader returns for a run's frames, computed from the frames the run writes instead
    of from its files: a run previews its own result without reading it back.

    Fed the frames in order (`keep` each one's positions, `add` the frame, `start` on the first), it gives
    exactly what the format's reader gives for the folder the run writes, from the run's first frame on
    (`ResultFrames.from_frame`, as `open_result` reads it with the run's report.json: a point cache's
    copies before that frame are not the run's): the positions at the precision the files hold them, the
    same frame numbers (`number`), base mesh, frame items, fps and per-frame data, and the same errors
    (`check`). Subclasses sit beside their reader.
    """

    #: `ResultFrames.source` of the reader
    source: str = ""

    def __init__(self, ctx: ExportContext) -> None:
        self.ctx = ctx
        self.base: Mesh | None = None
        #: the fps the files carry (None: the reader finds none)
        self.fps: float | None = None
        #: the pinned mask the files carry (the reader's `ResultFrames.pinned`)
        self.pinned: np.ndarray | None = None

    def number(self, frame: FrameData) -> int:
        """The frame's number as the reader gives it: its scene frame."""
        return self.ctx.scene_frame(frame.index)

    def keep(self, positions: np.ndarray) -> np.ndarray:
        """A frame's (V, 3) positions as the files hold them, compact enough to keep in memory."""
        return np.array(positions, dtype=np.float32)

    def start(self, frame: FrameData, mesh: Mesh, kept: np.ndarray) -> Mesh:
        """Set and return the base mesh from the first frame (`mesh`: its mesh in force)."""
        self.base = prefer_input(mesh, self.ctx.mesh)
        return self.base

    def add(self, frame: FrameData, mesh: Mesh) -> None:
        """Take note of a frame (after `start` for the first one)."""

    def item(self, mesh: Mesh, kept: np.ndarray) -> FrameItem:
        """A frame as the reader returns it: float64 positions in the base's layout, or a new Mesh."""
        return kept.astype(np.float64)

    def strain(self, frame: FrameData) -> np.ndarray | None:
        """The frame's strain as the reader returns it (`ResultFrames.strain`), None when it has none."""
        return None

    def check(self) -> None:
        """Raise what reading the files back would raise (MeshLoadError), if anything."""


class PointCacheReadBack(ReadBack):
    """A point cache read back (`point_cache_frames`): float32 in the written convention, the convention
    detected from the first frame as the reader does (the report naming it does not exist yet)."""

    def keep(self, positions: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(self.ctx.to_output_world(positions), dtype=np.float32)

    def start(self, frame: FrameData, mesh: Mesh, kept: np.ndarray) -> Mesh:
        self.base = self.ctx.mesh
        self.turns = detect_turns(kept, self.base.positions)
        return self.base

    def item(self, mesh: Mesh, kept: np.ndarray) -> FrameItem:
        return restore_input_world(kept.astype(np.float64), self.turns)


@dataclass(frozen=True)
class ResultReading:
    """How previews read one format back, from a result folder or from a run's frames in memory; an
    exporter class declares it (`BaseExporter.reading`, None when previews cannot read the format).

    priority: result folders are searched in increasing priority and the first reader that finds its
        files wins; a run's previews read its frames as the format of lowest priority among its formats.
        Distinct across the registry.
    looks_for: the files `read` reads, as the error for a folder without frames names them. Formats that
        write the same files (obj and ply: `frames/`) share one reader, searched once.
    read: (folder, input mesh or None, the quarter turns point caches were written with or None: detect
        them) -> the frames found, or None when the
        folder holds none of the files; MeshLoadError when they are there but cannot be read.
    read_back: the `ReadBack` of what `read` reads from the folder a run writes, on the run's context.
    folder_pinned: (folder, vertex count n) -> the (n,) pinned mask the format's files carry, used when the
        frames found and the report have none, whichever reader found them (None: the files carry none).
    frame_pinned: `folder_pinned` for a run's first frame in memory, (frame, n) -> mask or None.
    """

    priority: int
    looks_for: str
    read: Callable[[Path, Mesh | None, int | None], ResultFrames | None]
    read_back: Callable[[ExportContext], ReadBack]
    folder_pinned: Callable[[Path, int], np.ndarray | None] | None = None
    frame_pinned: Callable[[FrameData, int], np.ndarray | None] | None = None
