"""Interruptions: SIGINT, SIGTERM and SIGHUP stop a run cleanly, in the CLI process and in pool workers.

In the CLI process (`handling_signals`, installed once by `pipeline.cli` around every command) the
first signal raises `Interrupted` in the main thread: the job's staging folder is removed on the
way out (`pipeline.output_folder.staged_directory` removes it on any BaseException), the batch stops its
workers and writes its manifest, and the CLI edge prints one line and exits with 128 + the signal
number (130 for Ctrl-C, 143 for `kill`). Further signals are ignored while that cleanup runs, so a
second Ctrl-C cannot leave it half done.

The renames that put a finished folder into place (`publishing`) are never cut in two: a signal
that arrives inside waits until the folder is in place (or the old one is back). Nor is Numba's
compiler: a signal that arrives while the main thread holds its compiler lock (loading a kernel
from the cache, compiling, saving) waits until the lock is released (`_CompilerWatch`). Raised
inside, the exception left llvmlite's half-built objects behind: the run then failed with
"no compiled object yet" instead of its one line, or crashed on the way out (SIGSEGV).

Pool workers (`watch_parent` in their initializer) die with the batch process: on Linux the kernel
sends them SIGTERM when it dies (PR_SET_PDEATHSIG, even after SIGKILL); everywhere a watchdog
thread notices the new parent pid. A worker whose parent is gone exits at once, and never starts
putting a folder into place (`publishing` refuses and removes the staging folder). SIGTERM and
SIGHUP kill a worker at once (the batch removes its staging folder), except inside `publishing`;
SIGINT (Ctrl-C reaches the whole process group) stops the running job, which removes its staging
folder, and then the worker.

Which output folder an error or interrupt kept from being written (the CLI's line names it) is noted
by the job's staging folder as it removes itself (`note_unwritten`), and by the job around all its
work (`unwritten_on_failure`: an interrupt while the mesh is read or kernels compile, before any
staging folder exists), in a registry keyed by the exception, and read at the CLI edge
(`unwritten_target`) inside the `noting_unwritten` block that `cli_errors` opens; nothing is set on
the exception itself. A signal that waited for the renames is delivered after them: the folder is
then noted as written (`note_written`), and the line says so.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import logging
import os
import shutil
import signal
import sys
import threading
import time
from collections.abc import Iterator
from contextvars import ContextVar
from pathlib import Path
from types import FrameType
from typing import Any

import numba.core.event

#: the signals that interrupt a run (SIGHUP: the terminal went away), where the platform has them
INTERRUPT_SIGNALS = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name)
)
#: seconds between two checks of the parent pid by a worker's watchdog thread
WATCHDOG_INTERVAL = 0.2
#: exit status of a worker that found its parent gone (as if killed by SIGTERM, 128 + 15)
EXIT_PARENT_GONE = 128 + signal.SIGTERM.value
#: the interrupting signals a pool worker leaves to their default action (death) outside `publishing`
_DEADLY = tuple(signum for signum in INTERRUPT_SIGNALS if signum != signal.SIGINT)
#: Linux prctl option: the signal sent to this process when its parent thread dies
_PR_SET_PDEATHSIG = 1


class Interrupted(KeyboardInterrupt):
    """A run was stopped by a signal. A KeyboardInterrupt, so every `except KeyboardInterrupt`
    cleanup (staging folders, the batch manifest, the worker pool) runs for `kill` as for Ctrl-C.
    """

    def __init__(self, signum: int) -> None:
        super().__init__(int(signum))  # the args pickle: the exception can travel between processes
        self.signum = int(signum)

    def __str__(self) -> str:
        return f"interrupted by {self.name}"

    @property
    def exit_code(self) -> int:
        """The conventional exit status: 128 + the signal number (130 SIGINT, 143 SIGTERM, 129 SIGHUP)."""
        return 128 + self.signum

    @property
    def name(self) -> str:
        return signal_name(self.signum)


def signal_name(signum: int) -> str:
    """`SIGTERM` for 15; `signal 42` for a number without a name."""
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


def exit_code_of(exc: BaseException) -> int:
    """The exit status for an interrupt: 128 + signal for `Interrupted`, 130 for a bare KeyboardInterrupt."""
    return exc.exit_code if isinstance(exc, Interrupted) else 128 + signal.SIGINT.value


# -- state shared by the handlers and `publishing` ---------------------------------------------


class _State:
    """What the handlers of this process know: set up by `handling_signals` or `watch_parent`."""

    def __init__(self) -> None:
        #: "raise" (CLI process: Interrupted in the main thread) or "worker" (a pool worker)
        self.mode: str | None = None
        #: depth of `publishing` blocks (signals arriving inside wait for the block's end)
        self.deferring = 0
        #: depth of the main thread's holds of Numba's compiler lock (signals wait for its release)
        self.compiling = 0
        #: a signal that arrived inside `publishing`, delivered at its end
        self.pending: int | None = None
        #: the signal of the Interrupted raised, if one was: further signals are ignored while the
        #: cleanup runs, and `raise_if_lost` raises it again
        self.raised: int | None = None
        #: in a pool worker: the pid of the batch process it serves
        self.parent: int | None = None
        #: in a pool worker: a job is running (SIGINT then stops the job, letting it clean up)
        self.job_running = False


_state = _State()


def _die(signum: int) -> None:
    """End this process now as `signum` would (its default action), from the main thread."""
    with contextlib.suppress(OSError, ValueError):
        signal.signal(signum, signal.SIG_DFL)
        os.kill(os.getpid(), signum)
    os._exit(128 + signum)  # the signal's default action did not end the process


def _deliver(signum: int) -> None:
    """Act on an interrupting signal outside any `publishing` block."""
    if _state.mode == "worker":
        if signum == signal.SIGINT and _state.job_running and _state.raised is None:
            _state.raised = signum
            raise Interrupted(signum)  # Ctrl-C to the process group: the job removes its staging folder
        _die(signum)  # SIGTERM from the pool or the kernel (parent gone), SIGINT while idle: quietly
    if _state.raised is not None:
        return  # the cleanup of the first interrupt is running: let it finish
    _state.raised = signum
    # The exception may land inside a library's half-built object (llvmlite while Numba compiles), whose
    # __del__ then fails when it is collected, up to interpreter exit: that report goes to the log.
    sys.unraisablehook = _log_unraisable
    raise Interrupted(signum)


def raise_if_lost() -> None:
    """Raise again an Interrupted that never reached the run: a signal handled while Python ran a
    finalizer (`__del__`, a weakref callback) raises there, and Python reports such an exception as
    unraisable and goes on, so the run would continue with further signals ignored. A run's loop
    calls this once a frame; the cleanup of an interrupt that did arrive never runs that loop."""
    if _state.raised is not None:
        raise Interrupted(_state.raised)


def _log_unraisable(unraisable: Any) -> None:
    """`sys.unraisablehook` after an interrupt: errors in finalizers are logged, not printed on stderr."""
    logging.getLogger("meshdeform.interrupts").debug(
        "ignored in %r: %r", unraisable.object, unraisable.exc_value, exc_info=unraisable.exc_value
    )


def _handler(signum: int, frame: FrameType | None) -> None:
    if _state.deferring or _state.compiling:
        if _state.pending is None:
            _state.pending = signum
        return
    _deliver(signum)


def _deliver_pending() -> None:
    """Act on the signal that waited for a `publishing` block or the compiler, once neither holds it."""
    if _state.deferring or _state.compiling:
        return
    pending, _state.pending = _state.pending, None
    if pending is not None:
        _deliver(pending)


class _CompilerWatch(numba.core.event.Listener):
    """Counts the main thread's holds of Numba's compiler lock ("numba:compiler_lock" events: the
    lock is taken after the start event and released before the end event, and nests), and
    delivers a signal that arrived meanwhile once the outermost hold is released."""

    def on_start(self, event: numba.core.event.Event) -> None:
        if threading.current_thread() is threading.main_thread():
            _state.compiling += 1

    def on_end(self, event: numba.core.event.Event) -> None:
        if threading.current_thread() is threading.main_thread():
            _state.compiling = max(0, _state.compiling - 1)
            _deliver_pending()


_compiler_watch = _CompilerWatch()
_COMPILER_LOCK_EVENT = "numba:compiler_lock"


@contextlib.contextmanager
def handling_signals() -> Iterator[None]:
    """Turn SIGINT / SIGTERM / SIGHUP into `Interrupted` in this (main) thread for the block, then
    restore the previous handlers. Outside the main thread (signals cannot be handled there) and
    when already active, it does nothing."""
    if threading.current_thread() is not threading.main_thread() or _state.mode is not None:
        yield
        return
    previous: dict[int, Any] = {}
    for signum in INTERRUPT_SIGNALS:
        with contextlib.suppress(OSError, ValueError):
            previous[signum] = signal.signal(signum, _handler)
    _state.mode, _state.pending, _state.raised, _state.compiling = "raise", None, None, 0
    numba.core.event.register(_COMPILER_LOCK_EVENT, _compiler_watch)
    try:
        yield
    finally:
        numba.core.event.unregister(_COMPILER_LOCK_EVENT, _compiler_watch)
        for signum, handler in previous.items():
            with contextlib.suppress(OSError, ValueError, TypeError):
                signal.signal(signum, handler if handler is not None else signal.SIG_DFL)
        _state.mode, _state.pending, _state.raised, _state.compiling = None, None, None, 0


# -- putting a folder into place -----------------------------------------------------------------


def parent_alive() -> bool:
    """False in a pool worker whose batch process is gone (then it must not write anything more);
    True everywhere else."""
    return _state.parent is None or os.getppid() == _state.parent


@contextlib.contextmanager
def publishing(stage: Path | None = None) -> Iterator[None]:
    """Run the renames that put a finished folder into place without being cut in two by a signal
    (it is handled when the block ends). In a pool worker whose batch process is gone, refuse:
    remove `stage` and exit, so nothing appears in the output after the batch died."""
    _state.deferring += 1  # before the parent check: the watchdog reads the pid, then this count
    caught = _catch_deadly_signals() if _state.mode == "worker" and _state.deferring == 1 else {}
    try:
        if not parent_alive():
            if stage is not None:
                shutil.rmtree(stage, ignore_errors=True)
            os._exit(EXIT_PARENT_GONE)
        yield
    finally:
        _state.deferring -= 1
        for signum, handler in caught.items():
            signal.signal(signum, handler)
    _deliver_pending()


def _catch_deadly_signals() -> dict[int, Any]:
    """In a worker, SIGTERM and SIGHUP kill at once (default action); inside `publishing` they are
    caught instead, to wait for its end. Returns the handlers to restore."""
    caught: dict[int, Any] = {}
    if threading.current_thread() is threading.main_thread():
        for signum in _DEADLY:
            with contextlib.suppress(OSError, ValueError):
                caught[signum] = signal.signal(signum, _handler)
    return caught


# -- what an error kept from being written --------------------------------------------------------

#: the output folders that errors and interrupts kept from being written (or that were written in
#: full before the exception: an interrupt delivered once the renames were done), while a
#: `noting_unwritten` block listens: id of the exception -> (the exception, the folder, written).
#: Holding the exception keeps its id its own. Per thread (a ContextVar): jobs in threads of a Dask
#: worker do not see each other's.
_unwritten: ContextVar[dict[int, tuple[BaseException, Path, bool]] | None] = ContextVar("unwritten", default=None)


@contextlib.contextmanager
def noting_unwritten() -> Iterator[None]:
    """For the block, remember which output folder each error or interrupt raised in it kept from
    being written (`note_unwritten`), for `unwritten_target`; forgotten when the block ends. An inner
    block keeps its own notes: the CLI's line (`pipeline.commands.errors.cli_errors`) does not see
    those of a job whose error ends in its batch outcome (`pipeline.executors.execute_task`)."""
    token = _unwritten.set({})
    try:
        yield
    finally:
        _unwritten.reset(token)


def _note(exc: BaseException, target: Path, written: bool) -> None:
    noted = _unwritten.get()
    if noted is not None:
        noted.setdefault(id(exc), (exc, Path(target), written))


def note_unwritten(exc: BaseException, target: Path) -> None:
    """Record that `exc` kept `target` from being written (the job's staging folder, removing itself,
    says so), when a `noting_unwritten` block listens. The first note for an exception stays."""
    _note(exc, target, written=False)


def note_written(exc: BaseException, target: Path) -> None:
    """Record that `target` was put into place in full before `exc` (a signal that waited for the
    renames is delivered after them), so that no outer `unwritten_on_failure` says otherwise."""
    _note(exc, target, written=True)


@contextlib.contextmanager
def unwritten_on_failure(target: Path) -> Iterator[None]:
    """Note `target` as not written for any error or interrupt leaving the block, also one raised
    before its staging folder exists (reading the mesh, building the model, compiling kernels)."""
    try:
        yield
    except BaseException as exc:
        note_unwritten(exc, target)
        raise


def _noted(exc: BaseException) -> tuple[BaseException, Path, bool] | None:
    noted = _unwritten.get()
    entry = noted.get(id(exc)) if noted is not None else None
    return entry if entry is not None and entry[0] is exc else None


def unwritten_target(exc: BaseException) -> Path | None:
    """The output folder `exc` kept from being written, as noted in the current `noting_unwritten`
    block; None if none was."""
    entry = _noted(exc)
    return entry[1] if entry is not None and not entry[2] else None


def written_target(exc: BaseException) -> Path | None:
    """The output folder put into place in full just before `exc`, as noted (`note_written`); None if none was."""
    entry = _noted(exc)
    return entry[1] if entry is not None and entry[2] else None


# -- pool workers ------------------------------------------------------------------------------------


def _set_parent_death_signal(signum: int) -> bool:
    """Linux: ask the kernel to send `signum` to this process when its parent dies; True if set."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        return libc.prctl(_PR_SET_PDEATHSIG, int(signum), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def _watchdog(parent: int) -> None:
    """Exit this worker as soon as its parent is gone (outside a `publishing` block, which checks
    for itself and delivers the pending signal when it ends)."""
    while True:
        time.sleep(WATCHDOG_INTERVAL)
        if os.getppid() != parent:
            if not _state.deferring:
                os._exit(EXIT_PARENT_GONE)
            _state.pending = _state.pending or signal.SIGTERM.value


def watch_parent(parent: int) -> None:
    """In a pool worker (its initializer): die with the batch process `parent`, handle SIGTERM,
    SIGINT and SIGHUP as described in the module doc. Exits at once if `parent` is already gone."""
    _state.mode, _state.parent = "worker", parent
    numba.core.event.register(_COMPILER_LOCK_EVENT, _compiler_watch)  # for the job's SIGINT
    with contextlib.suppress(OSError, ValueError):
        signal.signal(signal.SIGINT, _handler)
        for signum in _DEADLY:  # (a spawned process starts with these at their default already)
            signal.signal(signum, signal.SIG_DFL)
    _set_parent_death_signal(signal.SIGTERM)
    if os.getppid() != parent:  # it died before the kernel was told to warn us
        os._exit(EXIT_PARENT_GONE)
    threading.Thread(target=_watchdog, args=(parent,), name="meshdeform-parent-watchdog", daemon=True).start()


@contextlib.contextmanager
def worker_job() -> Iterator[None]:
    """Run a job in a pool worker: a SIGINT (Ctrl-C reaches the whole process group) interrupts the
    job, which removes its staging folder, then the worker ends as killed by SIGINT; nothing travels
    back to the batch process, which handles its own SIGINT."""
    _state.job_running = True
    try:
        yield
    except Interrupted as exc:
        _die(exc.signum)
    finally:
        _state.job_running = False
