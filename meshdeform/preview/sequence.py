"""Previews of a whole sequence: one pass for the bounds and colour range, then the frames rendered."""

from __future__ import annotations

import contextlib
import functools
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from meshdeform.errors import ExportError
from meshdeform.export.base import frame_file_name
from meshdeform.export.results import FrameItem
from meshdeform.mesh import Mesh
from meshdeform.preview.media import VideoWriter, contact_sheet, downscale, write_png
from meshdeform.preview.options import CONTACT_SHEET_NAME, PREVIEW_FOLDER, PreviewOptions, PreviewResult
from meshdeform.preview.render import FrameRenderer, as_pinned_mask
from meshdeform.preview.scalars import FrameScalars, nice_ceiling


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
#: drive from two threads at once (two jobs in one Dask worker)
_RENDERING = threading.Lock()


def _one_render_at_a_time(function: Callable[..., Any]) -> Callable[..., Any]:
    @functools.wraps(function)
    def locked(*args: Any, **kwargs: Any) -> Any:
        with _RENDERING:
            return function(*args, **kwargs)

    return locked


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
) -> PreviewResult:
    """Render the previews of a sequence into `out_dir` (see the module docstring for file names).

    mesh: the topology (and, unless `rest_positions` is given, the rest pose) of the frames.
    positions_by_frame: per frame (V, 3) positions in the mesh's layout, or a Mesh when the
        topology changed; any sequence, including a lazy loader (it is read twice: bounds, render).
    frame_numbers: the frames' numbers (default 1..F). fps: sequence rate (video default).
    pinned: (V,) bool mask or vertex indices to highlight.
    strain: per-frame (V,) stretch ratios, or a function positions -> ratios; default: computed
        from the mesh's edges against the rest pose.
    """
    options = PreviewOptions.from_mapping(options)
    started = time.perf_counter()
    out_dir = Path(out_dir)
    count = len(positions_by_frame)
    if count == 0:
        raise ExportError("preview: the sequence has no frames")
    numbers = list(frame_numbers) if frame_numbers is not None else list(range(1, count + 1))
    if len(numbers) != count:
        raise ExportError(f"preview: {len(numbers)} frame numbers for {count} frames")
    rest = np.asarray(mesh.positions if rest_positions is None else rest_positions, dtype=np.float64)
    pinned_mask = as_pinned_mask(pinned, mesh.vertex_count)
    strain_fn = strain if callable(strain) else None
    strain_frames = None if callable(strain) else strain
    scalars = FrameScalars(options.color, rest, strain_fn, strain_frames)

    png_numbers = set(options.png_frames(numbers))
    wanted = [k for k, n in enumerate(numbers) if options.video is not None or n in png_numbers]
    if not wanted:
        raise ExportError("preview: none of the requested frames is in the sequence")

    wanted_set = set(wanted)
    # pass 1: bounds of every frame and the colour range, so camera and colours stay fixed
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    smin, smax = np.inf, -np.inf
    for k in range(count):
        positions, frame_mesh = _positions_and_mesh(positions_by_frame[k], mesh)
        if not np.isfinite(positions).all():
            raise ExportError(f"preview: frame {numbers[k]} has non-finite positions")
        if positions.shape[0]:
            lo = np.minimum(lo, positions.min(axis=0))
            hi = np.maximum(hi, positions.max(axis=0))
        if options.clim is None and options.color != "flat" and k in wanted_set:
            values = scalars(k, frame_mesh, positions)
            if values is not None and values.size:
                smin, smax = min(smin, float(values.min())), max(smax, float(values.max()))
    if not np.isfinite(lo).all():
        raise ExportError("preview: the frames have no vertices")
    clim = options.clim
    if clim is None and options.color == "strain":
        spread = max(abs(smax - 1.0), abs(1.0 - smin), 0.0) if np.isfinite(smin) else 0.0
        spread = nice_ceiling(max(spread, 0.01))
        clim = (1.0 - spread, 1.0 + spread)
    elif clim is None and options.color == "displacement":
        clim = (0.0, nice_ceiling(max(smax if np.isfinite(smax) else 0.0, 1e-6)))

    result = PreviewResult()
    tiles: list[np.ndarray] = []
    tile_numbers: list[int] = []
    video: VideoWriter | None = None
    preview_dir = out_dir / PREVIEW_FOLDER
    frame_count = max(numbers)
    try:
        if options.video is not None:
            video = VideoWriter(out_dir / f"preview.{options.video}", options.video, options.fps or fps)
        with FrameRenderer(mesh, options, np.stack([lo, hi]), clim, pinned_mask) as renderer:
            for k in wanted:
                positions, frame_mesh = _positions_and_mesh(positions_by_frame[k], mesh)
                values = scalars(k, frame_mesh, positions)
                image = renderer.render(positions, numbers[k], values, frame_mesh)
                result.frames_rendered += 1
                if video is not None:
                    video.append(image)
                if numbers[k] in png_numbers:
                    if options.pngs:
                        name = frame_file_name(numbers[k], frame_count, ".png", stem="")
                        result.images.append(write_png(preview_dir / name, image))
                    if options.contact_sheet:
                        tiles.append(downscale(image, options.sheet_tile_width))
                        tile_numbers.append(numbers[k])
        if options.contact_sheet:
            sheet = contact_sheet(tiles, tile_numbers, options.sheet_columns, options.sheet_tile_width)
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
    result.seconds = time.perf_counter() - started
    return result
