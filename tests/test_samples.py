"""The bundled samples: reproducible from their script, the showcase recipe covers each of them, and
the fold sample folds over itself without passing through itself (judged by tests/intersections.py)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numba
import numpy as np
from intersections import intersecting_pairs
from scipy.spatial import cKDTree

from meshdeform.io import load
from meshdeform.simulate import simulate
from pipeline.build import build_simulation
from pipeline.recipe import apply_overrides, load_recipe


def _make_samples_module(samples_dir: Path):
    spec = importlib.util.spec_from_file_location("make_samples", samples_dir / "make_samples.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_sample_meshes_are_exactly_what_the_script_makes(samples_dir: Path, tmp_path: Path) -> None:
    written = _make_samples_module(samples_dir).make_samples(tmp_path / "meshes", tmp_path / "body")
    committed = {"meshes": samples_dir / "meshes", "body": samples_dir / "recipes" / "body"}
    for folder, origin in committed.items():
        assert sorted(p.name for p in written if p.parent.name == folder) == sorted(p.name for p in origin.iterdir())
    for path in written:
        assert path.read_bytes() == (committed[path.parent.name] / path.name).read_bytes(), path.name


def test_showcase_recipe_gives_every_sample_its_own_scene(samples_dir: Path) -> None:
    recipe = load_recipe(samples_dir / "recipes" / "showcase.toml")
    solvers = {}
    before = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        for mesh_path in sorted((samples_dir / "meshes").iterdir()):
            per_asset = apply_overrides(recipe.for_asset(mesh_path.name), frames=3)
            mesh = load(mesh_path)
            built = build_simulation(per_asset, mesh)
            assert all(count > 0 for count in built.selections.values()), mesh_path.name
            frames = list(simulate(built.model, built.scene, built.settings))
            assert len(frames) == 3
            assert np.isfinite(frames[-1].positions).all()
            solvers[mesh_path.name] = built.settings.solver
    finally:
        numba.set_num_threads(before)
    assert solvers["icosphere.ply"] == "anchor"
    assert solvers["rope.obj"] == "verlet"
    assert solvers["flag.obj"] == "xpbd"


#: frames of the fold sample baked by the test: the flap has landed by frame 30 (of the sample's 96)
FOLD_FRAMES = 48
#: metres: within this in X and Z, a vertex lies over or under another part of the sheet
OVERLAP_XZ = 0.04
#: metres: vertices this far apart in the rest sheet (3 grid spacings) are not neighbours
APART_AT_REST = 0.2
#: metres of slack allowed on each contact distance (the issue's "thickness minus 1 mm")
SLACK = 0.001


def _capsule_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray, radius: float) -> np.ndarray:
    """(V, 3) points -> (V,) distance (m) to the surface of the capsule around segment a-b."""
    axis = b - a
    t = np.clip((points - a) @ axis / (axis @ axis), 0.0, 1.0)
    return np.linalg.norm(points - (a + t[:, None] * axis), axis=1) - radius


def test_fold_sample_folds_over_itself_and_never_through_itself(samples_dir: Path) -> None:
    recipe = apply_overrides(load_recipe(samples_dir / "recipes" / "fold.toml"), frames=FOLD_FRAMES)
    mesh = load(samples_dir / "meshes" / "sheet.obj")
    triangles = mesh.face_indices.reshape(-1, 3)
    assert np.array_equal(mesh.face_offsets, np.arange(0, mesh.face_indices.size + 1, 3))
    bar, floor = recipe.colliders
    assert bar.capsule is not None and floor.ground is not None and recipe.self_collision is not None
    a, b = np.asarray(bar.capsule.a, dtype=np.float64), np.asarray(bar.capsule.b, dtype=np.float64)
    self_thickness = recipe.self_collision.thickness or recipe.material.thickness
    rest = mesh.positions
    built = build_simulation(recipe, mesh)
    frames = 0
    for frame in simulate(built.model, built.scene, built.settings):
        p = frame.positions
        frames += 1
        assert intersecting_pairs(p, triangles) == 0, f"frame {frame.index}"
        assert (p[:, 1] - floor.ground.height).min() >= floor.thickness - SLACK, f"frame {frame.index}"
        assert _capsule_distance(p, a, b, bar.capsule.radius).min() >= bar.thickness - SLACK, f"frame {frame.index}"
        # parts of the sheet that are not neighbours keep the self-collision thickness between them
        close = cKDTree(p).query_pairs(2 * self_thickness, output_type="ndarray")
        apart = np.linalg.norm(rest[close[:, 0]] - rest[close[:, 1]], axis=1) > APART_AT_REST
        gaps = np.linalg.norm(p[close[apart, 0]] - p[close[apart, 1]], axis=1)
        assert gaps.size == 0 or gaps.min() >= self_thickness - SLACK, f"frame {frame.index}"
    assert frames == FOLD_FRAMES
    # settled on the floor: off the bar, every vertex below its underside
    assert p[:, 1].max() < min(a[1], b[1]) - bar.capsule.radius
    # folded over itself: many vertices lie over another part of the sheet (a different height,
    # a few cm away in X and Z, far from them in the rest sheet); a sheet lying flat has none
    xz = cKDTree(p[:, [0, 2]]).query_pairs(OVERLAP_XZ, output_type="ndarray")
    xz = xz[np.linalg.norm(rest[xz[:, 0]] - rest[xz[:, 1]], axis=1) > APART_AT_REST]
    rise = p[xz[:, 0], 1] - p[xz[:, 1], 1]
    layered = xz[np.abs(rise) >= self_thickness - SLACK]
    on_top = np.unique(np.where(p[layered[:, 0], 1] > p[layered[:, 1], 1], layered[:, 0], layered[:, 1]))
    assert on_top.size >= 0.2 * len(p), on_top.size
