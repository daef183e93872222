"""What is drawn over a rendered view, with Pillow: the frame label and the colour bar.

The renderer draws only the scene (`render.FrameRenderer`); the label ("frame 12") and the colour bar are
drawn here, at font sizes that stay legible at the image's size, the bar in the colour map's own colours
(the same 256-colour table the renderer colours the mesh with: `LUT_COLORS`), its two ends labelled with
the range (the bottom end is the colour of the range's low end, the top the high end's). PNGs and video
frames carry both (`Overlay.decorate`); the contact sheet crops the bare view (`Overlay.content`), labels
each tile above it and draws one bar for the whole sheet (`media.contact_sheet`).

Sizes are pixels; a colour range `clim` is (low, high) in the scalars' units (stretch ratio, metres).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from meshdeform.preview.options import PreviewOptions

#: the colour map of each colouring: strain from 1 (no stretch, pale) to the largest stretch (dark red)
COLORMAPS = {"strain": "Reds", "displacement": "viridis"}
#: the colour bar's title of each colouring
TITLES = {"strain": "stretch ratio", "displacement": "displacement"}
#: colours in the lookup table (as VTK's, which the renderer is given)
LUT_COLORS = 256


def colormap(color: str) -> Any:
    """The matplotlib colour map of a colouring, resampled to the renderer's `LUT_COLORS` colours."""
    import matplotlib

    return matplotlib.colormaps[COLORMAPS[color]].resampled(LUT_COLORS)


def map_colors(color: str, values: np.ndarray, clim: tuple[float, float]) -> np.ndarray:
    """(N, 3) uint8 colours of scalar `values` (N,) in the range `clim`, clamped to its ends."""
    lo, hi = clim
    t = np.clip((np.asarray(values, dtype=np.float64) - lo) / (hi - lo), 0.0, 1.0)
    rgba = np.asarray(colormap(color)(t))
    return np.round(rgba[..., :3] * 255).astype(np.uint8)


@functools.lru_cache(maxsize=32)
def font(size: int) -> Any:
    """Pillow's bundled sans-serif font at `size` pixels (a FreeType font: no system fonts needed)."""
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: one small bitmap font
        return ImageFont.load_default()


def text_size(text: str, size: int) -> tuple[int, int]:
    """(width, height) in pixels of `text` drawn at `size`, from the pen position to the ink's far corner."""
    _, _, right, bottom = font(size).getbbox(text)
    return int(right), int(bottom)


def text_rgb(background: str) -> tuple[int, int, int]:
    """Black on a light background, white on a dark one."""
    import pyvista as pv

    rgb = np.asarray(pv.Color(background).float_rgb)
    return (0, 0, 0) if float(rgb @ np.array([0.299, 0.587, 0.114])) > 0.5 else (255, 255, 255)


def background_rgb(background: str) -> tuple[int, int, int]:
    import pyvista as pv

    r, g, b = pv.Color(background).int_rgb
    return int(r), int(g), int(b)


def label_decimals(clim: tuple[float, float]) -> int:
    """Decimals that tell the range's ends apart: three significant digits of its span, 0 to 6."""
    span = clim[1] - clim[0]
    if not span > 0:
        return 3
    return min(6, max(0, 2 - math.floor(math.log10(span) + 1e-9)))


def nice_step(span: float, intervals: int = 4) -> float:
    """The smallest 1, 2, 2.5 or 5 times a power of ten that cuts `span` into at most `intervals` steps."""
    raw = span / max(intervals, 1)
    exp = math.floor(math.log10(raw))
    for step in (1.0, 2.0, 2.5, 5.0, 10.0):
        if step * 10.0**exp >= raw * (1 - 1e-9):
            return step * 10.0**exp
    return 10.0 ** (exp + 1)


@dataclass(frozen=True)
class ColorBar:
    """A vertical colour bar with its title, its two ends labelled and round values between them.

    color: strain | displacement; clim: (low, high); font_size: text height in pixels; bar_width: the
    colour strip's width; text / fill: RGB of the text and the panel behind it.
    """

    color: str
    clim: tuple[float, float]
    font_size: int
    bar_width: int
    text: tuple[int, int, int] = (0, 0, 0)
    fill: tuple[int, int, int] = (255, 255, 255)

    @property
    def margin(self) -> int:
        return max(4, self.font_size // 2)

    @property
    def gap(self) -> int:
        """Between the strip and its labels (tick marks in it)."""
        return max(4, self.font_size // 3)

    def format(self, value: float, step: float | None = None) -> str:
        """A label: the range's ends with `label_decimals`, a round value between them (`step` apart) with
        just the decimals of the step."""
        decimals = label_decimals(self.clim)
        if step is not None:
            decimals = min(decimals, max(0, -math.floor(math.log10(step) + 1e-9)))
            if abs(round(step * 10**decimals) - step * 10**decimals) > 1e-6:  # 2.5 x 10^k
                decimals += 1
        return f"{value:.{decimals}f}"

    @property
    def title(self) -> str:
        return TITLES[self.color]

    def width(self) -> int:
        """The panel's width: the title or the strip and its widest label, with margins."""
        lo, hi = self.clim
        labels = max(text_size(self.format(v), self.font_size)[0] for v in (lo, hi, (lo + hi) / 2))
        title = text_size(self.title, self.font_size)[0]
        return 2 * self.margin + max(title, self.bar_width + self.gap + labels)

    def ticks(self, height: int) -> list[tuple[float, int]]:
        """(value, pixel row from the strip's top) of the labelled values along a strip `height` tall: both
        ends, and the round values between them at least 2 text heights away from every other."""
        lo, hi = self.clim
        row = lambda v: round((hi - v) / (hi - lo) * (height - 1))  # noqa: E731
        ticks = [(hi, 0), (lo, height - 1)]
        step = nice_step(hi - lo)
        value = math.floor(lo / step + 1) * step
        room = 2.0 * self.font_size
        while value < hi - 1e-9 * step:
            r = row(value)
            if all(abs(r - other) >= room for _, other in ticks):
                ticks.append((value, r))
            value += step
        return sorted(ticks, key=lambda t: t[1])

    def strip(self, height: int) -> np.ndarray:
        """(height, bar_width, 3) uint8: the colour map from the high end (top row) to the low end (bottom)."""
        lo, hi = self.clim
        values = hi - np.linspace(0.0, 1.0, max(height, 2))[:height] * (hi - lo)
        rows = map_colors(self.color, values, self.clim)
        return np.repeat(rows[:, None, :], self.bar_width, axis=1)

    def draw(self, image: Any, left: int, top: int, bottom: int) -> tuple[int, int, int, int]:
        """Draw the panel on a Pillow RGB `image`: its left edge at `left`, the title's top at `top`, the
        strip down to row `bottom`. Returns the strip's box (left, top, right, bottom), both ends included."""
        from PIL import Image, ImageDraw

        draw = ImageDraw.Draw(image)
        size, margin = self.font_size, self.margin
        f = font(size)
        _, title_h = text_size(self.title, size)
        x = left + margin
        strip_top = top + title_h + size  # half a text height of room for the top label
        strip_bottom = max(bottom, strip_top + 2 * size)
        height = strip_bottom - strip_top + 1
        ticks = self.ticks(height)
        step = nice_step(self.clim[1] - self.clim[0])
        ends = (0, len(ticks) - 1)
        labels = [(self.format(v, None if i in ends else step), strip_top + r) for i, (v, r) in enumerate(ticks)]
        right = x + self.bar_width + self.gap + max(text_size(t, size)[0] for t, _ in labels)
        right = max(right, x + text_size(self.title, size)[0])
        draw.rectangle([left, top - margin, right + margin, strip_bottom + size // 2 + margin], fill=self.fill)
        draw.text((x, top), self.title, fill=self.text, font=f)
        image.paste(Image.fromarray(self.strip(height)), (x, strip_top))
        draw.rectangle([x - 1, strip_top - 1, x + self.bar_width, strip_bottom + 1], outline=self.text)
        for text, y in labels:
            draw.line([x + self.bar_width, y, x + self.bar_width + self.gap - 2, y], fill=self.text)
            draw.text((x + self.bar_width + self.gap, y), text, fill=self.text, font=f, anchor="lm")
        return x, strip_top, x + self.bar_width - 1, strip_bottom


class Overlay:
    """The label and colour bar of every frame of one preview (`options`; `clim` None: no bar), and the
    room they take: `reserve` (fractions of the width on the right and of the height at the top) is kept
    free of the cloth by the camera (`camera.frame_camera`)."""

    def __init__(self, options: PreviewOptions, clim: tuple[float, float] | None) -> None:
        width, height = options.size
        self.options = options
        self.text = text_rgb(options.background)
        self.fill = background_rgb(options.background)
        self.label_size = max(11, round(height / 26))
        self.margin = max(4, self.label_size // 2)
        self.bar: ColorBar | None = None
        right = 0.0
        if clim is not None and options.color != "flat":
            self.bar = ColorBar(
                options.color,
                clim,
                font_size=max(11, round(height / 34)),
                bar_width=max(8, round(height / 28)),
                text=self.text,
                fill=self.fill,
            )
            right = min(0.4, (self.bar.width() + self.margin) / width)
        top = (text_size("frame 0", self.label_size)[1] + 2 * self.margin) / height if options.label else 0.0
        self.reserve = (right, min(0.3, top))

    def content(self, image: np.ndarray) -> np.ndarray:
        """The bare view without the room kept for the label and the bar (H', W', 3)."""
        h, w = image.shape[:2]
        right, top = self.reserve
        return image[round(top * h) :, : w - round(right * w)]

    def decorate(self, image: np.ndarray, number: int) -> np.ndarray:
        """The rendered view (H, W, 3) with its label ("frame N", when `options.label`) and colour bar."""
        from PIL import Image, ImageDraw

        if self.bar is None and not self.options.label:
            return image
        canvas = Image.fromarray(np.ascontiguousarray(image))
        h, w = image.shape[:2]
        if self.options.label:
            draw = ImageDraw.Draw(canvas)
            text = f"frame {number}"
            tw, th = text_size(text, self.label_size)
            m = self.margin
            draw.rectangle([0, 0, tw + 2 * m, th + 2 * m - 1], fill=self.fill)
            draw.text((m, m), text, fill=self.text, font=font(self.label_size))
        if self.bar is not None:
            left = w - round(self.reserve[0] * w)
            self.bar.draw(canvas, left, round(0.14 * h), round(0.86 * h))
        return np.asarray(canvas)
