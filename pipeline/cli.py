"""The `meshdeform` command line: a thin Typer layer over the engine and the pipeline.

Each command lives in its own module under `pipeline/commands/` and registers itself here.
Library errors are turned into one line on stderr and an exit code at this edge.
"""

from __future__ import annotations

import importlib
import os

import typer

from pipeline import __version__
from pipeline.memory import tune_malloc

#: command modules, each exposing `register(app)`
COMMANDS = ("inspect", "simulate", "check", "preview", "batch")

app = typer.Typer(
    name="meshdeform",
    help="Bake mass-spring cloth and soft-body deformation of OBJ/PLY meshes without a DCC tool.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"meshdeform {__version__}")
        raise typer.Exit()


@app.callback()
def main(
    version: bool = typer.Option(
        False, "--version", callback=_version, is_eager=True, help="Print the version and exit."
    ),
) -> None:
    """Bake mass-spring cloth and soft-body deformation of OBJ/PLY meshes without a DCC tool."""
    # Keep Numba's compiled-kernel cache beside the package unless the user chose a place.
    os.environ.setdefault("NUMBA_CACHE_DIR", os.path.join(os.path.expanduser("~"), ".cache", "meshdeform", "numba"))
    tune_malloc()  # freed large arrays go back to the OS (lower peak memory), see pipeline.memory


for _name in COMMANDS:
    try:
        _module = importlib.import_module(f"pipeline.commands.{_name}")
    except ModuleNotFoundError as exc:  # a command module not present in this build
        if exc.name != f"pipeline.commands.{_name}":
            raise
        continue
    _module.register(app)
