"""No runaway work: recipe limits at their boundary, strict solver options, odd encodings, the run's
cost estimate printed by `check`, the disk-space refusal, and a corpus of mutated recipes that all
end quickly with exit 0 or 2 and at most one line on stderr."""

from __future__ import annotations

import dataclasses
import json
import math
import re
import subprocess
import sys
import time
from collections import namedtuple
from pathlib import Path
from typing import Any

import pytest
from factories import grid_sheet, write_grid
from typer.testing import CliRunner

from meshdeform.errors import RecipeError
from meshdeform.export import EXPORTERS
from meshdeform.io import load
from pipeline import estimate
from pipeline.cli import app
from pipeline.estimate import InsufficientDiskSpace, estimate_run, output_bytes, require_disk_space
from pipeline.job import run_job
from pipeline.output_folder import MARKER_NAME, REPORT_NAME
from pipeline.recipe import LIMITS, apply_overrides, load_recipe, parse_recipe

DOCS = Path(__file__).resolve().parent.parent / "docs" / "recipes.md"
runner = CliRunner()


def error_of(text: str) -> str:
    with pytest.raises(RecipeError) as info:
        parse_recipe(text, "r.toml")
    message = str(info.value)
    assert "\n" not in message
    return message


# ---------------------------------------------------------------------------------------------
# each limit: the limit itself is accepted, one step past it is refused with one line naming it
# ---------------------------------------------------------------------------------------------

IMPACT = "[[impacts]]\ntime = 0\npoint = [0, 0, 0]\nradius = 1\nstrength = 1\nevery = 0.1\ncount = {}\n"
# key -> (recipe with {} for the value, the limit, one step past it, the key path in the message)
BOUNDARIES = {
    "simulation.frames": ("[simulation]\nframes = {}\n", 1_000_000, 1_000_001, "simulation.frames (line 2)"),
    "simulation.substeps": (
        '[simulation]\nsolver = "springs"\nsubsteps = {}\n',
        100_000,
        100_001,
        "simulation.substeps (line 3)",
    ),
    "simulation.iterations": (
        "[simulation]\nsubsteps = 1\niterations = {}\n",
        100_000,
        100_001,
        "simulation.iterations (line 3)",
    ),
    "simulation.fps": ("[simulation]\nfps = {}\n", 10_000, 10_000.5, "simulation.fps (line 2)"),
    "simulation.start_frame": ("[simulation]\nstart_frame = {}\n", 1_000_000, 1_000_001, "simulation.start_frame"),
    "simulation.tear_burst": ("[simulation]\ntear_burst = {}\n", 100_000, 100_001, "simulation.tear_burst"),
    "simulation.<solver>.strain_iterations": (
        "[simulation.springs]\nstrain_iterations = {}\n",
        100_000,
        100_001,
        "simulation.springs.strain_iterations (line 2)",
    ),
    "simulation.<solver>.partitions": (
        "[simulation.verlet]\npartitions = {}\n",
        1024,
        1025,
        "simulation.verlet.partitions (line 2)",
    ),
    "simulation.<solver>.anchor_stiffness": (
        "[simulation.anchor]\nanchor_stiffness = {}\n",
        1e6,
        1.0001e6,
        "simulation.anchor.anchor_stiffness (line 2)",
    ),
    "simulation.<solver>.uniform_scale": (
        "[simulation.anchor]\nuniform_scale = {}\n",
        1000,
        1000.5,
        "simulation.anchor.uniform_scale (line 2)",
    ),
    "impacts[].count": (IMPACT, 1_000_000, 1_000_001, "impacts[0].count (line 7)"),
    "wind.turbulence": ("[wind]\nvelocity = [1, 0, 0]\nturbulence = {}\n", 100, 100.5, "wind.turbulence (line 3)"),
    "output.preview.every": ("[output]\npreview = {{ every = {} }}\n", 1_000_000, 1_000_001, "output.preview.every"),
    "output.preview.sheet_tile_width": (
        "[output]\npreview = {{ sheet_tile_width = {} }}\n",
        8192,
        8193,
        "output.preview.sheet_tile_width",
    ),
    "output.preview.sheet_columns": (
        "[output]\npreview = {{ sheet_columns = {} }}\n",
        1000,
        1001,
        "output.preview.sheet_columns",
    ),
}
# limits tested on their own below
SPECIAL = {"simulation.substeps x iterations", "any number", "any integer", "recipe file size", "tables in one array"}


def test_every_limit_is_tested_here_and_listed_in_the_docs() -> None:
    assert set(BOUNDARIES) | SPECIAL == set(LIMITS)
    section = DOCS.read_text(encoding="utf-8").split("## Limits", 1)[1].split("\n## ", 1)[0]
    for key in BOUNDARIES:
        shown = key.replace("[]", "[i]")
        row = next((line for line in section.splitlines() if line.startswith(f"| `{shown}`")), None)
        assert row is not None, f"{key} is not in the Limits table of docs/recipes.md"
        limit = LIMITS[key].maximum
        words = {f"{limit:g}", str(int(limit)), "10^6" if limit == 1e6 else ""}
        assert any(w and w in row for w in words), row


@pytest.mark.parametrize("key", sorted(BOUNDARIES))
def test_limit_is_accepted_and_one_step_past_it_refused(key: str) -> None:
    text, limit, past, where = BOUNDARIES[key]
    parse_recipe(text.format(limit))
    message = error_of(text.format(past))
    assert f"r.toml: {where}" in message, message
    assert re.search(rf"{re.escape(str(past))}.* is above the limit of {re.escape(f'{limit:g}')}\b", message) or (
        f"is above the limit of {int(limit)}" in message
    ), message


def test_fps_lower_limit() -> None:
    parse_recipe("[simulation]\nfps = 0.01\n")
    assert "simulation.fps (line 2): 0.005 is below the limit of 0.01 frames per second" in error_of(
        "[simulation]\nfps = 0.005\n"
    )


def test_frames_message_is_the_one_line_of_the_issue() -> None:
    assert error_of("# a flag\n\n[simulation]\nframes = 5000000\n") == (
        "r.toml: simulation.frames (line 4): 5000000 is above the limit of 1000000 frames"
    )


def test_substeps_times_iterations_uses_the_solver_defaults() -> None:
    # xpbd iterates twice per substep by default: 50000 substeps are 100000 sweeps, 50001 too many
    parse_recipe('[simulation]\nsolver = "xpbd"\nsubsteps = 50000\n')
    message = error_of('[simulation]\nsolver = "xpbd"\nsubsteps = 50001\n')
    assert message == (
        "r.toml: simulation.substeps (line 3): 50001 substeps x 2 iterations (xpbd's default) = 100002 "
        "is above the limit of 100000 solver sweeps per frame"
    )
    # implicit: 8 substeps of 3 iterations by default
    parse_recipe('[simulation]\nsolver = "implicit"\niterations = 12500\n')
    assert "8 substeps (implicit's default) x 12501 iterations = 100008" in error_of(
        '[simulation]\nsolver = "implicit"\niterations = 12501\n'
    )
    parse_recipe('[simulation]\nsolver = "implicit"\nsubsteps = 33333\n')
    message = error_of('[simulation]\nsolver = "implicit"\nsubsteps = 33334\n')
    assert "33334 substeps x 3 iterations (implicit's default) = 100002" in message
    # springs have no sweeps: iterations do not multiply their work
    parse_recipe('[simulation]\nsolver = "springs"\nsubsteps = 100000\niterations = 50\n')
    # verlet with both given: the message names substeps, the line is substeps'
    message = error_of('[simulation]\nsolver = "verlet"\nsubsteps = 400\niterations = 400\n')
    assert message.startswith("r.toml: simulation.substeps (line 3): 400 substeps x 400 iterations = 160000")


def test_limits_hold_for_merged_asset_rules() -> None:
    message = error_of('[[assets]]\nglob = "*.obj"\nsimulation = { frames = 2000000 }\n')
    assert "assets[0].simulation.frames" in message and "above the limit of 1000000 frames" in message


def test_command_line_overrides_meet_the_same_limits() -> None:
    recipe = parse_recipe("[simulation]\nsubsteps = 5000\n", "r.toml")
    cases = {
        "frames": ({"frames": 1_000_001}, "command line: --frames: 1000001 is above the limit of 1000000 frames"),
        "substeps": ({"substeps": 100_001}, "command line: --substeps: 100001 is above the limit"),
        # the recipe's 5000 substeps times the option's 30 iterations: the option is named
        "iterations": ({"iterations": 30}, "command line: --iterations: 5000 substeps x 30 iterations = 150000"),
        "huge": ({"frames": 10**30}, "command line: --frames: " + str(10**30) + " does not fit in 64 bits"),
        "fps": ({"fps": math.inf}, "command line: --fps: must be a finite number, got inf"),
    }
    for name, (options, expected) in cases.items():
        with pytest.raises(RecipeError) as info:
            apply_overrides(recipe, **options)
        assert str(info.value).startswith(expected), (name, str(info.value))
    assert apply_overrides(recipe, frames=1_000_000).simulation.frames == 1_000_000


# ---------------------------------------------------------------------------------------------
# numbers no key accepts, solver options
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("[simulation]\nfps = nan\n", "simulation.fps (line 2): must be a finite number, got nan"),
        ("[simulation]\ntethers = inf\n", "simulation.tethers (line 2): must be a finite number, got inf"),
        ("[simulation]\ngravity = [0, -inf, 0]\n", "simulation.gravity[1] (line 2): must be a finite number"),
        # keys passed on to the previewer are checked too
        ("[output]\npreview = { fps = nan }\n", "output.preview.fps (line 2): must be a finite number, got nan"),
        ("[[pins]]\nselect = { indices = [0] }\nanimate = [{ time = -inf }]\n", "pins[0].animate[0].time (line 3)"),
        ("[simulation]\nseed = 9223372036854775808\n", "simulation.seed (line 2): 9223372036854775808 does not fit"),
        ("[simulation]\nstart_frame = -9223372036854775809\n", "simulation.start_frame (line 2): -9223372036854775809"),
        ("[[pins]]\nselect = { indices = [1, 99999999999999999999] }\n", "pins[0].select.indices[1] (line 2)"),
        ("[material]\ndensity = 1e300\n", "material.density (line 2): 1e+300 is beyond the limit of 1e+12"),
        ("[[impacts]]\ntime = 0\npoint = [0, 0, 0]\nradius = 10000000000000\nstrength = 1\n", "impacts[0].radius"),
        ("[simulation]\ngravity = [0, -2e12, 0]\n", "simulation.gravity (line 2): -2e+12 is beyond the limit"),
        # an integer beyond 64 bits where a number goes: the 64-bit line, not a type complaint
        ("[wind]\nvelocity = [1, 0, 0]\ndrag = " + "9" * 30 + "\n", f"wind.drag (line 3): {'9' * 30} does not fit"),
    ],
)
def test_non_finite_huge_and_beyond_64_bit_numbers_are_refused(text: str, expected: str) -> None:
    assert expected in error_of(text)


def test_64_bit_and_magnitude_limits_accept_their_boundary() -> None:
    assert parse_recipe("[simulation]\nseed = 9223372036854775807\n").simulation.seed == 2**63 - 1
    assert parse_recipe("[material]\ndensity = 1e12\n").material.density == 1e12
    assert parse_recipe("[material]\ndensity = 1000000000000\n").material.density == 1e12


@pytest.mark.parametrize(
    ("table", "line", "expected"),
    [
        ("xpbd", "tethers = -1.0", "simulation.xpbd.tethers (line 2): must be at least 0, got -1.0"),
        ("verlet", "tethers = 0.5", "simulation.verlet.tethers (line 2): must be 0 (no tethers) or at least 1"),
        ("xpbd", "partitions = -2", "simulation.xpbd.partitions (line 2): must be at least 0, got -2"),
        ("springs", "strain_iterations = -1", "simulation.springs.strain_iterations (line 2): must be at least 0"),
        ("springs", "strain_limit = 0.9", "simulation.springs.strain_limit (line 2): must be at least 1, got 0.9"),
        ("anchor", "anchor_stiffness = -20.0", "simulation.anchor.anchor_stiffness (line 2): must be at least 0"),
        ("anchor", "anchor_damping = -5", "simulation.anchor.anchor_damping (line 2): must be at least 0"),
        ("anchor", "uniform_scale = 0", "simulation.anchor.uniform_scale (line 2): must be greater than 0"),
        ("anchor", 'anchor_frame = "wrld"', "simulation.anchor.anchor_frame (line 2): must be one of 'auto', 'world'"),
        ("anchor", "anchor_frame = 3", "simulation.anchor.anchor_frame (line 2): must be one of"),
        ("springs", 'stable_substeps = "no"', "simulation.springs.stable_substeps (line 2): expected true or false"),
        ("xpbd", "partitions = 2.0", "simulation.xpbd.partitions (line 2): expected an integer, got float 2.0"),
        ("xpbd", "tethers = true", "simulation.xpbd.tethers (line 2): expected a number, got boolean true"),
        ("anchor", "anchor_stiffness = 1e13", "simulation.anchor.anchor_stiffness (line 2): 1e+13 is beyond the limit"),
        ("anchor", "anchor_damping = nan", "simulation.anchor.anchor_damping (line 2): must be a finite number"),
    ],
)
def test_solver_options_are_range_checked(table: str, line: str, expected: str) -> None:
    assert expected in error_of(f"[simulation.{table}]\n{line}\n")


def test_every_option_of_every_solver_is_read_from_its_table_with_strict_types() -> None:
    """Each field of each registered solver's options class (beyond the shared ones) is a key of
    that solver's table: its default is accepted and reaches the options object, a boolean is no
    number, a number no boolean and a string neither."""
    import typing

    from meshdeform.solvers import SOLVERS
    from pipeline.recipe.solver_options import SHARED_OPTIONS, options_class

    checked = 0
    for solver in SOLVERS:
        cls = options_class(solver)
        hints = typing.get_type_hints(cls)
        for field in dataclasses.fields(cls):
            if field.name in SHARED_OPTIONS:
                continue
            text = f'[simulation]\nsolver = "{solver}"\n[simulation.{solver}]\n{field.name} = {{}}\n'
            if field.default is not None:
                options = parse_recipe(text.format(_toml(field.default))).simulation.solver_options()
                assert options == cls(), (solver, field.name)
            wrong = "1" if hints[field.name] is bool else "true"
            assert f"{solver}.{field.name} (line 4): " in error_of(text.format(wrong)), (solver, field.name)
            if hints[field.name] is not str:
                assert f"{solver}.{field.name} (line 4): " in error_of(text.format('"1"')), (solver, field.name)
            checked += 1
    assert checked >= 10


def test_every_option_of_every_solver_is_in_the_docs_table() -> None:
    from meshdeform.solvers import SOLVERS
    from pipeline.recipe.solver_options import own_options

    section = DOCS.read_text(encoding="utf-8").split("### [simulation.<solver>]", 1)[1].split("\n## ", 1)[0]
    rows = [line for line in section.splitlines() if line.startswith("| `")]
    for solver in SOLVERS:
        for option in own_options(solver):
            row = next((r for r in rows if r.split("|")[2].strip() == f"`{option}`"), None)
            assert row is not None and f"`{solver}`" in row.split("|")[1], (solver, option)


def test_solver_options_within_range_reach_the_solver() -> None:
    text = (
        '[simulation]\nsolver = "xpbd"\n[simulation.xpbd]\ntethers = 0\npartitions = 1024\n'
        '[simulation.anchor]\nanchor_frame = "centroid"\nstrain_iterations = 0\n'
    )
    xpbd = parse_recipe(text).simulation.solver_options()
    assert (xpbd.tethers, xpbd.partitions) == (0.0, 1024)
    anchor = apply_overrides(parse_recipe(text), solver="anchor").simulation.solver_options()
    assert (anchor.anchor_frame, anchor.strain_iterations) == ("centroid", 0)


def test_formats_as_a_string_is_one_line_naming_the_array_form() -> None:
    assert error_of('[output]\nformats = "obj"\n') == (
        'r.toml: output.formats (line 2): expected an array of format names, e.g. formats = ["obj"], got string "obj"'
    )


# ---------------------------------------------------------------------------------------------
# odd encodings, through the CLI
# ---------------------------------------------------------------------------------------------

TEXT = "[simulation]\n# café\nframes = 3\n"


@pytest.mark.parametrize(
    ("data", "expected"),
    [
        (TEXT.encode("utf-16"), "is UTF-16 text; a recipe must be UTF-8"),
        (TEXT.encode("utf-16-le"), "is UTF-16 text; a recipe must be UTF-8"),
        (TEXT.encode("utf-32"), "is UTF-32 text; a recipe must be UTF-8"),
        (TEXT.encode("latin-1"), "line 2: not UTF-8 text (invalid continuation byte at byte 18)"),
        (b"[simulation]\nframes = 3\n\x00\x00\n", "line 3: a NUL byte: a recipe is text"),
        (b"# " + b"x" * (2 * 2**20) + b"\n", "is larger than 2 MB, the limit for a recipe"),
    ],
    ids=["utf16-bom", "utf16-le", "utf32", "latin1", "nul", "huge"],
)
def test_odd_encodings_give_one_line_naming_the_file(tmp_path: Path, data: bytes, expected: str) -> None:
    path = tmp_path / "r.toml"
    path.write_bytes(data)
    result = runner.invoke(app, ["check", str(path)])
    assert result.exit_code == 2
    assert result.stderr.count("\n") == 1 and result.stderr.startswith(f"error: {path}: {expected}"), result.stderr


def test_a_utf8_byte_order_mark_is_skipped(tmp_path: Path) -> None:
    path = tmp_path / "r.toml"
    path.write_bytes(b"\xef\xbb\xbf" + TEXT.encode("utf-8"))
    assert load_recipe(path).simulation.frames == 3


# ---------------------------------------------------------------------------------------------
# the estimate and the disk-space refusal
# ---------------------------------------------------------------------------------------------


def test_check_prints_the_estimate_without_and_with_a_mesh(tmp_path: Path) -> None:
    recipe = tmp_path / "r.toml"
    recipe.write_text('[simulation]\nsolver = "xpbd"\nframes = 10\n[output]\nformats = ["obj", "pc2"]\n')
    result = runner.invoke(app, ["check", str(recipe)])
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()
    assert lines[0].startswith(f"OK {recipe}: solver xpbd; 10 frames")
    # xpbd: 22 substeps and 2 iterations by default (docs/recipes.md)
    assert lines[1] == (
        "estimate: 22 substeps x 2 iterations x 10 frames = 440 sweeps; springs and output size need --mesh"
    )

    mesh = tmp_path / "m.obj"
    write_grid(mesh, 5, 4)
    result = runner.invoke(app, ["check", str(recipe), "--mesh", str(mesh)])
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()
    springs = int(re.search(r"(\d+) springs", lines[2]).group(1))  # the model line
    found = re.match(r"estimate: (\d+) springs x 22 substeps x 2 iterations x 10 frames = ([\d,]+) spring", lines[1])
    assert found, lines[1]
    assert int(found.group(1)) == springs and int(found.group(2).replace(",", "")) == springs * 440
    # pc2: a 32-byte header and 12 bytes per vertex per sample (20 vertices; samples for scene
    # frames 0 .. 11: the start frame 1's copy of the rest pose before it, the rest pose, 10 frames)
    assert f"pc2 {(32 + 12 * 20 * 12) / 1000:.1f} KB)" in lines[1], lines[1]


def test_check_with_a_mesh_estimates_the_steps_a_calm_run_takes(tmp_path: Path) -> None:
    """Without colliders, self-collision or tearing the default solver takes its calm steps (2 x 3,
    `meshdeform.simulate.steps_for`), which only the built scene tells: with --mesh the estimate
    counts them; without a mesh it counts the solver's defaults (8 x 3), an upper bound."""
    recipe = tmp_path / "r.toml"
    recipe.write_text("[simulation]\nframes = 10\n[[pins]]\nselect = { indices = [0] }\n")
    mesh = write_grid(tmp_path / "m.obj", 5, 4)
    plain = runner.invoke(app, ["check", str(recipe)])
    assert plain.exit_code == 0, plain.output
    assert plain.stdout.splitlines()[1].startswith("estimate: 8 substeps x 3 iterations x 10 frames = 240 sweeps")
    result = runner.invoke(app, ["check", str(recipe), "--mesh", str(mesh)])
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()
    assert re.match(r"estimate: \d+ springs x 2 substeps x 3 iterations x 10 frames", lines[1]), lines[1]
    assert lines[2].endswith("2 substeps"), lines[2]  # the model line says what will run


@pytest.mark.parametrize("name", list(EXPORTERS))
def test_output_estimates_cover_what_a_run_writes(tmp_path: Path, name: str) -> None:
    """The estimate of every registered format is at least what a real run in that format writes (every
    file of its folder but the report and the marker), and not wildly more; exact for point caches."""
    mesh_path = write_grid(tmp_path / "m.obj", 9, 7, size=(2.0, 1.0))
    mesh = load(mesh_path)
    recipe = parse_recipe(
        f'[simulation]\nframes = 6\n[[pins]]\nselect = {{ indices = [0, 8] }}\n[output]\nformats = ["{name}"]\n'
    )
    estimated = output_bytes(recipe, mesh)
    out = tmp_path / "out"
    run_job(mesh_path, recipe, out)
    files = [p for p in out.rglob("*") if p.is_file() and p.name not in (REPORT_NAME, MARKER_NAME)]
    written = sum(p.stat().st_size for p in files)
    assert name in estimated, f"output_bytes has no estimate for {name}"
    if name in ("pc2", "mdd"):
        assert estimated[name] == written
    assert written <= estimated[name] <= 6 * written, (estimated[name], written)


def test_require_disk_space_refuses_when_the_outputs_do_not_fit(tmp_path: Path, monkeypatch) -> None:
    seen: list[Path] = []
    usage = namedtuple("usage", "total used free")

    def disk_usage(path: Any) -> Any:
        seen.append(Path(path))
        return usage(10**13, 0, 1_100_000_000)

    monkeypatch.setattr(estimate.shutil, "disk_usage", disk_usage)
    target = tmp_path / "out" / "x"  # not there yet: the nearest existing folder is asked
    with pytest.raises(InsufficientDiskSpace) as info:
        require_disk_space(12_300_000_000, target)
    message = str(info.value)
    assert message.startswith(f"{target}: the outputs need about 12.3 GB but only 1.1 GB is free on /")
    assert "\n" not in message and seen == [tmp_path]
    require_disk_space(1_100_000_000, target)  # exactly the free space: accepted
    require_disk_space(None, target)  # nothing known: nothing refused


def test_estimate_of_a_built_run_is_refused_on_a_full_disk_through_the_cli_error_edge(tmp_path, monkeypatch) -> None:
    """The typed error becomes one line and exit code 2 at the CLI edge."""
    import typer

    from pipeline.commands.errors import cli_errors

    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(estimate.shutil, "disk_usage", lambda path: usage(100, 100, 0))
    recipe = parse_recipe("[simulation]\nframes = 5\n")
    mesh = grid_sheet(3)
    total = estimate_run(recipe, mesh).total_bytes
    assert total is not None and total > 0
    with pytest.raises(typer.Exit) as info, cli_errors():
        require_disk_space(total, tmp_path / "out")
    assert info.value.exit_code == 2


# ---------------------------------------------------------------------------------------------
# the CLI contract: one line, exit 2, nothing written
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (("--frames", "1000001"), "error: command line: --frames: 1000001 is above the limit of 1000000 frames"),
        (("--frames", "9" * 25), "error: command line: --frames: " + "9" * 25 + " does not fit in 64 bits"),
        (("--substeps", "1000", "--iterations", "1000"), "error: command line: --substeps: 1000 substeps x 1000"),
        (("--fps", "inf"), "error: command line: --fps: must be a finite number, got inf"),
    ],
)
def test_simulate_stops_at_once_past_a_limit(tmp_path: Path, args: tuple[str, ...], expected: str) -> None:
    mesh = tmp_path / "m.obj"
    write_grid(mesh, 4)
    out = tmp_path / "out"
    started = time.perf_counter()
    result = runner.invoke(app, ["simulate", str(mesh), "-o", str(out), "-q", *args])
    assert time.perf_counter() - started < 10
    assert result.exit_code == 2, result.output
    assert result.stderr.count("\n") == 1 and result.stderr.startswith(expected), result.stderr
    assert not out.exists() and list(tmp_path.iterdir()) == [mesh]


def test_the_installed_entry_point_keeps_the_contract(tmp_path: Path) -> None:
    recipe = tmp_path / "r.toml"
    recipe.write_text("[simulation]\nframes = 5000000\n")
    exe = Path(sys.executable).with_name("meshdeform")
    command = [str(exe)] if exe.exists() else [sys.executable, "-m", "pipeline.cli"]
    done = subprocess.run([*command, "check", str(recipe)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert done.stderr == f"error: {recipe}: simulation.frames (line 2): 5000000 is above the limit of 1000000 frames\n"


# ---------------------------------------------------------------------------------------------
# a corpus of mutated recipes
# ---------------------------------------------------------------------------------------------

BASE: dict[str, Any] = {
    "simulation": {"solver": "verlet", "fps": 24, "frames": 12, "substeps": 4, "iterations": 3, "seed": 1,
                   "damping": 0.5, "start_frame": 1, "tear_burst": 4, "gravity": [0, -9.81, 0],
                   "verlet": {"tethers": 1.0, "partitions": 1},
                   "anchor": {"strain_iterations": 10, "anchor_stiffness": 20.0, "uniform_scale": 1.0}},
    "material": {"density": 0.2, "stretch_modulus": 1000.0, "structural": {"stiffness": 1.0, "damping": 0.1}},
    "pins": [
        {
            "select": {"indices": [0, 1]},
            "stiffness": 1.0,
            "animate": [{"time": 0.0}, {"time": 1.0, "translate": [0.1, 0, 0]}],
        }
    ],
    "impacts": [{"time": 0.1, "point": [0.5, 0.5, 0], "radius": 0.3, "strength": 2.0, "every": 0.2, "count": 3,
                 "relative": True}],
    "wind": {"velocity": [1, 0, 0], "turbulence": 0.3, "turbulence_scale": 1.0},
    "colliders": [{"sphere": {"center": [0, -1, 0], "radius": 0.5}, "friction": 0.2}],
    "tears": [{"select": {"indices": [3, 4]}, "max_stretch": 1.5, "average": 2}],
    "output": {"formats": ["obj"], "preview": {"every": 2}},
}
MUTANTS: list[Any] = [-1, 0, 2**63, -(2**63) - 1, 10**40, 1e300, -1e300, math.inf, -math.inf, math.nan, 1e-300,
                      "x", [], True]


def _toml(value: Any) -> str:
    """A parsed value as inline TOML (enough for the corpus: no dates, keys are bare)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        if math.isfinite(value):
            return repr(value)
        return "nan" if value != value else ("inf" if value > 0 else "-inf")
    if isinstance(value, int):
        return str(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return "{ " + ", ".join(f"{k} = {_toml(v)}" for k, v in value.items()) + " }"


def _document(data: dict[str, Any]) -> str:
    return "".join(f"{key} = {_toml(value)}\n" for key, value in data.items())


def _leaves(data: Any, path: tuple = ()) -> list[tuple]:
    if isinstance(data, dict):
        return [p for k, v in data.items() for p in _leaves(v, (*path, k))]
    if isinstance(data, list):
        return [p for i, v in enumerate(data) for p in _leaves(v, (*path, i))]
    return [path] if isinstance(data, int | float) and not isinstance(data, bool) else []


def _mutated(path: tuple, value: Any) -> dict[str, Any]:
    data = json.loads(json.dumps(BASE))
    node = data
    for part in path[:-1]:
        node = node[part]
    node[path[-1]] = value
    return data


def test_corpus_of_mutated_recipes_ends_quickly_with_one_line(tmp_path: Path) -> None:
    mesh = tmp_path / "m.obj"
    write_grid(mesh, 4)
    recipe = tmp_path / "r.toml"
    recipe.write_text(_document(BASE))
    base = runner.invoke(app, ["check", str(recipe), "--mesh", str(mesh)])
    assert base.exit_code == 0, base.output  # the unmutated recipe is valid: the mutants test the values

    cases = [(path, value) for path in _leaves(BASE) for value in MUTANTS]
    assert len(cases) > 300
    refused = 0
    for i, (path, value) in enumerate(cases):
        recipe.write_text(_document(_mutated(path, value)))
        args = ["check", str(recipe)] + (["--mesh", str(mesh)] if i % 7 == 0 else [])
        started = time.perf_counter()
        result = runner.invoke(app, args)
        seconds = time.perf_counter() - started
        case = f"{path} = {value!r}: exit {result.exit_code}, {result.stderr!r}, {result.exception!r}"
        assert seconds < 10, case
        assert result.exit_code in (0, 2), case
        assert result.stderr.count("\n") <= 1 and "Traceback" not in result.output, case
        if result.exit_code == 2:
            refused += 1
            assert result.stderr.startswith(f"error: {recipe}: "), case
    assert refused > len(cases) * 0.6


def test_simulate_refuses_a_run_whose_outputs_do_not_fit_before_writing_anything(tmp_path: Path, monkeypatch) -> None:
    """`meshdeform simulate` checks the free space after building the model and before any frame."""
    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(estimate.shutil, "disk_usage", lambda path: usage(10**9, 10**9 - 1000, 1000))
    mesh = tmp_path / "m.obj"
    write_grid(mesh, 6)
    out = tmp_path / "out"
    result = runner.invoke(app, ["simulate", str(mesh), "-o", str(out), "--frames", "3", "-q"])
    assert result.exit_code == 2
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and "the outputs need about" in lines[0] and "is free on" in lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.obj"]  # no output, no staging folder


def test_arrays_of_tables_are_limited_before_the_schema_reads_them() -> None:
    impact = "[[impacts]]\ntime = 0.1\npoint = [0, 0, 0]\nradius = 0.1\nstrength = 1\n"
    limit = int(LIMITS["tables in one array"].maximum)
    assert len(parse_recipe(impact * limit).impacts) == limit
    message = error_of(impact * (limit + 1))
    assert message == f"r.toml: impacts (line 1): {limit + 1} tables is above the limit of {limit} tables in one array"
    nested = "[material]\n" + "[[material.regions]]\nselect = { indices = [0] }\nstiffness = 1\n" * (limit + 1)
    assert "material.regions" in error_of(nested) and "tables in one array" in error_of(nested)
