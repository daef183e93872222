"""The command line as a user drives it: help, inspect, simulate, bad input."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import typer
from factories import TOP_CORNERS, grid_pins, write_grid
from typer.testing import CliRunner

from meshdeform.io import load
from pipeline import __version__
from pipeline.cli import app

runner = CliRunner()


def run(*args: str):
    return runner.invoke(app, [str(a) for a in args])


def test_version() -> None:
    result = run("--version")
    assert result.exit_code == 0
    assert __version__ in result.stdout


def test_every_command_has_help_text() -> None:
    command = typer.main.get_command(app)
    names = sorted(command.commands)
    assert {"inspect", "simulate"} <= set(names)
    for name in names:
        result = run(name, "--help")
        assert result.exit_code == 0, name
        assert command.commands[name].help, f"{name} has no help text"


def test_simulate_help_lists_the_registered_solvers_and_formats() -> None:
    from meshdeform.export import EXPORTERS
    from meshdeform.solvers import SOLVERS

    text = " ".join(run("simulate", "--help").stdout.split())
    assert all(name in text for name in SOLVERS)
    for name, cls in EXPORTERS.items():
        assert cls.summary and f"{name}: {cls.summary}" in text, name
    fixed = [name for name, cls in EXPORTERS.items() if not cls.supports_topology_change]
    assert fixed and f"cannot write {', '.join(fixed)}" in text


@pytest.mark.parametrize(("n", "m"), [(5, 9), (13, 4)])
def test_inspect_json_counts_springs_of_quad_grids(tmp_path: Path, n: int, m: int) -> None:
    path = tmp_path / "grid.obj"
    write_grid(path, n, m)
    result = run("inspect", path, "--json")
    assert result.exit_code == 0, result.output
    info = json.loads(result.stdout)
    assert info["vertices"] == n * m
    assert info["faces"] == (n - 1) * (m - 1)
    assert info["springs"] == {
        "structural": n * (m - 1) + m * (n - 1),
        "shear": 2 * (n - 1) * (m - 1),
        "bending": n * (m - 2) + m * (n - 2),
    }
    assert info["boundary_edges"] == 2 * (n - 1) + 2 * (m - 1)
    assert info["pieces"] == 1


def test_inspect_text_names_the_figures(samples_dir: Path) -> None:
    result = run("inspect", samples_dir / "meshes" / "flag.obj")
    assert result.exit_code == 0
    for word in ("vertices", "faces", "springs", "pieces", "boundary edges", "non-manifold"):
        assert word in result.stdout


def test_inspect_welded_counts_match_trimesh_on_real_meshes(shared_meshes: Path) -> None:
    import trimesh

    for path in sorted((shared_meshes / "real").iterdir()):
        result = run("inspect", path, "--json")
        assert result.exit_code == 0, f"{path.name}: {result.output}"
        info = json.loads(result.stdout)
        positions = load(path).positions
        unique = trimesh.grouping.unique_rows(positions, digits=15)[0]
        assert info["welded_vertices"] == len(unique), path.name


def test_simulate_writes_frames_in_input_order_with_pins_unmoved(tmp_path: Path) -> None:
    n, m = 12, 10
    mesh_path = write_grid(tmp_path / "cloth.obj", n, m, plane="xz")  # lying flat: it falls when pinned at two corners
    out = tmp_path / "out"
    top_left, top_right = np.flatnonzero(grid_pins(n, m, TOP_CORNERS))
    result = run(
        "simulate", mesh_path, "--out", out, "--frames", "12", "--solver", "verlet",
        "--pin", f"indices:{top_left},{top_right}", "--quiet",
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    frames = sorted((out / "frames").glob("frame_*.obj"))
    # scene frame 1 (the default start frame) is the rest pose, 2 .. 13 the 12 frames after it
    assert [f.name for f in frames] == [f"frame_{i:04d}.obj" for i in range(1, 14)]
    rest = load(mesh_path)
    np.testing.assert_array_equal(load(frames[0]).positions, rest.positions)
    last = load(frames[-1])
    assert last.vertex_count == rest.vertex_count
    np.testing.assert_array_equal(last.face_indices, rest.face_indices)
    for frame in frames:
        positions = load(frame).positions
        np.testing.assert_array_equal(positions[[top_left, top_right]], rest.positions[[top_left, top_right]])
    # the free part swings down under gravity (0.5 s of fall: well below the pins) and nothing flies off
    assert last.positions[:, 1].min() < rest.positions[:, 1].min() - 0.3
    assert np.abs(last.positions).max() < 5.0
    report = json.loads((out / "report.json").read_text())
    for key in ("vertices", "springs", "frames", "solver", "seconds", "max_stretch"):
        assert key in report
    assert report["frames"] == 12 and len(report["max_stretch"]) == 12
    assert report["vertices"] == n * m
    assert report["springs"]["structural"] == n * (m - 1) + m * (n - 1)


def test_simulate_box_pin_is_relative_to_bounds(tmp_path: Path) -> None:
    mesh_path = write_grid(tmp_path / "cloth.obj", 8, 8, plane="xz")
    out = tmp_path / "out"
    result = run("simulate", mesh_path, "--out", out, "--frames", "5", "--pin", "box:0,0,0.99,1,1,1", "--quiet")
    assert result.exit_code == 0, result.output
    report = json.loads((out / "report.json").read_text())
    assert report["pinned_vertices"] == 8
    rest = load(mesh_path).positions
    moved = load(out / "frames" / "frame_0005.obj").positions
    top = rest[:, 2] == rest[:, 2].max()  # the far edge of the flat sheet
    np.testing.assert_array_equal(moved[top], rest[top])
    assert (moved[~top, 1] < rest[~top, 1]).all()
    # the report lists the pinned input vertices, so a later `preview` of OBJ frames alone can show them
    assert report["pinned"] == np.flatnonzero(top).tolist()
    from meshdeform.preview import open_result

    np.testing.assert_array_equal(open_result(out).pinned, top)


def test_simulate_ply_output_keeps_vertex_count(tmp_path: Path, samples_dir: Path) -> None:
    out = tmp_path / "ball"
    mesh = samples_dir / "meshes" / "icosphere.ply"
    result = run("simulate", mesh, "--out", out, "--frames", "3", "--format", "ply", "--quiet", "--gravity", "0,0,0")
    assert result.exit_code == 0, result.output
    frames = sorted((out / "frames").glob("*.ply"))
    assert len(frames) == 4  # the rest pose and 3 frames
    assert load(frames[0]).vertex_count == load(mesh).vertex_count


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("--gravity", "0,-9.81"), "--gravity"),
        (("--pin", "sphere:1"), "pin"),
        (("--solver", "nope"), "solver"),
    ],
)
def test_bad_options_give_one_line_and_exit_2(tmp_path: Path, args: tuple[str, ...], message: str) -> None:
    mesh_path = write_grid(tmp_path / "cloth.obj", 4, 4, plane="xz")
    out = tmp_path / "out"
    result = run("simulate", mesh_path, "--out", out, "--frames", "2", "--quiet", *args)
    assert result.exit_code == 2, result.output
    assert message in result.stderr
    assert "Traceback" not in result.output
    assert not out.exists()


def test_missing_file_and_unknown_extension(tmp_path: Path) -> None:
    out = tmp_path / "out"
    missing = run("simulate", tmp_path / "nope.obj", "--out", out, "--quiet")
    assert missing.exit_code == 2 and "nope.obj" in missing.stderr
    odd = tmp_path / "mesh.stl"
    odd.write_text("solid x\nendsolid x\n")
    unknown = run("inspect", odd)
    assert unknown.exit_code == 2 and "mesh.stl" in unknown.stderr
    assert not out.exists()


def test_every_broken_mesh_loads_with_warning_or_fails_with_one_line(tmp_path: Path, shared_meshes: Path) -> None:
    for path in sorted((shared_meshes / "broken").iterdir()):
        out = tmp_path / path.stem
        result = run("simulate", path, "--out", out, "--frames", "2", "--quiet", "--gravity", "0,0,0")
        assert "Traceback" not in result.output, path.name
        if result.exit_code == 0:
            assert (out / "report.json").is_file(), path.name
            continue
        assert result.exit_code == 2, f"{path.name}: exit {result.exit_code}: {result.output}"
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1, f"{path.name}: {result.stderr}"
        assert path.name in lines[0]
        assert not out.exists(), path.name
        assert not list(tmp_path.glob(f".{path.stem}.partial-*")), path.name


def test_diverging_run_names_the_frame_and_leaves_nothing(tmp_path: Path) -> None:
    mesh_path = write_grid(tmp_path / "cloth.obj", 6, 6, plane="xz")
    recipe = tmp_path / "stiff.toml"
    recipe.write_text(
        '[simulation]\nsolver = "springs"\nsubsteps = 1\nfps = 2\n\n[simulation.springs]\nstable_substeps = false\n\n'
        "[material]\nstructural = { stiffness = 1.0 }\n"
    )
    out = tmp_path / "out"
    result = run("simulate", mesh_path, "--out", out, "--recipe", recipe, "--frames", "50", "--quiet",
                 "--pin", "indices:30,35")  # fmt: skip
    if result.exit_code == 0:
        pytest.fail("a one-substep explicit spring run at 2 fps was expected to diverge")
    assert result.exit_code == 1, result.output
    assert re.search(r"frame \d+", result.stderr) and len(result.stderr.strip().splitlines()) == 1
    assert not out.exists()


def test_kernel_cache_folder_falls_back_when_home_cannot_be_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The user's NUMBA_CACHE_DIR as it is; else ~/.cache/meshdeform/numba; else a folder in the
    temporary folder (a home that cannot be written: here a file where the home should be)."""
    from pipeline.cli import kernel_cache_dir

    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "mine"))
    assert kernel_cache_dir() == str(tmp_path / "mine")
    monkeypatch.delenv("NUMBA_CACHE_DIR")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert kernel_cache_dir() == str(tmp_path / "home" / ".cache" / "meshdeform" / "numba")
    (tmp_path / "blocked").write_text("not a folder")
    monkeypatch.setenv("HOME", str(tmp_path / "blocked"))
    monkeypatch.setenv("TMPDIR", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    monkeypatch.setattr("tempfile.tempdir", None)  # read TMPDIR again
    folder = Path(kernel_cache_dir() or "")
    assert folder.parent == tmp_path / "tmp" and folder.name.startswith("meshdeform-numba-") and folder.is_dir()


def test_short_h_is_help_for_the_app_and_every_command() -> None:
    command = typer.main.get_command(app)
    top = run("-h")
    assert top.exit_code == 0 and "Usage: meshdeform" in top.stdout
    for name in sorted(command.commands):
        result = run(name, "-h")
        assert result.exit_code == 0, (name, result.output)
        assert f"Usage: meshdeform {name}" in result.stdout, name
        assert result.stdout == run(name, "--help").stdout, name


def test_help_shows_plain_metavars_not_type_names() -> None:
    command = typer.main.get_command(app)
    type_token = re.compile(
        r"<(?:int|float|str|path|list|bool)[a-z_\[\]| ,]*>|\b(?:INTEGER|FLOAT|TEXT)(?: RANGE)?\b|\{[a-z_]+\}"
    )
    for name in ["", *sorted(command.commands)]:
        text = run(*([name] if name else []), "-h").stdout
        assert not type_token.findall(text), (name, type_token.findall(text))
    batch = run("batch", "-h").stdout
    assert "Usage: meshdeform batch [OPTIONS] ASSETS" in batch
    assert re.search(r"-j, --jobs N\s", batch) and re.search(r"--include INCLUDE\s", batch)
    assert re.search(r"-f, --format FORMAT\s", run("simulate", "-h").stdout)


def test_format_takes_a_comma_list_as_well_as_repeats(tmp_path: Path) -> None:
    mesh_path = write_grid(tmp_path / "cloth.obj", 4, 4, plane="xz")
    out = tmp_path / "out"
    result = run("simulate", mesh_path, "-o", out, "--frames", "2", "-q", "--format", "obj, usd", "-f", "pc2")
    assert result.exit_code == 0, result.output
    report = json.loads((out / "report.json").read_text())
    assert report["formats"] == ["obj", "usd", "pc2"]
    assert (out / "scene.usdc").is_file() and (out / "cache.pc2").is_file()
    assert len(list((out / "frames").glob("*.obj"))) == 3


@pytest.mark.parametrize(("value", "named"), [("obj,fbx", "'fbx'"), ("obj,obj", "twice")])
def test_format_list_is_checked_against_the_export_registry(tmp_path: Path, value: str, named: str) -> None:
    from meshdeform.export import EXPORTERS

    mesh_path = write_grid(tmp_path / "cloth.obj", 4, 4, plane="xz")
    out = tmp_path / "out"
    result = run("simulate", mesh_path, "-o", out, "--frames", "2", "-q", "--format", value)
    assert result.exit_code == 2, result.output
    assert "--format" in result.stderr and named in result.stderr
    if named == "'fbx'":
        assert all(name in result.stderr for name in EXPORTERS)
    assert not out.exists()


def test_simulate_json_prints_only_the_report(tmp_path: Path) -> None:
    mesh_path = write_grid(tmp_path / "cloth.obj", 4, 4, plane="xz")
    out = tmp_path / "out"
    result = run("simulate", mesh_path, "-o", out, "--frames", "3", "--json")
    assert result.exit_code == 0, result.output
    printed = json.loads(result.stdout)  # the whole of stdout is one JSON document
    assert printed == json.loads((out / "report.json").read_text())
    assert printed["frames"] == 3 and printed["vertices"] == 16


def test_check_json_gives_ok_errors_and_the_estimate(tmp_path: Path) -> None:
    mesh = write_grid(tmp_path / "flag.obj", 8, 5, size=(2.0, 1.0))
    recipe = tmp_path / "r.toml"
    recipe.write_text(
        "[simulation]\nframes = 10\nsubsteps = 4\niterations = 3\n"
        "[[pins]]\nselect = { box = { min = [0, 0.99, 0], max = [1, 1, 1] }, relative = true }\n"
    )
    plain = json.loads(run("check", recipe, "--json").stdout)
    assert plain["ok"] is True and plain["errors"] == [] and "mesh" not in plain
    assert plain["estimate"]["sweeps"] == 10 * 4 * 3 and plain["estimate"]["spring_projections"] is None

    result = run("check", recipe, "-m", mesh, "--json")
    assert result.exit_code == 0, result.output
    on_mesh = json.loads(result.stdout)
    assert on_mesh["mesh"]["vertices"] == 40 and on_mesh["mesh"]["selections"] == {"pins[0].select": 8}
    assert on_mesh["mesh"]["hard_pinned"] == 8
    assert on_mesh["estimate"]["vertices"] == 40 and on_mesh["estimate"]["total_bytes"] > 0

    bad = tmp_path / "bad.toml"
    bad.write_text("[simulation]\nframes = -1\n")
    result = run("check", bad, "--json")
    assert result.exit_code == 2
    failed = json.loads(result.stdout)
    assert failed["ok"] is False and len(failed["errors"]) == 1 and "simulation.frames" in failed["errors"][0]
    assert "estimate" not in failed
    assert result.stderr.startswith(f"error: {bad}: simulation.frames")


def test_check_simulate_and_batch_refuse_a_tearing_recipe_with_a_point_cache_alike(tmp_path: Path) -> None:
    mesh = write_grid(tmp_path / "assets" / "flag.obj", 6, 4)
    recipe = tmp_path / "tear.toml"
    recipe.write_text('[simulation]\nframes = 2\n[[tears]]\nmax_stretch = 1.3\n[output]\nformats = ["obj", "npz"]\n')
    expected = f"error: {recipe}: output.formats[1] (line 6): npz needs a fixed vertex count"
    for args in (
        ("check", recipe),
        ("simulate", mesh, "-r", recipe, "-o", tmp_path / "one"),
        ("batch", mesh.parent, "-r", recipe, "-o", tmp_path / "many", "--jobs", "0"),
    ):
        result = run(*args)
        assert result.exit_code == 2, (args[0], result.output)
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(expected), (args[0], result.stderr)
    assert not (tmp_path / "one").exists() and not (tmp_path / "many").exists()


def test_simulate_says_on_stderr_what_it_repaired_in_the_input(tmp_path: Path) -> None:
    mesh = tmp_path / "quad.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 1 0 1\nv 0 0 1\nvn 0 1 0\nf 1//1 2//2 3//3 4//4\n")
    result = run("simulate", mesh, "-o", tmp_path / "out", "--frames", "1")
    assert result.exit_code == 0, result.output
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert len(report["warnings"]) == 1 and "normal" in report["warnings"][0]
    assert result.stderr.splitlines() == [f"warning: {mesh}: {report['warnings'][0]}"]
    quiet = run("simulate", mesh, "-o", tmp_path / "quiet", "--frames", "1", "-q")
    assert quiet.exit_code == 0 and quiet.stderr == ""


def test_simulate_stdout_has_no_stray_blank_line(tmp_path: Path) -> None:
    mesh_path = write_grid(tmp_path / "cloth.obj", 4, 4, plane="xz")
    quiet = run("simulate", mesh_path, "-o", tmp_path / "quiet", "--frames", "2", "-q")
    assert quiet.exit_code == 0, quiet.output
    assert quiet.stdout == "" and quiet.stderr == ""
    loud = run("simulate", mesh_path, "-o", tmp_path / "loud", "--frames", "2")
    assert loud.exit_code == 0, loud.output
    lines = loud.stdout.split("\n")
    assert lines[-1] == "" and all(line.strip() for line in lines[:-1]), loud.stdout
    assert lines[0].startswith("cloth.obj: 2 frames")
    assert loud.stderr == ""


def _batch_folder(tmp_path: Path) -> tuple[Path, Path]:
    assets = tmp_path / "assets_with_a_rather_long_folder_name_to_pass_eighty_columns"
    write_grid(assets / "one.obj", 4, 4, plane="xz")
    write_grid(assets / "sub" / "two.obj", 4, 4, plane="xz")
    (assets / "bad.obj").write_text("v 0 0 0\nf 1 2 3\n")
    recipe = tmp_path / "r.toml"
    recipe.write_text("[simulation]\nframes = 2\n")
    return assets, recipe


def test_batch_in_a_ci_log_prints_one_unwrapped_line_per_finished_asset(tmp_path: Path) -> None:
    assets, recipe = _batch_folder(tmp_path)
    result = run("batch", assets, "-r", recipe, "-o", tmp_path / "out", "-j", "0")
    assert result.exit_code == 1, result.output
    lines = result.stderr.splitlines()
    assert sorted(line.split(":")[0] for line in lines) == ["failed bad.obj", "ok one.obj", "ok sub/two.obj"]
    assert all(line.strip() for line in lines)
    failed = next(line for line in lines if line.startswith("failed"))
    assert len(failed) > 80 and str(assets / "bad.obj") in failed and "out of range" in failed
    assert re.fullmatch(r"ok one\.obj: 2 frames in \d+\.\d\d s", next(x for x in lines if "one.obj" in x))
    again = run("batch", assets, "-r", recipe, "-o", tmp_path / "out", "-j", "0")
    assert "skipped one.obj: up to date" in again.stderr.splitlines()


def test_the_line_display_writes_each_asset_as_it_finishes(capsys: pytest.CaptureFixture[str]) -> None:
    from pipeline.commands.batch import LineBatchProgress

    display = LineBatchProgress()
    display.finished("a.obj", {"status": "ok", "frames": 3, "seconds": 0.5})
    assert capsys.readouterr().err == "ok a.obj: 3 frames in 0.50 s\n"
    display.finished("b.obj", {"status": "failed", "error": "b.obj: line 2:\n  bad"})
    assert capsys.readouterr().err == "failed b.obj: b.obj: line 2: bad\n"


@pytest.mark.parametrize("flag", ["--quiet", "--json"])
def test_batch_quiet_and_json_still_print_failures_on_stderr(tmp_path: Path, flag: str) -> None:
    assets, recipe = _batch_folder(tmp_path)
    result = run("batch", assets, "-r", recipe, "-o", tmp_path / "out", "-j", "0", flag)
    assert result.exit_code == 1, result.output
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("failed bad.obj: ") and "out of range" in lines[0]
    if flag == "--quiet":
        assert result.stdout == ""
    else:
        assert json.loads(result.stdout)["failed"] == 1


def test_verbose_shows_library_warnings_one_line_each(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import warnings

    import meshdeform.io

    real_load = meshdeform.io.load

    def warning_load(path, *args, **kwargs):
        # as if raised inside the engine: a module of meshdeform, where DeprecationWarnings are hidden by default
        here = {"__name__": "meshdeform.io.obj"}
        warnings.warn_explicit("coarse mesh", UserWarning, "meshdeform/io/obj.py", 7, "meshdeform.io.obj", here)
        warnings.warn_explicit("old spelling", DeprecationWarning, "meshdeform/io/obj.py", 9, "meshdeform.io.obj", here)
        return real_load(path, *args, **kwargs)

    monkeypatch.setattr(meshdeform.io, "load", warning_load)
    mesh = write_grid(tmp_path / "cloth.obj", 4, 4, plane="xz")
    quiet = run("inspect", mesh)
    assert quiet.exit_code == 0 and quiet.stderr == ""
    loud = run("--verbose", "inspect", mesh)
    assert loud.exit_code == 0, loud.output
    assert loud.stdout == quiet.stdout
    assert loud.stderr.splitlines() == [
        "warning: UserWarning: coarse mesh (meshdeform/io/obj.py:7)",
        "warning: DeprecationWarning: old spelling (meshdeform/io/obj.py:9)",
    ]


def test_shell_completion_is_on_and_completes_commands_and_options(monkeypatch: pytest.MonkeyPatch) -> None:
    import os
    import subprocess
    import sys

    top = run("-h").stdout
    assert "--install-completion" in top and "--show-completion" in top
    # the flag takes the user's shell from the process's ancestors (shellingham), and a test run
    # need not have one (a detached runner): say it is bash
    monkeypatch.setattr(typer.completion, "_get_shell_name", lambda: "bash")
    script = run("--show-completion")
    assert script.exit_code == 0 and "_meshdeform_completion" in script.stdout

    def complete(words: str) -> list[str]:
        env = {**os.environ, "_MESHDEFORM_COMPLETE": "complete_bash", "COMP_WORDS": words}
        env["COMP_CWORD"] = str(len(words.split()) - 1)
        code = "from pipeline.cli import app; app()"
        done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60)
        assert done.returncode == 0, done.stderr
        return done.stdout.split()

    assert complete("meshdeform sim") == ["simulate"]
    assert complete("meshdeform batch --inc") == ["--include"]


def test_nothing_at_run_time_needs_trimesh(tmp_path: Path) -> None:
    import ast
    import subprocess
    import sys
    import tomllib

    root = Path(__file__).resolve().parent.parent
    for path in [*root.glob("meshdeform/**/*.py"), *root.glob("pipeline/**/*.py")]:
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            names += [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            assert not any(n.split(".")[0] == "trimesh" for n in names), f"{path} imports trimesh"
    project = tomllib.loads((root / "pyproject.toml").read_text())["project"]
    assert not any(d.startswith("trimesh") for d in project["dependencies"])
    assert any(d.startswith("trimesh") for d in project["optional-dependencies"]["test"])
    # and runs with trimesh unimportable work: inspect, simulate writing every output format, check
    from meshdeform.export import EXPORTERS

    mesh = write_grid(tmp_path / "cloth.obj", 4, 4, plane="xz")
    recipe = tmp_path / "r.toml"
    recipe.write_text("[simulation]\nframes = 2\n")
    code = "import sys; sys.modules['trimesh'] = None\nfrom pipeline.cli import app\napp()"
    for args in (
        ["inspect", mesh],
        ["simulate", mesh, "-o", tmp_path / "out", "-r", recipe, "-q", "--format", ",".join(EXPORTERS)],
        ["check", recipe, "-m", mesh],
    ):
        command = [sys.executable, "-c", code, *map(str, args)]
        done = subprocess.run(command, capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, (args, done.stderr)
