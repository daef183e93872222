"""Preview image and video files: PNGs, the contact sheet, MP4 (imageio-ffmpeg) and GIF (Pillow), atomically."""

from __future__ import annotations

import contextlib
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from meshdeform.atomic import atomic_path
from meshdeform.errors import ExportError


def write_png(path: Path, image: np.ndarray) -> Path:
    from PIL import Image

    with atomic_path(path) as tmp:
        Image.fromarray(image).save(tmp, format="PNG")
    return path


def contact_sheet(
    images: Sequence[np.ndarray],
    numbers: Sequence[int],
    columns: int | None = None,
    tile_width: int = 320,
    *,
    color: str = "flat",
    clim: tuple[float, float] | None = None,
    background: str = "white",
) -> np.ndarray:
    """A grid of the views `images` at `tile_width` pixels wide, each under a band with its label ("frame
    12", at a size legible at the tile's), and one colour bar for the whole sheet on its right (`color`,
    `clim`; none for flat colour): (rows * (band + tile height), columns * tile_width + bar panel, 3)."""
    from PIL import Image, ImageDraw

    from meshdeform.preview.overlay import ColorBar, background_rgb, font, text_rgb, text_size

    n = len(images)
    if n == 0:
        raise ExportError("preview: no frames for the contact sheet")
    cols = int(columns) if columns else math.ceil(math.sqrt(n))
    cols = max(1, min(cols, n))
    rows = math.ceil(n / cols)
    h, w = images[0].shape[:2]
    tw = int(tile_width)
    th = max(1, round(tw * h / w))
    fill, ink = background_rgb(background), text_rgb(background)
    pad = max(2, tw // 64)
    labels = [f"frame {number}" for number in numbers]
    size = max(11, round(tw / 18))
    widest = max(labels, key=lambda t: text_size(t, size)[0])
    while size > 6 and text_size(widest, size)[0] > tw - 2 * pad:  # a narrow tile: smaller text
        size -= 1
    band = text_size("frame 0", size)[1] + 2 * pad
    bar = None
    if clim is not None and color != "flat":
        bar = ColorBar(color, clim, font_size=max(11, size), bar_width=max(10, size), text=ink, fill=fill)
    panel = bar.width() + 2 * bar.margin if bar is not None else 0
    cell = band + th
    sheet = Image.new("RGB", (cols * tw + panel, rows * cell), fill)
    draw = ImageDraw.Draw(sheet)
    for k, (image, label) in enumerate(zip(images, labels, strict=True)):
        x, y = (k % cols) * tw, (k // cols) * cell
        tile = Image.fromarray(np.asarray(image, dtype=np.uint8)).resize((tw, th), Image.Resampling.LANCZOS)
        sheet.paste(tile, (x, y + band))
        draw.text((x + pad, y + pad), label, fill=ink, font=font(size))
        draw.rectangle([x, y, x + tw - 1, y + cell - 1], outline=(160, 160, 160))
    if bar is not None:
        top = bar.margin + min(band, cell // 4)
        bar.draw(sheet, cols * tw + bar.margin, top, max(rows * cell - bar.margin - bar.font_size, top))
    return np.asarray(sheet)


class VideoWriter:
    """Streams frames into an MP4 (imageio-ffmpeg, H.264) or a GIF (Pillow), under a temporary name."""

    def __init__(self, path: Path, kind: str, fps: float) -> None:
        self.path = path
        self.kind = kind
        self.fps = fps
        self._atomic = atomic_path(path)
        self._tmp = self._atomic.__enter__()
        self._gif_frames: list[Any] = []
        self._writer: Any = None
        self.count = 0
        if kind == "mp4":
            import imageio.v2 as imageio

            self._writer = imageio.get_writer(
                str(self._tmp),
                format="FFMPEG",
                mode="I",
                fps=float(fps),
                codec="libx264",
                pixelformat="yuv420p",
                quality=8,
                macro_block_size=2,
                ffmpeg_log_level="error",
            )

    def append(self, image: np.ndarray) -> None:
        if self.kind == "mp4":
            h, w = image.shape[:2]
            self._writer.append_data(np.ascontiguousarray(image[: h - h % 2, : w - w % 2]))
        else:
            from PIL import Image

            self._gif_frames.append(Image.fromarray(image).quantize(colors=255, method=Image.Quantize.MEDIANCUT))
        self.count += 1

    def finish(self) -> Path:
        if self.kind == "mp4":
            self._writer.close()
        else:
            first, *rest = self._gif_frames
            duration = max(20, round(1000.0 / self.fps / 10) * 10)
            first.save(self._tmp, format="GIF", save_all=True, append_images=rest, duration=duration, loop=0)
            self._gif_frames = []
        self._atomic.__exit__(None, None, None)
        return self.path

    def discard(self) -> None:
        with contextlib.suppress(Exception):
            if self._writer is not None:
                self._writer.close()
        err = RuntimeError("preview aborted")
        self._atomic.__exit__(type(err), err, None)


def downscale(image: np.ndarray, width: int) -> np.ndarray:
    """A copy at `width` pixels wide (kept small for the contact sheet)."""
    from PIL import Image

    h, w = image.shape[:2]
    if w <= width:
        return image
    return np.asarray(Image.fromarray(image).resize((width, max(1, round(width * h / w))), Image.Resampling.LANCZOS))
