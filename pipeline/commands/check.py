"""`meshdeform check RECIPE [--mesh MESH]`: validate a recipe, optionally resolve it on a mesh."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import typer

from pipeline.commands.errors import cli_errors

if TYPE_CHECKING:
    from pipeline.recipe import Recipe


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
    ) -> None:
        """Validate RECIPE: unknown keys, wrong types, out-of-range values are errors (exit code 2).

        With --mesh, also build the simulation on MESH and print how many vertices each selection
        selects (a selection that selects nothing is an error). Nothing is written. The second line
        estimates the run's cost: substeps x iterations x frames, and with --mesh the spring
        projections and the bytes of every output.
        """
        from pipeline.build import build_simulation
        from pipeline.estimate import estimate_run
        from pipeline.recipe import load_recipe

        with cli_errors():
            loaded = load_recipe(recipe)
            if loaded.deprecation is not None:
                typer.echo(f"warning: {loaded.deprecation}", err=True)
            lines = [f"OK {recipe}: {_summary(loaded)}"]
            if mesh is None:
                lines.append(estimate_run(loaded).summary())
            else:
                from meshdeform.io import load

                # [[assets]] rules apply as in a batch whose folder holds the mesh
                for_mesh = loaded.for_asset(mesh.name)
                mesh_data = load(mesh)
                built = build_simulation(for_mesh, mesh_data)
                model = built.model
                lines.append(estimate_run(for_mesh, mesh_data, model).summary())
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
        typer.echo("\n".join(lines))
