"""Turning library errors and interrupts into one stderr line and an exit code, at the CLI edge."""

from __future__ import annotations

import contextlib
import errno
import os
from collections.abc import Iterator

import typer

from meshdeform.errors import MeshdeformError, SimulationDiverged
from pipeline.interrupts import Interrupted, exit_code_of, noting_unwritten, unwritten_target, written_target

#: exit codes: 0 ok, 1 a run failed (simulation diverged, some assets failed), 2 bad input or usage,
#: or the output cannot be written (no space left, quota, file too large); 128 + N stopped by signal N
#: (130 Ctrl-C, 143 SIGTERM, 129 SIGHUP)
EXIT_FAILED = 1
EXIT_USAGE = 2
#: errno values meaning "the output does not fit": reported as such, naming the output
NO_ROOM = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


def fail(message: str, code: int = EXIT_USAGE) -> typer.Exit:
    """Print `error: message` on stderr and return the Exit to raise."""
    typer.echo(f"error: {message}", err=True)
    return typer.Exit(code)


def interrupted_message(exc: BaseException, consequence: str | None = None) -> str:
    """`interrupted by SIGTERM; <consequence>`; by default the consequence is that nothing was
    written to the command's output folder (its staging folder is removed on the way out)."""
    name = exc.name if isinstance(exc, Interrupted) else "SIGINT"
    if consequence is None:
        target, written = unwritten_target(exc), written_target(exc)
        if target is not None:
            consequence = f"nothing was written to {target}"
        elif written is not None:
            consequence = f"{written} had been written in full"
    return f"interrupted by {name}" + (f"; {consequence}" if consequence else "")


def no_room(exc: BaseException) -> int | None:
    """The errno if `exc` or an error it came from says the output does not fit (disk full): an
    OSError with that errno, or a library error (USD's Tf.ErrorException) quoting its text."""
    seen: set[int] = set()
    current: BaseException | None = exc
    while current is not None and id(current) not in seen:
        seen.add(id(current))
        if isinstance(current, OSError) and current.errno in NO_ROOM:
            return current.errno
        text = str(current)
        for code in NO_ROOM:
            if os.strerror(code) in text:
                return code
        current = current.__cause__ or current.__context__
    return None


def no_room_message(exc: BaseException, code: int) -> str:
    """`out/x: no space left on device`: the output folder named (else the file, if known), the
    reason in plain words."""
    reason = os.strerror(code)
    reason = reason[:1].lower() + reason[1:]
    target = unwritten_target(exc) or (exc.filename if isinstance(exc, OSError) else None)
    return f"{target}: {reason}" if target else reason


def unexpected_message(exc: BaseException) -> str:
    """The one line for an error nobody expected (a bug, or a library failing in a new way)."""
    text = " ".join(str(exc).split()) or "(no message)"
    return f"unexpected {type(exc).__name__}: {text} (a bug: please report it; --verbose shows the traceback)"


@contextlib.contextmanager
def cli_errors(on_interrupt: str | None = None) -> Iterator[None]:
    """Translate engine errors and interrupts raised inside the block to one line and an exit code.

    `on_interrupt`: what an interrupt leaves behind, for its line (default: nothing written to --out).
    """
    with noting_unwritten():  # the output folder an error kept from being written, for its line
        try:
            yield
        except KeyboardInterrupt as exc:  # Interrupted (SIGINT, SIGTERM, SIGHUP) or a bare Ctrl-C
            raise fail(interrupted_message(exc, on_interrupt), exit_code_of(exc)) from None
        except SimulationDiverged as exc:
            raise fail(str(exc), EXIT_FAILED) from None
        except (MeshdeformError, OSError) as exc:
            code = no_room(exc)
            if code is not None:
                raise fail(no_room_message(exc, code), EXIT_USAGE) from None
            if isinstance(exc, MeshdeformError):
                raise fail(str(exc), EXIT_USAGE) from None
            raise fail(f"{exc.filename or ''}: {exc.strerror or exc}", EXIT_USAGE) from None
        except (typer.Exit, typer.Abort, typer.TyperException):
            raise
        except Exception as exc:  # a library error that is not ours; a full disk is still the user's to fix
            code = no_room(exc)
            if code is None:
                raise
            raise fail(no_room_message(exc, code), EXIT_USAGE) from None
