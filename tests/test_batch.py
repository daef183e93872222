"""Batch logic with a fake job: discovery, output names, per-asset recipes, manifest, resume, interrupts.

The fake job (module level, so it pickles) writes what `run_job` writes, in a staging folder
renamed into place: a few frame files and a report.json with the input and recipe hashes. The
real engine runs in tests/test_batch_e2e.py.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from meshdeform.errors import ExportError, MeshLoadError, RecipeError, SimulationDiverged
from pipeline import __version__
from pipeline.assets import discover, glob_match, output_folders, select
from pipeline.batch import BatchError, out_lock, remove_stale, run_batch
from pipeline.hashing import file_sha256
from pipeline.manifest import MANIFEST_TIMING_KEYS, drop_keys
from pipeline.output_folder import stage_path, staged_directory
from pipeline.recipe import recipe_hash

RECIPE = """
[simulation]
solver = "verlet"
frames = 3

[[assets]]
glob = "props/*"
simulation = { frames = 2 }

[[assets]]
glob = "*.ply"
simulation = { frames = 4 }
"""


@dataclass
class FakeResult:
    report: dict[str, Any]


def fake_job(
    mesh_path: Path, recipe: Any, out_dir: Path, *, on_frame: Any = None, overwrite: bool = False
) -> FakeResult:
    """run_job's contract without the engine: fails on 'broken'/'diverge'/'bug' names."""
    text = mesh_path.read_text(encoding="utf-8", errors="replace")
    if "broken" in text:
        raise MeshLoadError(f"{mesh_path}: line 1: not a mesh")
    if "diverge" in text:
        raise SimulationDiverged(f"{mesh_path.name}: positions became non-finite at frame 2", frame=2, solver="verlet")
    if "bug" in text:
        raise ZeroDivisionError("division by zero")
    if "export" in text:
        raise ExportError("pc2: cannot write frame 2: No space left on device")
    if "interrupt" in text:
        raise KeyboardInterrupt
    frames = recipe.simulation.frames
    with staged_directory(out_dir, overwrite=overwrite) as stage:
        (stage / "frames").mkdir()
        outputs = []
        for i in range(1, frames + 1):
            (stage / "frames" / f"frame_{i:04d}.obj").write_text(f"# {mesh_path.name} frame {i}\n{text}")
            outputs.append(f"frames/frame_{i:04d}.obj")
            if on_frame is not None:
                on_frame(i, frames)
        report = {
            "version": __version__,
            "input": str(mesh_path),
            "input_sha256": file_sha256(mesh_path),
            "recipe_sha256": recipe_hash(recipe),
            "frames": frames,
            "outputs": [*outputs, "report.json"],
            "seconds": 0.01,
        }
        (stage / "report.json").write_text(json.dumps(report, indent=2))
    return FakeResult(report)


def write(path: Path, text: str = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n") -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")
    return path


@pytest.fixture()
def folder(tmp_path: Path) -> Path:
    """Nested folders, odd names, a sidecar, a broken file, a name clash, things to ignore."""
    root = tmp_path / "assets"
    write(root / "flag.obj")
    write(root / "flag.toml", "[simulation]\nframes = 5\n")  # sidecar
    write(root / "props" / "chair one.obj")
    write(root / "props" / "deep" / "lampe à poser.PLY")
    write(root / "clash" / "a.obj")
    write(root / "clash" / "a.ply")
    write(root / "broken.obj", "broken")
    write(root / "notes.txt", "not a mesh")
    write(root / ".hidden.obj")
    write(root / ".cache" / "x.obj")
    return root


@pytest.fixture()
def recipe(tmp_path: Path) -> Path:
    return write(tmp_path / "recipe.toml", RECIPE)


def entries(result: Any) -> dict[str, dict[str, Any]]:
    return {e["input"]: e for e in result.manifest["assets"]}


# -- discovery, names, globs -----------------------------------------------------------------


def test_discover_sorted_recursive_and_skips_hidden(folder: Path) -> None:
    found = discover(folder).keys
    assert found == [
        "broken.obj",
        "clash/a.obj",
        "clash/a.ply",
        "flag.obj",
        "props/chair one.obj",
        "props/deep/lampe à poser.PLY",
    ]
    assert discover(folder).keys == found and discover(folder).skipped == {}  # stable


def test_output_folders_keep_the_suffix_only_on_a_clash() -> None:
    names = output_folders(["clash/a.obj", "clash/a.ply", "b.obj", "B.ply", "c.obj", "c.ply", "c.obj.ply"])
    assert names["clash/a.obj"][0] == "clash/a.obj" and names["clash/a.ply"][0] == "clash/a.ply"
    assert "clash/a.obj, clash/a.ply" in (names["clash/a.obj"][1] or "")
    assert names["b.obj"][0] == "b.obj" and names["B.ply"][0] == "B.ply"  # equal but for case
    assert names["c.obj"][0] == "c.obj" and names["c.obj.ply"][0] == "c.obj.ply"  # clash of the second round
    assert output_folders(["x/y.obj", "z.ply"]) == {"x/y.obj": ("x/y", None), "z.ply": ("z", None)}
    # a folder that would hold another asset's folder keeps its suffix (replacing it would delete theirs)
    nested = output_folders(["a.obj", "a/b.obj", "A/c/d.ply", "c.obj"])
    assert {k: n for k, (n, _) in nested.items()} == {
        "a.obj": "a.obj",
        "a/b.obj": "a/b",
        "A/c/d.ply": "A/c/d",
        "c.obj": "c",
    }
    # (the first asset below it, in batch order; folder names compare without case, as on macOS and Windows)
    assert nested["a.obj"][1] == "output folder keeps the suffix: a/ would hold the output folder of A/c/d.ply"
    assert len({n for n, _ in names.values()}) == len(names)


def test_globs_match_like_asset_rules() -> None:
    assert glob_match("*.ply", "props/deep/x.ply") and glob_match("props/*", "props/deep/x.ply")
    assert not glob_match("props/*.obj", "flag.obj")
    keys = ["a.obj", "props/b.obj", "props/c.ply"]
    assert select(keys, include=["props/*"]) == ["props/b.obj", "props/c.ply"]
    assert select(keys, exclude=["*.ply"]) == ["a.obj", "props/b.obj"]
    assert select(keys, include=["props/*"], exclude=["*.ply"]) == ["props/b.obj"]


# -- a whole batch ----------------------------------------------------------------------------


def test_batch_manifest_overrides_and_isolated_failures(folder: Path, recipe: Path, tmp_path: Path) -> None:
    write(folder / "diverge.obj", "diverge")
    write(folder / "bug.obj", "bug")
    write(folder / "export.obj", "export")
    write(folder / "badside.obj")
    write(folder / "badside.toml", "[simulation]\nframes = -1\n")
    out = tmp_path / "out"
    result = run_batch(folder, recipe, out, jobs=0, job=fake_job)
    assert result.exit_code == 1
    got = entries(result)
    assert list(got) == sorted(got, key=lambda k: tuple(k.split("/")))
    assert {k: e["status"] for k, e in got.items()} == {
        "badside.obj": "failed",
        "broken.obj": "failed",
        "bug.obj": "failed",
        "clash/a.obj": "ok",
        "clash/a.ply": "ok",
        "diverge.obj": "failed",
        "export.obj": "failed",
        "flag.obj": "ok",
        "props/chair one.obj": "ok",
        "props/deep/lampe à poser.PLY": "ok",
    }
    # overrides: sidecar over rules over base; the layers are listed
    assert got["flag.obj"]["frames"] == 5 and got["flag.obj"]["overrides"] == ["sidecar flag.toml"]
    assert got["props/chair one.obj"]["frames"] == 2
    # "props/*" spans sub-folders (fnmatch, as [[assets]] rules); "*.ply" is case-sensitive
    assert got["props/deep/lampe à poser.PLY"]["frames"] == 2
    assert got["props/deep/lampe à poser.PLY"]["overrides"] == ["[[assets]] #1 'props/*'"]
    assert got["clash/a.ply"]["frames"] == 4 and got["clash/a.obj"]["frames"] == 3
    # errors: one line, typed errors as they are, bugs with their type
    assert got["broken.obj"]["error"].endswith("broken.obj: line 1: not a mesh")
    assert got["broken.obj"]["error_type"] == "MeshLoadError"
    assert got["diverge.obj"]["error_type"] == "SimulationDiverged"
    assert got["export.obj"]["error"] == "pc2: cannot write frame 2: No space left on device"
    assert got["bug.obj"]["error"] == "ZeroDivisionError: division by zero"
    assert "badside.toml" in got["badside.obj"]["error"] and "simulation.frames" in got["badside.obj"]["error"]
    assert got["badside.obj"]["error_type"] == "RecipeError"  # the documented kind, however the reader words it
    assert all("\n" not in (e["error"] or "") for e in got.values())
    # outputs: OUT/<relative path without suffix>/, suffix kept on the clash
    assert (out / "props" / "chair one" / "frames" / "frame_0002.obj").is_file()
    assert (out / "props" / "deep" / "lampe à poser" / "report.json").is_file()
    assert (out / "clash" / "a.obj" / "report.json").is_file() and (out / "clash" / "a.ply").is_dir()
    assert got["clash/a.obj"]["output"] == "clash/a.obj" and "share clash/a/" in got["clash/a.obj"]["note"]
    assert not (out / "broken").exists() and not (out / "diverge").exists()
    # the manifest entry agrees with the report
    flag = got["flag.obj"]
    report = json.loads((out / "flag" / "report.json").read_text())
    assert flag["outputs"] == report["outputs"] and flag["recipe_sha256"] == report["recipe_sha256"]
    assert flag["input_sha256"] == file_sha256(folder / "flag.obj") and flag["version"] == __version__
    assert got["broken.obj"]["input_sha256"] == file_sha256(folder / "broken.obj")
    # the file on disk is the manifest returned, and complete
    on_disk = json.loads((out / "manifest.json").read_text())
    assert on_disk == result.manifest and on_disk["complete"] is True
    assert on_disk["summary"] == {**on_disk["summary"], "assets": 10, "ok": 5, "failed": 5, "skipped": 0, "pending": 0}
    log = (out / "batch.log").read_text()
    assert "failed bug.obj: ZeroDivisionError" in log and "Traceback" in log


def test_rerun_skips_up_to_date_and_redoes_what_changed(folder: Path, recipe: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    first = run_batch(folder, recipe, out, jobs=0, job=fake_job)
    stamp = (out / "props" / "chair one" / "report.json").stat().st_mtime_ns
    second = run_batch(folder, recipe, out, jobs=0, job=fake_job)
    statuses = {k: e["status"] for k, e in entries(second).items()}
    assert statuses == {k: ("failed" if k == "broken.obj" else "skipped") for k in statuses}
    assert (out / "props" / "chair one" / "report.json").stat().st_mtime_ns == stamp  # untouched
    kept = drop_keys(entries(first)["flag.obj"], [*MANIFEST_TIMING_KEYS, "status", "reason"])
    assert drop_keys(entries(second)["flag.obj"], [*MANIFEST_TIMING_KEYS, "status", "reason"]) == kept
    assert entries(second)["flag.obj"]["reason"] == "up to date" and entries(first)["flag.obj"]["reason"] is None
    # change an input, a sidecar, delete an output: only those are redone
    write(folder / "clash" / "a.obj", "v 0 0 0\nv 2 0 0\nv 0 2 0\nf 1 2 3\n")
    write(folder / "flag.toml", "[simulation]\nframes = 6\n")
    (out / "props" / "chair one" / "frames" / "frame_0001.obj").unlink()
    third = entries(run_batch(folder, recipe, out, jobs=0, job=fake_job))
    redone = {k for k, e in third.items() if e["status"] == "ok"}
    assert redone == {"clash/a.obj", "flag.obj", "props/chair one.obj"}
    assert third["flag.obj"]["frames"] == 6
    # --force redoes everything; a new tool version too
    assert {
        e["status"] for e in run_batch(folder, recipe, out, jobs=0, job=fake_job, force=True).manifest["assets"]
    } == {"ok", "failed"}
    import pipeline.batch as batch_module

    real = batch_module.__version__
    batch_module.__version__ = real + ".next"
    try:
        later = run_batch(folder, recipe, out, jobs=0, job=fake_job)
    finally:
        batch_module.__version__ = real
    assert "skipped" not in {e["status"] for e in later.manifest["assets"]}


def test_include_exclude_keep_other_entries(folder: Path, recipe: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    run_batch(folder, recipe, out, jobs=0, job=fake_job)
    result = run_batch(folder, recipe, out, jobs=0, job=fake_job, include=["props/*"], exclude=["*.PLY"], force=True)
    got = entries(result)
    assert result.summary["assets"] == 1 and got["props/chair one.obj"]["status"] == "ok"
    assert got["flag.obj"]["selected"] is False and got["flag.obj"]["status"] == "ok"  # carried over
    assert "selected" not in got["props/chair one.obj"]
    with pytest.raises(BatchError, match=r"no \.obj or \.ply files found with the --include/--exclude"):
        run_batch(folder, recipe, out, jobs=0, job=fake_job, include=["nothing*"])


def test_usage_errors(folder: Path, recipe: Path, tmp_path: Path) -> None:
    with pytest.raises(BatchError, match="no such folder"):
        run_batch(tmp_path / "missing", recipe, tmp_path / "out", jobs=0, job=fake_job)
    with pytest.raises(BatchError, match="cannot be the assets folder"):
        run_batch(folder, recipe, folder / ".." / folder.name, jobs=0, job=fake_job)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(BatchError, match=r"no \.obj or \.ply files"):
        run_batch(empty, recipe, tmp_path / "out", jobs=0, job=fake_job)
    bad = write(tmp_path / "bad.toml", "[simulation]\nsolver = 3\n")
    with pytest.raises(RecipeError, match=r"bad\.toml: simulation\.solver"):
        run_batch(folder, bad, tmp_path / "out", jobs=0, job=fake_job)
    assert not (tmp_path / "out").exists()  # nothing is created before the batch can start
    (tmp_path / "out").mkdir()
    with out_lock(tmp_path / "out"), pytest.raises(BatchError, match="another batch is writing"):
        run_batch(folder, recipe, tmp_path / "out", jobs=0, job=fake_job)


def test_interrupted_batch_keeps_what_is_done_and_resumes_cleanly(folder: Path, recipe: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    write(folder / "m_interrupt.obj", "interrupt")  # sorted after flag.obj, before props/
    # the lock file, a stale staging folder and temp manifest from a run that was killed while planning
    write(out / ".meshdeform-batch.lock", "")
    stale = stage_path(out / "props" / "chair one")
    write(stale / "frames" / "frame_0001.obj")
    write(out / ".manifest.x1y2.part.json", "{")
    with pytest.raises(KeyboardInterrupt):
        run_batch(folder, recipe, out, jobs=0, job=fake_job)
    assert not stale.exists() and not (out / ".manifest.x1y2.part.json").exists()
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["complete"] is False
    status = {e["input"]: e["status"] for e in manifest["assets"]}
    assert status["flag.obj"] == "ok" and status["clash/a.obj"] == "ok"
    assert status["m_interrupt.obj"] == "pending" and status["props/chair one.obj"] == "pending"
    assert not [p for p in out.rglob("*") if ".partial-" in p.name]  # no half-written result
    assert not (out / "m_interrupt").exists() and not (out / "props" / "chair one").exists()
    write(folder / "m_interrupt.obj")  # fixed
    resumed = entries(run_batch(folder, recipe, out, jobs=0, job=fake_job))
    assert resumed["flag.obj"]["status"] == "skipped" and resumed["m_interrupt.obj"]["status"] == "ok"
    assert resumed["props/chair one.obj"]["status"] == "ok"


def test_remove_stale_only_touches_staging_names(tmp_path: Path) -> None:
    keep = write(tmp_path / "a" / ".notes" / "x.txt")
    # a person's names that look like the old short staging names (8 hex digits: a date) are kept
    dated = [write(tmp_path / "a" / ".photos.old-20240101" / "img.txt"), write(tmp_path / ".b.partial-deadbeef" / "f")]
    write(stage_path(tmp_path / "a" / "b") / "f.obj")
    write(stage_path(tmp_path / "a" / "b", "old") / "f.obj")
    write(tmp_path / ".manifest.abc.part.json")
    removed = remove_stale(tmp_path)
    assert len(removed) == 3 and keep.exists() and all(p.exists() for p in dated)
    assert sorted(os.listdir(tmp_path / "a")) == [".notes", ".photos.old-20240101"]


def test_out_folder_inside_or_around_the_assets_or_recipe_folder_is_refused(
    folder: Path, recipe: Path, tmp_path: Path
) -> None:
    for out, reason in (
        (folder / "baked", "is inside the assets folder"),
        (folder / "props" / ".." / "x", "is inside the assets folder"),
        (tmp_path, "contains the assets folder"),
        (folder / "..", "contains the assets folder"),
    ):
        with pytest.raises(BatchError, match=reason):
            run_batch(folder, recipe, out, jobs=0, job=fake_job)
    elsewhere = tmp_path / "recipes" / "r.toml"
    write(elsewhere, RECIPE)
    with pytest.raises(BatchError, match="is the folder of the recipe"):
        run_batch(folder, elsewhere, tmp_path / "recipes", jobs=0, job=fake_job)
    assert not (folder / "baked").exists() and not (folder / "x").exists()
    assert sorted(os.listdir(tmp_path / "recipes")) == ["r.toml"]
