"""Library chatter stays off stderr: the CLI's stderr carries its own lines only.

NumPy's RuntimeWarnings (a diverging run), Numba's and other libraries' warnings, messages of the
`logging` module nobody configured (Python prints those of level WARNING and above on stderr) and
VTK's error and warning log (a writer failing on a full disk prints a dozen lines) would each
break the rule "one line on stderr". So, in the CLI process (`quiet_libraries`) and in every pool
worker (`quiet_worker`):

- Python warnings go to the `logging` module (`logging.captureWarnings`), and logging has a
  do-nothing root handler, so nothing reaches stderr by default; `--verbose` adds a stderr
  handler for them (each Python warning as one line, `warning: Category: message (file:line)`)
  and shows every distinct warning once, DeprecationWarnings of the libraries included.
- VTK's global warning display and its stderr log are turned off when VTK is first imported
  (`_SilenceVtkOnImport`, a `sys.meta_path` finder; removed when the block ends).

Why an import hook, not a call where VTK is used: the tool reaches VTK only through the engine,
which imports it lazily in several places (the vtk exporter, the preview renderer and its result
readers, pyvista) and must neither import `pipeline` nor know whether `--verbose` asked for VTK's
log. Silencing VTK here by importing it costs 0.3-0.4 s on every command and in every pool worker,
most of which never touch VTK; and VTK (9.3 and later) reads no environment variable for its
warning display or its stderr log. The finder is the one place that sees VTK arrive, whoever
imports it. (Without it, a VTK writer failing on a full disk prints a dozen lines of its log.)

A job's warnings are not lost: `collecting_warnings` gathers them (each distinct one once) so
that the batch can write them into its log.
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.abc
import importlib.machinery
import logging
import sys
import warnings
from collections.abc import Iterator
from types import ModuleType
from typing import Any

#: VTK's package, whose import the hook watches, and its core module, which holds the switches
VTK_CORE = "vtkmodules.vtkCommonCore"
VTK_PACKAGE = "vtkmodules"
#: at most this many distinct warnings are kept for one job
MAX_JOB_WARNINGS = 20


def silence_vtk(core: Any) -> None:
    """Turn off VTK's error/warning display and its stderr log (`core`: vtkmodules.vtkCommonCore)."""
    with contextlib.suppress(Exception):
        core.vtkObject.GlobalWarningDisplayOff()
    with contextlib.suppress(Exception):
        core.vtkLogger.SetStderrVerbosity(core.vtkLogger.VERBOSITY_OFF)


class _SilenceVtkOnImport(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """A meta-path finder that lets the `vtkmodules` package load as its own finder says, then loads
    its core module (every VTK module needs it) and silences it, and leaves `sys.meta_path`."""

    def __init__(self) -> None:
        self._loader: Any = None

    def find_spec(self, name: str, path: Any = None, target: Any = None) -> importlib.machinery.ModuleSpec | None:
        if name != VTK_PACKAGE:
            return None
        for finder in sys.meta_path:
            if finder is self or not hasattr(finder, "find_spec"):
                continue
            spec = finder.find_spec(name, path, target)
            if spec is not None and spec.loader is not None:
                self._loader, spec.loader = spec.loader, self
                return spec
        return None

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType | None:
        return self._loader.create_module(spec)

    def exec_module(self, module: ModuleType) -> None:
        self._loader.exec_module(module)
        if self in sys.meta_path:
            sys.meta_path.remove(self)
        with contextlib.suppress(Exception):  # (a VTK that cannot load fails where it is used, as before)
            silence_vtk(importlib.import_module(VTK_CORE))


def _silence_vtk_when_imported() -> Any:
    """Silence VTK now if it is loaded, else when it is; returns what to remove from sys.meta_path."""
    if VTK_PACKAGE in sys.modules:  # (its core module is, too, but for a bare `import vtkmodules`)
        with contextlib.suppress(Exception):
            silence_vtk(importlib.import_module(VTK_CORE))
        return None
    hook = _SilenceVtkOnImport()
    sys.meta_path.insert(0, hook)
    return hook


class _OneLineFormatter(logging.Formatter):
    """`name: message` for library log records; a captured Python warning (whose text
    `warnings.formatwarning` spreads over lines: location, then the source line) as
    `warning: Category: message (file:line)`, one line in a CI log."""

    def format(self, record: logging.LogRecord) -> str:
        if record.name != "py.warnings":
            return f"{record.name}: {' '.join(record.getMessage().split())}"
        first = record.getMessage().splitlines()[0] if record.getMessage() else ""
        location, _, rest = first.partition(": ")  # "/path/x.py:12: UserWarning: text"
        return f"warning: {rest} ({location})" if rest else f"warning: {first}"


def _quiet_logging(verbose: bool) -> list[tuple[logging.Logger, logging.Handler]]:
    """Warnings into logging, a null root handler, a stderr handler for warnings if `verbose`."""
    logging.captureWarnings(True)
    added: list[tuple[logging.Logger, logging.Handler]] = [(logging.getLogger(), logging.NullHandler())]
    if verbose:
        loud = logging.StreamHandler(sys.stderr)
        loud.setFormatter(_OneLineFormatter())
        added.append((logging.getLogger(), loud))
    for logger, handler in added:
        logger.addHandler(handler)
    return added


@contextlib.contextmanager
def quiet_libraries(verbose: bool = False) -> Iterator[None]:
    """For the block (a CLI command): library warnings and logs off stderr (on it with `verbose`),
    VTK silenced; everything restored afterwards (the CLI also runs inside test processes)."""
    was_capturing = bool(getattr(logging, "_warnings_showwarning", None))
    added = _quiet_logging(verbose)
    hook = None if verbose else _silence_vtk_when_imported()
    shown = warnings.catch_warnings() if verbose else contextlib.nullcontext()
    try:
        with shown:
            if verbose:
                warnings.simplefilter("default")  # each distinct warning once, deprecations too
            yield
    finally:
        for logger, handler in added:
            logger.removeHandler(handler)
        if not was_capturing:
            logging.captureWarnings(False)
        if hook is not None and hook in sys.meta_path:
            sys.meta_path.remove(hook)


def quiet_worker() -> None:
    """In a pool worker, for its whole life: library warnings and logs off stderr, VTK silenced."""
    _quiet_logging(verbose=False)
    _silence_vtk_when_imported()


class _Collector(logging.Handler):
    """Keeps the distinct messages of the warnings logged while a job runs, in order."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        with contextlib.suppress(Exception):
            line = " ".join(record.getMessage().split())
            if line not in self.lines and len(self.lines) < MAX_JOB_WARNINGS:
                self.lines.append(line)


@contextlib.contextmanager
def collecting_warnings() -> Iterator[list[str]]:
    """Gather the Python warnings and library log warnings emitted during the block (each distinct
    one once, at most MAX_JOB_WARNINGS) into the yielded list, for the batch log. Only warnings
    routed to logging are seen (`quiet_libraries` / `quiet_worker` route them)."""
    collector = _Collector()
    root = logging.getLogger()
    root.addHandler(collector)
    try:
        yield collector.lines
    finally:
        root.removeHandler(collector)
