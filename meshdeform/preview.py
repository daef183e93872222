"""Headless previews of a deformed mesh sequence with PyVista: PNG frames, a contact sheet, GIF, MP4.

One reused off-screen Plotter renders every frame: the mesh's points, normals and scalars are
updated in place (no new window per frame). The camera is fixed for the whole sequence, framed
on the union of all frames' bounds from a chosen view (iso, front, side, top), and the colour
range is fixed for the sequence too, so nothing jumps between frames. That needs one pass over
the frames before rendering: `render_previews` takes the frames as a sequence (a (F, V, 3)
array, a list, or any lazy object with `__len__`/`__getitem__`, such as `open_result`'s
loader, which reads a result folder's files on demand).

Colouring: a flat material, per-vertex strain (the largest stretch ratio, current / rest length,
of the edges at a vertex; a diverging heat map centred on 1 with a colour bar: red stretched,
blue compressed) or the displacement from rest. Pinned vertices and torn edges (boundary edges
the rest mesh did not have) can be highlighted, with an optional wireframe overlay.

Files (inside `out_dir`): `preview/0001.png` ... (frame numbers, 4 digits), `preview/contact_sheet.png`,
`preview.mp4` / `preview.gif`. Every file is written atomically.
"""

from __future__ import annotations

import contextlib
import functools
import json
import math
import re
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field, fields, is_dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from meshdeform.arrays import isin_int, run_lengths
from meshdeform.atomic import atomic_path
from meshdeform.errors import ExportError, MeshLoadError
from meshdeform.export.base import frame_file_name
from meshdeform.mesh import Mesh
from meshdeform.strain import SegmentStretch

VIEWS = ("iso", "front", "side", "top")
COLORS = ("strain", "flat", "displacement")
VIDEOS = ("mp4", "gif")
PREVIEW_FOLDER = "preview"
CONTACT_SHEET_NAME = "contact_sheet.png"

#: a frame is either positions (V, 3) in the base mesh's layout or a Mesh (a changed topology)
FrameItem = np.ndarray | Mesh


@dataclass(frozen=True)
class PreviewOptions:
    """What to render and how.

    every: save every Nth frame as PNG (frames 1, 1 + N, 1 + 2N, ...); `frames` (frame numbers
        from 1) overrides it. The video always has every frame.
    size: image (width, height) in pixels. view: iso | front | side | top (with `up_axis`).
    color: strain | flat | displacement. wireframe: draw polygon edges over the surface.
    highlight_pins / highlight_tears: mark pinned vertices / boundary edges not in the rest mesh.
    background: any colour name or hex string. video: "mp4", "gif" or None.
    contact_sheet: a grid of the saved frames labelled with their numbers.
    pngs: write the per-frame PNG files (off: only the contact sheet and video).
    fps: video frame rate (default: the sequence's). label: frame number in each image.
    anti_aliasing: 4x MSAA (off renders about 3 to 4 times faster with software OpenGL).
    sheet_columns: contact sheet columns (default about square); sheet_tile_width: tile width in px.
    clim: fixed colour range (default: from the whole sequence).
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

    def __post_init__(self) -> None:
        def bad(what: str) -> ExportError:
            return ExportError(f"preview: {what}")

        if int(self.every) < 1:
            raise bad(f"every must be at least 1, not {self.every!r}")
        if self.frames is not None:
            frames = tuple(int(f) for f in self.frames)
            if any(f < 1 for f in frames):
                raise bad("frame numbers start at 1")
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

    def png_frames(self, numbers: Sequence[int]) -> list[int]:
        """Which of the available frame numbers are saved as PNG (and go on the contact sheet)."""
        if self.frames is not None:
            wanted = set(self.frames)
            return [n for n in numbers if n in wanted]
        return [n for n in numbers if (n - 1) % self.every == 0]


@dataclass
class PreviewResult:
    """What `render_previews` wrote and how long it took."""

    images: list[Path] = field(default_factory=list)
    contact_sheet: Path | None = None
    video: Path | None = None
    frames_rendered: int = 0
    seconds: float = 0.0

    @property
    def files(self) -> list[Path]:
        out = list(self.images)
        out += [p for p in (self.contact_sheet, self.video) if p is not None]
        return out


# ---------------------------------------------------------------------------------------------
# per-frame scalars


def _edge_keys(mesh: Mesh) -> np.ndarray:
    """Every polygon side and polyline segment as a key a * n + b (a < b), one per occurrence."""
    n = max(mesh.vertex_count, 1)
    a = [mesh.face_indices]
    b = [mesh.face_indices[mesh.corner_next]]
    if mesh.line_count:
        last = np.zeros(mesh.line_indices.shape[0], dtype=bool)
        sizes = np.diff(mesh.line_offsets)
        last[mesh.line_offsets[1:][sizes > 0] - 1] = True
        start = np.flatnonzero(~last)
        a.append(mesh.line_indices[start])
        b.append(mesh.line_indices[start + 1])
    ea = np.concatenate(a).astype(np.int64)
    eb = np.concatenate(b).astype(np.int64)
    lo, hi = np.minimum(ea, eb), np.maximum(ea, eb)
    keep = lo != hi
    return lo[keep] * n + hi[keep]


def boundary_edges(mesh: Mesh) -> np.ndarray:
    """Polygon edges used by exactly one polygon, (E, 2) sorted pairs."""
    if mesh.face_count == 0:
        return np.zeros((0, 2), dtype=np.int64)
    n = max(mesh.vertex_count, 1)
    a = mesh.face_indices.astype(np.int64)
    b = mesh.face_indices[mesh.corner_next].astype(np.int64)
    keys = np.sort(np.minimum(a, b) * n + np.maximum(a, b))
    starts, lengths = run_lengths(keys)
    single = keys[starts[lengths == 1]]
    return np.stack([single // n, single % n], axis=1)


class EdgeStrain(SegmentStretch):
    """Per-vertex stretch ratio: the largest current / rest length of the edges at each vertex.

    Edges are the mesh's polygon sides and polyline segments; rest lengths come from `rest`
    (V0, 3). For a torn mesh with extra vertices, only edges between original vertices count
    (the others, and vertices without edges, read 1.0).
    """

    def __init__(self, mesh: Mesh, rest: np.ndarray) -> None:
        n = max(mesh.vertex_count, 1)
        keys = np.sort(_edge_keys(mesh))
        if keys.size:
            starts, _ = run_lengths(keys)
            keys = keys[starts]
        a, b = keys // n, keys % n
        ok = (a < rest.shape[0]) & (b < rest.shape[0])
        a, b = a[ok], b[ok]
        d = rest[b] - rest[a]
        length = np.sqrt(np.einsum("ij,ij->i", d, d))
        ok = length > 0
        super().__init__(a[ok], b[ok], length[ok], mesh.vertex_count)


class _Scalars:
    """The colouring values of a frame, for the current topology."""

    def __init__(
        self,
        color: str,
        rest: np.ndarray,
        strain_fn: Callable[[np.ndarray], np.ndarray] | None,
        strain_frames: Sequence[np.ndarray] | None,
    ) -> None:
        self.color = color
        self.rest = rest
        self._model_strain = strain_fn
        self._strain_frames = strain_frames
        self._edge_strain: EdgeStrain | None = None
        self._edge_mesh: Mesh | None = None

    def __call__(self, k: int, mesh: Mesh, positions: np.ndarray) -> np.ndarray | None:
        if self.color == "flat":
            return None
        if self.color == "displacement":
            out = np.zeros(positions.shape[0])
            m = min(positions.shape[0], self.rest.shape[0])
            d = positions[:m] - self.rest[:m]
            out[:m] = np.sqrt(np.einsum("ij,ij->i", d, d))
            return out
        if self._strain_frames is not None:
            values = np.asarray(self._strain_frames[k], dtype=np.float64)
            if values.shape == (positions.shape[0],):
                return values
        if self._model_strain is not None and positions.shape[0] == self.rest.shape[0]:
            return np.asarray(self._model_strain(positions), dtype=np.float64)
        if self._edge_mesh is not mesh:
            self._edge_strain = EdgeStrain(mesh, self.rest)
            self._edge_mesh = mesh
        assert self._edge_strain is not None
        return self._edge_strain(positions)


def _nice_ceiling(value: float) -> float:
    """Round up to a readable colour-bar end: 1, 1.5, 2, 2.5, 3, 4, 5, 6 or 8 times a power of ten."""
    if value <= 0:
        return 1.0
    exp = math.floor(math.log10(value))
    for step in (1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0):
        if step * 10.0**exp >= value * (1 - 1e-12):
            return step * 10.0**exp
    return 10.0 ** (exp + 1)


# ---------------------------------------------------------------------------------------------
# camera


def _view_basis(view: str, up_axis: str) -> tuple[np.ndarray, np.ndarray]:
    """(direction from the focal point to the camera, view-up) for a named view."""
    if up_axis == "y":
        table = {
            "front": ((0, 0, 1), (0, 1, 0)),
            "side": ((1, 0, 0), (0, 1, 0)),
            "top": ((0, 1, 0), (0, 0, -1)),
            "iso": ((1, 0.8, 1.4), (0, 1, 0)),
        }
    else:
        table = {
            "front": ((0, -1, 0), (0, 0, 1)),
            "side": ((1, 0, 0), (0, 0, 1)),
            "top": ((0, 0, 1), (0, 1, 0)),
            "iso": ((1, -1.4, 0.8), (0, 0, 1)),
        }
    d, u = (np.asarray(v, dtype=np.float64) for v in table[view])
    d /= np.linalg.norm(d)
    u = u - d * (u @ d)
    u /= np.linalg.norm(u)
    return d, u


@dataclass(frozen=True)
class CameraSetup:
    """A fixed perspective camera: position, focal point, view-up, view angle, clipping range, window shift."""

    position: tuple[float, float, float]
    focal_point: tuple[float, float, float]
    up: tuple[float, float, float]
    view_angle: float
    clipping: tuple[float, float]
    window_center: tuple[float, float]


def frame_camera(
    bounds: np.ndarray,
    view: str,
    size: tuple[int, int],
    up_axis: str = "y",
    view_angle: float = 30.0,
    margin: float = 0.1,
    reserve_right: float = 0.0,
    reserve_top: float = 0.0,
) -> CameraSetup:
    """A camera from `view` that shows the whole box `bounds` ((2, 3) min/max) tightly.

    The distance is the smallest at which every box corner is inside the view (perspective),
    less a margin; `reserve_right` (a fraction of the width) is kept free for a colour bar and
    `reserve_top` (a fraction of the height) for the frame label.
    """
    lo, hi = np.asarray(bounds[0], dtype=np.float64), np.asarray(bounds[1], dtype=np.float64)
    extent = np.maximum(hi - lo, 1e-9)
    center = (lo + hi) / 2
    d, u = _view_basis(view, up_axis)
    r = np.cross(u, d)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]) - center
    x, y, z = corners @ r, corners @ u, corners @ d
    tan_v = math.tan(math.radians(view_angle) / 2) * (1 - margin) * (1 - reserve_top)
    tan_h = math.tan(math.radians(view_angle) / 2) * size[0] / size[1] * (1 - margin) * (1 - reserve_right)
    distance = float(max(np.max(z + np.abs(x) / tan_h), np.max(z + np.abs(y) / tan_v), 1e-6))
    radius = float(np.linalg.norm(extent)) / 2
    near = max(distance - radius * 1.05, distance * 1e-3)
    far = distance + radius * 1.05
    position = center + d * distance
    return CameraSetup(
        position=tuple(position.tolist()),
        focal_point=tuple(center.tolist()),
        up=tuple(u.tolist()),
        view_angle=view_angle,
        clipping=(near, far),
        window_center=(reserve_right, reserve_top),
    )


# ---------------------------------------------------------------------------------------------
# the renderer


def _label_format(clim: tuple[float, float] | None, labels: int) -> str:
    """A printf format with just enough decimals to tell the colour-bar labels apart."""
    if clim is None:
        return "%.3g"
    step = (clim[1] - clim[0]) / max(labels - 1, 1)
    if step <= 0:
        return "%.3g"
    decimals = max(0, math.ceil(-math.log10(step) - 1e-9))
    while decimals < 6 and abs(step * 10**decimals - round(step * 10**decimals)) > 1e-6 * 10**decimals * step:
        decimals += 1
    return f"%.{decimals}f"


def _text_color(background: str) -> str:
    import pyvista as pv

    rgb = np.asarray(pv.Color(background).float_rgb)
    return "black" if float(rgb @ np.array([0.299, 0.587, 0.114])) > 0.5 else "white"


class FrameRenderer:
    """One off-screen Plotter reused for every frame; `render` returns an (H, W, 3) uint8 image."""

    def __init__(
        self,
        mesh: Mesh,
        options: PreviewOptions,
        bounds: np.ndarray,
        clim: tuple[float, float] | None,
        pinned: np.ndarray | Sequence[int] | None = None,
    ) -> None:
        import pyvista as pv
        from vtkmodules.vtkCommonCore import vtkObject

        from meshdeform.export.vtk import polydata_from_mesh

        self._warnings = vtkObject.GetGlobalWarningDisplay()
        vtkObject.GlobalWarningDisplayOff()  # no "bad X server connection" noise when headless
        self.options = options
        self.rest_mesh = mesh
        self._pinned_rest = _as_pinned_mask(pinned, mesh.vertex_count)
        self._pv = pv
        self._polydata_from_mesh = polydata_from_mesh
        # a fresh theme (not the user's global one) so images are reproducible; MSAA is the only
        # anti-aliasing that works with EGL/OSMesa, and it is most of the cost with software GL
        theme = pv.themes.Theme()
        theme.multi_samples = 4 if options.anti_aliasing else 0
        theme.anti_aliasing = "msaa" if options.anti_aliasing else None
        self.plotter = pv.Plotter(off_screen=True, window_size=list(options.size), lighting="light_kit", theme=theme)
        p = self.plotter
        try:
            p.set_background(options.background)
            text_color = _text_color(options.background)
            pv.Color(options.flat_color)
        except ValueError as exc:
            p.close()
            vtkObject.SetGlobalWarningDisplay(self._warnings)
            raise ExportError(f"preview: unknown colour ({str(exc).splitlines()[0]})") from exc
        self.poly = pv.wrap(polydata_from_mesh(mesh))
        self._mesh: Mesh = mesh
        self._set_arrays(mesh.positions, None)
        colored = options.color != "flat"
        lines_only = mesh.face_count == 0
        kwargs: dict[str, Any] = {
            "show_edges": options.wireframe,
            "edge_color": "#303030",
            "line_width": 1 if not lines_only else max(2, options.size[1] // 150),
            "render_lines_as_tubes": lines_only,
            "ambient": 0.4,
            "diffuse": 0.65,
            "specular": 0.1,
            "specular_power": 20,
            "smooth_shading": False,
            "interpolation": "gouraud",
        }
        if colored:
            title = "stretch ratio" if options.color == "strain" else "displacement"
            kwargs.update(
                scalars="scalars",
                cmap="coolwarm" if options.color == "strain" else "viridis",
                clim=list(clim) if clim is not None else None,
                scalar_bar_args={
                    "title": title,
                    "vertical": True,
                    "position_x": 0.86,
                    "position_y": 0.12,
                    "width": 0.07,
                    "height": 0.74,
                    "color": text_color,
                    "fmt": _label_format(clim, 5),
                    "n_labels": 5,
                    "title_font_size": max(10, options.size[1] // 40),
                    "label_font_size": max(9, options.size[1] // 50),
                },
            )
        else:
            kwargs.update(color=options.flat_color, show_scalar_bar=False)
        self.actor = p.add_mesh(self.poly, **kwargs)
        self.pins: Any = None
        if options.highlight_pins and self._pinned_rest is not None and self._pinned_rest.any():
            self.pins = pv.PolyData(np.asarray(mesh.positions[self._pinned_rest], dtype=np.float32))
            p.add_mesh(
                self.pins,
                color="#ffd400",
                point_size=max(6, options.size[1] // 70),
                render_points_as_spheres=True,
                show_scalar_bar=False,
            )
        self.tears: Any = None
        if options.highlight_tears:
            self._rest_boundary = self._keys(boundary_edges(mesh), mesh.vertex_count)
            self.tears = pv.PolyData()
            self._tear_actor = p.add_mesh(
                pv.PolyData(np.zeros((1, 3), dtype=np.float32)),
                color="#ff00e0",
                line_width=max(2, options.size[1] // 200),
                show_scalar_bar=False,
            )
            self._tear_actor.mapper.SetInputData(self.tears)
        self.label: Any = None
        if options.label:
            self.label = p.add_text(
                "", position="upper_left", font_size=max(8, options.size[1] // 60), color=text_color, name="label"
            )
        camera = frame_camera(
            bounds,
            options.view,
            options.size,
            options.up_axis,
            reserve_right=0.16 if colored else 0.0,
            reserve_top=0.07 if options.label else 0.0,
        )
        cam = p.camera
        cam.position = camera.position
        cam.focal_point = camera.focal_point
        cam.up = camera.up
        cam.view_angle = camera.view_angle
        cam.SetWindowCenter(*camera.window_center)
        cam.clipping_range = camera.clipping
        p.camera_set = True
        self.camera = camera

    @staticmethod
    def _keys(edges: np.ndarray, n: int) -> np.ndarray:
        return edges[:, 0] * max(n, 1) + edges[:, 1]

    def _set_arrays(self, positions: np.ndarray, scalars: np.ndarray | None) -> None:
        from meshdeform.geometry import vertex_normals

        poly = self.poly
        pts = np.asarray(positions, dtype=np.float32)
        if poly.n_points == pts.shape[0]:
            poly.points[:] = pts
            poly.GetPoints().Modified()
        else:
            poly.points = pts
        if self._mesh.face_count:
            normals = vertex_normals(self._mesh, positions).astype(np.float32)
            poly.point_data["Normals"] = normals
            poly.point_data.active_normals_name = "Normals"
        values = np.ones(pts.shape[0], dtype=np.float32) if scalars is None else scalars.astype(np.float32)
        poly.point_data["scalars"] = values
        poly.point_data.active_scalars_name = "scalars"
        poly.Modified()

    def _set_topology(self, mesh: Mesh, positions: np.ndarray) -> None:
        new = self._pv.wrap(self._polydata_from_mesh(mesh, positions))
        self.poly.copy_from(new, deep=False)
        self._mesh = mesh

    def render(
        self, positions: np.ndarray, number: int, scalars: np.ndarray | None = None, mesh: Mesh | None = None
    ) -> np.ndarray:
        """Update the scene in place to this frame and return the image."""
        if mesh is not None and mesh is not self._mesh:
            self._set_topology(mesh, positions)
        current = self._mesh
        self._set_arrays(positions, scalars)
        if self.pins is not None:
            mask = self._pinned_rest
            assert mask is not None
            m = min(mask.shape[0], positions.shape[0])
            self.pins.points = np.asarray(positions[:m][mask[:m]], dtype=np.float32)
            self.pins.Modified()
        if self.tears is not None:
            # torn: boundary edges now that were not boundary edges of the rest mesh (new vertices
            # from tearing are appended, so edges between original vertices keep their indices)
            edges = boundary_edges(current)
            rest_count = self.rest_mesh.vertex_count
            old = (edges < rest_count).all(axis=1)
            same = np.zeros(edges.shape[0], dtype=bool)
            same[old] = isin_int(self._keys(edges[old], rest_count), self._rest_boundary)
            torn = edges[~same]
            lines = np.hstack([np.full((torn.shape[0], 1), 2), torn]).ravel()
            self.tears.points = np.asarray(positions, dtype=np.float32)
            self.tears.lines = lines if torn.size else np.zeros(0, dtype=np.int64)
            self.tears.Modified()
        if self.label is not None:
            self.label.set_text("upper_left", f"frame {number}")
        self.plotter.render()  # pyvista renders by itself only before the first screenshot
        return np.asarray(self.plotter.screenshot(return_img=True))[..., :3].copy()

    def close(self) -> None:
        from vtkmodules.vtkCommonCore import vtkObject

        with contextlib.suppress(Exception):
            self.plotter.close()
        vtkObject.SetGlobalWarningDisplay(self._warnings)

    def __enter__(self) -> FrameRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# ---------------------------------------------------------------------------------------------
# image files


def _write_png(path: Path, image: np.ndarray) -> Path:
    from PIL import Image

    with atomic_path(path) as tmp:
        Image.fromarray(image).save(tmp, format="PNG")
    return path


def contact_sheet(
    images: Sequence[np.ndarray], numbers: Sequence[int], columns: int | None = None, tile_width: int = 320
) -> np.ndarray:
    """A grid of downscaled images, each labelled with its frame number: (rows * th, cols * tw, 3)."""
    from PIL import Image, ImageDraw, ImageFont

    n = len(images)
    if n == 0:
        raise ExportError("preview: no frames for the contact sheet")
    cols = int(columns) if columns else math.ceil(math.sqrt(n))
    cols = max(1, min(cols, n))
    rows = math.ceil(n / cols)
    h, w = images[0].shape[:2]
    tw = int(tile_width)
    th = max(1, round(tw * h / w))
    sheet = Image.new("RGB", (cols * tw, rows * th), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    try:
        font = ImageFont.load_default(size=max(10, th // 9))
    except TypeError:  # Pillow < 10.1
        font = ImageFont.load_default()
    for k, (image, number) in enumerate(zip(images, numbers, strict=True)):
        x, y = (k % cols) * tw, (k // cols) * th
        tile = Image.fromarray(np.asarray(image, dtype=np.uint8)).resize((tw, th), Image.Resampling.LANCZOS)
        sheet.paste(tile, (x, y))
        draw.rectangle([x, y, x + tw - 1, y + th - 1], outline=(160, 160, 160))
        text = str(number)  # bottom left, clear of the rendered frame label at the top
        box = draw.textbbox((0, 0), text, font=font)
        origin = (x + 6 - box[0], y + th - 6 - box[3])
        box = draw.textbbox(origin, text, font=font)
        draw.rectangle([box[0] - 3, box[1] - 3, box[2] + 3, box[3] + 3], fill=(0, 0, 0))
        draw.text(origin, text, fill=(255, 255, 255), font=font)
    return np.asarray(sheet)


class _VideoWriter:
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


# ---------------------------------------------------------------------------------------------
# the driver


def _positions_and_mesh(item: FrameItem, base: Mesh) -> tuple[np.ndarray, Mesh]:
    if isinstance(item, Mesh):
        return np.asarray(item.positions, dtype=np.float64), item
    positions = np.asarray(item, dtype=np.float64)
    if positions.shape != (base.vertex_count, 3):
        raise ExportError(
            f"preview: a frame has positions of shape {positions.shape}, expected ({base.vertex_count}, 3)"
        )
    return positions, base


def _as_pinned_mask(pinned: np.ndarray | Sequence[int] | None, n: int) -> np.ndarray | None:
    if pinned is None:
        return None
    arr = np.asarray(pinned)
    if arr.dtype == bool or (arr.dtype == np.uint8 and arr.shape == (n,)):
        mask = arr.astype(bool)
        if mask.shape != (n,):
            raise ExportError(f"preview: pinned mask has shape {mask.shape}, expected ({n},)")
        return mask
    mask = np.zeros(n, dtype=bool)
    idx = arr.astype(np.int64).ravel()
    if idx.size and (idx.min() < 0 or idx.max() >= n):
        raise ExportError(f"preview: pinned vertex index out of range 0..{n - 1}")
    mask[idx] = True
    return mask


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
    pinned_mask = _as_pinned_mask(pinned, mesh.vertex_count)
    strain_fn = strain if callable(strain) else None
    strain_frames = None if callable(strain) else strain
    scalars = _Scalars(options.color, rest, strain_fn, strain_frames)

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
        spread = _nice_ceiling(max(spread, 0.01))
        clim = (1.0 - spread, 1.0 + spread)
    elif clim is None and options.color == "displacement":
        clim = (0.0, _nice_ceiling(max(smax if np.isfinite(smax) else 0.0, 1e-6)))

    result = PreviewResult()
    tiles: list[np.ndarray] = []
    tile_numbers: list[int] = []
    video: _VideoWriter | None = None
    preview_dir = out_dir / PREVIEW_FOLDER
    frame_count = max(numbers)
    try:
        if options.video is not None:
            video = _VideoWriter(out_dir / f"preview.{options.video}", options.video, options.fps or fps)
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
                        result.images.append(_write_png(preview_dir / name, image))
                    if options.contact_sheet:
                        tiles.append(_downscale(image, options.sheet_tile_width))
                        tile_numbers.append(numbers[k])
        if options.contact_sheet:
            sheet = contact_sheet(tiles, tile_numbers, options.sheet_columns, options.sheet_tile_width)
            result.contact_sheet = _write_png(preview_dir / CONTACT_SHEET_NAME, sheet)
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


def _downscale(image: np.ndarray, width: int) -> np.ndarray:
    """A copy at `width` pixels wide (kept small for the contact sheet)."""
    from PIL import Image

    h, w = image.shape[:2]
    if w <= width:
        return image
    return np.asarray(Image.fromarray(image).resize((width, max(1, round(width * h / w))), Image.Resampling.LANCZOS))


# ---------------------------------------------------------------------------------------------
# result folders


_NUMBER = re.compile(r"(\d+)$")


def _numbered_files(folder: Path, suffixes: Sequence[str]) -> list[tuple[int, Path]]:
    found = []
    if not folder.is_dir():
        return found
    for path in folder.iterdir():
        if path.name.startswith(".") or path.suffix.lower() not in suffixes:
            continue
        match = _NUMBER.search(path.stem)
        if match:
            found.append((int(match.group(1)), path))
    return sorted(found)


class _FileFrames(Sequence[FrameItem]):
    """Lazily loaded per-frame OBJ/PLY files: positions when the topology is the base's, else a Mesh."""

    def __init__(self, paths: list[Path], base: Mesh) -> None:
        self.paths = paths
        self.base = base

    def __len__(self) -> int:
        return len(self.paths)

    def __getitem__(self, k: int) -> FrameItem:  # type: ignore[override]
        from meshdeform.io import load

        frame = load(self.paths[k])
        same = (
            frame.vertex_count == self.base.vertex_count
            and np.array_equal(frame.face_offsets, self.base.face_offsets)
            and np.array_equal(frame.face_indices, self.base.face_indices)
        )
        return frame.positions if same else frame


@dataclass
class ResultSequence:
    """A result folder's frames, ready for `render_previews`."""

    mesh: Mesh
    frames: Sequence[FrameItem]
    frame_numbers: list[int]
    fps: float
    rest_positions: np.ndarray
    pinned: np.ndarray | None
    strain: Sequence[np.ndarray] | None
    source: str
    report: dict[str, Any]


def _read_report(result_dir: Path) -> dict[str, Any]:
    path = result_dir / "report.json"
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise MeshLoadError(f"{path}: cannot read the report: {exc}") from exc
    return data if isinstance(data, dict) else {}


def _report_fps(report: Mapping[str, Any]) -> float | None:
    for value in (report.get("fps"), (report.get("settings") or {}).get("fps")):
        if isinstance(value, int | float) and value > 0:
            return float(value)
    return None


def _report_pinned(report: Mapping[str, Any], n: int) -> np.ndarray | None:
    for key in ("pinned", "pinned_indices"):
        value = report.get(key)
        if isinstance(value, list):
            return _as_pinned_mask(np.asarray(value, dtype=np.int64), n)
    return None


def _vtp_pinned(result_dir: Path, n: int) -> np.ndarray | None:
    files = _numbered_files(result_dir / "vtk", (".vtp",))
    if not files:
        return None
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkIOXML import vtkXMLPolyDataReader

    reader = vtkXMLPolyDataReader()
    reader.SetFileName(str(files[0][1]))
    reader.Update()
    array = reader.GetOutput().GetPointData().GetArray("pinned")
    if array is None:
        return None
    mask = vtk_to_numpy(array).astype(bool)
    return mask if mask.shape == (n,) else None


def _usd_frames(path: Path) -> tuple[Mesh, np.ndarray, list[int], float]:
    from meshdeform.export.usd import start_usd

    start_usd()
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(path))
    if stage is None:
        raise MeshLoadError(f"{path}: cannot open the USD stage")
    prim = next((p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)), None)
    if prim is None:
        raise MeshLoadError(f"{path}: no UsdGeom.Mesh in the stage")
    geom = UsdGeom.Mesh(prim)
    counts = np.asarray(geom.GetFaceVertexCountsAttr().Get(), dtype=np.int64)
    indices = np.asarray(geom.GetFaceVertexIndicesAttr().Get(), dtype=np.int64)
    points_attr = geom.GetPointsAttr()
    codes = points_attr.GetTimeSamples() or [Usd.TimeCode.Default()]
    z_up = UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    positions = []
    for code in codes:
        p = np.asarray(points_attr.Get(code), dtype=np.float64)
        if z_up:  # back from (x, -z, y) to the input's Y-up coordinates
            p = np.stack([p[:, 0], p[:, 2], -p[:, 1]], axis=1)
        positions.append(p)
    if len({p.shape for p in positions}) != 1:
        raise MeshLoadError(f"{path}: the topology changes over time; preview the frames/ files instead")
    offsets = np.concatenate([[0], np.cumsum(counts)])
    start = stage.GetStartTimeCode() if stage.HasAuthoredTimeCodeRange() else (codes[0] if codes else 1)
    numbers = [round(float(c) - float(start)) + 1 for c in codes] if points_attr.GetTimeSamples() else [1]
    mesh = Mesh(positions=positions[0], face_indices=indices, face_offsets=offsets, source=path)
    return mesh, np.stack(positions), numbers, float(stage.GetTimeCodesPerSecond() or 24.0)


@dataclass
class _Found:
    base: Mesh
    frames: Sequence[FrameItem]
    numbers: list[int]
    source: str
    fps: float | None = None
    pinned: np.ndarray | None = None
    strain: Sequence[np.ndarray] | None = None


def _prefer_input(base: Mesh, input_mesh: Mesh | None) -> Mesh:
    """The input mesh (rest pose, UVs, groups) when it matches the frames' vertex count."""
    return input_mesh if input_mesh is not None and input_mesh.vertex_count == base.vertex_count else base


def _from_frame_files(root: Path, input_mesh: Mesh | None) -> _Found | None:
    from meshdeform.io import load

    files = _numbered_files(root / "frames", (".obj", ".ply"))
    if not files:
        return None
    suffix = files[0][1].suffix.lower()
    files = [(n, p) for n, p in files if p.suffix.lower() == suffix]
    base = _prefer_input(load(files[0][1]), input_mesh)
    return _Found(base, _FileFrames([p for _, p in files], base), [n for n, _ in files], f"frames/*{suffix}")


def _from_npz(root: Path, input_mesh: Mesh | None) -> _Found | None:
    path = root / "positions.npz"
    if not path.is_file():
        return None
    with np.load(path) as data:
        positions = np.asarray(data["positions"], dtype=np.float64)
        numbers = [int(n) for n in data["frames"]] if "frames" in data else list(range(1, len(positions) + 1))
        rest = np.asarray(data["rest_positions"]) if "rest_positions" in data else positions[0]
        base = Mesh(positions=rest, face_indices=data["face_indices"], face_offsets=data["face_offsets"])
        if "line_indices" in data:
            base = replace(base, line_indices=data["line_indices"], line_offsets=data["line_offsets"])
        found = _Found(_prefer_input(base, input_mesh), list(positions), numbers, path.name)
        found.fps = float(data["fps"]) if "fps" in data else None
        if "point_pinned" in data:
            found.pinned = np.asarray(data["point_pinned"][0]).astype(bool)
        if "point_strain" in data:
            found.strain = list(np.asarray(data["point_strain"], dtype=np.float64))
    return found


def _from_usd(root: Path, input_mesh: Mesh | None) -> _Found | None:
    usd = next((root / n for n in ("scene.usdc", "scene.usda", "scene.usd") if (root / n).is_file()), None)
    if usd is None:
        return None
    base, stacked, numbers, fps = _usd_frames(usd)
    return _Found(_prefer_input(base, input_mesh), list(stacked), numbers, usd.name, fps=fps)


def _read_vtp(path: Path) -> Mesh:
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkIOXML import vtkXMLPolyDataReader

    reader = vtkXMLPolyDataReader()
    reader.SetFileName(str(path))
    reader.Update()
    poly = reader.GetOutput()
    if poly is None or poly.GetPoints() is None:
        raise MeshLoadError(f"{path}: cannot read the VTK PolyData file")
    polys, lines = poly.GetPolys(), poly.GetLines()
    return Mesh(
        positions=vtk_to_numpy(poly.GetPoints().GetData()).astype(np.float64),
        face_indices=vtk_to_numpy(polys.GetConnectivityArray()).astype(np.int64),
        face_offsets=vtk_to_numpy(polys.GetOffsetsArray()).astype(np.int64),
        line_indices=vtk_to_numpy(lines.GetConnectivityArray()).astype(np.int64),
        line_offsets=vtk_to_numpy(lines.GetOffsetsArray()).astype(np.int64),
        source=path,
    )


class _VtpFrames(Sequence[FrameItem]):
    """Lazily read `vtk/frame_*.vtp` files: positions when the topology is the base's, else a Mesh."""

    def __init__(self, paths: list[Path], base: Mesh) -> None:
        self.paths = paths
        self.base = base

    def __len__(self) -> int:
        return len(self.paths)

    def __getitem__(self, k: int) -> FrameItem:  # type: ignore[override]
        frame = _read_vtp(self.paths[k])
        same = frame.vertex_count == self.base.vertex_count and np.array_equal(
            frame.face_indices, self.base.face_indices
        )
        return frame.positions if same else frame


def _from_vtp(root: Path, input_mesh: Mesh | None) -> _Found | None:
    files = _numbered_files(root / "vtk", (".vtp",))
    if not files:
        return None
    first = _read_vtp(files[0][1])
    base = first
    if input_mesh is not None and np.array_equal(input_mesh.face_indices, first.face_indices):
        base = input_mesh
    return _Found(base, _VtpFrames([p for _, p in files], base), [n for n, _ in files], "vtk/*.vtp")


def _from_y_up(points: np.ndarray, up_axis: str) -> np.ndarray:
    """Undo `convert_up_axis`: Blender's (x, -z, y) back to the input's (x, y, z)."""
    if up_axis == "y":
        return points
    return np.stack([points[..., 0], points[..., 2], -points[..., 1]], axis=-1)


def _from_point_cache(root: Path, input_mesh: Mesh | None, up_axis: str | None) -> _Found | None:
    from meshdeform.export.mdd import read_mdd
    from meshdeform.export.pc2 import read_pc2

    pc2, mdd = root / "cache.pc2", root / "cache.mdd"
    if not (pc2.is_file() or mdd.is_file()):
        return None
    if input_mesh is None:
        raise MeshLoadError(
            f"{root}: point caches hold no topology, and the input mesh (report.json 'input') is missing"
        )
    fps = None
    if pc2.is_file():
        positions, _, _ = read_pc2(pc2)
        source = pc2.name
    else:
        positions, times = read_mdd(mdd)
        source = mdd.name
        if times.size >= 2 and times[1] > times[0]:
            fps = float(1.0 / (times[1] - times[0]))
    if positions.shape[1:] != (input_mesh.vertex_count, 3):
        raise MeshLoadError(
            f"{root / source}: {positions.shape[1]} points, the input mesh has {input_mesh.vertex_count}"
        )
    if up_axis is None:  # the first frame is close to rest in the convention it was written in
        rest = input_mesh.positions
        error_y = np.abs(positions[0] - rest).mean()
        error_z = np.abs(_from_y_up(positions[0], "z") - rest).mean()
        up_axis = "z" if error_z < error_y else "y"
    frames = list(_from_y_up(positions.astype(np.float64), up_axis))
    return _Found(input_mesh, frames, list(range(1, len(frames) + 1)), source, fps=fps)


def open_result(result_dir: str | Path, mesh: Mesh | None = None, up_axis: str | None = None) -> ResultSequence:
    """Find a result folder's frames, in this order: `frames/*.obj|ply`, `positions.npz`,
    `scene.usdc|usda`, `vtk/*.vtp`, `cache.pc2`, `cache.mdd`.

    The rest pose is `mesh` if given, else the input mesh named by `report.json` (key `input`)
    when it still exists, else the first frame. Point caches need that mesh for the topology;
    their axis convention is `up_axis`, the report's `up_axis`, or whichever makes the first
    frame closest to the rest pose. Pinned vertices come from the report (`pinned`: vertex
    indices), the npz (`point_pinned`) or the first VTK frame (`pinned` array); fps from the
    report, the npz, the USD stage or the MDD times. Raises MeshLoadError when nothing is found.
    """
    from meshdeform.io import load

    root = Path(result_dir)
    if not root.is_dir():
        raise MeshLoadError(f"{root}: no such result folder")
    report = _read_report(root)
    input_mesh = mesh
    if input_mesh is None and isinstance(report.get("input"), str):
        candidate = Path(report["input"])
        if not candidate.is_absolute() and not candidate.exists():
            candidate = root / candidate
        if candidate.is_file():
            with contextlib.suppress(MeshLoadError):
                input_mesh = load(candidate)
    if up_axis is None and report.get("up_axis") in ("y", "z"):
        up_axis = str(report["up_axis"])
    found = (
        _from_frame_files(root, input_mesh)
        or _from_npz(root, input_mesh)
        or _from_usd(root, input_mesh)
        or _from_vtp(root, input_mesh)
        or _from_point_cache(root, input_mesh, up_axis)
    )
    if found is None:
        raise MeshLoadError(
            f"{root}: no frames found (looked for frames/*.obj|ply, positions.npz, scene.usdc, vtk/*.vtp, "
            "cache.pc2, cache.mdd)"
        )
    base = found.base
    pinned = found.pinned
    if pinned is None:
        pinned = _report_pinned(report, base.vertex_count)
    if pinned is None:
        pinned = _vtp_pinned(root, base.vertex_count)
    return ResultSequence(
        mesh=base,
        frames=found.frames,
        frame_numbers=found.numbers,
        fps=_report_fps(report) or found.fps or 24.0,
        rest_positions=np.asarray(base.positions, dtype=np.float64),
        pinned=pinned,
        strain=found.strain,
        source=found.source,
        report=report,
    )


def render_result(
    result_dir: str | Path,
    options: PreviewOptions | Mapping[str, Any] | None = None,
    *,
    mesh: Mesh | None = None,
    model: Any = None,
    out_dir: str | Path | None = None,
    up_axis: str | None = None,
) -> tuple[ResultSequence, PreviewResult]:
    """Render previews of a result folder's frames (see `open_result`) into it (or `out_dir`).

    With the SpringModel of the run (`model`), pinned vertices and strain come from it exactly
    (strain: the largest stretch of each vertex's structural springs, as in the VTK output).
    `up_axis` is the convention point caches were written in (default: detected).
    Returns the sequence read and what was rendered.
    """
    seq = open_result(result_dir, mesh=mesh, up_axis=up_axis)
    pinned = seq.pinned
    strain: Any = seq.strain
    if model is not None:
        vertex_map = np.asarray(model.vertex_map)
        if vertex_map.shape == (seq.mesh.vertex_count,):
            with contextlib.suppress(AttributeError):
                pinned = np.asarray(model.pinned)[vertex_map]
            if strain is None:
                strain = _welded_strain(model, vertex_map)
    result = render_previews(
        seq.mesh,
        seq.frames,
        out_dir if out_dir is not None else result_dir,
        options,
        frame_numbers=seq.frame_numbers,
        fps=seq.fps,
        rest_positions=seq.rest_positions,
        pinned=pinned,
        strain=strain,
    )
    return seq, result


def render_result_previews(
    result_dir: str | Path,
    options: PreviewOptions | Mapping[str, Any] | None = None,
    *,
    mesh: Mesh | None = None,
    model: Any = None,
    out_dir: str | Path | None = None,
    up_axis: str | None = None,
) -> list[Path]:
    """`render_result`, returning only the files written."""
    _, result = render_result(result_dir, options, mesh=mesh, model=model, out_dir=out_dir, up_axis=up_axis)
    return result.files


def _welded_strain(model: Any, vertex_map: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """Input-layout strain from the model's structural springs (positions gathered to welded)."""
    from meshdeform.strain import VertexStrain

    vertex_strain = VertexStrain(model)
    welded_count = int(model.vertex_count)

    def strain(positions: np.ndarray) -> np.ndarray:
        welded = np.zeros((welded_count, 3))
        welded[vertex_map] = positions
        return vertex_strain(welded)[vertex_map]

    return strain
