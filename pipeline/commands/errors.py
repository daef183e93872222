"""Turning library errors into one stderr line and an exit code, at the CLI edge."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import typer

from meshdeform.errors import MeshdeformError, SimulationDiverged

#: exit codes: 0 ok, 1 a run failed (simulation diverged, some assets failed), 2 bad input or usage
EXIT_FAILED = 1
EXIT_USAGE = 2


def fail(message: str, code: int = EXIT_USAGE) -> typer.Exit:
    """Print `error: message` on stderr and return the Exit to raise."""
    typer.echo(f"error: {message}", err=True)
    return typer.Exit(code)


@contextlib.contextmanager
def cli_errors() -> Iterator[None]:
    """Translate engine errors raised inside the block to one line and an exit code."""
    try:
        yield
    except SimulationDiverged as exc:
        raise fail(str(exc), EXIT_FAILED) from None
    except MeshdeformError as exc:
        raise fail(str(exc), EXIT_USAGE) from None
    except OSError as exc:
        raise fail(f"{exc.filename or ''}: {exc.strerror or exc}", EXIT_USAGE) from None
