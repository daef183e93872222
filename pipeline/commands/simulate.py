"""`meshdeform simulate MESH --out DIR`: run one mesh through a recipe, with CLI overrides."""

from __future__ import annotations

import json
from pathlib import Path

import typer
from typer._click import Context, HelpFormatter  # Typer's own Click
from typer.core import TyperCommand

from pipeline.commands.errors import cli_errors, fail


def parse_vector(text: str, option: str) -> tuple[float, float, float]:
    """`X,Y,Z` -> a 3-tuple of floats, or a usage error naming the option."""
    parts = [p for p in text.replace(" ", "").split(",") if p]
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        raise fail(f"{option}: expected three numbers X,Y,Z, got {text!r}") from None
    if len(values) != 3:
        raise fail(f"{option}: expected three numbers X,Y,Z, got {text!r}")
    return values  # type: ignore[return-value]


def split_commas(values: list[str]) -> list[str]:
    """The values of a repeatable option, each of which may itself be a comma-separated list:
    `--format obj,usd --format ply` -> ['obj', 'usd', 'ply'] (empty items dropped)."""
    return [item.strip() for value in values for item in value.split(",") if item.strip()]


def registry_help() -> dict[str, str]:
    """The help of the options that list a registry, by parameter name: the solvers
    (`meshdeform.solvers.SOLVERS`) and the output formats, each with their one-line summaries
    (`meshdeform.export.EXPORTERS`)."""
    from meshdeform.export import EXPORTERS
    from meshdeform.solvers import SOLVERS

    formats = "; ".join(f"{name}: {cls.summary}" for name, cls in EXPORTERS.items())
    fixed = ", ".join(name for name, cls in EXPORTERS.items() if not cls.supports_topology_change)
    solvers = "; ".join(f"{name}: {cls.summary}" for name, cls in SOLVERS.items())
    return {
        "solver": f"Solver, replaces the recipe's simulation.solver: {solvers}.",
        "output_format": "Output formats, comma-separated or repeated (--format obj,usd); replaces the recipe's"
        f" output.formats: {formats}."
        f" A recipe that tears or cuts cannot write {fixed} (they need a fixed vertex count).",
    }


class SimulateCommand(TyperCommand):
    """`simulate`, whose registry-listing option help (`registry_help`) is filled in when the help is
    shown: listing the solvers imports them (about a second), which other commands need not pay."""

    def format_help(self, ctx: Context, formatter: HelpFormatter) -> None:
        texts = registry_help()
        for param in self.params:
            if param.name in texts:
                param.help = texts[param.name]
        super().format_help(ctx, formatter)


def register(app: typer.Typer) -> None:
    @app.command(cls=SimulateCommand)
    def simulate(
        mesh: Path = typer.Argument(..., help="An OBJ or PLY file."),
        out: Path = typer.Option(
            ...,
            "--out",
            "-o",
            help="Output folder, created. An existing one is replaced when the run succeeds only if it holds a"
            " previous meshdeform result and nothing else; any other non-empty folder, the current folder, the"
            " folder of the mesh or the recipe (or one containing it) and an existing file are refused (exit 2).",
        ),
        recipe: Path | None = typer.Option(None, "--recipe", "-r", help="A recipe TOML; options below override it."),
        solver: str | None = typer.Option(None, help="Solver (listed by registry_help)."),
        frames: int | None = typer.Option(None, help="Number of frames to bake."),
        fps: float | None = typer.Option(None, help="Frames per second."),
        substeps: int | None = typer.Option(None, help="Solver steps per frame."),
        iterations: int | None = typer.Option(None, help="Constraint iterations per step."),
        damping: float | None = typer.Option(None, help="Velocity damping (see docs/recipes.md)."),
        gravity: str | None = typer.Option(None, help="Gravity X,Y,Z in m/s^2 (default 0,-9.81,0: Y up)."),
        pin: list[str] = typer.Option(
            [], "--pin", help="Hard pin: 'indices:0,5,9' or 'box:x0,y0,z0,x1,y1,z1' (box relative 0..1 to bounds)."
        ),
        output_format: list[str] = typer.Option(
            [], "--format", "-f", help="Output formats, comma-separated or repeated (listed by registry_help)."
        ),
        quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar, no summary."),
        as_json: bool = typer.Option(
            False, "--json", help="Print only the run's report (report.json), as one JSON object on stdout."
        ),
        overwrite: bool = typer.Option(
            False,
            "--overwrite",
            help="Write into an existing folder that holds files meshdeform did not write: the new outputs are"
            " moved in file by file, replacing a previous result's files of the same names; files of a previous"
            " result that are not written again are removed; every other file is kept (a user's file with an"
            " output's name refuses the run).",
        ),
    ) -> None:
        """Simulate MESH with a recipe and write frames/frame_0001.obj ... and report.json into --out."""
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

        from pipeline.job import run_job
        from pipeline.output_folder import check_output_folder, output_lock
        from pipeline.recipe import apply_overrides, load_recipe

        with cli_errors():
            # before anything is read or created (run_job checks again once the lock is held)
            check_output_folder(out, overwrite=overwrite, protect={"input": mesh, "recipe": recipe}, refuse_cwd=True)
            base = load_recipe(recipe)
            if base.deprecation is not None:
                typer.echo(f"warning: {base.deprecation}", err=True)
            loaded = base.for_asset(mesh.name)  # [[assets]] rules match the file name
            loaded = apply_overrides(
                loaded,
                solver=solver,
                frames=frames,
                fps=fps,
                substeps=substeps,
                iterations=iterations,
                damping=damping,
                gravity=parse_vector(gravity, "--gravity") if gravity else None,
                pins=pin,
                formats=split_commas(output_format),  # validated against EXPORTERS by the recipe
            )
            stderr = Console(stderr=True)  # the bar never on stdout (which carries the summary or the JSON)
            progress = Progress(
                TextColumn("[bold]{task.description}"),
                BarColumn(),
                MofNCompleteColumn(),
                TimeRemainingColumn(),
                transient=True,
                console=stderr,
                disable=quiet or as_json or not stderr.is_terminal,  # no bar (nor its blank line) in a CI log
            )
            with output_lock(out), progress:  # a second run on the same --out is refused at once
                task = progress.add_task(mesh.name, total=loaded.simulation.frames)
                result = run_job(
                    mesh, loaded, out, overwrite=overwrite, on_frame=lambda i, n: progress.update(task, completed=i)
                )
        if as_json:
            typer.echo(json.dumps(result.report, ensure_ascii=False))
        elif not quiet:
            report = result.report
            typer.echo(
                f"{mesh.name}: {report['frames']} frames with {report['solver']} in {report['seconds']:.2f} s "
                f"({report['frames_per_second'] or 0:.1f} frames/s), max stretch {max(report['max_stretch']):.3f}"
                f" -> {out}"
            )
            for warning in report["warnings"]:  # what was repaired or ignored in the input, and the like
                if not warning.startswith("not converged"):
                    typer.echo(f"warning: {mesh}: {warning}", err=True)
            if report["converged"] is False:  # the report's warning, on the summary's stream
                typer.echo(f"  {next(w for w in report['warnings'] if w.startswith('not converged'))}")
