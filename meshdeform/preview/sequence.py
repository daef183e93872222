"""Previews of a whole sequence: one pass for the bounds and colour range of every frame, then the frames rendered."""

from __future__ import annotations

import contextlib
import functools
import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from meshdeform.errors import ExportError
from meshdeform.export.base import frame_file_name
from meshdeform.export.results import FrameItem
from meshdeform.mesh import Mesh
from meshdeform.preview.colliders import ColliderSurfaces
from meshdeform.preview.framing import main_pieces
from meshdeform.preview.media import VideoWriter, contact_sheet, downscale, write_png
from meshdeform.preview.options import CONTACT_SHEET_NAME, PREVIEW_FOLDER, PreviewOptions, PreviewResult
from meshdeform.preview.render import FrameRenderer, as_pinned_mask
from meshdeform.preview.scalars import FrameScalars
from meshdeform.scene.colliders import Collider


def _positions_and_mesh(item: FrameItem, base: Mesh) -> tuple[np.ndarray, Mesh]:
    if isinstance(item, Mesh):
        return np.asarray(item.positions, dtype=np.float64), item
    positions = np.asarray(item, dtype=np.float64)
    if positions.shape != (base.vertex_count, 3):
        raise ExportError(
            f"preview: a frame has positions of shape {positions.shape}, expected ({base.vertex_count}, 3)"
        )
    return positions, base


#: one render at a time per process: VTK's render windows and OpenGL contexts are not safe to
#: drive from two threads at once (two jobs in one Dask worker); re-entrant, as `render_previews`
#: holds it over both passes (a lazy loader may read VTK files) and the render pass takes it too
_RENDERING = threading.RLock()


#: the smallest span of a measured colour range (a sequence that never stretches)
MIN_SPAN = 1e-3


def _one_render_at_a_time(function: Callable[..., Any]) -> Callable[..., Any]:
    @functools.wraps(function)
    def locked(*args: Any, **kwargs: Any) -> Any:
        with _RENDERING:
            return function(*args, **kwargs)

    return locked


def not_in_sequence(numbers: Sequence[int]) -> str:
    """The refusal of a preview none of whose requested frames the sequence holds, naming the frames
    it does hold (their first and last numbers)."""
    held = f"frames {min(numbers)} to {max(numbers)}" if numbers else "no frames"
    return f"preview: none of the requested frames is in the sequence, which holds {held}"


class SequencePreview:
    """The previews of one sequence in their two passes, so camera and colours are fixed before the first image.

    `measure` takes every frame in order (the bounds of what is framed in each, the colour range of all);
    `render` then renders the frames it `wants` (PNG and contact-sheet frames, or every frame for a video).
    `render_previews` runs both over a sequence; a run measures its frames as they are simulated and keeps
    only the wanted ones (`meshdeform.preview.live`). Arguments as `render_previews`'s; `strain` frames are
    indexed by the frame's position (from 0) in the order measured. `scene_fps`: the simulation's frame
    rate, which times the colliders (frame n at (n - start_frame) / scene_fps seconds; default `fps`).
    first_frame: the number of the sequence's first frame, from which `options.every` counts (default:
    the first measured). start_frame: the scene frame of the simulation's time 0, its rest pose (default:
    `first_frame`).
    """

    def __init__(
        self,
        mesh: Mesh,
        options: PreviewOptions | Mapping[str, Any] | None = None,
        *,
        fps: float = 24.0,
        rest_positions: np.ndarray | None = None,
        pinned: np.ndarray | Sequence[int] | None = None,
        strain: Sequence[np.ndarray] | Mapping[int, np.ndarray] | Callable[[np.ndarray], np.ndarray] | None = None,
        colliders: Sequence[Collider] = (),
        scene_fps: float | None = None,
        first_frame: int | None = None,
        start_frame: int | None = None,
    ) -> None:
        self.options = PreviewOptions.from_mapping(options)
        self.first_frame = first_frame
        self.start_frame = start_frame
        self.mesh = mesh
        self.fps = fps
        self.colliders = list(colliders)
        self.scene_fps = scene_fps
        rest = np.asarray(mesh.positions if rest_positions is None else rest_positions, dtype=np.float64)
        self.pinned = as_pinned_mask(pinned, mesh.vertex_count)
        strain_fn = strain if callable(strain) else None
        strain_frames = None if callable(strain) else strain
        self.scalars = FrameScalars(self.options.color, rest, strain_fn, strain_frames)
        #: the numbers of the frames measured so far, in order
        self.numbers: list[int] = []
        self.seconds = 0.0
        self._lo = np.full(3, np.inf)
        self._hi = np.full(3, -np.inf)
        self._smin, self._smax = np.inf, -np.inf

    def _first(self, number: int) -> int:
        """The sequence's first frame number (`number` itself before any is known)."""
        if self.first_frame is not None:
            return self.first_frame
        return self.numbers[0] if self.numbers else number

    def wants(self, number: int) -> bool:
        """Is frame `number` rendered: a PNG (or contact-sheet) frame, or any frame when there is a video?"""
        return self.options.video is not None or self.options.is_png_frame(number, self._first(number))

    def measure(self, number: int, item: FrameItem) -> int:
        """Pass 1 for the next frame: the bounds of what the camera frames in it (`options.framing`: a torn
        frame's main pieces, `framing.main_pieces`, or everything) and its colour range (every frame's, so
        that the range is the whole sequence's). Returns its position k (from 0), by which `render` and
        the strain frames know it."""
        tick = time.perf_counter()
        options = self.options
        k = len(self.numbers)
        positions, frame_mesh = _positions_and_mesh(item, self.mesh)
        if not np.isfinite(positions).all():
            raise ExportError(f"preview: frame {number} has non-finite positions")
        framed = positions
        if options.framing == "main" and frame_mesh is not self.mesh and positions.shape[0]:
            framed = positions[main_pieces(frame_mesh, positions)]
        if framed.shape[0]:
            self._lo = np.minimum(self._lo, framed.min(axis=0))
            self._hi = np.maximum(self._hi, framed.max(axis=0))
        if options.clim is None and options.color != "flat":
            values = self.scalars(k, frame_mesh, positions)
            if values is not None and values.size:
                self._smin, self._smax = min(self._smin, float(values.min())), max(self._smax, float(values.max()))
        self.numbers.append(number)
        self.seconds += time.perf_counter() - tick
        return k

    def check_wanted(self) -> None:
        """ExportError when no frame measured is one to render."""
        if not any(self.wants(n) for n in self.numbers):
            raise ExportError(not_in_sequence(self.numbers))

    def clim(self) -> tuple[float, float] | None:
        """The colour range of every image: the option, else from every frame measured: strain from 1 (no
        stretch; compression shows as none) to the largest stretch, displacement from 0 to the largest
        (each at least `MIN_SPAN` above the low end); None for flat colour."""
        if self.options.color == "flat":
            return None
        if self.options.clim is not None:
            return self.options.clim
        low = 1.0 if self.options.color == "strain" else 0.0
        high = self._smax if np.isfinite(self._smax) else low
        return low, max(high, low + MIN_SPAN)

    @_one_render_at_a_time
    def render(self, out_dir: str | Path, frames: Iterable[tuple[int, FrameItem]]) -> PreviewResult:
        """Pass 2: render the wanted frames, (k, item) in order, into `out_dir`; every file written is
        removed again if it fails."""
        tick = time.perf_counter()
        if not self.numbers:
            raise ExportError("preview: the sequence has no frames")
        self.check_wanted()
        if not np.isfinite(self._lo).all():
            raise ExportError("preview: the frames have no vertices")
        options, mesh, numbers = self.options, self.mesh, self.numbers
        out_dir = Path(out_dir)
        result = PreviewResult()
        tiles: list[np.ndarray] = []
        tile_numbers: list[int] = []
        video: VideoWriter | None = None
        preview_dir = out_dir / PREVIEW_FOLDER
        frame_count = max(numbers)
        try:
            if options.video is not None:
                video = VideoWriter(out_dir / f"preview.{options.video}", options.video, options.fps or self.fps)
            bounds = np.stack([self._lo, self._hi])
            surfaces = ColliderSurfaces(self.colliders, bounds) if self.colliders else None
            scene_fps = self.scene_fps or self.fps
            first = self._first(numbers[0])
            start = self.start_frame if self.start_frame is not None else first
            result.clim = self.clim()
            with FrameRenderer(mesh, options, bounds, result.clim, self.pinned, surfaces) as renderer:
                overlay = renderer.overlay
                for k, item in frames:
                    positions, frame_mesh = _positions_and_mesh(item, mesh)
                    values = self.scalars(k, frame_mesh, positions)
                    time_k = (numbers[k] - start) / scene_fps  # seconds since the rest pose
                    view = renderer.render(positions, values, frame_mesh, time_k)
                    png = options.is_png_frame(numbers[k], first)
                    if video is not None or (png and options.pngs):
                        image = overlay.decorate(view, numbers[k])
                    result.frames_rendered += 1
                    if video is not None:
                        video.append(image)
                    if png:
                        if options.pngs:
                            name = frame_file_name(numbers[k], frame_count, ".png", stem="")
                            result.images.append(write_png(preview_dir / name, image))
                        if options.contact_sheet:
                            tiles.append(downscale(overlay.content(view), options.sheet_tile_width))
                            tile_numbers.append(numbers[k])
            if options.contact_sheet:
                sheet = contact_sheet(
                    tiles,
                    tile_numbers,
                    options.sheet_columns,
                    options.sheet_tile_width,
                    color=options.color,
                    clim=result.clim,
                    background=options.background,
                )
                result.contact_sheet = write_png(preview_dir / CONTACT_SHEET_NAME, sheet)
            if video is not None:
                result.video = video.finish()
                video = None
        except BaseException:
            if video is not None:
                video.discard()
            for path in result.files:
                with contextlib.suppress(OSError):
                    path.unlink()
            raise
        self.seconds += time.perf_counter() - tick
        result.seconds = self.seconds
        return result


@_one_render_at_a_time
def render_previews(
    mesh: Mesh,
    positions_by_frame: Sequence[FrameItem],
    out_dir: str | Path,
    options: PreviewOptions | Mapping[str, Any] | None = None,
    *,
    frame_numbers: Sequence[int] | None = None,
    fps: float = 24.0,
    rest_positions: np.ndarray | None = None,
    pinned: np.ndarray | Sequence[int] | None = None,
    strain: Sequence[np.ndarray] | Callable[[np.ndarray], np.ndarray] | None = None,
    colliders: Sequence[Collider] = (),
    start_frame: int | None = None,
) -> PreviewResult:
    """Render the previews of a sequence into `out_dir` (see the package docstring for file names).

    mesh: the topology (and, unless `rest_positions` is given, the rest pose) of the frames.
    positions_by_frame: per frame (V, 3) positions in the mesh's layout, or a Mesh when the
        topology changed; any sequence, including a lazy loader (it is read twice: bounds, render).
    frame_numbers: the frames' scene frame numbers, increasing (default 1..F); `options.every` counts
        from the first. fps: sequence rate (video default).
    pinned: (V,) bool mask or vertex indices to highlight.
    strain: per-frame (V,) stretch ratios, or a function positions -> ratios; default: computed
        from the mesh's edges against the rest pose.
    colliders: the scene's colliders, drawn at each frame's time ((frame number - start_frame) / fps)
        unless `options.colliders` is off. start_frame: the scene frame of time 0, the rest pose
        (default: the first frame's number).
    """
    options = PreviewOptions.from_mapping(options)
    count = len(positions_by_frame)
    if count == 0:
        raise ExportError("preview: the sequence has no frames")
    numbers = list(frame_numbers) if frame_numbers is not None else list(range(1, count + 1))
    if len(numbers) != count:
        raise ExportError(f"preview: {len(numbers)} frame numbers for {count} frames")
    preview = SequencePreview(
        mesh,
        options,
        fps=fps,
        rest_positions=rest_positions,
        pinned=pinned,
        strain=strain,
        colliders=colliders,
        first_frame=numbers[0],
        start_frame=start_frame,
    )
    if not any(preview.wants(n) for n in numbers):
        raise ExportError(not_in_sequence(numbers))
    for k in range(count):  # pass 1: bounds of every frame and the colour range
        preview.measure(numbers[k], positions_by_frame[k])
    wanted = (k for k in range(count) if preview.wants(numbers[k]))
    return preview.render(out_dir, ((k, positions_by_frame[k]) for k in wanted))
