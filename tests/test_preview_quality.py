"""Previews worth looking at, judged by their pixels on bakes of scenes made here (not the samples).

- the strain colour bar runs from 1 to the run's largest stretch, computed here from the OBJ frames: its
  ends are the colour map's (matplotlib's own colours) and re-rendering the folder with that range gives
  the same images, while a range only a little longer does not; the same on every PNG, every video frame
  and the contact sheet; the same strain is the same colour in two frames;
- the contact sheet labels each tile once, in a band of its own, with text tall enough to read, and its
  one colour bar has both ends labelled;
- after a cut, the piece that falls away leaves the view and the main piece fills it (`framing = "main"`),
  or everything is framed (`"all"`);
- a run's video plays at the run's fps.
"""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import pyvista as pv

pv.OFF_SCREEN = True

import imageio.v2 as imageio_v2  # noqa: E402
import imageio.v3 as iio  # noqa: E402
import matplotlib  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from factories import grid_sheet, write_grid  # noqa: E402
from scipy import ndimage  # noqa: E402

from meshdeform.preview import PreviewOptions, render_previews, render_result  # noqa: E402
from meshdeform.preview.overlay import COLORMAPS  # noqa: E402

WHITE = np.array([255, 255, 255])
FPS = 30


def lut(color: str = "strain") -> np.ndarray:
    """(256, 3) the colour map's colours as matplotlib gives them (0..255)."""
    cmap = matplotlib.colormaps[COLORMAPS[color]]
    return np.round(cmap(np.linspace(0.0, 1.0, 256))[:, :3] * 255)


def read_obj(path: Path) -> tuple[np.ndarray, list[list[int]]]:
    """(positions (V, 3), polygons as 0-based vertex lists) of an OBJ file, read here."""
    positions, polygons = [], []
    for line in path.read_text().splitlines():
        parts = line.split()
        if parts and parts[0] == "v":
            positions.append([float(x) for x in parts[1:4]])
        elif parts and parts[0] == "f":
            polygons.append([int(p.split("/")[0]) - 1 for p in parts[1:]])
    return np.array(positions), polygons


def largest_edge_stretch(folder: Path, rest: np.ndarray) -> float:
    """The largest current / rest length of any polygon edge in any OBJ frame of a result folder."""
    frames = sorted((folder / "frames").glob("*.obj"))
    _, polygons = read_obj(frames[0])
    edges = {tuple(sorted((p[i], p[(i + 1) % len(p)]))) for p in polygons for i in range(len(p))}
    a, b = np.array(sorted(edges)).T
    rest_length = np.linalg.norm(rest[a] - rest[b], axis=1)
    best = 0.0
    for path in frames:
        positions, _ = read_obj(path)
        best = max(best, float((np.linalg.norm(positions[a] - positions[b], axis=1) / rest_length).max()))
    return best


def find_bar(image: np.ndarray, color: str = "strain") -> tuple[int, int, int, int]:
    """The colour strip of a colour bar in the right half of `image`: (left, top, right, bottom), ends
    included: the columns holding the longest vertical runs of colour-map colours."""
    w = image.shape[1]
    x0 = w // 2
    region = image[:, x0:].astype(int)
    colours = lut(color)
    on_map = np.zeros(region.shape[:2], dtype=bool)
    for chunk in np.array_split(np.arange(256), 8):
        d = np.abs(region[:, :, None, :] - colours[chunk][None, None]).max(axis=3).min(axis=2)
        on_map |= d <= 2
    on_map &= np.abs(region - WHITE).sum(axis=2) > 0  # the pale end is not the white background
    runs = np.zeros(on_map.shape[1], dtype=int)
    tops = np.zeros(on_map.shape[1], dtype=int)
    for x in range(on_map.shape[1]):
        labels, count = ndimage.label(on_map[:, x])
        if count:
            sizes = ndimage.sum(on_map[:, x], labels, range(1, count + 1))
            best = int(np.argmax(sizes)) + 1
            rows = np.flatnonzero(labels == best)
            runs[x], tops[x] = rows.size, rows[0]
    columns = np.flatnonzero(runs >= 0.9 * runs.max())
    x = int(np.median(columns))  # the middle column's run: the strip's rows
    return x0 + int(columns.min()), int(tops[x]), x0 + int(columns.max()), int(tops[x] + runs[x]) - 1


def assert_bar_ends_are_the_colour_maps(image: np.ndarray, min_height: int) -> tuple[int, int, int, int]:
    left, top, right, bottom = find_bar(image)
    colours = lut()
    x = (left + right) // 2
    assert bottom - top + 1 >= min_height, (top, bottom)
    assert right - left + 1 >= 8  # wide enough to see
    assert np.abs(image[top, x].astype(int) - colours[-1]).max() <= 2, image[top, x]  # the high end
    assert np.abs(image[bottom, x].astype(int) - colours[0]).max() <= 2, image[bottom, x]  # 1: no stretch
    # each end is labelled: dark text right of the strip, level with it
    for row in (top, bottom):
        text = image[max(row - 6, 0) : row + 7, right + 2 : right + 60]
        assert (text.max(axis=2) < 100).sum() >= 8, row
    return left, top, right, bottom


SCENE = """
[simulation]
solver = "xpbd"
fps = {fps}
frames = {frames}
damping = 0.2

[material]
structural = {{ stiffness = 0.6 }}
density = 0.2

[[pins]]
relative = true
select = {{ any = [
  {{ box = {{ min = [0, 0.99, 0], max = [0.01, 1, 1] }} }},
  {{ box = {{ min = [0.99, 0.99, 0], max = [1, 1, 1] }} }},
] }}

[wind]
velocity = [0.0, 0.0, 3.0]
turbulence = 0.3

[output]
formats = ["obj"]
preview = {preview}
"""


def bake(tmp: Path, name: str, scene: str, mesh: Path) -> Path:
    from pipeline.job import run_job
    from pipeline.recipe import load_recipe

    recipe = tmp / f"{name}.toml"
    recipe.write_text(textwrap.dedent(scene))
    run_job(mesh, load_recipe(recipe), tmp / name)
    return tmp / name


@pytest.fixture(scope="module")
def hammock(tmp_path_factory) -> tuple[Path, np.ndarray]:
    """A sheet hung by its two top corners in wind, 24 frames at 30 fps: PNGs every 6 frames, an MP4 and a
    contact sheet. Returns the result folder and the rest positions."""
    tmp = tmp_path_factory.mktemp("hammock")
    mesh = write_grid(tmp / "hammock.obj", 16, 12, size=(1.2, 0.9))
    preview = '{ every = 6, video = "mp4", contact_sheet = true, size = [480, 360], view = "front" }'
    folder = bake(tmp, "out", SCENE.format(fps=FPS, frames=24, preview=preview), mesh)
    return folder, read_obj(mesh)[0]


# ---------------------------------------------------------------------------------------------
# (a) the colour range


def test_the_colour_bar_runs_from_1_to_the_runs_largest_stretch_on_every_png(hammock, tmp_path: Path) -> None:
    folder, rest = hammock
    largest = largest_edge_stretch(folder, rest)
    report = json.loads((folder / "report.json").read_text())
    assert largest == pytest.approx(max(report["max_stretch"]), abs=1e-5)  # the run's own figure agrees
    assert largest > 1.02  # it did stretch
    pngs = sorted((folder / "preview").glob("0*.png"))
    assert [p.name for p in pngs] == ["0001.png", "0007.png", "0013.png", "0019.png", "0025.png"]
    images = [iio.imread(p)[..., :3] for p in pngs]
    boxes = [assert_bar_ends_are_the_colour_maps(image, min_height=int(0.5 * 360)) for image in images]
    assert len(set(boxes)) == 1  # the same place on every frame
    left, top, _, bottom = boxes[0]
    panel = (slice(top - 30, bottom + 12), slice(left - 2, 480))
    assert all(np.array_equal(image[panel], images[0][panel]) for image in images)  # the same bar, labels too

    # the range is [1, largest]: the folder re-rendered with it gives the same images, and one only 5 %
    # of the stretch longer gives other colours (and labels)
    def rerender(high: float, name: str) -> list[np.ndarray]:
        options = {"every": 6, "size": [480, 360], "view": "front", "clim": [1.0, high]}
        _, result = render_result(folder, options, out_dir=tmp_path / name)
        return [iio.imread(p)[..., :3].astype(int) for p in result.images]

    same = rerender(largest, "same")
    longer = rerender(1.0 + 1.05 * (largest - 1.0), "longer")
    for run, again in zip(images, same, strict=True):
        assert np.abs(run.astype(int) - again).max() <= 1
    assert max(float(np.abs(run.astype(int) - other).mean()) for run, other in zip(images, longer, strict=True)) > 0.2


def test_every_video_frame_has_the_same_bar_and_the_video_plays_at_the_runs_fps(hammock) -> None:
    folder, _ = hammock
    png = iio.imread(folder / "preview" / "0013.png")[..., :3].astype(int)
    left, top, right, bottom = find_bar(png.astype(np.uint8))
    reader = imageio_v2.get_reader(folder / "preview.mp4", format="FFMPEG")
    try:
        assert reader.get_meta_data()["fps"] == pytest.approx(FPS)  # the run's, not 24
        frames = [np.asarray(f)[..., :3].astype(int) for f in reader]
    finally:
        reader.close()
    assert len(frames) == 25  # the rest pose and 24 frames
    strip = (slice(top + 2, bottom - 1), slice(left + 2, right - 1))
    for k, frame in enumerate(frames):  # H.264 is lossy: the same colours within its error
        assert np.abs(frame[strip] - png[strip]).mean() < 4, k
    assert np.abs(frames[12] - png).mean() < 3  # frame 13 is the PNG 0013


def test_the_same_strain_is_the_same_colour_in_two_frames(tmp_path: Path) -> None:
    """A flat sheet facing the camera, stretched evenly: by 1.1 in frames 2 and 3 (moved between them),
    by 1.2 in frame 4, the largest. Frames 2 and 3 show the colour half-way up the map, frame 4 the top."""
    mesh = grid_sheet(9, 9, uvs=False)
    rest = mesh.positions
    frames = [rest, rest * 1.1, rest * 1.1 + [0.25, 0.1, 0.0], rest * 1.2]
    options = PreviewOptions(size=(320, 240), view="front", highlight_pins=False, label=False, anti_aliasing=False)
    result = render_previews(mesh, frames, tmp_path, options)
    assert result.clim == pytest.approx((1.0, 1.2))
    images = [iio.imread(p)[..., :3].astype(int) for p in result.images]
    left = find_bar(images[0].astype(np.uint8))[0]

    def sheet_colour(image: np.ndarray) -> np.ndarray:
        cloth = np.abs(image - WHITE).sum(axis=2) > 30
        cloth[:, left - 4 :] = False
        core = ndimage.binary_erosion(cloth, iterations=3)
        return np.median(image[core], axis=0)

    colours = [sheet_colour(image) for image in images]
    assert np.abs(colours[1] - colours[2]).max() <= 2, colours
    mid, top = lut()[127], lut()[255]
    # shading scales the channels alike: compare green against red with the map's
    ratio = [c[1] / c[0] for c in colours]
    assert ratio[1] == pytest.approx(mid[1] / mid[0], abs=0.08)
    assert ratio[3] == pytest.approx(top[1] / top[0], abs=0.08)
    assert ratio[0] > 0.85  # no stretch: pale


# ---------------------------------------------------------------------------------------------
# (b) the contact sheet


def sheet_cells(sheet: np.ndarray) -> list[tuple[int, int, int, int]]:
    """(x0, y0, x1, y1) of each tile's cell, from the grey outlines the sheet draws round them."""
    grey = (np.abs(sheet.astype(int) - 160).max(axis=2) <= 2)
    xs = np.flatnonzero(grey.sum(axis=0) > 100)  # outline lines at least 100 px long
    ys = np.flatnonzero(grey.sum(axis=1) > 100)

    def spans(lines: np.ndarray) -> list[tuple[int, int]]:
        groups = np.split(lines, np.flatnonzero(np.diff(lines) > 1) + 1)
        edges = [(int(g[0]), int(g[-1])) for g in groups]
        return [(edges[i][1], edges[i + 1][0]) for i in range(len(edges) - 1) if edges[i + 1][0] - edges[i][1] > 20]

    cells = [(x0, y0, x1, y1) for y0, y1 in spans(ys) for x0, x1 in spans(xs)]
    filled = np.abs(sheet.astype(int) - WHITE).sum(axis=2) > 30
    return [c for c in cells if filled[c[1] + 1 : c[3], c[0] + 1 : c[2]].any()]  # not the empty places


def test_the_contact_sheet_labels_each_tile_once_legibly_with_one_colour_bar(hammock) -> None:
    folder, _ = hammock
    sheet = iio.imread(folder / "preview" / "contact_sheet.png")[..., :3]
    cells = sheet_cells(sheet)
    assert len(cells) == 5  # frames 1, 7, 13, 19, 25 (a third row-column left empty)
    bands = []
    for x0, y0, x1, y1 in cells:
        cell = sheet[y0 + 1 : y1, x0 + 1 : x1].astype(int)
        dark = cell.max(axis=2) < 90  # black text on white
        rows = np.flatnonzero(dark.any(axis=1))
        assert rows.size, (x0, y0)
        text_rows = rows[rows < rows[0] + 40]
        height = int(text_rows[-1] - text_rows[0] + 1)
        assert height >= 10, height  # tall enough to read at the tile's size (320 px wide)
        band = cell[: text_rows[-1] + 3]
        # the band holds only the text and its background: no rendered cloth under or over the label
        assert (np.abs(band - WHITE).sum(axis=2) > 30).mean() < 0.2
        chroma = band.max(axis=2) - band.min(axis=2)
        assert chroma.max() <= 12
        # one label: all its ink in one line at the top left
        columns = np.flatnonzero(dark[: text_rows[-1] + 1].any(axis=0))
        assert columns[0] < 20 and columns[-1] < (x1 - x0) * 0.6
        bands.append(dark[: text_rows[-1] + 1, : columns[-1] + 1])
    assert len({b.tobytes() for b in bands}) == len(bands)  # each tile's label is its own
    # the sheet's one colour bar, right of the tiles, legible: taller than a tile, both ends labelled
    assert_bar_ends_are_the_colour_maps(sheet, min_height=cells[0][3] - cells[0][1])
    assert find_bar(sheet)[0] > max(x1 for _, _, x1, _ in cells)


# ---------------------------------------------------------------------------------------------
# (c) pieces that fall away


CUT = """
[simulation]
solver = "xpbd"
fps = 24
frames = 36
damping = 0.1

[[pins]]
relative = true
select = { box = { min = [0, 0.99, 0], max = [1, 1, 1] } }

[[cuts]]
time = 0.2
relative = true
plane = { point = [0.5, 0.3, 0.5], normal = [0, 1, 0] }

[output]
formats = ["obj"]
preview = { frames = [37], size = [320, 240], view = "front", color = "flat", highlight_pins = false }
"""


def main_blob_fill(image: np.ndarray, content: tuple[int, int]) -> tuple[float, float]:
    """(width, height) of the largest blob of non-background pixels, as fractions of the content area."""
    cloth = np.abs(image.astype(int) - WHITE).sum(axis=2) > 30
    cloth[:40] = False  # the label
    labels, count = ndimage.label(cloth)
    assert count
    biggest = int(np.argmax(ndimage.sum(cloth, labels, range(1, count + 1)))) + 1
    rows, cols = np.nonzero(labels == biggest)
    return (cols.max() - cols.min() + 1) / content[0], (rows.max() - rows.min() + 1) / content[1]


def test_the_camera_stays_on_the_main_piece_when_a_piece_falls_away(tmp_path: Path) -> None:
    mesh = write_grid(tmp_path / "banner.obj", 21, 21)
    folder = bake(tmp_path, "cut", CUT, mesh)
    report = json.loads((folder / "report.json").read_text())
    assert report["pieces"][-1] == 2
    final, _ = read_obj(folder / "frames" / "frame_0037.obj")
    assert final[:, 1].min() < -3.0  # the lower piece fell metres below the sheet
    image = iio.imread(folder / "preview" / "0037.png")[..., :3]
    width, height = main_blob_fill(image, (320, 240))
    assert width > 0.6 or height > 0.6, (width, height)  # the main piece fills the view
    assert np.abs(image[-20:].astype(int) - WHITE).sum(axis=2).max() <= 30  # nothing else in the view
    # framing everything: the same frame shows both pieces, the main one small
    options = {"frames": [37], "size": [320, 240], "view": "front", "color": "flat", "framing": "all"}
    _, result = render_result(folder, options, out_dir=tmp_path / "all", mesh=None)
    width_all, height_all = main_blob_fill(iio.imread(result.images[0])[..., :3], (320, 240))
    assert max(width_all, height_all) < 0.4, (width_all, height_all)


# ---------------------------------------------------------------------------------------------
# memory


def test_a_big_run_with_a_video_counts_the_previews_scratch_file_in_its_estimate(tmp_path: Path) -> None:
    from meshdeform.mesh import grid_mesh
    from meshdeform.preview.spool import MEMORY_BUDGET
    from pipeline.estimate import output_bytes
    from pipeline.recipe import load_recipe

    recipe = tmp_path / "r.toml"
    recipe.write_text('[simulation]\nframes = 200\n[output]\npreview = { video = "mp4" }\n')
    small, big = grid_mesh(10, 10), grid_mesh(400, 400)
    assert "preview scratch" not in output_bytes(load_recipe(recipe), small)
    scratch = output_bytes(load_recipe(recipe), big)["preview scratch"]
    kept = 201 * 400 * 400 * 3 * 4  # at least the frames' float32 positions, less what stays in memory
    assert scratch >= kept - MEMORY_BUDGET
