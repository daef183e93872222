"""`meshdeform check RECIPE [--mesh MESH]`: validate a recipe, optionally resolve it on a mesh."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from pipeline.commands.errors import EXIT_USAGE, cli_errors

if TYPE_CHECKING:
    from pipeline.estimate import RunEstimate
    from pipeline.recipe import Recipe


def estimate_json(estimate: RunEstimate) -> dict[str, Any]:
    """The run's cost as `--json` prints it: the estimate's fields and its derived totals (None
    where they need a mesh)."""
    return {
        **asdict(estimate),
        "sweeps": estimate.sweeps,
        "spring_projections": estimate.spring_projections,
        "total_bytes": estimate.total_bytes,
    }


def _summary(recipe: Recipe) -> str:
    sim = recipe.simulation
    parts = [
        f"solver {sim.solver}",
        f"{sim.frames} frames at {sim.fps:g} fps ({sim.duration:.2f} s)",
    ]
    counted = [
        (len(recipe.pins), "pin"),
        (len(recipe.impacts), "impact"),
        (len(recipe.colliders), "collider"),
        (len(recipe.tears), "tear"),
        (len(recipe.assets), "asset rule"),
    ]
    parts += [f"{n} {word}{'s' if n != 1 else ''}" for n, word in counted if n]
    if recipe.wind is not None:
        parts.append("wind")
    contact = recipe.self_collision
    if contact is not None and contact.enabled:
        thickness = contact.thickness if contact.thickness is not None else recipe.material.thickness
        parts.append(f"self-collision (thickness {thickness * 1000:g} mm)")
    parts.append("outputs " + ", ".join(recipe.output.formats))
    return "; ".join(parts)


def register(app: typer.Typer) -> None:
    @app.command()
    def check(
        recipe: Path = typer.Argument(..., help="The recipe TOML to validate."),
        mesh: Path | None = typer.Option(
            None, "--mesh", "-m", help="Also resolve the recipe on this OBJ/PLY: print what each selection selects."
        ),
        as_json: bool = typer.Option(
            False,
            "--json",
            help="Print only the result as one JSON object on stdout: ok, errors, warnings, estimate and with"
            " --mesh the counts and selections (an invalid recipe: ok false, exit code 2, its line on stderr too).",
        ),
    ) -> None:
        """Validate RECIPE: unknown keys, wrong types, out-of-range values are errors (exit code 2).

        With --mesh, also build the simulation on MESH and print how many vertices each selection
        selects (a selection that selects nothing is an error). Nothing is written. The second line
        estimates the run's cost: substeps x iterations x frames, and with --mesh the spring
        projections and the bytes of every output.
        """
        result: dict[str, Any] = {"ok": False, "recipe": str(recipe), "errors": [], "warnings": []}
        try:
            with cli_errors():
                lines = _check(recipe, mesh, result, warn_on_stderr=not as_json)
        except typer.Exit as exc:
            if as_json and exc.exit_code == EXIT_USAGE and result["errors"]:
                typer.echo(json.dumps(result, ensure_ascii=False))
            raise
        result["ok"] = True
        if as_json:
            typer.echo(json.dumps(result, ensure_ascii=False))
        else:
            typer.echo("\n".join(lines))


def _check(recipe_path: Path, mesh: Path | None, result: dict[str, Any], *, warn_on_stderr: bool) -> list[str]:
    """Validate the recipe (and resolve it on `mesh`), filling `result` (the --json object) and
    returning the text lines. A recipe or mesh error is noted in result["errors"] and raised on; a
    deprecated spelling's warning goes to stderr at once if `warn_on_stderr` (text mode)."""
    from meshdeform.errors import MeshdeformError
    from pipeline.build import build_simulation
    from pipeline.estimate import estimate_run
    from pipeline.recipe import load_recipe

    try:
        loaded = load_recipe(recipe_path)
        if loaded.deprecation is not None:
            result["warnings"].append(loaded.deprecation)
            if warn_on_stderr:
                typer.echo(f"warning: {loaded.deprecation}", err=True)
        lines = [f"OK {recipe_path}: {_summary(loaded)}"]
        if mesh is None:
            estimate = estimate_run(loaded)
            lines.append(estimate.summary())
            result["estimate"] = estimate_json(estimate)
            return lines
        from meshdeform.io import load

        # [[assets]] rules apply as in a batch whose folder holds the mesh
        for_mesh = loaded.for_asset(mesh.name)
        mesh_data = load(mesh)
        built = build_simulation(for_mesh, mesh_data)
    except (MeshdeformError, OSError) as exc:  # (cli_errors words an OSError as its line)
        result["errors"].append(
            str(exc) if isinstance(exc, MeshdeformError) else f"{exc.filename or ''}: {exc.strerror or exc}"
        )
        raise
    model = built.model
    estimate = estimate_run(for_mesh, mesh_data, model, built.settings)
    lines.append(estimate.summary())
    lines.append(
        f"{mesh}: {model.vertex_count} simulated vertices, {model.spring_count} springs, "
        f"{int(model.pinned.sum())} hard-pinned, {built.settings.substeps} substeps"
    )
    width = max((len(k) for k in built.selections), default=0)
    lines += [
        f"  {label:<{width}}  {count} {'vertex' if count == 1 else 'vertices'}"
        for label, count in built.selections.items()
    ]
    lines += [f"warning: {w}" for w in built.warnings]
    result["warnings"] += list(built.warnings)
    result["estimate"] = estimate_json(estimate)
    result["mesh"] = {
        "path": str(mesh),
        "vertices": model.vertex_count,
        "springs": model.spring_count,
        "hard_pinned": int(model.pinned.sum()),
        "substeps": built.settings.substeps,
        "selections": dict(built.selections),
    }
    return lines
