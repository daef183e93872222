"""Real batches through the command line: the engine, worker processes, Dask, interrupts, determinism.

One folder of real meshes (samples, ../shared/meshes real and broken, odd names, nested folders,
a sidecar, an [[assets]] rule, a name clash, an asset that diverges) is baked once serially in a
one-worker pool (`--jobs 1`), once with `--jobs 2` and once on a Dask LocalCluster; every output
file must be byte-identical across the three (report.json and manifest.json minus timings).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from pipeline.cli import app
from pipeline.job import TIMING_KEYS
from pipeline.manifest import MANIFEST_TIMING_KEYS, drop_keys

REPO = Path(__file__).resolve().parents[1]
FRAMES = 3
RECIPE = f"""
[simulation]
solver = "verlet"
frames = {FRAMES}
substeps = 2

[[pins]]
select = {{ indices = [0] }}

[output]
formats = ["obj", "pc2", "usd"]
up_axis = "y"

[[assets]]
glob = "real/*"
simulation = {{ frames = 4 }}
"""
EXPECTED = {
    "broken/empty.obj": "failed",
    "broken/malformed.obj": "failed",
    "clash/a.obj": "ok",
    "clash/a.ply": "ok",
    "diverge/rope.obj": "failed",
    "real/concave.obj": "ok",
    "real/cube-minimal-custom_props.ply": "ok",
    "rope.obj": "ok",
    "sub dir/sheet copy.obj": "ok",
    "ünï/ico sphère.ply": "ok",
}

runner = CliRunner()


def cli(*args: Any) -> Any:
    return runner.invoke(app, [str(a) for a in args])


def build_folder(root: Path, samples: Path, shared: Path) -> None:
    def put(source: Path, relative: str) -> None:
        target = root / relative
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(source, target)

    meshes = samples / "meshes"
    put(meshes / "rope.obj", "rope.obj")
    put(meshes / "sheet.obj", "sub dir/sheet copy.obj")
    # sidecar; with self-collision, so that contact is run under every executor too
    (root / "sub dir" / "sheet copy.toml").write_text("[simulation]\nframes = 2\n[self_collision]\nthickness = 0.004\n")
    put(meshes / "icosphere.ply", "ünï/ico sphère.ply")
    put(shared / "real" / "concave.obj", "real/concave.obj")
    put(shared / "real" / "cube-minimal-custom_props.ply", "real/cube-minimal-custom_props.ply")
    put(shared / "real" / "concave.obj", "clash/a.obj")
    put(shared / "real" / "platonic_shelf.ply", "clash/a.ply")
    put(shared / "broken" / "empty.obj", "broken/empty.obj")
    put(shared / "broken" / "malformed.obj", "broken/malformed.obj")
    put(meshes / "rope.obj", "diverge/rope.obj")
    # explicit springs far past their stable step, under tension from the base recipe's pin: blows up
    (root / "diverge" / "rope.toml").write_text(
        '[simulation]\nsolver = "springs"\nsubsteps = 1\nfps = 2\nstable_substeps = false\n'
    )
    (root / "README.txt").write_text("not a mesh")


@pytest.fixture(scope="module")
def env(tmp_path_factory: pytest.TempPathFactory, samples_dir: Path, shared_meshes: Path) -> dict[str, Path]:
    base = tmp_path_factory.mktemp("batch_e2e")
    assets = base / "assets"
    build_folder(assets, samples_dir, shared_meshes)
    recipe = base / "recipe.toml"
    recipe.write_text(RECIPE)
    return {"base": base, "assets": assets, "recipe": recipe}


@pytest.fixture(scope="module")
def jobs2(env: dict[str, Path]) -> tuple[Any, Path]:
    out = env["base"] / "out-jobs2"
    return cli("batch", env["assets"], "--recipe", env["recipe"], "--out", out, "--jobs", 2), out


def manifest_of(out: Path) -> dict[str, Any]:
    return json.loads((out / "manifest.json").read_text(encoding="utf-8"))


def statuses(out: Path) -> dict[str, str]:
    return {e["input"]: e["status"] for e in manifest_of(out)["assets"]}


def tree(out: Path) -> dict[str, Path]:
    return {p.relative_to(out).as_posix(): p for p in sorted(out.rglob("*")) if p.is_file() and p.name != "batch.log"}


def assert_same_outputs(a: Path, b: Path) -> None:
    """Every file byte for byte; report.json and manifest.json after dropping their timing keys."""
    files_a, files_b = tree(a), tree(b)
    assert sorted(files_a) == sorted(files_b)
    for name, path in files_a.items():
        if path.name in ("report.json", "manifest.json"):
            keys = TIMING_KEYS if path.name == "report.json" else MANIFEST_TIMING_KEYS
            assert drop_keys(json.loads(path.read_text()), keys) == drop_keys(
                json.loads(files_b[name].read_text()), keys
            ), name
        else:
            assert path.read_bytes() == files_b[name].read_bytes(), name


def test_batch_of_real_meshes_with_two_workers(jobs2: tuple[Any, Path], env: dict[str, Path]) -> None:
    result, out = jobs2
    assert result.exit_code == 1, result.output  # some assets failed, the batch went on
    assert statuses(out) == EXPECTED
    entries = {e["input"]: e for e in manifest_of(out)["assets"]}
    assert entries["broken/empty.obj"]["error_type"] == "MeshLoadError"
    assert "malformed.obj" in entries["broken/malformed.obj"]["error"]
    assert entries["diverge/rope.obj"]["error_type"] == "SimulationDiverged"
    assert entries["diverge/rope.obj"]["overrides"] == ["sidecar rope.toml"]
    assert all("\n" not in (e["error"] or "") for e in entries.values())
    # outputs where DESIGN.md section 6 puts them, frame counts from rules and sidecars
    assert entries["sub dir/sheet copy.obj"]["frames"] == 2
    assert entries["real/concave.obj"]["frames"] == 4 and entries["rope.obj"]["frames"] == FRAMES
    for key, entry in entries.items():
        if entry["status"] != "ok":
            assert not (out / entry["output"]).exists()
            continue
        folder = out / entry["output"]
        report = json.loads((folder / "report.json").read_text())
        assert report["frames"] == entry["frames"] and report["outputs"] == entry["outputs"]
        assert report["input_sha256"] == entry["input_sha256"]
        assert report["recipe_sha256"] == entry["recipe_sha256"]
        for name in entry["outputs"]:
            assert (folder / name).is_file(), (key, name)
        # the rest pose at scene frame 1 (the default start frame), then one file a frame
        assert (folder / "frames" / f"frame_{entry['frames'] + 1:04d}.obj").is_file()
        vertices = report["vertices"]
        # samples for scene frames 0 .. frames + 1: a copy of the rest pose before start frame 1
        assert (folder / "cache.pc2").stat().st_size == 32 + 12 * vertices * (entry["frames"] + 2)
    assert (out / "ünï" / "ico sphère" / "report.json").is_file()
    assert (out / "clash" / "a.obj").is_dir() and (out / "clash" / "a.ply").is_dir()
    assert "keeps the suffix" in entries["clash/a.ply"]["note"]
    assert not [p for p in out.rglob("*") if ".partial-" in p.name or ".old-" in p.name]
    # the summary table, the log
    assert "slowest assets" in result.stdout and "failed assets" in result.stdout
    log = (out / "batch.log").read_text()
    assert "processes executor (jobs=2)" in log and "failed broken/empty.obj" in log


def test_rerun_skips_finished_assets_and_json_summary(jobs2: tuple[Any, Path], env: dict[str, Path]) -> None:
    out = env["base"] / "out-rerun"
    shutil.copytree(jobs2[1], out)  # a copy: the determinism test compares the untouched first run
    before = {k: p.stat().st_mtime_ns for k, p in tree(out).items() if "/" in k}
    result = cli("batch", env["assets"], "-r", env["recipe"], "-o", out, "--jobs", 2, "--json")
    assert result.exit_code == 1
    summary = json.loads(result.stdout)  # one JSON object, nothing else on stdout
    assert summary["skipped"] == 7 and summary["failed"] == 3 and summary["ok"] == 0
    assert {f["input"] for f in summary["failed_assets"]} == {k for k, v in EXPECTED.items() if v == "failed"}
    assert {k: p.stat().st_mtime_ns for k, p in tree(out).items() if "/" in k} == before  # nothing rewritten
    quiet = cli("batch", env["assets"], "-r", env["recipe"], "-o", out, "--quiet", "--include", "real/*")
    assert quiet.exit_code == 0 and quiet.stdout == ""


def test_serial_two_jobs_and_dask_outputs_are_identical(jobs2: tuple[Any, Path], env: dict[str, Path]) -> None:
    distributed = pytest.importorskip("distributed")
    _, out2 = jobs2
    out1 = env["base"] / "out-jobs1"
    serial = cli("batch", env["assets"], "-r", env["recipe"], "-o", out1, "--jobs", 1, "--quiet")
    assert serial.exit_code == 1 and statuses(out1) == EXPECTED
    assert_same_outputs(out1, out2)
    out3 = env["base"] / "out-dask"
    cluster = distributed.LocalCluster(
        n_workers=1, threads_per_worker=2, processes=True, dashboard_address=":0", silence_logs=40
    )
    try:
        result = cli("batch", env["assets"], "-r", env["recipe"], "-o", out3, "--dask", cluster.scheduler_address, "-q")
    finally:
        cluster.close()
    assert result.exit_code == 1, result.output
    assert statuses(out3) == EXPECTED
    assert "dask executor" in (out3 / "batch.log").read_text()
    assert_same_outputs(out1, out3)


def test_usage_errors_exit_2(env: dict[str, Path], tmp_path: Path) -> None:
    missing = cli("batch", tmp_path / "nope", "-r", env["recipe"], "-o", tmp_path / "o")
    assert missing.exit_code == 2 and "no such folder" in missing.stderr
    bad = tmp_path / "bad.toml"
    bad.write_text("[simulation]\nframes = 0\n")
    recipe = cli("batch", env["assets"], "-r", bad, "-o", tmp_path / "o")
    assert recipe.exit_code == 2 and "simulation.frames" in recipe.stderr
    (tmp_path / "empty").mkdir()
    empty = cli("batch", tmp_path / "empty", "-r", env["recipe"], "-o", tmp_path / "o")
    assert empty.exit_code == 2 and "no .obj or .ply files" in empty.stderr
    dask = cli("batch", env["assets"], "-r", env["recipe"], "-o", tmp_path / "o", "--dask", "nonsense://x")
    assert dask.exit_code == 2 and "Dask scheduler" in dask.stderr


def start_batch(assets: Path, recipe: Path, out: Path) -> subprocess.Popen[str]:
    """`meshdeform batch` in its own process group, as a terminal would run it."""
    command = [sys.executable, "-c", "from pipeline.cli import app; app()", "batch", str(assets), "-r", str(recipe)]
    command += ["-o", str(out), "-j", "2", "-q"]
    return subprocess.Popen(command, cwd=REPO, start_new_session=True, stderr=subprocess.PIPE, text=True)


def wait_until_done(process: subprocess.Popen[str], out: Path, more_than: int, total: int) -> set[str]:
    """Wait until more than `more_than` (but not all) assets are finished; returns the finished keys."""
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and process.poll() is None:
        if (out / "manifest.json").is_file():
            with contextlib.suppress(ValueError):
                done = {k for k, v in statuses(out).items() if v in ("ok", "skipped")}
                if more_than < len(done) < total:
                    return done
        time.sleep(0.03)
    raise AssertionError("the batch ended before it could be interrupted")


def test_interrupted_batches_resume_cleanly(env: dict[str, Path], tmp_path: Path) -> None:
    """Ctrl-C (SIGINT to the process group), then kill -9 of every process mid-batch: nothing
    unfinished looks finished, and the same command then completes the batch, skipping what was done."""
    assets = tmp_path / "assets"
    total = 10
    for i in range(total):
        (assets / f"g{i // 4}").mkdir(parents=True, exist_ok=True)
        shutil.copyfile(env["assets"] / "sub dir" / "sheet copy.obj", assets / f"g{i // 4}" / f"sheet{i:02d}.obj")
    recipe = tmp_path / "recipe.toml"
    recipe.write_text('[simulation]\nsolver = "verlet"\nframes = 20\n[output]\nformats = ["obj"]\nup_axis = "y"\n')
    out = tmp_path / "out"

    def finished_folders_are_complete() -> set[str]:
        complete = set()
        for key in statuses(out):
            folder = out / Path(key).with_suffix("")
            if (folder / "report.json").is_file():
                report = json.loads((folder / "report.json").read_text())
                assert all((folder / name).is_file() for name in report["outputs"])
                complete.add(key)
            else:
                assert not folder.exists()
        return complete

    # Ctrl-C: workers and parent stop, the manifest says what is done, nothing half-written remains
    process = start_batch(assets, recipe, out)
    wait_until_done(process, out, 0, total)
    os.killpg(process.pid, signal.SIGINT)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 130 and "interrupted" in stderr
    manifest = manifest_of(out)
    assert manifest["complete"] is False
    done = {e["input"] for e in manifest["assets"] if e["status"] == "ok"}
    # (an asset may finish in a worker just before the parent stops listening: complete, not yet listed)
    assert done and done <= finished_folders_are_complete()
    assert not [p for p in out.rglob("*") if ".partial-" in p.name]

    # kill -9 of everything: staging folders may remain (hidden); finished folders are complete
    process = start_batch(assets, recipe, out)
    wait_until_done(process, out, len(done), total)
    os.killpg(process.pid, signal.SIGKILL)
    process.communicate(timeout=60)
    complete = finished_folders_are_complete()
    assert done < complete

    resumed = cli("batch", assets, "-r", recipe, "-o", out, "-j", 2, "-q")
    assert resumed.exit_code == 0, resumed.output
    final = statuses(out)
    assert len(final) == total and complete == {k for k, v in final.items() if v == "skipped"}
    assert finished_folders_are_complete() == set(final)
    assert not [p for p in out.rglob("*") if ".partial-" in p.name or ".old-" in p.name]
    assert manifest_of(out)["complete"] is True
