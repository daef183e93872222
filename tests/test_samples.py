"""The bundled samples: reproducible from their script, and the showcase recipe covers each of them."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numba
import numpy as np

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
    written = _make_samples_module(samples_dir).make_samples(tmp_path)
    committed = sorted(p.name for p in (samples_dir / "meshes").iterdir())
    assert sorted(p.name for p in written) == committed
    for path in written:
        assert path.read_bytes() == (samples_dir / "meshes" / path.name).read_bytes(), path.name


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
