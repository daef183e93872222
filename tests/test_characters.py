"""Cloth on an animated body through the command line: a capsule body given as an OBJ rest mesh
and a PC2 cache (both written here byte by byte, not by meshdeform), a cape whose top is attached
to it, checked against the body's own motion: the attached vertices follow the rigid motion the
cache was made from within 1 mm in every frame, and no point of the cape (every triangle sampled
on a lattice) comes inside the body or nearer than its thickness minus 1 mm (distances by brute
force over the body's triangles at that frame's pose). Malformed caches fail in one line, exit 2.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
import trimesh
from test_collider_contact import lattice, mesh_distance
from typer.testing import CliRunner

from meshdeform.mesh import grid_mesh
from meshdeform.scene.pins import SoftPins
from meshdeform.simulate import simulate
from pipeline.build import build_simulation
from pipeline.cli import app
from pipeline.recipe import parse_recipe

runner = CliRunner()
FPS = 24
FRAMES = 20
THICKNESS = 0.01
RADIUS = 0.15


def body_pose(frame: int) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (3, 3) and translation (3,) of the body at cache frame `frame` (from 0): it walks
    along +x at 0.48 m/s and turns about its vertical axis by 3 degrees a frame."""
    angle = np.radians(3.0 * frame)
    c, s = np.cos(angle), np.sin(angle)
    rotation = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    return rotation, np.array([0.02 * frame, 0.0, 0.0])


def capsule() -> trimesh.Trimesh:
    body = trimesh.creation.capsule(height=0.6, radius=RADIUS, count=[24, 24])
    body.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0]))  # axis along y
    return body


def obj_text(vertices: np.ndarray, faces: np.ndarray) -> str:
    """An OBJ file's text: `v` lines at full precision, then `f` lines (1-based)."""
    v = [f"v {float(x)!r} {float(y)!r} {float(z)!r}" for x, y, z in vertices]
    f = ["f " + " ".join(str(int(i) + 1) for i in face) for face in faces]
    return "\n".join(v + f) + "\n"


def pc2_bytes(samples: np.ndarray) -> bytes:
    """A PC2 file of samples (F, V, 3): header (start frame 1, one sample a frame), float32 points."""
    header = struct.pack("<12siiffi", b"POINTCACHE2\0", 1, samples.shape[1], 1.0, 1.0, samples.shape[0])
    return header + np.asarray(samples, dtype="<f4").tobytes()


def write_body(folder: Path, frames: int) -> np.ndarray:
    """body.obj (rest = cache frame 0) and body.pc2 with `frames` samples; returns the rest vertices."""
    body = capsule()
    rest = np.asarray(body.vertices)
    (folder / "body.obj").write_text(obj_text(rest, np.asarray(body.faces)))
    samples = np.array([rest @ r.T + t for r, t in (body_pose(f) for f in range(frames))])
    (folder / "body.pc2").write_bytes(pc2_bytes(samples))
    return rest


def write_cape(folder: Path) -> np.ndarray:
    """A 0.4 x 0.6 m cape of 12 x 16 vertices hanging 1.4 cm behind the body's back (z < 0)."""
    mesh = grid_mesh(12, 16, plane="xy")
    p = np.asarray(mesh.positions) * np.array([0.4, 0.6, 1.0]) + np.array([-0.2, -0.35, 0.0])
    p[:, 2] = -(RADIUS + THICKNESS + 0.004)
    faces = np.asarray(mesh.face_indices).reshape(-1, 4)
    (folder / "cape.obj").write_text(obj_text(p, faces))
    return p


RECIPE = f"""
[simulation]
fps = {FPS}
frames = {FRAMES}

[material]
thickness = {THICKNESS}

[[colliders]]
name = "body"
mesh = {{ path = "body.obj", cache = "body.pc2" }}
friction = 0.3

[[pins]]
select = {{ box = {{ min = [-0.08, 0.24, -1], max = [0.08, 1, 1] }} }}
attach = "body"
"""


def test_a_cape_attached_to_a_walking_turning_body_follows_it_and_stays_outside(tmp_path: Path) -> None:
    rest_body = write_body(tmp_path, FRAMES + 2)
    cape = write_cape(tmp_path)
    (tmp_path / "cape.toml").write_text(RECIPE)
    out = tmp_path / "out"
    done = runner.invoke(app, ["simulate", str(tmp_path / "cape.obj"), "-r", str(tmp_path / "cape.toml"),
                               "--out", str(out), "--format", "npz", "--quiet"])  # fmt: skip
    assert done.exit_code == 0, done.output
    data = np.load(out / "positions.npz")
    positions = data["positions"].astype(np.float64)
    assert positions.shape == (FRAMES + 1, cape.shape[0], 3)  # the rest pose, then every frame
    np.testing.assert_array_equal(data["frames"], np.arange(1, FRAMES + 2))  # their scene frames
    attached = (np.abs(cape[:, 0]) <= 0.08) & (cape[:, 1] >= 0.24)
    assert attached.sum() >= 3
    faces = np.asarray(capsule().faces)
    quads = np.asarray(grid_mesh(12, 16, plane="xy").face_indices).reshape(-1, 4)
    cloth_triangles = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    for k in range(FRAMES + 1):  # row k is scene frame 1 + k, as is the cache's sample k
        rotation, translation = body_pose(k)
        expected = cape[attached] @ rotation.T + translation
        assert np.abs(positions[k, attached] - expected).max() < 1e-3, k
        body = rest_body @ rotation.T + translation
        samples = lattice(positions[k], cloth_triangles, n=4)
        d = mesh_distance(samples, body, faces)
        assert d.min() >= THICKNESS - 1e-3, (k, d.min())
        axis_distance = np.linalg.norm((samples - translation)[:, [0, 2]], axis=1)
        inside_cylinder = (np.abs(samples[:, 1]) < 0.3) & (axis_distance < RADIUS)
        assert not inside_cylinder.any(), k
    # the body carried the cape along: its free bottom moved with the walk
    assert positions[-1, :, 0].mean() - cape[:, 0].mean() > 0.2


@pytest.mark.parametrize("cache", ["short", "points", "truncated"])
def test_a_malformed_cache_fails_in_one_line_before_anything_runs(tmp_path: Path, cache: str) -> None:
    rest = write_body(tmp_path, FRAMES + 2)
    write_cape(tmp_path)
    (tmp_path / "cape.toml").write_text(RECIPE)
    pc2 = tmp_path / "body.pc2"
    if cache == "short":  # fewer frames than the run needs
        write_body(tmp_path, FRAMES // 2)
    elif cache == "points":  # the rest mesh has one vertex more than the cache
        pc2.write_bytes(pc2_bytes(np.zeros((FRAMES + 2, rest.shape[0] + 1, 3))))
    else:
        pc2.write_bytes(pc2.read_bytes()[:-7])
    out = tmp_path / "out"
    done = runner.invoke(app, ["simulate", str(tmp_path / "cape.obj"), "-r", str(tmp_path / "cape.toml"),
                               "--out", str(out), "--format", "npz"])  # fmt: skip
    assert done.exit_code == 2, done.output
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, lines
    assert "body.pc2" in lines[0] and "colliders" in lines[0]
    assert not (out / "positions.npz").exists()


RIGID = """
[simulation]
fps = 24
frames = 48
gravity = [0, 0, 0]

[[colliders]]
name = "ball"
sphere = {{ center = [0, 0, -0.5], radius = 0.2 }}
animate = [ {{ time = 0.0 }}, {{ time = 0.5, translate = [0.3, 0.2, 0], rotate = [0, 0, 40] }} ]

[[pins]]
select = {{ indices = [0, 1] }}
attach = "ball"
stiffness = {stiffness}

[output]
formats = ["npz"]
"""


@pytest.mark.parametrize("stiffness", [1.0, 0.9])
def test_pins_attached_to_a_keyframed_collider_follow_its_keys(tmp_path: Path, stiffness: float) -> None:
    """Attached to a rigid collider, pinned vertices move by its keyframes: hard ones exactly,
    soft ones (stiffness 0.9) close behind; the rest of the cloth, held by no gravity, is dragged."""
    mesh = grid_mesh(6, 6, plane="xy")
    quads = np.asarray(mesh.face_indices).reshape(-1, 4)
    (tmp_path / "cloth.obj").write_text(obj_text(np.asarray(mesh.positions), quads))
    (tmp_path / "r.toml").write_text(RIGID.format(stiffness=stiffness))
    out = tmp_path / "out"
    args = ["simulate", str(tmp_path / "cloth.obj"), "-r", str(tmp_path / "r.toml"), "-o", str(out), "-q"]
    done = runner.invoke(app, args)
    assert done.exit_code == 0, done.output
    positions = np.load(out / "positions.npz")["positions"].astype(np.float64)
    rest = np.asarray(mesh.positions)[[0, 1]]
    pivot = np.array([0.0, 0.0, -0.5])  # a collider's keys turn about its centre
    for k in range(positions.shape[0]):
        s = min(k / 24 / 0.5, 1.0)  # linear keys: the fraction of the way at frame k
        angle = np.radians(40.0 * s)
        c, n = np.cos(angle), np.sin(angle)
        rotation = np.array([[c, -n, 0.0], [n, c, 0.0], [0.0, 0.0, 1.0]])
        expected = pivot + np.array([0.3, 0.2, 0.0]) * s + (rest - pivot) @ rotation.T
        error = np.abs(positions[k, [0, 1]] - expected).max()
        # soft: a spring (k = 9000 / s^2) pulling the whole cloth along lags while the keys move
        assert error < (1e-5 if stiffness == 1.0 else 0.1), (k, error)
    if stiffness < 1.0:
        # a second after the keys stopped it has nearly caught up (the cloth it drags still swings),
        # 0.36 m from where it was pinned
        assert np.abs(positions[-1, [0, 1]] - expected).max() < 0.02
        assert np.linalg.norm(positions[-1, [0, 1]] - rest, axis=1).min() > 0.3
    assert np.abs(positions[-1, 2:] - np.asarray(mesh.positions)[2:]).max() > 0.05


@pytest.mark.parametrize("modulus", [1e3, 1e4, 3e4])
def test_soft_pins_drag_a_stiff_cloth_without_being_held_as_contacts(modulus: float) -> None:
    """implicit holds a vertex a collider pushed against the push during its iterations; a soft
    pin's pull is no obstacle, and holding the pulled vertices against the cloth's springs made a
    stiff cloth dragged by them diverge (10 000 N/m at frame 35, 30 000 at frame 13, springs
    past 10x). Now every frame keeps its springs within 1.5x, and the pins follow their target."""
    text = RIGID.format(stiffness=0.9).replace("[simulation]", '[simulation]\nsolver = "implicit"')
    text += f"\n[material]\nstretch_modulus = {modulus}\n"
    built = build_simulation(parse_recipe(text), grid_mesh(6, 6, plane="xy"))
    (pin,) = [c for c in built.scene.constraints if isinstance(c, SoftPins)]
    structural = built.model.kinds == 0
    for frame in simulate(built.model, built.scene, built.settings):
        lengths = built.model.spring_lengths(frame.welded_positions)[structural]
        assert (lengths < 1.5 * built.model.rest_lengths[structural]).all(), frame.index
    gap = np.linalg.norm(frame.welded_positions[pin.indices] - pin.targets(frame.time), axis=1).max()
    assert gap < 0.02


def test_a_batch_redoes_an_asset_whose_body_cache_alone_changed(tmp_path: Path) -> None:
    """The result of a run with a deforming body is up to date only while the body's point cache is
    the same: the body moved 1 m in its cache (recipe, body mesh and cape unchanged) makes the batch
    run the asset again, where it was skipped as up to date, and the report's `colliders_sha256`
    (which `meshdeform preview` checks before drawing the body) changes with it. A folder of frame
    files counts by each file's name and contents."""
    from pipeline.recipe import load_recipe, recipe_hash

    assets = tmp_path / "assets"
    assets.mkdir()
    write_body(tmp_path, FRAMES + 2)
    write_cape(assets)
    recipe = tmp_path / "cape.toml"
    recipe.write_text(RECIPE.replace(f"frames = {FRAMES}", "frames = 3"))
    out = tmp_path / "out"

    def batch() -> dict:
        done = runner.invoke(app, ["batch", str(assets), "-r", str(recipe), "-o", str(out), "--jobs", "0", "-q"])
        assert done.exit_code == 0, done.output
        return json.loads((out / "manifest.json").read_text())["assets"][0]

    assert batch()["status"] == "ok"
    first = json.loads((out / "cape" / "report.json").read_text())["colliders_sha256"]
    assert batch()["status"] == "skipped"
    samples = np.array([np.asarray(capsule().vertices) + [1.0, 0.0, 0.0]] * (FRAMES + 2))
    (tmp_path / "body.pc2").write_bytes(pc2_bytes(samples))
    assert batch()["status"] == "ok"
    assert json.loads((out / "cape" / "report.json").read_text())["colliders_sha256"] != first

    frames = tmp_path / "frames"
    frames.mkdir()
    for index in range(3):
        (frames / f"body_{index:03d}.obj").write_text(obj_text(samples[index], np.asarray(capsule().faces)))
    recipe.write_text(RECIPE.replace('cache = "body.pc2"', 'cache = "frames"'))
    before = recipe_hash(load_recipe(recipe))
    (frames / "body_002.obj").write_text(obj_text(samples[2] + 0.01, np.asarray(capsule().faces)))
    assert recipe_hash(load_recipe(recipe)) != before


def test_a_body_whose_cache_starts_away_from_its_mesh_s_pose_is_warned_about(tmp_path: Path) -> None:
    """The cloth is made around the body mesh's pose; a cache whose start puts the body 6 cm from it
    (the first sample not the rest pose) starts the cloth inside the body: the built simulation says
    so, naming the collider's cache and the distance; a cache that starts at the pose says nothing."""
    from meshdeform.io import load
    from pipeline.recipe import load_recipe

    write_body(tmp_path, FRAMES + 2)
    write_cape(tmp_path)
    (tmp_path / "cape.toml").write_text(RECIPE)
    cape = load(tmp_path / "cape.obj")
    assert not build_simulation(load_recipe(tmp_path / "cape.toml"), cape).warnings
    samples = np.array([np.asarray(capsule().vertices) + [0.0, 0.0, 0.06]] * (FRAMES + 2))
    (tmp_path / "body.pc2").write_bytes(pc2_bytes(samples))
    (warning,) = build_simulation(load_recipe(tmp_path / "cape.toml"), cape).warnings
    assert warning.startswith("colliders[0].mesh.cache: at the run's start the body lies up to 60 mm from")
