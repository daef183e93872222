"""`meshdeform batch ASSETS --recipe R.toml --out OUT`: every OBJ/PLY under a folder, in parallel.

A thin layer over `pipeline.batch.run_batch`: options, the progress display (Rich bars in a
terminal, one line per finished asset elsewhere), the summary table and the exit code (0 all ok
or skipped, 1 some failed, 2 usage error, 128 + N stopped by signal N: 130 Ctrl-C, 143 SIGTERM;
`pipeline.interrupts`).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import typer

from pipeline.commands.errors import EXIT_FAILED, cli_errors, fail

#: how many of the slowest assets the summary lists
SLOWEST = 5


class RichBatchProgress:
    """One overall bar for the batch and one bar per running asset (frames), on stderr."""

    def __init__(self, console: Any) -> None:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        self.progress = Progress(
            TextColumn("{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            console=console,
            transient=True,
        )
        self.overall: Any = None
        self.running: dict[str, Any] = {}
        self.failed = 0

    def __enter__(self) -> RichBatchProgress:
        self.progress.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.progress.stop()

    def begin(self, total: int, done: int) -> None:
        self.overall = self.progress.add_task("[bold]assets", total=total)

    def started(self, key: str) -> None:
        name = key if len(key) <= 40 else "…" + key[-39:]
        self.running[key] = self.progress.add_task(f"  {name}", total=None)

    def frame(self, key: str, frame: int, total: int) -> None:
        task = self.running.get(key)
        if task is not None:
            self.progress.update(task, completed=frame, total=total)

    def finished(self, key: str, entry: dict[str, Any]) -> None:
        task = self.running.pop(key, None)
        if task is not None:
            self.progress.remove_task(task)
        if entry["status"] == "failed":
            self.failed += 1
            self.progress.console.print(f"[red]failed[/red] {key}: {entry['error']}", markup=True, highlight=False)
        if self.overall is not None:
            self.progress.advance(self.overall)


def asset_line(key: str, entry: dict[str, Any]) -> str:
    """One line for a finished asset, unwrapped whatever its length (a CI log, grep):
    `ok props/box.obj: 24 frames in 1.20 s`, `failed a.obj: <error>`, `skipped b.obj: <reason>`."""
    status = entry["status"]
    if status == "ok":
        detail = f"{entry['frames']} frames in {entry['seconds'] or 0:.2f} s" if entry.get("frames") else "up to date"
    elif status == "failed":
        detail = entry.get("error") or "failed"
    else:
        detail = entry.get("reason") or status
    return f"{status} {key}: {' '.join(str(detail).split())}"


class LineBatchProgress:
    """Where no terminal shows bars (a CI log, a pipe): one line on stderr per asset as it finishes
    (`asset_line`), flushed at once; with `errors_only` (--quiet, --json) only the failed ones."""

    def __init__(self, errors_only: bool = False) -> None:
        self.errors_only = errors_only

    def __enter__(self) -> LineBatchProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def begin(self, total: int, done: int) -> None:
        return None

    def started(self, key: str) -> None:
        return None

    def frame(self, key: str, frame: int, total: int) -> None:
        return None

    def finished(self, key: str, entry: dict[str, Any]) -> None:
        if entry["status"] == "failed" or not self.errors_only:
            sys.stderr.write(asset_line(key, entry) + "\n")
            sys.stderr.flush()


def summary_json(result: Any) -> dict[str, Any]:
    """The one JSON object `--json` prints: counts, time, manifest path, failures."""
    return {
        **result.summary,
        "exit_code": result.exit_code,
        "executor": result.executor,
        "complete": result.manifest["complete"],
        "manifest": str(result.manifest_path),
        "log": str(result.log_path),
        "failed_assets": [
            {"input": e["input"], "error": e["error"]} for e in result.manifest["assets"] if e["status"] == "failed"
        ],
    }


def print_summary(console: Any, result: Any) -> None:
    """Counts, total time, the slowest assets and the failures, as Rich tables."""
    from rich.table import Table

    summary = result.summary
    counts = Table(title="batch", show_header=False, title_justify="left")
    counts.add_column("what")
    counts.add_column("value", justify="right")
    for status, style in (("ok", "green"), ("failed", "red"), ("skipped", "cyan"), ("pending", "yellow")):
        if status != "pending" or summary["pending"]:
            counts.add_row(f"[{style}]{status}[/{style}]", str(summary[status]))
    counts.add_row("total time", f"{summary['total_seconds']:.2f} s ({result.executor})")
    console.print(counts)
    entries = [e for e in result.manifest["assets"] if e.get("selected", True)]
    ran = sorted((e for e in entries if e["status"] in ("ok", "failed") and e["seconds"]), key=lambda e: -e["seconds"])[
        :SLOWEST
    ]
    if ran:
        slow = Table(title="slowest assets", title_justify="left")
        slow.add_column("asset")
        slow.add_column("status")
        slow.add_column("frames", justify="right")
        slow.add_column("seconds", justify="right")
        for e in ran:
            slow.add_row(e["input"], e["status"], str(e["frames"] or "-"), f"{e['seconds']:.2f}")
        console.print(slow)
    failed = [e for e in entries if e["status"] == "failed"]
    if failed:
        errors = Table(title="failed assets", title_justify="left")
        errors.add_column("asset")
        errors.add_column("error", overflow="fold")
        for e in failed:
            errors.add_row(e["input"], e["error"] or "")
        console.print(errors)
    console.print(f"manifest: {result.manifest_path}", highlight=False)


def register(app: typer.Typer) -> None:
    @app.command()
    def batch(
        assets: Path = typer.Argument(..., help="Folder searched recursively for .obj and .ply files."),
        recipe: Path = typer.Option(..., "--recipe", "-r", help="The recipe TOML applied to every asset."),
        out: Path = typer.Option(
            ...,
            "--out",
            "-o",
            help="Output folder: OUT/<asset path without suffix>/. Created, or a previous batch's; any other"
            " non-empty folder, a folder inside or containing ASSETS or the recipe's folder is refused (exit 2).",
        ),
        jobs: int | None = typer.Option(
            None, "--jobs", "-j", min=0, help="Worker processes (default: number of cores; 0: run in this process)."
        ),
        include: list[str] = typer.Option(
            [],
            "--include",
            help="Only assets matching this glob (repeatable; fnmatch on the relative path: 'props/*', '*.ply').",
        ),
        exclude: list[str] = typer.Option([], "--exclude", help="Leave out assets matching this glob (repeatable)."),
        dask: str | None = typer.Option(
            None, "--dask", help="Run on a Dask scheduler, e.g. tcp://host:8786 (shared file system needed)."
        ),
        force: bool = typer.Option(False, "--force", help="Redo assets whose outputs are up to date."),
        overwrite: bool = typer.Option(
            False,
            "--overwrite",
            help="Write into an OUT or asset folders holding files meshdeform did not write: new outputs replace"
            " a previous result's files of the same names, its files not written again are removed, all else is"
            " kept (without it such an asset folder fails that asset alone; a user's file with an output's name"
            " fails it with it).",
        ),
        quiet: bool = typer.Option(
            False, "--quiet", "-q", help="No progress display and no summary; failed assets still go to stderr."
        ),
        as_json: bool = typer.Option(False, "--json", help="Print only the summary, as one JSON object on stdout."),
    ) -> None:
        """Run a recipe on every OBJ/PLY under ASSETS; resumable, failures isolated, manifest in OUT."""
        from rich.console import Console

        from pipeline.batch import run_batch

        stdout = Console(highlight=False)
        stderr = Console(stderr=True, highlight=False)
        display: RichBatchProgress | LineBatchProgress
        if quiet or as_json:
            display = LineBatchProgress(errors_only=True)
        elif stderr.is_terminal:
            display = RichBatchProgress(stderr)
        else:  # a CI log: a line per finished asset, no bars
            display = LineBatchProgress()
        interrupted = f"finished assets are kept, rerun the same command to resume ({out})"
        try:
            with cli_errors(on_interrupt=interrupted), display:
                result = run_batch(
                    assets,
                    recipe,
                    out,
                    jobs=jobs,
                    include=include,
                    exclude=exclude,
                    dask=dask,
                    force=force,
                    overwrite=overwrite,
                    progress=display,
                )
        except OSError as exc:  # e.g. Dask scheduler unreachable
            raise fail(str(exc)) from None
        if as_json:
            typer.echo(json.dumps(summary_json(result), ensure_ascii=False))
        elif not quiet:
            print_summary(stdout, result)
        if result.exit_code:
            raise typer.Exit(EXIT_FAILED)
