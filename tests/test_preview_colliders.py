"""Previews draw the scene's colliders: real offscreen renders judged by their pixels, each shape's
surface checked as geometry (closed, outward, on the analytic shape), and a run's previews with its
colliders rendered again the same from its result folder by `meshdeform preview`."""

from __future__ import annotations

import math
from pathlib import Path

import pyvista as pv

pv.OFF_SCREEN = True

import imageio.v3 as iio  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from factories import grid_sheet  # noqa: E402
from typer.testing import CliRunner  # noqa: E402

from meshdeform.io import save  # noqa: E402
from meshdeform.mesh import Mesh  # noqa: E402
from meshdeform.preview import FrameRenderer, PreviewOptions, frame_camera, render_previews  # noqa: E402
from meshdeform.preview.camera import CameraSetup  # noqa: E402
from meshdeform.preview.colliders import ColliderSurfaces, Surface  # noqa: E402
from meshdeform.scene.colliders import Box, Capsule, Collider, Plane, Sphere, TriangleMesh  # noqa: E402
from meshdeform.scene.deforming import DeformingCollider, DeformingMesh  # noqa: E402
from meshdeform.scene.pins import Keyframe, Keyframes  # noqa: E402

SIZE = (320, 240)
#: a saturated blue cloth: nothing it renders can pass for the colliders' neutral grey
OPTIONS = {
    "size": SIZE,
    "color": "flat",
    "flat_color": "#2f6fdf",
    "label": False,
    "highlight_pins": False,
    "anti_aliasing": False,
}


def grey_mask(image: np.ndarray) -> np.ndarray:
    """(H, W) pixels of a neutral grey: channels within 16 of each other, neither background white nor black."""
    rgb = image.astype(np.int16)
    spread = rgb.max(axis=2) - rgb.min(axis=2)
    mean = rgb.mean(axis=2)
    return (spread <= 16) & (mean > 30) & (mean < 240)


def blue_mask(image: np.ndarray) -> np.ndarray:
    rgb = image.astype(np.int16)
    return rgb[..., 2] - rgb[..., 0] > 60


def project(camera: CameraSetup, points: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Pixel (column, row) of world points through a pinhole camera (vertical view angle, no window shift)."""
    position = np.asarray(camera.position)
    forward = np.asarray(camera.focal_point) - position
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, camera.up)
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    rel = np.atleast_2d(points) - position
    x, y, z = rel @ right, rel @ up, rel @ forward
    focal = 0.5 * size[1] / math.tan(math.radians(camera.view_angle) / 2)
    return np.stack([0.5 * size[0] + focal * x / z, 0.5 * size[1] - focal * y / z], axis=1)


def pixel(image: np.ndarray, at: np.ndarray) -> np.ndarray:
    col, row = (round(float(v)) for v in at)
    return image[row, col]


def drape(radius: float = 0.5, gap: float = 0.01) -> tuple[Mesh, np.ndarray]:
    """A 1.4 m sheet lying over a ball of `radius` at the origin, `gap` above it on the cap, then falling
    away steeply outside 0.8 of the radius (its hem well above the ball's lower half)."""
    mesh = grid_sheet(30, plane="xz", centred=True, size=1.4)
    p = mesh.positions.copy()
    r = radius + gap
    d = np.hypot(p[:, 0], p[:, 2])
    rim = 0.8 * r
    p[:, 1] = np.where(d < rim, np.sqrt(np.maximum(r * r - d * d, 0.0)), math.sqrt(r * r - rim * rim) - 1.3 * (d - rim))
    return mesh, p


def render_frame(mesh: Mesh, positions: np.ndarray, scene: list[Collider], view: str = "front", **options):
    """One frame at t = 0 through FrameRenderer, with the camera it used."""
    opts = PreviewOptions(**{**OPTIONS, "view": view, **options})
    bounds = np.stack([positions.min(axis=0), positions.max(axis=0)])
    surfaces = ColliderSurfaces(scene, bounds)
    with FrameRenderer(mesh, opts, bounds, None, None, surfaces) as renderer:
        return renderer.render(positions), renderer.camera


# ---------------------------------------------------------------------------------------------
# pixels


def test_a_sheet_draped_over_a_ball_shows_the_ball_in_grey() -> None:
    mesh, positions = drape()
    ball = Collider(Sphere([0.0, 0.0, 0.0], 0.5))
    image, camera = render_frame(mesh, positions, [ball])
    grey = grey_mask(image)
    assert grey.mean() > 0.02  # the ball's lower half, under the hem
    # its front below the hem is grey; the cloth's top, 1 cm over the ball's, is cloth
    assert grey_mask(pixel(image, project(camera, [0.0, -0.4, 0.3], SIZE)[0])[None, None])[0, 0]
    apex = pixel(image, project(camera, [0.0, 0.505, 0.0], SIZE)[0] + [0, 2])
    assert blue_mask(apex[None, None])[0, 0], apex
    # every grey pixel lies inside the ball's outline (the projected sphere, with one pixel to spare)
    rows, cols = np.nonzero(grey)
    centre = project(camera, [0.0, 0.0, 0.0], SIZE)[0]
    distance = float(np.linalg.norm(np.asarray(camera.position)))
    outline = 0.5 * SIZE[1] / math.tan(math.radians(camera.view_angle) / 2) * math.tan(math.asin(0.5 / distance))
    assert np.hypot(cols - centre[0], rows - centre[1]).max() <= outline * 1.06 + 1.5


def test_no_colliders_no_grey_and_the_cloth_is_framed_the_same() -> None:
    mesh, positions = drape()
    with_ball, _ = render_frame(mesh, positions, [Collider(Sphere([0.0, 0.0, 0.0], 0.5))])
    without, _ = render_frame(mesh, positions, [])
    switched_off, _ = render_frame(mesh, positions, [Collider(Sphere([0.0, 0.0, 0.0], 0.5))], colliders=False)
    assert grey_mask(without).sum() == 0
    assert np.array_equal(switched_off, without)
    # the camera stays on the cloth: the cloth's pixels where it is drawn in both are where they were
    cloth = blue_mask(without)
    assert cloth.mean() > 0.1
    assert (blue_mask(with_ball) & ~cloth).sum() == 0


def test_the_ground_is_a_floor_under_the_cloth() -> None:
    mesh = grid_sheet(12, plane="xz", centred=True, size=1.0, offset=[0.0, 0.4, 0.0])
    positions = mesh.positions
    ground = Collider(Plane([0.0, 0.0, 0.0], [0.0, 1.0, 0.0]))
    image, camera = render_frame(mesh, positions, [ground], view="iso")
    grey = grey_mask(image)
    assert grey.mean() > 0.3
    # the floor shows beside the cloth; where it passes under the cloth (seen from above) the cloth hides it
    for point in ([0.6, 0.0, -0.6], [0.7, 0.0, 0.0]):
        assert grey_mask(pixel(image, project(camera, point, SIZE)[0])[None, None])[0, 0], point
    for point in ([-0.6, 0.0, -0.6], [0.0, 0.4, 0.0]):
        assert blue_mask(pixel(image, project(camera, point, SIZE)[0])[None, None])[0, 0], point


@pytest.mark.parametrize(
    ("numbers", "start_frame", "places"),
    [
        (None, None, (-0.5, -0.5, 0.5)),  # frames 1, 2, 3, the first the rest pose: t = 0, 0.5, 1 s
        ([5, 6, 7], 4, (-0.5, 0.5, 0.5)),  # the rest pose at scene frame 4: t = 0.5, 1, 1.5 s
    ],
)
def test_a_keyframed_ball_is_drawn_where_it_is_at_each_frames_time(
    tmp_path: Path, numbers: list[int] | None, start_frame: int | None, places: tuple[float, ...]
) -> None:
    """Frame n at (n - start frame) / fps seconds since the rest pose (the first frame unless the start
    frame is given): the ball keyed at x = -0.5 (t = 0.5 s, held before) and x = +0.5 (t = 1 s, held
    after) shows at those places at 2 fps, in front of a backdrop sheet."""
    backdrop = grid_sheet(8, plane="xy", centred=True, size=2.0, offset=[0.0, 0.0, -1.0])
    keys = Keyframes([Keyframe(0.5, translate=(0.0, 0.0, 0.0)), Keyframe(1.0, translate=(1.0, 0.0, 0.0))], [0, 0, 0])
    ball = Collider(Sphere([-0.5, 0.0, 0.0], 0.2), keys=keys)
    frames = [backdrop.positions] * 3
    options = {**OPTIONS, "view": "front"}
    result = render_previews(
        backdrop, frames, tmp_path, options, frame_numbers=numbers, fps=2.0, colliders=[ball], start_frame=start_frame
    )
    assert len(result.images) == 3
    bounds = np.stack([backdrop.positions.min(axis=0), backdrop.positions.max(axis=0)])
    camera = frame_camera(bounds, "front", SIZE)
    for path, x in zip(result.images, places, strict=True):
        grey = grey_mask(iio.imread(path)[..., :3])
        rows, cols = np.nonzero(grey)
        assert rows.size > 200
        expected = project(camera, [x, 0.0, 0.0], SIZE)[0]
        assert abs(cols.mean() - expected[0]) < 3 and abs(rows.mean() - expected[1]) < 3, (path.name, expected)


# ---------------------------------------------------------------------------------------------
# surfaces


def as_polydata(surface: Surface) -> pv.PolyData:
    faces = np.hstack([np.full((surface.triangles.shape[0], 1), 3), surface.triangles]).ravel()
    return pv.PolyData(surface.points, faces=faces)


def signed_volume(surface: Surface) -> float:
    """Divergence theorem over the triangles: positive for a closed surface oriented outward."""
    p0, p1, p2 = (surface.points[surface.triangles[:, i]] for i in range(3))
    return float(np.einsum("ij,ij->i", p0, np.cross(p1, p2)).sum() / 6.0)


def assert_closed_and_outward(surface: Surface, volume: float, rel: float) -> None:
    poly = as_polydata(surface)
    assert poly.n_open_edges == 0
    assert poly.is_manifold
    assert signed_volume(surface) == pytest.approx(volume, rel=rel)
    assert abs(poly.volume) == pytest.approx(volume, rel=rel)


def surface_of(collider: Collider, time: float = 0.0, bounds=((-1.0, 0.5, -1.0), (1.0, 1.5, 1.0))) -> Surface:
    (surface,) = ColliderSurfaces([collider], np.asarray(bounds, dtype=float)).at(time)
    return surface


def test_sphere_surface_lies_on_the_sphere_and_encloses_it() -> None:
    centre, r = np.array([0.3, -0.2, 1.0]), 0.4
    s = surface_of(Collider(Sphere(centre, r)))
    assert np.allclose(np.linalg.norm(s.points - centre, axis=1), r, rtol=0, atol=1e-12)
    assert_closed_and_outward(s, 4 / 3 * math.pi * r**3, rel=0.02)
    assert s.smooth and not s.floor


def test_capsule_surface_is_at_radius_from_its_segment() -> None:
    a, b, r = np.array([0.0, 0.0, 0.0]), np.array([0.6, 0.3, -0.2]), 0.1
    s = surface_of(Collider(Capsule(a, b, r)))
    ab = b - a
    t = np.clip((s.points - a) @ ab / (ab @ ab), 0.0, 1.0)
    dist = np.linalg.norm(s.points - (a + t[:, None] * ab), axis=1)
    assert np.allclose(dist, r, rtol=0, atol=1e-12)
    length = float(np.linalg.norm(ab))
    assert_closed_and_outward(s, math.pi * r * r * length + 4 / 3 * math.pi * r**3, rel=0.02)
    # it reaches both ends: the farthest points along the axis are a - r and b + r
    along = (s.points - a) @ (ab / length)
    assert along.min() == pytest.approx(-r) and along.max() == pytest.approx(length + r)


def test_box_surface_is_its_12_triangles_within_its_bounds() -> None:
    lo, hi = np.array([-0.2, 0.0, -0.4]), np.array([0.5, 0.3, 0.1])
    s = surface_of(Collider(Box(lo, hi)))
    assert s.triangles.shape == (12, 3)
    assert np.all(s.points >= lo) and np.all(s.points <= hi)
    assert {tuple(p) for p in s.points.tolist()} == {
        (x, y, z) for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])
    }
    assert_closed_and_outward(s, float(np.prod(hi - lo)), rel=1e-12)


def test_mesh_collider_surface_is_the_mesh_moved_by_its_keys() -> None:
    sphere = pv.Icosphere(radius=0.3, nsub=2)
    vertices = np.asarray(sphere.points, dtype=np.float64)
    triangles = sphere.faces.reshape(-1, 4)[:, 1:]
    keys = Keyframes([Keyframe(0.0, translate=(0.0, 0.0, 0.0)), Keyframe(2.0, translate=(0.0, 2.0, 0.0))], [0, 0, 0])
    s = surface_of(Collider(TriangleMesh(vertices, triangles), keys=keys), time=1.0)
    assert np.array_equal(s.triangles, triangles)
    assert np.allclose(s.points, vertices + [0.0, 1.0, 0.0])
    assert as_polydata(s).n_open_edges == 0


def test_a_deforming_body_is_drawn_at_its_cache_positions_at_each_time() -> None:
    sphere = pv.Icosphere(radius=0.3, nsub=2)
    vertices = np.asarray(sphere.points, dtype=np.float64)
    triangles = sphere.faces.reshape(-1, 4)[:, 1:]
    body = DeformingMesh(vertices, triangles, lambda t: vertices * (1.0 + t))  # swells
    collider = DeformingCollider(body)
    assert ColliderSurfaces([collider], np.array([[-1.0] * 3, [1.0] * 3])).animated
    for time in (0.0, 0.5, 1.0):
        s = surface_of(collider, time=time)
        assert np.array_equal(s.triangles, triangles)
        assert np.allclose(np.linalg.norm(s.points, axis=1), 0.3 * (1.0 + time))


def test_a_scaled_keyframed_sphere_grows_about_its_pivot() -> None:
    keys = Keyframes([Keyframe(0.0, scale=(1.0, 1.0, 1.0)), Keyframe(1.0, scale=(2.0, 2.0, 2.0))], [0.0, 0.0, 0.0])
    s = surface_of(Collider(Sphere([1.0, 0.0, 0.0], 0.25), keys=keys), time=1.0)
    assert np.allclose(np.linalg.norm(s.points - [2.0, 0.0, 0.0], axis=1), 0.5)


@pytest.mark.parametrize(
    ("point", "normal", "keys"),
    [
        ([0.0, 0.0, 0.0], [0.0, 1.0, 0.0], None),  # the ground
        ([0.0, 0.2, 0.5], [0.3, 1.0, -0.2], None),
        # a plane turned 90 degrees about z by t = 1: its normal +y goes to -x
        (
            [0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            Keyframes([Keyframe(0.0), Keyframe(1.0, rotate=(0.0, 0.0, 90.0))], [0, 0, 0]),
        ),
    ],
)
def test_a_plane_is_a_square_in_it_centred_under_the_cloth(point, normal, keys) -> None:
    bounds = np.array([[-1.0, 0.5, -1.0], [1.0, 1.5, 1.0]])
    s = surface_of(Collider(Plane(point, normal), keys=keys), time=1.0, bounds=bounds)
    n = np.asarray(normal, dtype=float) / np.linalg.norm(normal)
    if keys is not None:
        n = np.array([-n[1], n[0], n[2]])
    assert s.floor and s.points.shape == (4, 3) and s.triangles.shape == (2, 3)
    assert np.allclose((s.points - point) @ n, 0.0, atol=1e-12)  # in the plane
    # the triangles face along the plane's normal
    p0, p1, p2 = (s.points[s.triangles[:, i]] for i in range(3))
    assert np.all(np.cross(p1 - p0, p2 - p0) @ n > 0)
    # centred on the foot of the cloth's centre and wider than the cloth
    centre = bounds.mean(axis=0)
    assert np.allclose(s.points.mean(axis=0), centre - ((centre - point) @ n) * n)
    edge = np.linalg.norm(s.points[1] - s.points[0])
    assert edge > 2 * np.linalg.norm(bounds[1] - bounds[0])


# ---------------------------------------------------------------------------------------------
# a run's previews, then `meshdeform preview` of its folder


RECIPE = """
[simulation]
solver = "xpbd"
fps = 24
frames = 6
substeps = 4

[[colliders]]
sphere = { center = [0, 0.45, 0], radius = 0.3 }

[[colliders]]
ground = { height = 0.0 }

[[colliders]]
capsule = { a = [-0.6, 0.3, -0.5], b = [-0.6, 0.3, 0.5], radius = 0.05 }
animate = [{ time = 0.0, translate = [0, 0, 0] }, { time = 0.25, translate = [1.2, 0, 0] }]

[output]
formats = ["obj"]
preview = { every = 5, size = [160, 120], color = "flat" }
"""


def test_meshdeform_preview_redraws_the_runs_colliders(tmp_path: Path) -> None:
    """The run's previews show its colliders (the bar moving between frames 1 and 6); `meshdeform preview`
    of its folder, with the same options, renders the same bytes; without colliders, or once the recipe
    the report names has changed, none are drawn (and it says why)."""
    from pipeline.cli import app

    runner = CliRunner()
    mesh_path = tmp_path / "assets" / "sheet.obj"
    mesh_path.parent.mkdir()
    save(mesh_path, grid_sheet(10, plane="xz", centred=True, size=1.2, offset=[0.0, 0.8, 0.0]))
    recipe = tmp_path / "recipes" / "drop.toml"
    recipe.parent.mkdir()
    recipe.write_text(RECIPE)
    out = tmp_path / "out"
    ran = runner.invoke(app, ["simulate", str(mesh_path), "-r", str(recipe), "-o", str(out), "--quiet"])
    assert ran.exit_code == 0, ran.output
    names = ["0001.png", "0006.png"]
    assert sorted(p.name for p in (out / "preview").glob("*.png")) == names

    def images(folder: Path) -> list[np.ndarray]:
        return [iio.imread(folder / "preview" / name)[..., :3] for name in names]

    first, last = images(out)
    assert grey_mask(first).mean() > 0.2  # the floor, the ball and the bar
    assert not np.array_equal(grey_mask(first), grey_mask(last))

    options = ["--every", "5", "--size", "160x120", "--color", "flat"]

    def preview(folder: str, *extra: str, result_dir: Path = out):
        result = runner.invoke(app, ["preview", str(result_dir), "-o", str(tmp_path / folder), *options, *extra])
        assert result.exit_code == 0, result.output
        return result

    redo = preview("again")
    assert "colliders not drawn" not in redo.stderr
    for name in names:
        assert (tmp_path / "again" / "preview" / name).read_bytes() == (out / "preview" / name).read_bytes()

    preview("bare", "--no-colliders")
    bare = images(tmp_path / "bare")
    assert grey_mask(bare[0]).mean() < 0.02

    # a run with command-line overrides: its colliders are still the recipe's
    shorter = tmp_path / "shorter"
    ran = runner.invoke(app, ["simulate", str(mesh_path), "-r", str(recipe), "-o", str(shorter), "-q", "--frames", "5"])
    assert ran.exit_code == 0, ran.output
    assert (
        "colliders not drawn" not in preview("shorter-again", "--no-png", "--contact-sheet", result_dir=shorter).stderr
    )
    preview("shorter-bare", "--no-png", "--contact-sheet", "--no-colliders", result_dir=shorter)
    sheets = [
        iio.imread(tmp_path / f / "preview" / "contact_sheet.png")[..., :3] for f in ("shorter-again", "shorter-bare")
    ]
    assert grey_mask(sheets[0]).mean() > 10 * grey_mask(sheets[1]).mean()

    recipe.write_text(RECIPE.replace("radius = 0.3", "radius = 0.2"))  # not the recipe that ran any more
    stale = preview("stale")
    assert "colliders not drawn" in stale.stderr and str(recipe) in stale.stderr
    assert all(np.array_equal(a, b) for a, b in zip(images(tmp_path / "stale"), bare, strict=True))
