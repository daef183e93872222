"""The `meshdeform` command line: a thin Typer layer over the engine and the pipeline.

Each command lives in its own module under `pipeline/commands/` and registers itself here.
Library errors are turned into one line on stderr and an exit code at this edge. Every command
runs with SIGINT / SIGTERM / SIGHUP turned into `pipeline.interrupts.Interrupted` (one line, exit
128 + the signal number, nothing half-written left) and with library warnings and logs kept off
stderr (`pipeline.diagnostics`; `--verbose` shows them).
"""

from __future__ import annotations

import importlib
import os
import sys
import tempfile
import traceback
from typing import Any

import typer
from typer._click import exceptions as click_errors  # Typer's own Click: its usage errors
from typer.core import TyperArgument, TyperGroup, TyperOption

from pipeline import __version__
from pipeline.diagnostics import quiet_libraries
from pipeline.interrupts import handling_signals
from pipeline.memory import tune_malloc

#: command modules, each exposing `register(app)`
COMMANDS = ("inspect", "simulate", "check", "preview", "batch")
#: exit code when Click aborts before a command runs (Ctrl-C at a prompt: 128 + SIGINT)
EXIT_ABORTED = 130


class PlainArgument(TyperArgument):
    """An argument shown as its metavar alone (`MESH`), without Typer's `<path>` type and braces."""

    def display_type_rich(self, ctx: Any) -> str | None:
        return None

    def _usage_display_name(self) -> str:
        name = self.display_name_raw
        return name if self.required else f"[{name}]"


class PlainOption(TyperOption):
    """An option shown with a plain metavar (`--jobs N`), not Typer's type names (`<int range>`)."""


def _plain_metavar(param: TyperOption) -> str:
    """The metavar an option without one is shown with: N for a whole number, NUMBER for a real one,
    PATH for a path, else the option's long name in capitals (`--pin PIN`, `--format FORMAT`)."""
    annotation = param.type_descriptor.annotation
    if annotation is int:
        return "N"
    if annotation is float:
        return "NUMBER"
    if param.type_descriptor.is_path:
        return "PATH"
    longest = max(param.opts, key=len).lstrip("-")
    return longest.upper().replace("-", "_")


def plain_help(command: Any) -> None:
    """Give `command`'s arguments and valued options plain metavars (scripts and CI logs read help
    without Typer's `<int range>` / `<list[str]>` type names); a metavar set by the command is kept."""
    for param in command.params:
        if type(param) is TyperArgument:
            if param.metavar is None:
                param.metavar = param.name.upper()
            param.__class__ = PlainArgument
        elif type(param) is TyperOption and not param.is_flag:
            if param.metavar is None:
                param.metavar = _plain_metavar(param)
            param.__class__ = PlainOption


class MeshdeformGroup(TyperGroup):
    """The app's command group: each command runs inside the signal handlers and the quiet logging.

    An interrupt that arrives outside a command's own `cli_errors` block (while it parses or
    imports) still ends with one line and 128 + the signal number, not Click's "Aborted!"; an
    unexpected error (a bug) ends with one line and exit 1, its traceback shown with --verbose.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        plain_help(self)
        for command in self.commands.values():
            plain_help(command)

    def main(self, *args: Any, standalone_mode: bool = True, **kwargs: Any) -> Any:
        """Click's entry point, with its usage errors (a bad option value, an unknown option, a missing
        argument) as one line `error: ...` and exit code 2 instead of Click's usage block."""
        kwargs.setdefault("prog_name", "meshdeform")  # (also when run as `python -c` or `python -m`)
        if not standalone_mode:
            return super().main(*args, standalone_mode=False, **kwargs)
        try:
            code = super().main(*args, standalone_mode=False, **kwargs)
        except click_errors.NoArgsIsHelpError as exc:  # plain `meshdeform`: the help, as before
            exc.show()
            sys.exit(exc.exit_code)
        except click_errors.UsageError as exc:
            command = exc.ctx.command_path + ": " if exc.ctx is not None else ""
            hint = f" (see {exc.ctx.command_path} --help)" if exc.ctx is not None else ""
            message = " ".join(exc.format_message().split())
            typer.echo(f"error: {command}{message}{hint}", err=True)
            sys.exit(exc.exit_code)
        except click_errors.ClickException as exc:
            typer.echo(f"error: {' '.join(exc.format_message().split())}", err=True)
            sys.exit(exc.exit_code)
        except typer.Abort:  # Ctrl-C / end of input before a command ran
            typer.echo("error: aborted", err=True)
            sys.exit(EXIT_ABORTED)
        sys.exit(code if isinstance(code, int) else 0)

    def invoke(self, ctx: typer.Context) -> Any:
        from pipeline.commands.errors import EXIT_FAILED, fail, interrupted_message, unexpected_message
        from pipeline.interrupts import exit_code_of

        verbose = bool(ctx.params.get("verbose"))
        with handling_signals(), quiet_libraries(verbose=verbose):
            try:
                return super().invoke(ctx)
            except KeyboardInterrupt as exc:
                raise fail(interrupted_message(exc), exit_code_of(exc)) from None
            except (typer.Exit, typer.Abort, typer.TyperException):
                raise
            except Exception as exc:
                if verbose:
                    traceback.print_exc()
                raise fail(unexpected_message(exc), EXIT_FAILED) from None


app = typer.Typer(
    name="meshdeform",
    cls=MeshdeformGroup,
    help="Bake mass-spring cloth and soft-body deformation of OBJ/PLY meshes without a DCC tool.",
    no_args_is_help=True,
    context_settings={"help_option_names": ["-h", "--help"]},  # (inherited by every command's context)
    add_completion=True,  # --install-completion / --show-completion (Typer's, for bash, zsh, fish, PowerShell)
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)


def kernel_cache_dir() -> str | None:
    """The folder for Numba's compiled kernels: NUMBA_CACHE_DIR when set (the user's choice, as it
    is), else ~/.cache/meshdeform/numba, else (a home that cannot be written, as in a read-only
    container) meshdeform-numba-<uid> in the temporary folder; None when neither can be written
    (Numba then tries the package's __pycache__ and its own user folder).

    One folder for every command, so a kernel compiled by one run is loaded by the next and by the
    batch's worker processes (they inherit the variable). Without a writable place Numba refuses
    to import a kernel that asks to be cached.
    """
    chosen = os.environ.get("NUMBA_CACHE_DIR")
    if chosen:
        return chosen
    candidates = (
        os.path.join(os.path.expanduser("~"), ".cache", "meshdeform", "numba"),
        os.path.join(tempfile.gettempdir(), f"meshdeform-numba-{os.getuid() if hasattr(os, 'getuid') else 0}"),
    )
    for folder in candidates:
        try:
            os.makedirs(folder, exist_ok=True)
        except OSError:
            continue
        if os.access(folder, os.W_OK | os.X_OK):
            return folder
    return None


def _version(value: bool) -> None:
    if value:
        typer.echo(f"meshdeform {__version__}")
        raise typer.Exit()


@app.callback()
def main(
    version: bool = typer.Option(
        False, "--version", callback=_version, is_eager=True, help="Print the version and exit."
    ),
    verbose: bool = typer.Option(
        False, "--verbose", help="Show library warnings (NumPy, Numba, ...) on stderr; by default they are hidden."
    ),
) -> None:
    """Bake mass-spring cloth and soft-body deformation of OBJ/PLY meshes without a DCC tool."""
    # (`verbose` is read by MeshdeformGroup.invoke, which sets up logging around the command.)
    # Before the engine (and Numba) is imported: where compiled kernels are kept, for this process and its workers.
    cache = kernel_cache_dir()
    if cache is not None:
        os.environ["NUMBA_CACHE_DIR"] = cache
    tune_malloc()  # freed large arrays go back to the OS (lower peak memory), see pipeline.memory


for _name in COMMANDS:
    try:
        _module = importlib.import_module(f"pipeline.commands.{_name}")
    except ModuleNotFoundError as exc:  # a command module not present in this build
        if exc.name != f"pipeline.commands.{_name}":
            raise
        continue
    _module.register(app)
