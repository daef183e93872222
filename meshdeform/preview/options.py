"""What a preview renders and how (`PreviewOptions`), what it wrote (`PreviewResult`), and the file names."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, fields, is_dataclass
from pathlib import Path
from typing import Any

from meshdeform.errors import ExportError

VIEWS = ("iso", "front", "side", "top")
COLORS = ("strain", "flat", "displacement")
VIDEOS = ("mp4", "gif")
FRAMINGS = ("main", "all")
PREVIEW_FOLDER = "preview"
CONTACT_SHEET_NAME = "contact_sheet.png"


@dataclass(frozen=True)
class PreviewOptions:
    """What to render and how.

    every: save every Nth frame as PNG, counted from the sequence's first frame F (a run's rest pose at
        its start frame): frames F, F + N, F + 2N, ...; `frames` (scene frame numbers, as the result's
        files number them, from 0) overrides it. The video always has every frame.
    size: image (width, height) in pixels. view: iso | front | side | top (with `up_axis`).
    color: strain | flat | displacement. wireframe: draw polygon edges over the surface.
    highlight_pins / highlight_tears: mark pinned vertices / boundary edges not in the rest mesh.
    background: any colour name or hex string. video: "mp4", "gif" or None.
    contact_sheet: a grid of the saved frames labelled with their numbers.
    pngs: write the per-frame PNG files (off: only the contact sheet and video).
    fps: video frame rate (default: the sequence's). label: frame number in each image.
    anti_aliasing: 4x MSAA (most of the render cost with software OpenGL: docs/performance.md).
    sheet_columns: contact sheet columns (default about square); sheet_tile_width: tile width in px.
    clim: fixed colour range (default: from every frame of the sequence, the same in every image: strain
        from 1, no stretch, to the largest stretch of any frame; displacement from 0 to the largest).
    colliders: draw the scene's colliders, when the previewer is given them (grey solids, planes as a
        floor under the cloth; `meshdeform.preview.colliders`).
    framing: what the fixed camera frames over the sequence: "main", the main pieces of a torn mesh (the
        largest piece and any at least half its size: pieces that fall away are left to leave the view;
        `meshdeform.preview.framing`), or "all", every vertex of every frame.
    """

    every: int = 1
    frames: tuple[int, ...] | None = None
    size: tuple[int, int] = (800, 600)
    view: str = "iso"
    color: str = "strain"
    wireframe: bool = False
    highlight_pins: bool = True
    highlight_tears: bool = False
    background: str = "white"
    video: str | None = None
    contact_sheet: bool = False
    pngs: bool = True
    fps: float | None = None
    up_axis: str = "y"
    label: bool = True
    anti_aliasing: bool = True
    flat_color: str = "#a9bcd6"
    sheet_columns: int | None = None
    sheet_tile_width: int = 320
    clim: tuple[float, float] | None = None
    colliders: bool = True
    framing: str = "main"

    def __post_init__(self) -> None:
        def bad(what: str) -> ExportError:
            return ExportError(f"preview: {what}")

        if int(self.every) < 1:
            raise bad(f"every must be at least 1, not {self.every!r}")
        if self.frames is not None:
            frames = tuple(int(f) for f in self.frames)
            if any(f < 0 for f in frames):
                raise bad("frame numbers are scene frames, from 0")
            object.__setattr__(self, "frames", frames)
        size = tuple(int(s) for s in self.size)
        if len(size) != 2 or min(size) < 16 or max(size) > 8192:
            raise bad(f"size must be (width, height) between 16 and 8192 pixels, not {self.size!r}")
        object.__setattr__(self, "size", size)
        if self.view not in VIEWS:
            raise bad(f"view must be one of {', '.join(VIEWS)}, not {self.view!r}")
        if self.color not in COLORS:
            raise bad(f"color must be one of {', '.join(COLORS)}, not {self.color!r}")
        video = None if self.video in (None, "", "none") else str(self.video).lower()
        if video is not None and video not in VIDEOS:
            raise bad(f"video must be one of {', '.join(VIDEOS)} or none, not {self.video!r}")
        object.__setattr__(self, "video", video)
        if self.up_axis not in ("y", "z"):
            raise bad(f"up_axis must be y or z, not {self.up_axis!r}")
        if self.fps is not None and not float(self.fps) > 0:
            raise bad(f"fps must be positive, not {self.fps!r}")
        if int(self.sheet_tile_width) < 16:
            raise bad("sheet_tile_width must be at least 16 pixels")
        if self.sheet_columns is not None and int(self.sheet_columns) < 1:
            raise bad("sheet_columns must be at least 1")
        if self.framing not in FRAMINGS:
            raise bad(f"framing must be one of {', '.join(FRAMINGS)}, not {self.framing!r}")
        if not isinstance(self.colliders, bool):
            raise bad(f"colliders must be true or false, not {self.colliders!r}")
        if self.clim is not None:
            lo, hi = (float(c) for c in self.clim)
            if not hi > lo:
                raise bad(f"clim must be (low, high) with high > low, not {self.clim!r}")
            object.__setattr__(self, "clim", (lo, hi))

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any] | PreviewOptions | Any | None) -> PreviewOptions:
        """Options from a recipe's `[output] preview` table (or a pydantic model, or options)."""
        if data is None or data is True:
            return cls()
        if isinstance(data, PreviewOptions):
            return data
        if hasattr(data, "model_dump"):
            data = data.model_dump(exclude_none=True)
        elif is_dataclass(data) and not isinstance(data, type):
            data = {k: v for k, v in asdict(data).items() if v is not None}
        if not isinstance(data, Mapping):
            raise ExportError(f"preview: options must be a table, not {type(data).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ExportError(f"preview: unknown option(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}")
        values = dict(data)
        for key in ("frames", "size", "clim"):
            if values.get(key) is not None:
                values[key] = tuple(values[key])
        return cls(**values)

    def is_png_frame(self, number: int, first: int) -> bool:
        """Is frame `number` of a sequence whose first frame is `first` saved as PNG (and put on the
        contact sheet)?"""
        if self.frames is not None:
            return number in self.frames
        return (number - first) % self.every == 0

    def png_frames(self, numbers: Sequence[int]) -> list[int]:
        """Which of a sequence's frame numbers (increasing, the first one first) are saved as PNG (and go
        on the contact sheet)."""
        return [n for n in numbers if self.is_png_frame(n, numbers[0])]


@dataclass
class PreviewResult:
    """What `render_previews` wrote and how long it took."""

    images: list[Path] = field(default_factory=list)
    contact_sheet: Path | None = None
    video: Path | None = None
    frames_rendered: int = 0
    seconds: float = 0.0
    #: the colour range of every image (None: flat colour)
    clim: tuple[float, float] | None = None

    @property
    def files(self) -> list[Path]:
        out = list(self.images)
        out += [p for p in (self.contact_sheet, self.video) if p is not None]
        return out
