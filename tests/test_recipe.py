"""Recipes: TOML -> validated Recipe, errors with file / key path / line, merging, overrides, hash, `check`."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from factories import command_app, grid_sheet, write_grid
from typer.testing import CliRunner

from meshdeform.errors import RecipeError
from pipeline.build import build_simulation
from pipeline.commands.check import register
from pipeline.recipe import (
    apply_overrides,
    load_recipe,
    merge_recipe_data,
    parse_recipe,
    recipe_from_data,
    recipe_hash,
)

SAMPLES = Path(__file__).resolve().parent.parent / "samples" / "recipes"

FULL = """\
[simulation]
solver = "verlet"
fps = 30
frames = 12
substeps = 4
iterations = 5
damping = 0.2
up = "y"
seed = 3

[simulation.verlet]
tethers = 1.05

[simulation.springs]
strain_limit = 1.1

[material]
structural = { stiffness = 1.0, compression = 0.5 }
shear = { stiffness = 0.5, enabled = false }
density = 0.3

[[pins]]
select = { box = { min = [0, 0.9, 0], max = [1, 1, 1] }, relative = true }
animate = [
  { time = 0.0, translate = [0, 0, 0] },
  { time = 2.0, translate = [0.5, 0, 0] },
]

[[impacts]]
time = 0.5
point = [0.5, 0.5, 0.1]
radius = 0.3
strength = -4.0

[wind]
velocity = [2, 0, 0]
turbulence = 0.3

[[colliders]]
sphere = { center = [0, 0, 0], radius = 0.3 }
friction = 0.2

[[tears]]
select = { indices = [1, 2] }
max_stretch = 1.6

[output]
formats = ["obj", "usd"]
preview = { every = 12, video = "mp4", color = "strain" }
"""


def error_of(text: str, name: str = "bad.toml") -> str:
    with pytest.raises(RecipeError) as info:
        parse_recipe(text, name)
    message = str(info.value)
    assert "\n" not in message
    return message


def test_full_recipe_parses_into_typed_sections() -> None:
    r = parse_recipe(FULL, "full.toml")
    assert r.simulation.solver == "verlet" and r.simulation.frames == 12 and r.simulation.fps == 30.0
    assert r.simulation.solver_options().tethers == 1.05
    assert r.simulation.solver_options().iterations == 5
    assert r.simulation.given_options("springs") == {"strain_limit": 1.1}  # validated, not in force
    assert r.material.to_material().structural.compression == 0.5
    assert r.material.to_material().shear.enabled is False
    assert r.pins[0].is_hard and len(r.pins[0].animate) == 2
    assert r.impacts[0].strength == -4.0 and r.impacts[0].direction == "radial"
    assert r.wind is not None and r.wind.turbulence == 0.3
    assert r.colliders[0].kind == "sphere"
    assert r.tears[0].max_stretch == 1.6
    assert r.output.formats == ("obj", "usd")
    assert r.output.preview_options == {"every": 12, "video": "mp4", "color": "strain"}
    with pytest.raises(Exception):  # noqa: B017 - frozen
        r.simulation.frames = 3  # type: ignore[misc]


def test_defaults_and_gravity_following_the_up_axis() -> None:
    r = load_recipe(None)
    assert r.simulation.gravity is None
    assert build_simulation(r, grid_sheet(3)).scene.gravity == (0.0, -9.81, 0.0)
    assert r.pins == () and r.wind is None and r.output.formats == ("obj",)
    z_up = parse_recipe('[simulation]\nup = "z"\n')
    assert build_simulation(z_up, grid_sheet(3)).scene.gravity == (0.0, 0.0, -9.81)
    assert z_up.up_axis == "z"
    given = parse_recipe('[simulation]\nup = "z"\ngravity = [0, -1, 0]\n')
    assert build_simulation(given, grid_sheet(3)).scene.gravity == (0.0, -1.0, 0.0)


@pytest.mark.parametrize("path", sorted(SAMPLES.glob("*.toml")), ids=lambda p: p.name)
def test_sample_recipes_are_valid(path: Path) -> None:
    recipe = load_recipe(path)
    assert recipe.source == path


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        # a typo in a key: the key path, its line and a suggestion
        (
            "[simulation]\nfps = 24\nfrmes = 3\n",
            r"^bad\.toml: simulation\.frmes \(line 3\): unknown key 'frmes' \(did you mean 'frames'\?\)",
        ),
        # a string where a number goes
        (
            '[simulation]\n\nframes = "120"\n',
            r"^bad\.toml: simulation\.frames \(line 3\): expected an integer, got string \"120\"",
        ),
        ('[wind]\nvelocity = [1, "x", 0]\n', r"^bad\.toml: wind\.velocity \(line 2\): expected 3 numbers"),
        # negative radius, in an array of tables
        (
            "[[impacts]]\ntime = 0\npoint = [0, 0, 0]\nradius = 1\nstrength = 1\n\n[[impacts]]\ntime = 1\n"
            "point = [0, 0, 0]\nradius = -0.3\nstrength = 1\n",
            r"^bad\.toml: impacts\[1\]\.radius \(line 10\): must be greater than 0",
        ),
        # deep inside an inline table spread over lines
        (
            "[[pins]]\nselect = { any = [\n  { indices = [1] },\n  { box = { min = [0, 0, 0], max = [1, 1] } },\n] }\n",
            r"^bad\.toml: pins\[0\]\.select\.any\[1\]\.box\.max \(line 4\): expected 3 numbers \[x, y, z\], got 2",
        ),
        ("[[pins]]\nstiffness = 0.5\n", r"^bad\.toml: pins\[0\]\.select \(line 1\): missing required key 'select'"),
        (
            "[[pins]]\nselect = { box = { min = [0,0,0], max = [1,1,1] }, sphere = { center = [0,0,0], radius = 1 } }",
            r"pins\[0\]\.select \(line 2\): a selection needs exactly one of .* \(found box and sphere\)",
        ),
        (
            '[simulation]\nsolver = "xbpd"\n',
            r"simulation\.solver \(line 2\): unknown solver 'xbpd' \(did you mean 'xpbd'\?\)",
        ),
        ("[simulation]\ndamping = 1.5\n", r"simulation\.damping \(line 2\): must be less than 1"),
        (
            "[simulation]\nstrain_limt = 1.1\n",
            r"simulation\.strain_limt \(line 2\): unknown key .*did you mean 'strain_limit'",
        ),
        ('[output]\nformats = ["obj", "pc3"]\n', r"output\.formats \(line 2\): unknown format 'pc3'"),
        (
            "[[pins]]\nselect = { indices = [0] }\nanimate = [\n {time = 1.0},\n {time = 0.5},\n]\n",
            r"pins\[0\]\.animate \(line 3\): keyframe times must increase",
        ),
        ("[wind]\nturbulence = 0.5\n", r"wind \(line 1\): turbulence is a fraction of the wind speed"),
        ("[[colliders]]\nmesh = 'table.obj'\nrelative = true\n", r"colliders\[0\] \(line 1\): relative does not apply"),
        (
            "[material]\nstructural = { stiffness = 2 }\n",
            r"material\.structural\.stiffness \(line 2\): must be at most 1",
        ),
        ("[[tears]]\nmax_stretch = 1.0\n", r"tears\[0\]\.max_stretch \(line 2\): must be greater than 1"),
        ("frames = 3\n", r"^bad\.toml: frames \(line 1\): unknown key 'frames'"),
        ("[simulation]\nframes = \n", r"^bad\.toml: line 2: invalid TOML"),
    ],
)
def test_bad_recipes_give_one_line_with_file_key_path_and_line(text: str, expected: str) -> None:
    assert re.search(expected, error_of(text)), error_of(text)


def test_formats_and_solvers_are_the_registries_names() -> None:
    from meshdeform.export import EXPORTERS
    from meshdeform.solvers import SOLVERS

    assert parse_recipe(f"[output]\nformats = {list(EXPORTERS)!r}\n".replace("'", '"')).output.formats == tuple(
        EXPORTERS
    )
    assert error_of('[output]\nformats = ["objj"]\n').endswith(
        f"unknown format 'objj' (did you mean 'obj'?); choose from: {', '.join(EXPORTERS)}"
    )
    for name in SOLVERS:
        assert parse_recipe(f'[simulation]\nsolver = "{name}"\n').simulation.solver == name
    assert error_of('[simulation]\nsolver = "nope"\n').endswith(f"choose one of: {', '.join(sorted(SOLVERS))}")


def test_a_recipe_that_tears_is_refused_the_formats_that_need_a_fixed_vertex_count() -> None:
    from meshdeform.export import EXPORTERS

    tears = "[[tears]]\nmax_stretch = 1.5\n[output]\nformats = [{}]\n"
    following = [name for name, cls in EXPORTERS.items() if cls.supports_topology_change]
    for name, cls in EXPORTERS.items():
        if cls.supports_topology_change:
            assert parse_recipe(tears.format(f'"{name}"'), "t.toml").output.formats == (name,)
            continue
        with pytest.raises(RecipeError) as info:
            parse_recipe(tears.format(f'"obj", "{name}"'), "t.toml")
        message = str(info.value)
        assert message.startswith(f"t.toml: output.formats[1] (line 4): {name} needs a fixed vertex count"), message
        assert f"write {', '.join(following[:-1])} or {following[-1]} instead" in message


def test_an_assets_rule_that_adds_tearing_to_a_point_cache_recipe_is_refused_at_its_line() -> None:
    text = '[output]\nformats = ["pc2"]\n[[assets]]\nglob = "*"\n[[assets.tears]]\nmax_stretch = 1.5\n'
    with pytest.raises(RecipeError) as info:
        parse_recipe(text, "t.toml")
    assert str(info.value).startswith("t.toml: assets[0].output.formats[0]"), str(info.value)
    assert "pc2 needs a fixed vertex count" in str(info.value)


def test_load_recipe_errors_name_the_file(tmp_path: Path) -> None:
    path = tmp_path / "r.toml"
    path.write_text("[material]\ndensity = 'heavy'\n")
    with pytest.raises(RecipeError, match=re.escape(f"{path}: material.density (line 2): expected a number")):
        load_recipe(path)
    with pytest.raises(RecipeError, match="no such recipe file"):
        load_recipe(tmp_path / "missing.toml")


def test_empty_selection_is_a_build_error_with_key_path_and_line() -> None:
    text = (
        "[simulation]\nsolver = 'verlet'\n\n[[pins]]\nselect = { indices = [0] }\n\n[[pins]]\n"
        "select = { box = { min = [5, 5, 5], max = [6, 6, 6] } }\n"
    )
    recipe = parse_recipe(text, "pins.toml")
    with pytest.raises(RecipeError, match=r"^pins\.toml: pins\[1\]\.select \(line 8\): selects no vertex"):
        build_simulation(recipe, grid_sheet(4))
    bad_group = parse_recipe("[[pins]]\nselect = { all = [ { indices = [0] }, { group = 'pole' } ] }\n", "g.toml")
    with pytest.raises(
        RecipeError, match=r"^g\.toml: pins\[0\]\.select\.all\[1\]\.group \(line 2\): the mesh has no group"
    ):
        build_simulation(bad_group, grid_sheet(4))


def test_merge_deep_merges_tables_and_replaces_arrays() -> None:
    base = {"simulation": {"fps": 24, "frames": 10}, "pins": [{"a": 1}, {"b": 2}], "wind": {"velocity": [1, 0, 0]}}
    over = {"simulation": {"frames": 5}, "pins": [{"c": 3}], "wind": {"velocity": [0, 0, 2]}}
    merged = merge_recipe_data(base, over)
    assert merged == {"simulation": {"fps": 24, "frames": 5}, "pins": [{"c": 3}], "wind": {"velocity": [0, 0, 2]}}
    assert base["simulation"]["frames"] == 10  # inputs untouched


def test_asset_rules_override_per_glob_and_are_validated_at_load() -> None:
    text = FULL + '\n[[assets]]\nglob = "heavy/*.obj"\nmaterial = { density = 2.0 }\nsimulation = { frames = 5 }\n'
    r = parse_recipe(text, "a.toml")
    heavy = r.for_asset("heavy/cape.obj")
    assert heavy.material.density == 2.0 and heavy.simulation.frames == 5
    assert heavy.material.structural.compression == 0.5  # merged, not replaced
    plain = r.for_asset("light/cape.obj")
    assert plain.material.density == 0.3
    assert recipe_hash(heavy) != recipe_hash(plain)
    bad = FULL + '\n[[assets]]\nglob = "*.ply"\nmaterial = { density = -1 }\n'
    with pytest.raises(RecipeError, match=r"assets\[0\]\.material\.density \(line \d+\): must be greater than 0"):
        parse_recipe(bad, "a.toml")


def test_apply_overrides_win_and_add_hard_pins() -> None:
    r = parse_recipe(FULL, "full.toml")
    o = apply_overrides(
        r,
        solver="xpbd",
        frames=7,
        fps=12,
        gravity=(0, 0, -9.81),
        pins=["indices:0,5", "box:0,0,0,1,0.1,1"],
        formats=["usd"],
    )
    assert (o.simulation.solver, o.simulation.frames, o.simulation.fps) == ("xpbd", 7, 12.0)
    assert o.simulation.gravity == (0.0, 0.0, -9.81)
    assert o.output.formats == ("usd",)
    assert len(o.pins) == 3 and o.pins[1].select.indices == (0, 5) and o.pins[2].select.relative
    assert r.simulation.frames == 12  # the original is unchanged
    built = build_simulation(o, grid_sheet(6))
    assert built.selections["pins[1].select"] == 2 and built.selections["pins[2].select"] == 6
    with pytest.raises(RecipeError, match=r"^command line: --frames: must be at least 1"):
        apply_overrides(r, frames=0)
    with pytest.raises(RecipeError, match=r"^command line: --pin 'box:1,2': expected 6 numbers"):
        apply_overrides(r, pins=["box:1,2"])
    far = apply_overrides(r, pins=["indices:99"])
    with pytest.raises(RecipeError, match=r"^command line: --pin 'indices:99': .*out of range"):
        build_simulation(far, grid_sheet(6))


def test_recipe_hash_is_stable_and_normalised() -> None:
    a = parse_recipe("[simulation]\nframes = 10\nfps = 24\n")
    b = parse_recipe("# same content, other spelling\n[simulation]\nfps = 24.0\nframes = 10\nseed = 0\n")
    c = parse_recipe("[simulation]\nframes = 11\n")
    assert recipe_hash(a) == recipe_hash(b)
    assert recipe_hash(a) != recipe_hash(c)
    assert re.fullmatch(r"[0-9a-f]{64}", recipe_hash(a))


def test_recipe_from_data_validates_merged_data() -> None:
    r = recipe_from_data({"simulation": {"frames": 4}}, "sidecar")
    assert r.simulation.frames == 4
    with pytest.raises(RecipeError, match=r"^sidecar: simulation\.frames: expected an integer"):
        recipe_from_data({"simulation": {"frames": "x"}}, "sidecar")


def test_check_command_prints_selection_counts_or_one_error_line(tmp_path: Path) -> None:
    runner = CliRunner()
    mesh = tmp_path / "flag.obj"
    write_grid(mesh, 8, 5, size=(2.0, 1.0))
    recipe = tmp_path / "r.toml"
    recipe.write_text(
        "[[pins]]\nselect = { box = { min = [0, 0.99, 0], max = [1, 1, 1] }, relative = true }\n"
        "[[tears]]\nselect = { indices = [3, 4, 5] }\nmax_stretch = 1.5\n"
    )
    result = runner.invoke(command_app(register), ["check", str(recipe), "--mesh", str(mesh)])
    assert result.exit_code == 0, result.output
    assert result.stdout.startswith(f"OK {recipe}")
    assert re.search(r"pins\[0\]\.select\s+8 vertices", result.stdout)
    assert re.search(r"tears\[0\]\.select\s+3 vertices", result.stdout)

    bad = tmp_path / "bad.toml"
    bad.write_text("[simulation]\nframes = -1\n")
    result = runner.invoke(command_app(register), ["check", str(bad)])
    assert result.exit_code == 2
    assert result.stdout == ""
    assert result.stderr.strip() == f"error: {bad}: simulation.frames (line 2): must be at least 1, got -1"

    empty = tmp_path / "empty.toml"
    empty.write_text("[[pins]]\nselect = { sphere = { center = [9, 9, 9], radius = 0.1 } }\n")
    result = runner.invoke(command_app(register), ["check", str(empty), "--mesh", str(mesh)])
    assert result.exit_code == 2
    assert "pins[0].select (line 2): selects no vertex of flag.obj (40 vertices)" in result.stderr


def test_build_maps_recipe_onto_model_scene_and_settings() -> None:
    r = parse_recipe(FULL, "full.toml")
    built = build_simulation(r, grid_sheet(6))
    assert built.settings.solver == "verlet" and built.settings.substeps == 4 and built.settings.fps == 30.0
    options = built.settings.options  # the verlet solver's own options
    assert type(options).__name__ == "VerletOptions" and options.iterations == 5 and options.tethers == 1.05
    assert built.scene.gravity == (0.0, -9.81, 0.0)
    assert built.model.pinned.sum() == 6
    assert built.scene.pin_motion is not None
    np.testing.assert_allclose(
        built.scene.pin_motion(2.0)[:, 0] - built.model.rest_positions[built.model.pinned, 0], 0.5
    )
    assert len(built.scene.forces) == 2 and len(built.scene.constraints) == 1
    assert built.model.material.density == 0.3
    assert built.scene.tearing is not None


SAMPLE_MESHES = {
    "flag.toml": "flag.obj",
    "curtain.toml": "curtain.obj",
    "stressball.toml": "icosphere.ply",
    "blackhole.toml": "sheet.obj",
    "drop.toml": "sheet.obj",
    "fold.toml": "sheet.obj",
    "rope.toml": "rope.obj",
    "tear.toml": "curtain.obj",
    "cape.toml": "cape.obj",
}


@pytest.fixture(scope="module")
def sample_meshes(tmp_path_factory) -> Path:
    import importlib.util

    spec = importlib.util.spec_from_file_location("make_samples", SAMPLES.parent / "make_samples.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    out = tmp_path_factory.mktemp("meshes")
    module.make_samples(out)
    return out


@pytest.mark.parametrize(("recipe_name", "mesh_name"), sorted(SAMPLE_MESHES.items()))
def test_sample_recipes_build_on_their_sample_meshes_and_run(sample_meshes: Path, recipe_name, mesh_name) -> None:
    import numba

    from meshdeform.io import load
    from meshdeform.simulate import simulate

    # every single-mesh sample recipe is covered (showcase.toml spans all meshes: tests/test_samples.py)
    assert {p.name for p in SAMPLES.glob("*.toml")} - {"showcase.toml"} == set(SAMPLE_MESHES)
    recipe = apply_overrides(load_recipe(SAMPLES / recipe_name), frames=2)
    built = build_simulation(recipe, load(sample_meshes / mesh_name))
    assert all(count > 0 for count in built.selections.values())
    before = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        frames = list(simulate(built.model, built.scene, built.settings))
    finally:
        numba.set_num_threads(before)
    assert len(frames) == 2 and np.isfinite(frames[-1].positions).all()


def test_recipes_pickle_for_worker_processes() -> None:
    import pickle

    r = apply_overrides(parse_recipe(FULL, "full.toml"), pins=["indices:30"])
    copy = pickle.loads(pickle.dumps(r))
    assert copy == r and recipe_hash(copy) == recipe_hash(r)
    assert copy.label == "full.toml" and copy.line_of(("pins", 0, "select")) == 23
    assert copy.simulation.solver_options() == r.simulation.solver_options()
    with pytest.raises(RecipeError, match=r"^command line: --pin 'indices:30': .*out of range"):
        build_simulation(copy, grid_sheet(3))


@pytest.mark.parametrize(
    ("pin", "expected"),
    [
        ("indices:1000000000000000000000000000000", "expected vertex indices like indices:0,5,9"),
        ("indices:nan", "expected vertex indices like indices:0,5,9"),
        ("indices:1e3", "expected vertex indices like indices:0,5,9"),
        ("indices:-1", "expected vertex indices like indices:0,5,9"),
        ("box:0,0,0,1,1,nan", "expected finite numbers after 'box:'"),
        ("box:0,0,0,1,inf,1", "expected finite numbers after 'box:'"),
    ],
)
def test_command_line_pins_refuse_huge_and_non_finite_numbers(pin: str, expected: str) -> None:
    """A --pin typo is one RecipeError line, never an OverflowError or a NaN bound."""
    with pytest.raises(RecipeError, match=rf"^command line: --pin '{re.escape(pin)}': {re.escape(expected)}$"):
        apply_overrides(parse_recipe(""), pins=[pin])


# ---------------------------------------------------------------------------------------------
# [simulation.<solver>] tables, and the deprecated flat keys
# ---------------------------------------------------------------------------------------------

TABLES = """\
[simulation]
solver = "xpbd"
iterations = 3

[simulation.xpbd]
tethers = 1.05
partitions = 1

[simulation.anchor]
anchor_stiffness = 30
anchor_frame = "centroid"
"""


def test_the_solver_in_force_reads_its_table_and_the_others_are_validated_for_a_switch() -> None:
    r = parse_recipe(TABLES, "t.toml")
    options = r.simulation.solver_options()
    assert type(options).__name__ == "XPBDOptions"
    assert (options.iterations, options.damping, options.tethers, options.partitions) == (3, 0.9, 1.05, 1)
    assert r.deprecation is None
    anchor = apply_overrides(r, solver="anchor").simulation.solver_options()
    assert (anchor.anchor_stiffness, anchor.anchor_frame, anchor.iterations) == (30.0, "centroid", 3)
    assert isinstance(anchor.anchor_stiffness, float)
    springs = apply_overrides(r, solver="springs").simulation.solver_options()
    assert type(springs).__name__ == "SpringsOptions"
    bad = TABLES.replace('anchor_frame = "centroid"', 'anchor_frame = "wrld"')
    assert re.match(r"t\.toml: simulation\.anchor\.anchor_frame \(line 11\): must be one of", error_of(bad, "t.toml"))


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        # a key of another solver's table names that solver
        (
            "[simulation.xpbd]\nanchor_stiffness = 30\n",
            "simulation.xpbd.anchor_stiffness (line 2): anchor_stiffness is an option of anchor, not of xpbd: "
            "put it in [simulation.anchor]",
        ),
        (
            "[simulation.verlet]\nstrain_limit = 1.1\n",
            "simulation.verlet.strain_limit (line 2): strain_limit is an option of anchor and springs, not of "
            "verlet: put it in [simulation.anchor] or [simulation.springs]",
        ),
        (
            "[simulation.xpbd]\niterations = 3\n",
            "simulation.xpbd.iterations (line 2): iterations is a key of [simulation] (every solver takes it)",
        ),
        (
            "[simulation.xpbd]\ntether = 1.0\n",
            "simulation.xpbd.tether (line 2): unknown key 'tether' (did you mean 'tethers'?); allowed keys: ",
        ),
        ("[simulation.implicit]\ntethers = 1.0\n", "tethers is an option of verlet and xpbd, not of implicit"),
        ("[simulation]\nxpbd = 1\n", "simulation.xpbd (line 2): expected a table of xpbd's options, got integer 1"),
        (
            "[simulation]\nxpdb = { tethers = 1 }\n",
            "simulation.xpdb (line 2): unknown key 'xpdb' (did you mean 'xpbd'?); allowed keys: solver, fps",
        ),
        # flat keys: the solver in force's are read (deprecated), another solver's are an error
        (
            '[simulation]\nsolver = "xpbd"\nanchor_stiffness = 30\n',
            "simulation.anchor_stiffness (line 3): anchor_stiffness is an option of anchor, not of xpbd (the "
            "solver in force): put it in [simulation.anchor]",
        ),
        (
            '[simulation]\nsolver = "xpbd"\ntethers = 1.0\n[simulation.xpbd]\ntethers = 1.1\n',
            "simulation.tethers (line 3): tethers is given twice, here and in [simulation.xpbd]",
        ),
        (
            '[simulation]\nsolver = "xpbd"\ntethers = 0.5\n',
            "simulation.tethers (line 3): must be 0 (no tethers) or at least 1",
        ),
    ],
)
def test_solver_table_mistakes_are_one_line_naming_the_key_and_where_it_belongs(text: str, expected: str) -> None:
    assert expected in error_of(text, "r.toml")


FLAT = '[simulation]\nsolver = "verlet"\niterations = 4\npartitions = 2\ntethers = 1.05\n'
MOVED = '[simulation]\nsolver = "verlet"\niterations = 4\n\n[simulation.verlet]\npartitions = 2\ntethers = 1.05\n'


def test_flat_solver_keys_still_work_with_one_deprecation_line_naming_the_table() -> None:
    flat, moved = parse_recipe(FLAT, "f.toml"), parse_recipe(MOVED, "m.toml")
    assert flat.simulation.solver_options() == moved.simulation.solver_options()
    assert recipe_hash(flat) == recipe_hash(moved)  # results made before the move stay up to date
    assert moved.deprecation is None
    assert flat.deprecation == (
        "f.toml: simulation.partitions (line 4): solver options directly under [simulation] are deprecated and "
        "will be refused in the next release: move partitions, tethers to [simulation.verlet]"
    )
    rule = '\n[[assets]]\nglob = "*.ply"\nsimulation = { solver = "anchor", anchor_stiffness = 30 }\n'
    layered = parse_recipe(MOVED + rule, "a.toml")
    assert layered.deprecation is not None and layered.deprecation.startswith(
        "a.toml: assets[0].simulation.anchor_stiffness (line 11): "
    )
    assert layered.deprecation.endswith("move anchor_stiffness to assets[0].simulation.anchor")
    assert layered.for_asset("ball.ply").simulation.solver_options().anchor_stiffness == 30.0
    tables = rule.replace("anchor_stiffness = 30", "anchor = { anchor_stiffness = 30 }")
    assert recipe_hash(parse_recipe(MOVED + tables)) == recipe_hash(parse_recipe(MOVED + rule))


def test_switching_solver_on_the_command_line_names_the_option_for_a_foreign_flat_key() -> None:
    flat = parse_recipe(FLAT, "f.toml")
    assert apply_overrides(flat, solver="xpbd").simulation.solver_options().tethers == 1.05  # xpbd has tethers
    with pytest.raises(RecipeError) as info:
        apply_overrides(flat, solver="springs")
    assert str(info.value) == (
        "command line: --solver: partitions is an option of verlet and xpbd, not of springs (the solver in "
        "force): put it in [simulation.verlet] or [simulation.xpbd]"
    )
    assert apply_overrides(parse_recipe(MOVED), solver="springs").simulation.solver == "springs"


def test_tearing_runs_without_the_solvers_tethers_unless_the_table_asks_for_them() -> None:
    xpbd = '[simulation]\nsolver = "xpbd"\n'
    tears = "[[tears]]\nmax_stretch = 1.5\n"
    default = build_simulation(parse_recipe(xpbd + tears), grid_sheet(4)).settings.options
    asked = build_simulation(parse_recipe(xpbd + "[simulation.xpbd]\ntethers = 1.2\n" + tears), grid_sheet(4))
    assert default.tethers is None and asked.settings.options.tethers == 1.2
    assert build_simulation(parse_recipe(xpbd), grid_sheet(4)).settings.options.tethers == 1.0


def test_the_deprecation_line_goes_to_stderr_once_and_into_the_batch_log(tmp_path: Path) -> None:
    from pipeline.batch import run_batch
    from pipeline.cli import app

    assets = tmp_path / "assets"
    assets.mkdir()
    write_grid(assets / "a.obj", 3)
    write_grid(assets / "b.obj", 3)
    recipe = tmp_path / "flat.toml"
    recipe.write_text(FLAT + "frames = 2\n[[assets]]\nglob = 'a.obj'\nmaterial = { density = 0.3 }\n")
    expected = parse_recipe(recipe.read_text(), str(recipe)).deprecation
    assert expected is not None
    simulate = ["simulate", str(assets / "a.obj"), "-r", str(recipe), "-o", str(tmp_path / "one"), "-q"]
    for args in (["check", str(recipe)], simulate):
        result = CliRunner().invoke(app, args)
        assert result.exit_code == 0, result.output
        assert result.stderr == f"warning: {expected}\n", args
    run_batch(assets, recipe, tmp_path / "batch", jobs=0)
    log = (tmp_path / "batch" / "batch.log").read_text()
    assert log.count(expected) == 1


@pytest.mark.parametrize("solver", ["springs", "anchor"])
def test_iterations_given_to_a_solver_without_them_are_reported_as_none_with_a_warning(solver: str) -> None:
    """`springs` and `anchor` step explicitly and sweep nothing: `iterations = 10` changes nothing
    (the same bytes as without it), the settings in force say 0 iterations (the report's
    `iterations`), and the build warns that the key has no effect; xpbd keeps the 10 it is given."""
    from meshdeform.simulate import simulate

    mesh = grid_sheet(6)
    head = f'[simulation]\nsolver = "{solver}"\nframes = 2\n'
    given = build_simulation(parse_recipe(head + "iterations = 10\n"), mesh)
    plain = build_simulation(parse_recipe(head), mesh)
    assert given.settings.iterations == 0
    (warning,) = [w for w in given.warnings if w.startswith("simulation.iterations")]
    assert f"the {solver} solver has no iterations" in warning
    assert not [w for w in plain.warnings if w.startswith("simulation.iterations")]
    ran = [f.welded_positions for f in simulate(given.model, given.scene, given.settings)]
    same = [f.welded_positions for f in simulate(plain.model, plain.scene, plain.settings)]
    assert all(a.tobytes() == b.tobytes() for a, b in zip(ran, same, strict=True))
    sweeping = build_simulation(parse_recipe('[simulation]\nsolver = "xpbd"\nframes = 2\niterations = 10\n'), mesh)
    assert sweeping.settings.iterations == 10 and not sweeping.warnings


def test_a_pin_attached_to_no_collider_is_refused_at_its_line() -> None:
    text = (
        '[[colliders]]\nname = "pole"\nsphere = { center = [0, 0, 0], radius = 0.1 }\n'
        '[[pins]]\nselect = { indices = [0] }\nattach = "pol"\n'
    )
    with pytest.raises(RecipeError) as info:
        parse_recipe(text, "t.toml")
    assert str(info.value) == "t.toml: pins[0].attach (line 6): 'pol' names no collider (named colliders: pole)"
