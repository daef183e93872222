"""A batch: every OBJ/PLY under a folder through one recipe, in parallel, resumable, failures isolated.

    discover (sorted, relative paths) -> select (--include/--exclude) -> output folder names
    -> per-asset recipe (base <- [[assets]] rules <- sidecar NAME.toml) -> up to date? skip
    -> executor (serial / processes / Dask) -> manifest.json updated as assets finish.

Which assets, their output folders and their recipes: `pipeline.assets`. This module plans and runs
them (`run_batch`), keeps OUT's manifest and log, and guards OUT itself.

The per-asset `report.json` (written by `run_job` together with the outputs, renamed into place
in one step) is what a rerun trusts: an asset is skipped when its report names the same input
hash, merged-recipe hash and tool version and every output it lists exists.

Folders are checked before anything runs (`check_out`): OUT may not be, contain or lie inside the
assets folder, nor be or contain the recipe's folder, and a non-empty OUT must be a previous batch's
(its manifest) unless `overwrite`. Each asset folder is then checked as `simulate` checks --out
(`pipeline.output_folder.check_output_folder`): one holding files meshdeform did not write fails that
asset alone.
"""

from __future__ import annotations

import contextlib
import functools
import json
import logging
import os
import re
import shutil
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from meshdeform.errors import MeshdeformError
from pipeline import __version__
from pipeline.assets import Asset, AssetRecipe, discover, load_base_recipe, output_folders, resolve_recipe, select
from pipeline.executors import AssetOutcome, AssetTask, Executor, JobFunction, make_executor, one_line
from pipeline.hashing import file_sha256
from pipeline.manifest import MANIFEST_NAME, Manifest, new_entry, read_manifest
from pipeline.output_folder import (
    REPORT_NAME,
    STAGE_PATTERN,
    OutputFolderError,
    check_output_folder,
    entry_count,
    exclusive_lock,
    holds_folder_of,
    linked_part,
)

if TYPE_CHECKING:
    from pipeline.recipe import Recipe

LOG_NAME = "batch.log"
LOCK_NAME = ".meshdeform-batch.lock"
#: atomic temp files of the manifest (staging folders: `pipeline.output_folder.STAGE_PATTERN`)
_STALE_MANIFEST = re.compile(r"^\.manifest\..+\.part\.json$")
#: the manifest's "reason" of an asset skipped because its outputs are current
UP_TO_DATE = "up to date"


class BatchError(MeshdeformError):
    """The batch cannot start: missing folder, no assets, output folder busy (a usage error)."""


# -- resume ------------------------------------------------------------------------------------


def read_report(out_dir: Path) -> dict[str, Any] | None:
    """The report.json of a finished job in `out_dir`, or None."""
    try:
        data = json.loads((out_dir / REPORT_NAME).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def up_to_date(report: dict[str, Any] | None, out_dir: Path, mesh: Path, recipe_sha: str) -> bool:
    """Is a previous result reusable: same tool version, merged-recipe hash and input hash, and every
    output it lists still there? (The input is hashed only when the cheaper checks pass.)"""
    if not report or report.get("version") != __version__ or report.get("recipe_sha256") != recipe_sha:
        return False
    outputs = report.get("outputs")
    if not isinstance(outputs, list) or not all((out_dir / str(p)).is_file() for p in outputs):
        return False
    try:
        return report.get("input_sha256") == file_sha256(mesh)
    except OSError:
        return False


# -- the output folder OUT ---------------------------------------------------------------------


def remove_stale(out: Path) -> list[Path]:
    """Delete what interrupted runs left in OUT: staging folders `.NAME.partial-*` / `.NAME.old-*` at
    any depth and temporary manifest files. Only safe while this batch holds the OUT lock."""
    removed: list[Path] = []
    if not out.is_dir():
        return removed
    for folder, dirs, files in os.walk(out):
        here = Path(folder)
        for name in list(dirs):
            if STAGE_PATTERN.match(name):
                shutil.rmtree(here / name, ignore_errors=True)
                removed.append(here / name)
                dirs.remove(name)
        if here == out:
            for name in files:
                if _STALE_MANIFEST.match(name):
                    with contextlib.suppress(OSError):
                        (here / name).unlink()
                        removed.append(here / name)
    return removed


@contextlib.contextmanager
def out_lock(out: Path) -> Iterator[None]:
    """Hold an exclusive lock on OUT (`OUT/.meshdeform-batch.lock`, filelock: every OS) for the batch,
    so two batches never write into one folder; the second is refused at once."""
    with exclusive_lock(out / LOCK_NAME, str(out), "another batch is writing into this folder", BatchError):
        yield


def is_batch_folder(out: Path) -> bool:
    """Is `out` empty (staging leftovers aside) or a previous batch's output: a meshdeform manifest.json,
    or the lock file every batch creates first (a batch stopped before its first manifest)?"""
    names = [n for n in os.listdir(out) if not STAGE_PATTERN.match(n) and not _STALE_MANIFEST.match(n)]
    if not names or LOCK_NAME in names:
        return True
    previous = read_manifest(out / MANIFEST_NAME)
    return previous is not None and previous.get("tool") == "meshdeform"


def check_out(out: Path, assets_dir: Path, recipe_path: Path, *, overwrite: bool) -> None:
    """Refuse (BatchError, one line) an OUT that a batch must not write, before anything is read or made.

    OUT may not be the assets folder, contain it or lie inside it; not be or contain the recipe's
    folder; not be an existing non-folder; and, unless `overwrite`, a non-empty OUT must be a previous
    batch's (`is_batch_folder`). Paths are compared with symlinks, ".." and trailing slashes resolved.
    """
    real_out = Path(os.path.realpath(out))
    real_assets = Path(os.path.realpath(assets_dir))
    if real_out == real_assets:
        raise BatchError(f"{out}: the output folder cannot be the assets folder itself (its frames would be inputs)")
    if real_out in real_assets.parents:
        raise BatchError(f"{out}: contains the assets folder {assets_dir}; choose an --out outside it")
    if real_assets in real_out.parents:
        raise BatchError(
            f"{out}: is inside the assets folder {assets_dir} (its frames would be inputs); choose an --out outside it"
        )
    if (clash := holds_folder_of(real_out, "recipe", recipe_path)) is not None:
        raise BatchError(f"{out}: {clash}; choose another --out")
    if os.path.lexists(real_out) and not real_out.is_dir():
        raise BatchError(f"{out}: exists and is not a folder; choose another --out")
    if real_out.is_dir() and not overwrite and not is_batch_folder(real_out):
        names = sorted(os.listdir(real_out))
        raise BatchError(
            f"{out}: folder exists and is not a meshdeform batch output ({entry_count(len(names))}, "
            f"e.g. {names[0]!r}); "
            "choose another --out or pass --overwrite"
        )


# -- running -----------------------------------------------------------------------------------


class BatchProgress(Protocol):
    """What a display is told: the plan, then each asset's start, frames and end (main thread)."""

    def begin(self, total: int, done: int) -> None: ...

    def started(self, key: str) -> None: ...

    def frame(self, key: str, frame: int, total: int) -> None: ...

    def finished(self, key: str, entry: dict[str, Any]) -> None: ...


@dataclass
class BatchResult:
    """The end of a batch: the manifest as written, its path, and the exit code it calls for."""

    manifest: dict[str, Any]
    manifest_path: Path
    log_path: Path
    exit_code: int
    executor: str
    seconds: float
    removed_stale: list[Path] = field(default_factory=list)

    @property
    def summary(self) -> dict[str, Any]:
        return self.manifest["summary"]


class _Recorder:
    """Executor reporter: updates the manifest, the log and the display as assets move."""

    def __init__(self, manifest: Manifest, log: logging.Logger, progress: BatchProgress | None) -> None:
        self.manifest = manifest
        self.log = log
        self.progress = progress

    def started(self, task: AssetTask) -> None:
        self.manifest.flush_if_due()
        if self.progress is not None:
            self.progress.started(task.key)

    def frame(self, task: AssetTask, frame: int, total: int) -> None:
        self.manifest.flush_if_due()  # a throttled write is not left waiting for the next asset
        if self.progress is not None:
            self.progress.frame(task.key, frame, total)

    def finished(self, task: AssetTask, outcome: AssetOutcome) -> None:
        entry = self.manifest.update(
            task.key,
            status=outcome.status,
            error=outcome.error,
            error_type=outcome.error_type,
            outputs=outcome.outputs,
            frames=outcome.frames,
            seconds=outcome.seconds,
            input_sha256=outcome.input_sha256 or self.manifest.entries[task.key]["input_sha256"],
            recipe_sha256=outcome.recipe_sha256 or self.manifest.entries[task.key]["recipe_sha256"],
        )
        self.manifest.write()
        for warning in outcome.warnings:  # library warnings of the job: the log, never stderr
            self.log.warning("%s: %s", task.key, warning)
        if outcome.status == "ok":
            self.log.info(
                "ok %s: %s frames in %.2f s -> %s", task.key, outcome.frames, outcome.seconds, entry["output"]
            )
        else:
            self.log.error("failed %s: %s", task.key, outcome.error)
            if outcome.traceback:
                self.log.error("%s", outcome.traceback.rstrip())
        if self.progress is not None:
            self.progress.finished(task.key, entry)


def _open_log(path: Path) -> logging.Logger:
    logger = logging.getLogger(f"meshdeform.batch.{id(path)}.{time.monotonic_ns()}")
    logger.setLevel(logging.INFO)
    logger.propagate = False
    handler = logging.FileHandler(path, encoding="utf-8")
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(message)s"))
    logger.addHandler(handler)
    logging.getLogger().addHandler(handler)  # library logs and warnings of this process: the batch log
    return logger


def _close_log(logger: logging.Logger) -> None:
    for handler in list(logger.handlers):
        logging.getLogger().removeHandler(handler)
        handler.close()
        logger.removeHandler(handler)


@dataclass(frozen=True)
class _Batch:
    """What `run_batch` settled before it takes OUT's lock (folders absolute, options resolved).

    base: the batch recipe. every: every asset key under `assets_dir` (a previous manifest's entries of
    those not selected are kept). assets: the selected ones, in discovery order. links: the skipped
    symlinks the selection keeps, key -> reason. jobs: the job count (resolved from the cores when not
    given). job: the job function (None: `run_job`), bound to overwrite=True under `overwrite`.
    """

    assets_dir: Path
    out: Path
    base: Recipe
    every: tuple[str, ...]
    assets: tuple[Asset, ...]
    links: dict[str, str]
    jobs: int
    dask: str | None
    force: bool
    overwrite: bool
    job: JobFunction | None


def run_batch(
    assets_dir: Path,
    recipe_path: Path,
    out: Path,
    *,
    jobs: int | None = None,
    include: Sequence[str] = (),
    exclude: Sequence[str] = (),
    dask: str | None = None,
    force: bool = False,
    overwrite: bool = False,
    progress: BatchProgress | None = None,
    job: JobFunction | None = None,
    executor: Executor | None = None,
) -> BatchResult:
    """Run the recipe on every selected asset under `assets_dir` into `out`; see the module doc.

    Raises BatchError / RecipeError for usage errors (nothing is run or created then). Asset failures
    never raise: they are entries with status "failed". KeyboardInterrupt propagates after the manifest
    (with `"complete": false`) has been written and the workers stopped. `overwrite` lets the batch
    write into a non-batch OUT and into asset folders holding other files, keeping those files (the
    job, `run_job` or the one given, is then called with `overwrite=True`).
    """
    from pipeline.executors import available_cores

    started = time.perf_counter()
    assets_dir = Path(os.path.abspath(assets_dir))
    out = Path(os.path.abspath(out))
    if not assets_dir.is_dir():
        raise BatchError(f"{assets_dir}: no such folder")
    recipe_path = Path(os.path.abspath(recipe_path))
    check_out(out, assets_dir, recipe_path, overwrite=overwrite)
    base = load_base_recipe(recipe_path)
    found = discover(assets_dir)
    every = found.keys
    keys = select(every, include, exclude)
    links = {key: reason for key, reason in found.skipped.items() if key in select([key], include, exclude)}
    if not keys:
        filters = " with the --include/--exclude given" if include or exclude else ""
        unfollowed = f" ({len(links)} symlink(s) to paths outside the folder not followed)" if links else ""
        raise BatchError(f"{assets_dir}: no .obj or .ply files found{filters}{unfollowed}")
    if overwrite:
        from pipeline.job import run_job

        job = functools.partial(job or run_job, overwrite=True)
    folders = output_folders(every)  # on every asset, so names do not change with the selection
    assets = tuple(Asset(key=k, path=assets_dir / k, output=folders[k][0], note=folders[k][1]) for k in keys)
    jobs = available_cores() if jobs is None else jobs
    if executor is not None:
        runner = executor
    else:
        try:
            runner = make_executor(jobs, dask)
        except (OSError, ValueError) as exc:  # a Dask scheduler that cannot be reached
            raise BatchError(f"cannot connect to the Dask scheduler at {dask}: {' '.join(str(exc).split())}") from None
    batch = _Batch(
        assets_dir=assets_dir,
        out=out,
        base=base,
        every=tuple(every),
        assets=assets,
        links=links,
        jobs=jobs,
        dask=dask,
        force=force,
        overwrite=overwrite,
        job=job,
    )
    try:
        return _run(batch, runner, progress, started)
    finally:
        if executor is None:
            runner.close()


def _run(batch: _Batch, runner: Executor, progress: BatchProgress | None, started: float) -> BatchResult:
    """The locked part of `run_batch`: plan, run, keep the manifest current (`started`: its
    `time.perf_counter()` at the start, for the manifest's total_seconds)."""
    from pipeline.recipe import recipe_hash

    assets_dir, out, base, assets = batch.assets_dir, batch.out, batch.base, batch.assets
    out.mkdir(parents=True, exist_ok=True)
    with out_lock(out):
        removed = remove_stale(out)
        log = _open_log(out / LOG_NAME)
        previous = read_manifest(out / MANIFEST_NAME)
        manifest = Manifest(
            out / MANIFEST_NAME,
            {
                "tool": "meshdeform",
                "version": __version__,
                "assets_dir": str(assets_dir),
                "recipe": base.label,
                "recipe_sha256": recipe_hash(base),
            },
        )
        if previous:
            chosen = {asset.key for asset in assets}
            existing = set(batch.every)
            for entry in previous["assets"]:
                key = entry.get("input") if isinstance(entry, dict) else None
                if key in existing and key not in chosen:
                    manifest.carry(entry)
        try:
            log.info(
                "batch %s -> %s with %s (%d of %d assets%s)",
                assets_dir,
                out,
                base.label,
                len(assets),
                len(batch.every),
                ", --force" if batch.force else "",
            )
            if base.deprecation is not None:
                log.warning("%s", base.deprecation)
            if removed:
                log.info("removed %d stale staging folder(s) of interrupted runs", len(removed))
            for key, reason in batch.links.items():
                manifest.add(new_entry(key, None, version=__version__, status="skipped", reason=reason))
                log.info("skipped %s: %s", key, reason)
            tasks = _plan(batch, manifest, log)
            manifest.write(force=True)
            if progress is not None:
                progress.begin(len(assets), len(assets) - len(tasks))
            for key, entry in manifest.entries.items():
                if entry["status"] != "pending" and progress is not None:
                    progress.finished(key, entry)
            name = runner.name if tasks else "none"
            if tasks:
                log.info(
                    "running %d asset(s) with the %s executor (jobs=%s%s)",
                    len(tasks),
                    name,
                    batch.jobs,
                    f", dask={batch.dask}" if batch.dask else "",
                )
                runner.run(tasks, _Recorder(manifest, log, progress))
            manifest.complete = True
        except BaseException:
            manifest.total_seconds = time.perf_counter() - started
            with contextlib.suppress(Exception):
                manifest.write(force=True)
                remove_stale(out)
                log.warning("interrupted: %s", json.dumps(manifest.summary()))
            _close_log(log)
            raise
        manifest.total_seconds = time.perf_counter() - started
        manifest.write(force=True)
        summary = manifest.summary()
        log.info("done: %s", json.dumps(summary))
        _close_log(log)
    exit_code = 1 if summary["failed"] or summary["pending"] else 0
    return BatchResult(
        manifest=manifest.to_dict(),
        manifest_path=manifest.path,
        log_path=out / LOG_NAME,
        exit_code=exit_code,
        executor=name,
        seconds=manifest.total_seconds,
        removed_stale=removed,
    )


def _plan(batch: _Batch, manifest: Manifest, log: logging.Logger) -> list[AssetTask]:
    """Resolve each asset's recipe, record skips, recipe failures and asset folders that may not be
    written (holding files meshdeform did not write, unless `overwrite`), and return the tasks to run."""
    from pipeline.recipe import recipe_hash

    base = batch.base
    tasks: list[AssetTask] = []
    for index, asset in enumerate(batch.assets):
        out_dir = batch.out / asset.output
        try:
            recipe, layers = resolve_recipe(base, asset)
        except Exception as exc:  # a bad sidecar or rule fails this asset only
            entry = manifest.add(new_entry(asset.key, asset.output, version=__version__, note=asset.note))
            _fail_before_running(entry, asset, exc, log)
            continue
        entry = manifest.add(new_entry(asset.key, asset.output, version=__version__, overrides=layers, note=asset.note))
        sha = recipe_hash(recipe)
        entry["recipe_sha256"] = sha
        linked = linked_part(batch.out, asset.output)
        if linked is not None:  # outputs would land outside OUT, or replace a result elsewhere
            link_error = OutputFolderError(
                f"{out_dir}: {linked!r} in {batch.out} is a symbolic link; a batch writes only inside its --out"
                " folder: remove the link or choose another --out"
            )
            _fail_before_running(entry, asset, link_error, log)
            continue
        report = None if batch.force else read_report(out_dir)
        if report is not None and up_to_date(report, out_dir, asset.path, sha):
            entry.update(
                status="skipped",
                reason=UP_TO_DATE,
                outputs=list(report.get("outputs", [])),
                frames=report.get("frames"),
                seconds=0.0,
                input_sha256=report.get("input_sha256"),
            )
            log.info("skipped %s: up to date in %s", asset.key, asset.output)
            continue
        try:
            check_output_folder(out_dir, overwrite=batch.overwrite)
        except OutputFolderError as exc:  # that folder holds someone's files: this asset fails alone
            _fail_before_running(entry, asset, exc, log)
            continue
        tasks.append(
            AssetTask(
                index=index,
                key=asset.key,
                mesh_path=str(asset.path),
                out_dir=str(out_dir),
                recipe=AssetRecipe(base=str(base.source), key=asset.key, mesh=str(asset.path)),
                job=batch.job,
            )
        )
    return tasks


def _fail_before_running(entry: dict[str, Any], asset: Asset, exc: Exception, log: logging.Logger) -> None:
    """Record in its manifest `entry` and the log that `asset` failed before it ran (`exc` in one
    line), with its input's hash when the file can be read."""
    error, kind = one_line(exc)
    entry.update(status="failed", error=error, error_type=kind, seconds=0.0)
    with contextlib.suppress(OSError):
        entry["input_sha256"] = file_sha256(asset.path)
    log.error("failed %s: %s", asset.key, error)
