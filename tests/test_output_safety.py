"""Output folders are safe on anyone's files (issue 13), through the command line.

Folders holding a user's files are passed as `simulate -o` / `batch --out` in every way a user could
mistype them; each is refused with exit 2 and one stderr line, and a checksum snapshot of everything
under the test's folder (the user's files, the input, the recipe, the parents) is unchanged: nothing
is deleted, rewritten or added. Then what may be written is: a previous result is replaced, a result
holding a user's file is refused, `--overwrite` keeps every file meshdeform did not write, a second
run on a folder being written is refused, and a batch does not follow symlinks out of its assets.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from factories import write_grid
from robustness_corpus import snapshot
from typer.testing import CliRunner

from pipeline.cli import app
from pipeline.output_folder import MARKER_NAME, output_lock

runner = CliRunner()
RECIPE = '[simulation]\nsolver = "verlet"\nframes = 2\n'
OUTSIDE_LINK = "symlink to a path outside the assets folder"


def cli(*args: Any) -> Any:
    return runner.invoke(app, [str(a) for a in args])


def put(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")
    return path


def one_error_line(result: Any) -> str:
    """The command failed as a usage error with exactly one stderr line; return it."""
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    assert "Traceback" not in result.output
    return lines[0]


@pytest.fixture()
def user(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> dict[str, Path]:
    """A user's home: a project with the mesh, its notes and a recipe folder, a documents folder, a
    symlink to the project, and the shell in home/work (a folder with a file of its own)."""
    home = tmp_path / "home"
    project = home / "project"
    paths = {
        "root": tmp_path,
        "home": home,
        "project": project,
        "mesh": write_grid(project / "cloth.obj", 4, plane="xz"),
        "notes": put(project / "notes.txt", "my notes\n"),
        "recipe": put(project / "recipes" / "cloth.toml", RECIPE),
        "docs": home / "docs",
        "work": home / "work",
        "link": tmp_path / "project-link",
        "docs_link": tmp_path / "docs-link",
    }
    put(home / "docs" / "a.txt", "a\n")
    put(home / "docs" / "b" / "c.txt", "c\n")
    put(home / "work" / "todo.txt", "todo\n")
    paths["link"].symlink_to(project, target_is_directory=True)
    paths["docs_link"].symlink_to(home / "docs", target_is_directory=True)
    (home / "work" / "dangling").symlink_to(tmp_path / "nowhere" / "out", target_is_directory=True)
    monkeypatch.chdir(home / "work")
    return paths


#: (what the user typed as -o, from the paths of `user`; what the one line must say)
MISTYPED: list[tuple[str, Callable[[dict[str, Path]], str], str]] = [
    ("dot", lambda p: ".", "is the current folder"),
    ("dot slash", lambda p: "./", "is the current folder"),
    ("dot dot", lambda p: "..", "contains the current folder"),
    ("cwd absolute", lambda p: str(p["work"]), "is the current folder"),
    ("home", lambda p: str(p["home"]), "contains the current folder"),
    ("root of the test", lambda p: str(p["root"]), "contains the current folder"),
    ("input folder", lambda p: str(p["project"]), "is the folder of the input"),
    ("input folder, trailing slashes", lambda p: str(p["project"]) + "//", "is the folder of the input"),
    ("input folder via ..", lambda p: str(p["project"] / "recipes" / ".."), "is the folder of the input"),
    ("input folder, relative", lambda p: "../project", "is the folder of the input"),
    ("input folder via a symlink", lambda p: str(p["link"]), "is the folder of the input"),
    ("input folder via a symlink, slash", lambda p: str(p["link"]) + "/", "is the folder of the input"),
    ("recipe folder", lambda p: str(p["recipe"].parent), "is the folder of the recipe"),
    ("recipe folder via a symlink", lambda p: str(p["link"] / "recipes"), "is the folder of the recipe"),
    ("an existing file", lambda p: str(p["notes"]), "exists and is not a folder"),
    ("the input mesh itself", lambda p: str(p["mesh"]), "exists and is not a folder"),
    ("a file in the current folder", lambda p: "todo.txt", "exists and is not a folder"),
    ("a file system root", lambda p: "/", "is a file system root"),
    ("a dangling symlink", lambda p: "dangling", "is a symbolic link to a missing path"),
]
#: folders refused only because they hold files meshdeform did not write (--overwrite writes beside them)
FOREIGN: list[tuple[str, Callable[[dict[str, Path]], str], str]] = [
    ("a documents folder", lambda p: str(p["docs"]), "exists and is not a meshdeform result (2 entries, e.g. 'a.txt')"),
    ("a documents folder via a symlink", lambda p: str(p["docs_link"]), "is not a meshdeform result"),
    ("a documents folder, relative", lambda p: "../docs/", "is not a meshdeform result"),
    ("a sub-folder of the documents", lambda p: str(p["docs"] / "b"), "(1 entry, e.g. 'c.txt')"),
]


@pytest.mark.parametrize(
    ("typed", "message"), [(c[1], c[2]) for c in MISTYPED + FOREIGN], ids=[c[0] for c in MISTYPED + FOREIGN]
)
def test_simulate_refuses_a_mistyped_out_and_touches_nothing(
    user: dict[str, Path], typed: Callable[[dict[str, Path]], str], message: str
) -> None:
    before = snapshot(user["root"])
    out = typed(user)
    line = one_error_line(cli("simulate", user["mesh"], "-r", user["recipe"], "-o", out, "-q"))
    assert message in line
    assert line.startswith(f"error: {Path(out)}:")  # names the path as typed
    assert snapshot(user["root"]) == before


@pytest.mark.parametrize(("typed", "message"), [(c[1], c[2]) for c in MISTYPED], ids=[c[0] for c in MISTYPED])
def test_overwrite_does_not_lift_the_path_refusals(
    user: dict[str, Path], typed: Callable[[dict[str, Path]], str], message: str
) -> None:
    before = snapshot(user["root"])
    line = one_error_line(cli("simulate", user["mesh"], "-r", user["recipe"], "-o", typed(user), "-q", "--overwrite"))
    assert message in line
    assert snapshot(user["root"]) == before


def test_the_home_folder_from_elsewhere_contains_the_input(
    user: dict[str, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    elsewhere = user["root"] / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    before = snapshot(user["root"])
    line = one_error_line(cli("simulate", user["mesh"], "-o", user["home"], "-q", "--overwrite"))
    assert f"contains the input {user['mesh']}" in line
    assert snapshot(user["root"]) == before


def written_files(folder: Path) -> list[str]:
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file())


def test_a_previous_result_is_replaced_whole(user: dict[str, Path]) -> None:
    out = user["root"] / "results" / "cloth"
    first = cli("simulate", user["mesh"], "-o", out, "--frames", "4", "-q", "--solver", "verlet")
    assert first.exit_code == 0, first.output
    marker = json.loads((out / MARKER_NAME).read_text())
    assert marker["tool"] == "meshdeform" and marker["files"] == [
        *(f"frames/frame_{i:04d}.obj" for i in range(1, 6)),  # the rest pose and 4 frames
        "report.json",
    ]
    outside = {k: v for k, v in snapshot(user["root"]).items() if not k.startswith("results/cloth/")}
    again = cli("simulate", user["mesh"], "-o", str(out) + "/", "--frames", "2", "-q", "--solver", "verlet")
    assert again.exit_code == 0, again.output
    # the frames of the first run not written again are gone with it: the folder is the second run alone
    assert written_files(out) == [MARKER_NAME, *(f"frames/frame_{i:04d}.obj" for i in range(1, 4)), "report.json"]
    assert json.loads((out / MARKER_NAME).read_text())["files"] == written_files(out)[1:]
    # nothing left beside it (no staging folder, no lock file), nothing else changed
    assert {k: v for k, v in snapshot(user["root"]).items() if not k.startswith("results/cloth/")} == outside


@pytest.mark.parametrize(
    "theirs",
    [
        ".photos.old-20240101/img.txt",  # a dated folder that looks like a short staging name
        ".backup.partial-20231231/a.txt",
        "frames/.todo.meshdeform.lock",  # a lock-like name deep inside: not beside any target
        "preview.gif",  # a preview of theirs: meshdeform's previews are listed in the marker
        "preview/0001.png",
    ],
)
def test_a_users_file_that_looks_like_meshdeforms_is_never_taken_for_it(user: dict[str, Path], theirs: str) -> None:
    out = user["root"] / "cloth"
    assert cli("simulate", user["mesh"], "-o", out, "-q", "--frames", "2").exit_code == 0
    put(out / theirs, "mine\n")
    before = snapshot(user["root"])
    line = one_error_line(cli("simulate", user["mesh"], "-o", out, "-q", "--frames", "3"))
    assert "entry meshdeform did not write" in line
    assert snapshot(user["root"]) == before


def test_a_previous_result_holding_a_users_file_is_refused(user: dict[str, Path]) -> None:
    out = user["root"] / "cloth"
    assert cli("simulate", user["mesh"], "-o", out, "-q", "--frames", "2").exit_code == 0
    put(out / "frames" / "my edit.obj", "v 0 0 0\n")
    before = snapshot(user["root"])
    line = one_error_line(cli("simulate", user["mesh"], "-o", out, "-q", "--frames", "3"))
    assert "holds a meshdeform result and 1 entry meshdeform did not write (e.g. 'frames/my edit.obj')" in line
    assert "--overwrite" in line
    assert snapshot(user["root"]) == before


def test_overwrite_writes_beside_the_users_files_and_keeps_them(user: dict[str, Path]) -> None:
    docs = user["docs"]
    put(docs / "frames" / "mine.txt", "mine\n")  # a user file where the frames go
    put(docs / "report.json", '{"mine": true}\n')  # a file with an output's name: never replaced
    before = snapshot(user["root"])
    line = one_error_line(cli("simulate", user["mesh"], "-o", docs, "-q", "--frames", "3", "--overwrite"))
    assert line == (
        f"error: {docs}: will not replace 'report.json': meshdeform did not write it; move it away or choose"
        " another --out (the folder was left as it was)"
    )
    assert snapshot(user["root"]) == before
    (docs / "report.json").unlink()
    keep = snapshot(docs)
    result = cli("simulate", user["mesh"], "-o", docs, "-q", "--frames", "3", "--overwrite")
    assert result.exit_code == 0, result.output
    now = snapshot(docs)
    assert {k: now[k] for k in keep} == keep  # every other file as it was
    assert json.loads((docs / "report.json").read_text())["frames"] == 3
    frames = [f"frames/frame_{i:04d}.obj" for i in range(1, 5)]  # the rest pose and 3 frames
    assert json.loads((docs / MARKER_NAME).read_text())["files"] == [*frames, "report.json"]
    # a shorter run: the frame meshdeform wrote and does not write again is removed, the user's stay
    result = cli("simulate", user["mesh"], "-o", docs, "-q", "--frames", "2", "--overwrite")
    assert result.exit_code == 0, result.output
    assert not (docs / "frames" / "frame_0004.obj").exists() and (docs / "frames" / "frame_0003.obj").is_file()
    now = snapshot(docs)
    assert {k: now[k] for k in keep} == keep
    # without --overwrite the folder is still refused: it holds the user's files
    line = one_error_line(cli("simulate", user["mesh"], "-o", docs, "-q", "--frames", "2"))
    assert "3 entries meshdeform did not write (e.g. 'a.txt')" in line


def test_a_result_file_the_user_edited_to_the_same_size_is_theirs(user: dict[str, Path]) -> None:
    out = user["root"] / "out" / "cloth"
    assert cli("simulate", user["mesh"], "-o", out, "-q", "--frames", "2").exit_code == 0
    frame = out / "frames" / "frame_0003.obj"  # the rest pose is frame 1
    text = frame.read_text()
    edited = text.replace("v ", "v  ", 1)[:-1]  # other bytes, the same length
    assert len(edited) == len(text) and edited != text
    frame.write_text(edited)
    before = snapshot(user["root"])
    line = one_error_line(cli("simulate", user["mesh"], "-o", out, "-q", "--frames", "2"))
    assert "1 entry meshdeform did not write (e.g. 'frames/frame_0003.obj')" in line
    line = one_error_line(cli("simulate", user["mesh"], "-o", out, "-q", "--frames", "2", "--overwrite"))
    assert "will not replace 'frames/frame_0003.obj': it was changed since meshdeform wrote it" in line
    assert snapshot(user["root"]) == before
    # a shorter run under --overwrite leaves the edited frame where it is, the user's now
    result = cli("simulate", user["mesh"], "-o", out, "-q", "--frames", "1", "--overwrite")
    assert result.exit_code == 0, result.output
    assert frame.read_text() == edited


def test_overwrite_never_replaces_a_symlink_with_an_output_s_name(user: dict[str, Path]) -> None:
    docs = user["docs"]
    target = user["root"] / "elsewhere.obj"
    put(target, "the user's file\n")
    (docs / "frames").mkdir()
    (docs / "frames" / "frame_0001.obj").symlink_to(target)
    before = snapshot(user["root"])
    line = one_error_line(cli("simulate", user["mesh"], "-o", docs, "-q", "--frames", "2", "--overwrite"))
    assert "will not replace 'frames/frame_0001.obj': meshdeform did not write it" in line
    assert snapshot(user["root"]) == before and (docs / "frames" / "frame_0001.obj").is_symlink()


def test_overwrite_never_deletes_a_file_in_the_way(user: dict[str, Path]) -> None:
    docs = user["docs"]
    put(docs / "frames", "a file where the frames folder would go\n")
    before = snapshot(user["root"])
    line = one_error_line(cli("simulate", user["mesh"], "-o", docs, "-q", "--frames", "2", "--overwrite"))
    assert "'frames' is in the way and meshdeform did not write it" in line
    assert snapshot(user["root"]) == before


def test_simulate_removes_what_killed_runs_on_its_folder_left_and_nothing_else(user: dict[str, Path]) -> None:
    out = user["root"] / "out" / "cloth"
    killed = put(out.parent / f".cloth.partial-meshdeform-{'ab' * 16}" / "frames" / "frame_0001.obj", "v 0 0 0\n")
    set_aside = put(out.parent / f".cloth.old-meshdeform-{'cd' * 16}" / "report.json", "{}\n")
    others = [
        put(out.parent / f".other.partial-meshdeform-{'ef' * 16}" / "x.obj", "another folder's\n"),
        put(out.parent / ".cloth.partial-mine" / "notes.txt", "a name a person picked\n"),
        put(out.parent / "cloth.partial-meshdeform-backup" / "notes.txt", "mine\n"),
    ]
    result = cli("simulate", user["mesh"], "-o", out, "-q", "--frames", "1")
    assert result.exit_code == 0, result.output
    assert not killed.parent.parent.exists() and not set_aside.parent.exists()
    assert all(path.is_file() for path in others)


def test_a_second_run_on_a_locked_folder_is_refused_at_once(user: dict[str, Path]) -> None:
    out = user["root"] / "out" / "cloth"
    before = snapshot(user["root"])
    with output_lock(out):  # what a running simulate holds
        line = one_error_line(cli("simulate", user["mesh"], "-o", out, "-q"))
    assert line == f"error: {out}: another meshdeform run is writing this folder"
    assert snapshot(user["root"]) == before  # the lock's folders and file are gone with it


def test_two_simulate_runs_on_one_folder(user: dict[str, Path]) -> None:
    big = write_grid(user["root"] / "big.obj", 30, plane="xz")
    out = user["root"] / "out"
    command = [sys.executable, "-c", "from pipeline.cli import app; app()", "simulate", str(big), "-o", str(out)]
    first = subprocess.Popen(
        [*command, "--frames", "600", "--format", "pc2", "--solver", "verlet", "-q"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 120
        while not list(user["root"].glob(".out.partial-*")):  # the first run is simulating
            assert first.poll() is None, first.communicate()
            assert time.monotonic() < deadline, "the first run never started writing"
            time.sleep(0.05)
        second = cli("simulate", user["mesh"], "-o", out, "-q", "--frames", "2")
        assert one_error_line(second) == f"error: {out}: another meshdeform run is writing this folder"
        _, stderr = first.communicate(timeout=300)
    finally:
        if first.poll() is None:
            first.kill()
    assert first.returncode == 0, stderr
    assert json.loads((out / "report.json").read_text())["frames"] == 600  # the first run's result, whole
    assert sorted(p.name for p in user["root"].iterdir() if p.name.startswith(".")) == []


def test_a_staging_folder_that_cannot_be_made_gives_one_line(
    user: dict[str, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    # (the tests run as root, where a read-only folder is still writable: the refusal is injected)
    real_mkdir = os.mkdir

    def read_only_parent(path: Any, *args: Any, **kwargs: Any) -> None:
        if ".partial-" in os.fspath(path):
            raise PermissionError(13, "Permission denied", os.fspath(path))
        real_mkdir(path, *args, **kwargs)

    monkeypatch.setattr(os, "mkdir", read_only_parent)
    out = user["root"] / "new" / "cloth"
    before = snapshot(user["root"])
    line = one_error_line(cli("simulate", user["mesh"], "-o", out, "-q"))
    assert line == f"error: {out}: cannot create a staging folder in {out.parent}: Permission denied"
    assert snapshot(user["root"]) == before  # the parent it made for the run is removed again


def test_an_out_below_a_file_gives_one_line(user: dict[str, Path]) -> None:
    before = snapshot(user["root"])
    line = one_error_line(cli("simulate", user["mesh"], "-o", user["notes"] / "cloth", "-q"))
    assert line == f"error: {user['notes'] / 'cloth'}: {user['notes']} exists and is not a folder; choose another --out"
    assert snapshot(user["root"]) == before


# -- batch ----------------------------------------------------------------------------------------


@pytest.fixture()
def batch(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> dict[str, Path]:
    """Assets (two meshes, symlinks in and out of the folder, a link loop), a recipe beside them, and a
    folder of someone else's meshes the links point at."""
    root = tmp_path
    assets = root / "project" / "assets"
    write_grid(assets / "a.obj", 4, plane="xz")
    write_grid(assets / "sub" / "b.obj", 4, plane="xz")
    write_grid(root / "private" / "secret.obj", 4, plane="xz")
    write_grid(root / "private" / "more" / "other.obj", 4, plane="xz")
    (assets / "inner.obj").symlink_to(assets / "a.obj")  # inside: an asset like any other
    (assets / "sub" / "leak.obj").symlink_to(root / "private" / "secret.obj")
    (assets / "private").symlink_to(root / "private", target_is_directory=True)
    (assets / "up").symlink_to("..", target_is_directory=True)  # the project folder
    (assets / "sub" / "loop").symlink_to("..", target_is_directory=True)  # back into the assets: a loop
    recipe = put(root / "project" / "recipe.toml", RECIPE)
    monkeypatch.chdir(root / "project")
    return {"root": root, "assets": assets, "recipe": recipe, "private": root / "private"}


def manifest(out: Path) -> dict[str, dict[str, Any]]:
    return {e["input"]: e for e in json.loads((out / "manifest.json").read_text())["assets"]}


def test_batch_does_not_follow_symlinks_out_of_the_assets_folder(batch: dict[str, Path]) -> None:
    private = snapshot(batch["private"])
    out = batch["root"] / "out"
    result = cli("batch", batch["assets"], "-r", batch["recipe"], "-o", out, "--jobs", 0, "-q")
    assert result.exit_code == 0, result.output
    entries = manifest(out)
    assert {k: e["status"] for k, e in entries.items()} == {
        "a.obj": "ok",
        "inner.obj": "ok",
        "private/": "skipped",
        "sub/b.obj": "ok",
        "sub/leak.obj": "skipped",
        "up/": "skipped",
    }
    for key in ("private/", "sub/leak.obj", "up/"):
        assert entries[key]["reason"] == OUTSIDE_LINK and entries[key]["output"] is None
    assert not (out / "sub" / "leak").exists() and not (out / "private").exists()
    assert (out / "inner" / "report.json").is_file()
    assert snapshot(batch["private"]) == private


@pytest.mark.parametrize(
    ("typed", "message"),
    [
        (lambda b: b["assets"] / "baked", "is inside the assets folder"),
        (lambda b: b["assets"] / "sub", "is inside the assets folder"),
        (lambda b: b["assets"] / "up" / "assets" / "out", "is inside the assets folder"),  # via a symlink
        (lambda b: b["assets"], "cannot be the assets folder itself"),
        (lambda b: str(b["assets"]) + "//", "cannot be the assets folder itself"),
        (lambda b: ".", "contains the assets folder"),  # the project folder
        (lambda b: "..", "contains the assets folder"),
        (lambda b: b["private"], "folder exists and is not a meshdeform batch output (2 entries, e.g. 'more')"),
        (lambda b: b["recipe"], "exists and is not a folder"),
        (lambda b: b["assets"] / "a.obj", "is inside the assets folder"),
    ],
    ids=["inside", "a sub-folder", "inside via a symlink", "the assets", "the assets, slashes", "dot", "dot dot",
         "someone's folder", "the recipe file", "an asset file"],
)  # fmt: skip
def test_batch_refuses_a_mistyped_out_and_touches_nothing(
    batch: dict[str, Path], typed: Callable[[dict[str, Path]], Any], message: str
) -> None:
    before = snapshot(batch["root"])
    line = one_error_line(cli("batch", batch["assets"], "-r", batch["recipe"], "-o", typed(batch), "--jobs", 0, "-q"))
    assert message in line
    assert snapshot(batch["root"]) == before


def test_batch_refuses_the_recipe_folder(batch: dict[str, Path]) -> None:
    recipes = batch["root"] / "recipes"
    recipe = put(recipes / "r.toml", RECIPE)
    before = snapshot(batch["root"])
    for out in (recipes, batch["root"]):
        line = one_error_line(cli("batch", batch["assets"], "-r", recipe, "-o", out, "--jobs", 0, "-q", "--overwrite"))
        assert "the recipe" in line or "contains the assets folder" in line
    assert snapshot(batch["root"]) == before


def test_batch_asset_folder_holding_a_users_file_fails_alone(batch: dict[str, Path]) -> None:
    out = batch["root"] / "out"
    assert cli("batch", batch["assets"], "-r", batch["recipe"], "-o", out, "--jobs", 0, "-q").exit_code == 0
    mine = put(out / "a" / "notes.txt", "mine\n")
    write_grid(batch["assets"] / "a.obj", 5, plane="xz")  # changed: a.obj must be redone
    second = cli("batch", batch["assets"], "-r", batch["recipe"], "-o", out, "--jobs", 0, "-q")
    assert second.exit_code == 1, second.output
    entries = manifest(out)
    assert entries["a.obj"]["status"] == "failed" and entries["a.obj"]["error_type"] == "OutputFolderError"
    assert "'notes.txt'" in entries["a.obj"]["error"] and "--overwrite" in entries["a.obj"]["error"]
    assert entries["sub/b.obj"]["status"] == "skipped" and entries["inner.obj"]["status"] == "ok"  # links a.obj
    assert mine.read_text() == "mine\n"
    third = cli("batch", batch["assets"], "-r", batch["recipe"], "-o", out, "--jobs", 0, "-q", "--overwrite")
    assert third.exit_code == 0, third.output
    assert manifest(out)["a.obj"]["status"] == "ok" and mine.read_text() == "mine\n"
    assert json.loads((out / "a" / "report.json").read_text())["vertices"] == 25


def test_batch_never_writes_through_a_symlink_inside_its_out(batch: dict[str, Path]) -> None:
    out = batch["root"] / "out"
    assert cli("batch", batch["assets"], "-r", batch["recipe"], "-o", out, "--jobs", 0, "-q").exit_code == 0
    elsewhere = batch["root"] / "elsewhere"
    shutil.move(out / "a", elsewhere)  # a meshdeform result of its own, outside OUT
    (out / "a").symlink_to(elsewhere, target_is_directory=True)
    (out / "sub").rename(batch["root"] / "sub-elsewhere")
    (out / "sub").symlink_to(batch["root"] / "sub-elsewhere", target_is_directory=True)
    before = snapshot(batch["root"] / "elsewhere"), snapshot(batch["root"] / "sub-elsewhere")
    for flags in ((), ("--overwrite",)):
        result = cli("batch", batch["assets"], "-r", batch["recipe"], "-o", out, "--jobs", 0, "-q", "--force", *flags)
        assert result.exit_code == 1, result.output
        entries = manifest(out)
        for key, link in (("a.obj", "a"), ("sub/b.obj", "sub")):
            assert entries[key]["status"] == "failed" and entries[key]["error_type"] == "OutputFolderError"
            assert f"{link!r} in {out} is a symbolic link" in entries[key]["error"], entries[key]["error"]
        assert entries["inner.obj"]["status"] == "ok"
        assert (snapshot(batch["root"] / "elsewhere"), snapshot(batch["root"] / "sub-elsewhere")) == before


def test_batch_overwrite_writes_into_someones_folder_and_keeps_their_files(batch: dict[str, Path]) -> None:
    out = batch["root"] / "shared"
    put(out / "README.md", "ours\n")
    put(out / "sub" / "b" / "notes.txt", "ours too\n")
    before = snapshot(out)
    line = one_error_line(cli("batch", batch["assets"], "-r", batch["recipe"], "-o", out, "--jobs", 0, "-q"))
    assert "is not a meshdeform batch output (2 entries, e.g. 'README.md')" in line
    assert snapshot(out) == before
    result = cli("batch", batch["assets"], "-r", batch["recipe"], "-o", out, "--jobs", 0, "-q", "--overwrite")
    assert result.exit_code == 0, result.output
    now = snapshot(out)
    assert {k: now[k] for k in before} == before
    assert (out / "sub" / "b" / "report.json").is_file() and (out / "manifest.json").is_file()
    # from now on it is a batch folder: a plain rerun is accepted and finds everything up to date
    again = cli("batch", batch["assets"], "-r", batch["recipe"], "-o", out, "--jobs", 0, "-q")
    assert again.exit_code == 0, again.output
    assert {e["status"] for e in manifest(out).values()} == {"skipped"}


def test_batch_does_not_read_a_sidecar_that_links_out_of_the_assets_folder(batch: dict[str, Path]) -> None:
    """A sidecar NAME.toml is read only when it resolves inside the assets folder: a link to a shared
    recipe in the folder works, a link out of it fails that asset alone with the reason."""
    put(batch["private"] / "evil.toml", "[simulation]\nframes = 3\n")
    put(batch["assets"] / "common.toml", "[simulation]\nframes = 3\n")
    (batch["assets"] / "a.toml").symlink_to(batch["private"] / "evil.toml")
    (batch["assets"] / "sub" / "b.toml").symlink_to(batch["assets"] / "common.toml")
    out = batch["root"] / "out"
    result = cli("batch", batch["assets"], "-r", batch["recipe"], "-o", out, "--jobs", 0, "-q")
    assert result.exit_code == 1
    entries = manifest(out)
    assert entries["a.obj"]["status"] == "failed"
    assert "symlink to a path outside the assets folder" in entries["a.obj"]["error"]
    assert entries["sub/b.obj"]["status"] == "ok" and entries["sub/b.obj"]["frames"] == 3


def test_a_result_file_the_user_changed_is_theirs(user: dict[str, Path]) -> None:
    """The marker records each file's size: a frame the user edited since is not replaced without
    --overwrite, and --overwrite keeps it when the new run does not write that file again."""
    out = user["root"] / "cloth"
    assert cli("simulate", user["mesh"], "-o", out, "-q", "--frames", "3").exit_code == 0
    edited = out / "frames" / "frame_0004.obj"  # the last of the rest pose and 3 frames
    edited.write_text(edited.read_text() + "# my cleanup\n")
    before = snapshot(user["root"])
    line = one_error_line(cli("simulate", user["mesh"], "-o", out, "-q", "--frames", "2"))
    assert "1 entry meshdeform did not write (e.g. 'frames/frame_0004.obj')" in line
    assert snapshot(user["root"]) == before
    assert cli("simulate", user["mesh"], "-o", out, "-q", "--frames", "2", "--overwrite").exit_code == 0
    assert edited.read_text().endswith("# my cleanup\n")
