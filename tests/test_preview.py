"""Previews on real pixels: rendered offscreen, checked as images (coverage, motion, colour, golden)."""

from __future__ import annotations

import os
from pathlib import Path

import pyvista as pv

pv.OFF_SCREEN = True

import imageio.v2 as imageio_v2  # noqa: E402
import imageio.v3 as iio  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from factories import grid_pins, grid_sheet, slit_grid  # noqa: E402

from meshdeform.errors import ExportError  # noqa: E402
from meshdeform.mesh import Mesh  # noqa: E402
from meshdeform.preview import (  # noqa: E402
    EdgeStrain,
    FrameRenderer,
    PreviewOptions,
    boundary_edges,
    contact_sheet,
    frame_camera,
    render_previews,
)

GOLDEN = Path(__file__).parent / "golden"
FRAMES = 12


def hanging_cloth(n: int = 16, frames: int = FRAMES) -> tuple[Mesh, list[np.ndarray], np.ndarray]:
    """A sheet pinned along its top row that sags (stretching most next to the pins) and waves.

    With u the distance from the top, u -> u + s (2u - u^2) / 2: the vertical stretch is 1 + s
    at the pins and 1 at the bottom. A travelling wave in z makes every frame different.
    """
    mesh = grid_sheet(n)
    rest = mesh.positions
    pinned = np.flatnonzero(grid_pins(n, n, ["top"]))
    out = []
    for i in range(1, frames + 1):
        s = 0.4 * i / frames
        u = 1.0 - rest[:, 1]
        pos = rest.copy()
        pos[:, 1] = 1.0 - (u + s * (2 * u - u * u) / 2)
        pos[:, 2] = 0.12 * np.sin(3 * rest[:, 0] + 0.8 * i) * u
        out.append(pos)
    return mesh, out, pinned


def object_mask(image: np.ndarray, background: tuple[int, int, int] = (255, 255, 255)) -> np.ndarray:
    """Pixels that are not background, (H, W) bool."""
    return np.abs(image.astype(np.int16) - np.array(background, dtype=np.int16)).sum(axis=2) > 30


def render_one(mesh: Mesh, frames: list[np.ndarray], k: int, pinned=None, **options) -> np.ndarray:
    opts = PreviewOptions(**options)
    stack = np.stack(frames)
    bounds = np.stack([stack.min(axis=(0, 1)), stack.max(axis=(0, 1))])
    strain = EdgeStrain(mesh, mesh.positions)
    with FrameRenderer(mesh, opts, bounds, (1.0, 1.4), pinned) as renderer:
        scalars = strain(frames[k]) if opts.color == "strain" else None
        return renderer.overlay.decorate(renderer.render(frames[k], scalars), k + 1)


def verify_image_cache(image: np.ndarray, name: str, tolerance: float = 4.0) -> None:
    """Compare with tests/golden/<name>.png by mean absolute difference (0..255 scale).

    As pytest-pyvista's verify_image_cache: a missing golden image is written (and the test
    skipped) so it can be inspected and committed; set MESHDEFORM_RESET_GOLDEN=1 to rewrite.
    """
    path = GOLDEN / f"{name}.png"
    if not path.exists() or os.environ.get("MESHDEFORM_RESET_GOLDEN"):
        GOLDEN.mkdir(parents=True, exist_ok=True)
        iio.imwrite(path, image)
        pytest.skip(f"golden image {path.name} written; look at it and commit it")
    golden = iio.imread(path)[..., :3]
    assert golden.shape == image.shape, f"{name}: size {image.shape} != golden {golden.shape}"
    error = float(np.abs(golden.astype(np.float64) - image.astype(np.float64)).mean())
    assert error <= tolerance, f"{name}: mean abs difference {error:.2f} > {tolerance}"


@pytest.fixture(scope="module")
def cloth() -> tuple[Mesh, list[np.ndarray], np.ndarray]:
    return hanging_cloth()


# ---------------------------------------------------------------------------------------------
# pixels


def test_a_rendered_frame_is_not_blank_and_fits_the_window(cloth) -> None:
    mesh, frames, pinned = cloth
    image = render_one(mesh, frames, FRAMES - 1, pinned, size=(320, 240), view="front", label=False)
    assert image.shape == (240, 320, 3) and image.dtype == np.uint8
    mask = object_mask(image)
    mask[:, int(320 * 0.84) :] = False  # the colour bar
    assert 0.15 < mask.mean() < 0.8
    # framed on the bounds: the cloth does not touch the image border
    assert not mask[0].any() and not mask[-1].any() and not mask[:, 0].any()


def test_frames_of_a_moving_cloth_differ_and_the_camera_stays(cloth, tmp_path: Path) -> None:
    mesh, frames, pinned = cloth
    result = render_previews(
        mesh, frames, tmp_path, PreviewOptions(frames=(1, FRAMES), size=(320, 240), label=False), pinned=pinned
    )
    first, last = (iio.imread(p) for p in result.images)
    assert [p.name for p in result.images] == ["0001.png", f"{FRAMES:04d}.png"]
    assert np.abs(first.astype(int) - last.astype(int)).mean() > 3.0
    # the pinned top edge does not move, so with a fixed camera its pixels stay put
    rows_first = np.flatnonzero(object_mask(first)[:, :260].any(axis=1))
    rows_last = np.flatnonzero(object_mask(last)[:, :260].any(axis=1))
    assert abs(rows_first[0] - rows_last[0]) <= 2
    assert rows_last[-1] > rows_first[-1] + 5  # the cloth sagged


def test_strain_colouring_is_redder_next_to_the_pins(cloth) -> None:
    mesh, frames, _pinned = cloth
    image = render_one(mesh, frames, FRAMES - 1, None, size=(320, 240), view="front", label=False).astype(int)
    mask = object_mask(image)
    mask[:, int(320 * 0.7) :] = False  # the colour bar
    rows = np.flatnonzero(mask.any(axis=1))
    top, bottom = rows[0], rows[-1]
    third = (bottom - top) // 3
    # the colour map runs from near white to dark red: green falls against red as the stretch grows,
    # whatever the shading (which scales both)
    green_to_red = image[..., 1] / np.maximum(image[..., 0], 1)
    upper = green_to_red[top : top + third][mask[top : top + third]].mean()
    lower = green_to_red[bottom - third : bottom][mask[bottom - third : bottom]].mean()
    assert upper < lower - 0.2, (upper, lower)
    assert upper < 0.6  # clearly red, not grey


def test_pins_are_highlighted(cloth) -> None:
    mesh, frames, pinned = cloth
    kwargs = {"size": (320, 240), "view": "front", "label": False, "color": "flat"}
    with_pins = render_one(mesh, frames, 0, pinned, **kwargs).astype(int)
    without = render_one(mesh, frames, 0, pinned, highlight_pins=False, **kwargs).astype(int)
    yellow = (with_pins[..., 0] > 180) & (with_pins[..., 1] > 150) & (with_pins[..., 2] < 90)
    assert yellow.sum() > 50
    rows = np.flatnonzero(yellow.any(axis=1))
    assert rows.max() < 240 * 0.35  # along the top edge
    assert ((without[..., 0] > 180) & (without[..., 1] > 150) & (without[..., 2] < 90)).sum() == 0


def test_golden_front_view_with_strain_pins_and_wireframe(cloth) -> None:
    mesh, frames, pinned = cloth
    stack = np.stack(frames)
    assert np.allclose(stack[:, pinned], mesh.positions[pinned])  # data check before the image
    image = render_one(mesh, frames, FRAMES - 1, pinned, size=(400, 300), view="front", wireframe=True)
    verify_image_cache(image, "preview_front_strain")


def test_golden_iso_view_flat(cloth) -> None:
    mesh, frames, pinned = cloth
    image = render_one(mesh, frames, FRAMES // 2, pinned, size=(400, 300), view="iso", color="flat")
    verify_image_cache(image, "preview_iso_flat")


def test_torn_edges_are_highlighted() -> None:
    mesh = grid_sheet(8)
    # a slit along column 4 through the lowest three rows of quads (the vertex at row 3 is its tip)
    torn, _ = slit_grid(mesh, 8, column=4, quad_rows=3, shift=(0.04, 0.0, 0.0))
    edges = boundary_edges(torn)
    assert len(edges) == len(boundary_edges(mesh)) + 6  # three cut quad sides on each side
    pos = torn.positions.copy()
    pos[64:, 0] += 0.1
    pos[:64][mesh.positions[:, 0] > 0.5, 0] += 0.1
    common = {"size": (320, 240), "view": "front", "color": "flat", "label": False}
    bounds = np.stack([pos.min(axis=0), pos.max(axis=0)])
    images = []
    for tears in (True, False):
        with FrameRenderer(mesh, PreviewOptions(highlight_tears=tears, **common), bounds, None) as renderer:
            images.append(renderer.render(pos, None, mesh=torn).astype(int))
    magenta = [(im[..., 0] > 200) & (im[..., 1] < 80) & (im[..., 2] > 180) for im in images]
    assert magenta[0].sum() > 20 and magenta[1].sum() == 0


# ---------------------------------------------------------------------------------------------
# sheet, GIF, MP4, options


def test_contact_sheet_grid_size(cloth, tmp_path: Path) -> None:
    mesh, frames, pinned = cloth
    options = PreviewOptions(every=2, size=(160, 120), contact_sheet=True, sheet_tile_width=100, pngs=False)
    result = render_previews(mesh, frames, tmp_path, options, pinned=pinned)
    assert result.images == [] and result.frames_rendered == 6  # frames 1, 3, ..., 11
    sheet = iio.imread(result.contact_sheet)
    assert result.contact_sheet == tmp_path / "preview" / "contact_sheet.png"
    # ceil(sqrt(6)) = 3 columns of 100 px tiles, then the colour bar; 2 rows of a label band over a tile
    assert sheet.shape[1] > 3 * 100 and sheet.shape[0] % 2 == 0
    tiles = [np.zeros((30, 40, 3), np.uint8)] * 7
    flat = contact_sheet(tiles, list(range(7)), columns=2, tile_width=40)
    assert flat.shape[1] == 2 * 40 and flat.shape[0] % 4 == 0 and flat.shape[0] > 4 * 30  # no bar when flat


def test_gif_and_mp4_have_every_frame(cloth, tmp_path: Path) -> None:
    mesh, frames, pinned = cloth
    for video in ("gif", "mp4"):
        options = PreviewOptions(size=(160, 120), video=video, frames=(1,), fps=12)
        result = render_previews(mesh, frames, tmp_path, options, pinned=pinned)
        assert result.video == tmp_path / f"preview.{video}"
        assert result.frames_rendered == FRAMES
        if video == "gif":
            stack = iio.imread(result.video, index=None)
            assert stack.shape[:3] == (FRAMES, 120, 160)
        else:
            reader = imageio_v2.get_reader(result.video, format="FFMPEG")
            try:
                assert reader.count_frames() == FRAMES
                assert reader.get_meta_data()["fps"] == pytest.approx(12)
                assert reader.get_data(0).shape == (120, 160, 3)
            finally:
                reader.close()
    assert not list(tmp_path.rglob(".*"))  # no temporary files left


def test_displacement_colouring_and_a_lazy_loader(cloth, tmp_path: Path) -> None:
    mesh, frames, _pinned = cloth
    calls: list[int] = []

    class Loader:
        def __len__(self) -> int:
            return len(frames)

        def __getitem__(self, k: int) -> np.ndarray:
            calls.append(k)
            return frames[k]

    options = PreviewOptions(frames=(FRAMES,), size=(160, 120), color="displacement", view="side")
    # 12 is not among 101..112
    with pytest.raises(ExportError, match="the requested frames is in the sequence, which holds frames 101 to 112"):
        render_previews(mesh, Loader(), tmp_path, options, frame_numbers=range(101, 101 + FRAMES))
    options = PreviewOptions(frames=(112,), size=(160, 120), color="displacement", view="top")
    result = render_previews(mesh, Loader(), tmp_path, options, frame_numbers=range(101, 101 + FRAMES))
    assert [p.name for p in result.images] == ["0112.png"]
    assert len(calls) > FRAMES  # bounds pass over every frame, then the render pass


def test_frame_camera_contains_the_bounds() -> None:
    bounds = np.array([[0.0, -2.0, 0.0], [1.0, 1.0, 0.5]])
    for view in ("iso", "front", "side", "top"):
        cam = frame_camera(bounds, view, (800, 600))
        center = np.asarray(cam.focal_point)
        assert np.allclose(center, bounds.mean(axis=0))
        distance = np.linalg.norm(np.asarray(cam.position) - center)
        radius = np.linalg.norm(bounds[1] - bounds[0]) / 2
        assert cam.clipping[0] <= distance - radius + 1e-9 and cam.clipping[1] >= distance + radius - 1e-9


def test_options_are_validated() -> None:
    with pytest.raises(ExportError, match="view"):
        PreviewOptions(view="below")
    with pytest.raises(ExportError, match="color"):
        PreviewOptions(color="rainbow")
    with pytest.raises(ExportError, match="video"):
        PreviewOptions(video="avi")
    with pytest.raises(ExportError, match="every"):
        PreviewOptions(every=0)
    with pytest.raises(ExportError, match="unknown option"):
        PreviewOptions.from_mapping({"evry": 3})
    opts = PreviewOptions.from_mapping({"every": 12, "video": "mp4", "color": "strain", "size": [640, 480]})
    assert opts.every == 12 and opts.video == "mp4" and opts.size == (640, 480)
    assert opts.png_frames(range(1, 30)) == [1, 13, 25]
    # frame numbers are scene frames: every Nth counts from the sequence's first (a run's rest pose)
    assert opts.png_frames(range(0, 30)) == [0, 12, 24]
    assert opts.png_frames(range(1001, 1030)) == [1001, 1013, 1025]
    assert PreviewOptions(frames=(0, 7)).png_frames(range(0, 8)) == [0, 7]  # a run starting at scene frame 0
    with pytest.raises(ExportError, match="scene frames, from 0"):
        PreviewOptions(frames=(-1, 3))
    assert PreviewOptions(video="none").video is None


def test_unknown_background_colour_is_an_export_error(cloth, tmp_path: Path) -> None:
    mesh, frames, _ = cloth
    with pytest.raises(ExportError, match="colour"):
        render_previews(mesh, frames[:2], tmp_path, PreviewOptions(background="notacolour", size=(64, 48)))
    assert not list(tmp_path.rglob("*.png"))


def test_edge_strain_is_the_largest_stretch_at_each_vertex() -> None:
    mesh = grid_sheet(3, 2)  # vertices 0 1 2 / 3 4 5
    pos = mesh.positions.copy()
    pos[2, 0] += 0.5  # edge 1-2 from 0.5 to 1.0 long: ratio 2
    ratios = EdgeStrain(mesh, mesh.positions)(pos)
    assert ratios[2] == pytest.approx(2.0) and ratios[1] == pytest.approx(2.0)
    assert ratios[0] == pytest.approx(1.0) and ratios[3] == pytest.approx(1.0)
