"""The exporter registry: format name -> exporter class, and the streaming session over several.

`EXPORTERS` is the one list of output formats: the recipe's `output.formats` accepts its names,
`meshdeform simulate --help` lists them with each class's one-line `summary`, a recipe that tears or
cuts is refused the formats whose class has `supports_topology_change = False`, `meshdeform check`
adds up their `estimated_bytes`, and previews search a result folder for the formats whose
`reading()` says how to read them back. Adding a format is one exporter module (a `BaseExporter`
subclass declaring those) plus its class in the tuple below (docs/ARCHITECTURE.md, "Adding a format").
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from meshdeform.errors import ExportError
from meshdeform.export.base import BaseExporter, ExportContext, FrameData
from meshdeform.export.gltf import GltfExporter
from meshdeform.export.mdd import MddExporter
from meshdeform.export.npz import NpzExporter
from meshdeform.export.obj import ObjExporter
from meshdeform.export.pc2 import Pc2Exporter
from meshdeform.export.ply import PlyExporter
from meshdeform.export.usd import UsdExporter
from meshdeform.export.vat import VatExporter
from meshdeform.export.vtk import VtkExporter
from meshdeform.export.xdmf import XdmfExporter

EXPORTERS: dict[str, type[BaseExporter]] = {
    cls.name: cls
    for cls in (
        ObjExporter,
        PlyExporter,
        Pc2Exporter,
        MddExporter,
        UsdExporter,
        VtkExporter,
        XdmfExporter,
        NpzExporter,
        GltfExporter,
        VatExporter,
    )
}


def topology_following() -> str:
    """The formats that follow a topology change (`supports_topology_change`), as a sentence lists them:
    "obj, ply, usd or vtk"."""
    names = [name for name, cls in EXPORTERS.items() if cls.supports_topology_change]
    return " or ".join([", ".join(names[:-1]), names[-1]] if len(names) > 1 else names)


def make_exporter(name: str, **options: Any) -> BaseExporter:
    """A new exporter for a format name (case-insensitive); `options` go to its constructor.

    Options: usd `ascii` (write .usda layers), `normals`, `layers` ("single" or "split") and `uv_set`;
    vtk `compress`. Unknown names or
    options raise ExportError listing what is known.
    """
    cls = EXPORTERS.get(str(name).strip().lower())
    if cls is None:
        raise ExportError(f"unknown export format {name!r}; known formats: {', '.join(EXPORTERS)}")
    try:
        return cls(**options)
    except TypeError as exc:
        raise ExportError(f"{cls.name}: {exc}") from exc


class ExportSession:
    """Several exporters driven together: opened at once, fed each frame, closed or aborted as one.

    Used as a context manager, an exception inside the block aborts every exporter, so an
    interrupted run leaves no finished-looking file behind:

        with ExportSession(["obj", "pc2"], ctx) as session:
            for frame in frames:
                session.write(frame)
        session.outputs   # {"obj": [...], "pc2": [...]}

    The context may instead be given to `open` (`with session.open(ctx):`), so the exporters are
    made, and unknown formats or options refused, before the output folder exists (a staging
    folder made later). Closing inside the block is allowed (to time it, or to use the files
    before the block ends); an exception later in the block still removes what was finished.
    """

    def __init__(
        self,
        formats: Iterable[str],
        ctx: ExportContext | None = None,
        options: Mapping[str, Mapping[str, Any]] | None = None,
    ) -> None:
        names = list(dict.fromkeys(str(f).strip().lower() for f in formats))
        options = options or {}
        self.ctx = ctx
        self.exporters: dict[str, BaseExporter] = {n: make_exporter(n, **dict(options.get(n, {}))) for n in names}
        self.outputs: dict[str, list[Path]] = {}
        self._open = False

    def check_topology_change(self) -> list[str]:
        """Names of the chosen formats that refuse a changed topology (to warn before a tearing run)."""
        return [n for n, e in self.exporters.items() if not e.supports_topology_change]

    def open(self, ctx: ExportContext | None = None) -> ExportSession:
        """Open every exporter on `ctx` (default: the context given to the constructor); if one fails,
        those already opened are aborted."""
        if ctx is not None:
            self.ctx = ctx
        if self.ctx is None:
            raise ExportError("export session: no export context to open on")
        opened: list[BaseExporter] = []
        try:
            for exporter in self.exporters.values():
                exporter.open(self.ctx)
                opened.append(exporter)
        except BaseException:
            for exporter in opened:
                with contextlib.suppress(Exception):
                    exporter.abort()
            raise
        self._open = True
        return self

    def write(self, frame: FrameData) -> None:
        for exporter in self.exporters.values():
            exporter.write(frame)

    def close(self) -> dict[str, list[Path]]:
        try:
            for name, exporter in self.exporters.items():
                self.outputs[name] = exporter.close()
        except BaseException:
            self.abort()
            raise
        self._open = False
        return self.outputs

    @property
    def files(self) -> list[Path]:
        """Every file the closed session finished, format after format."""
        return [path for paths in self.outputs.values() for path in paths]

    def abort(self) -> None:
        """Abort every exporter (each one even when another fails) and delete what the session has
        finished so far."""
        for exporter in self.exporters.values():
            with contextlib.suppress(Exception):
                exporter.abort()
        for paths in self.outputs.values():
            for path in paths:
                with contextlib.suppress(OSError):
                    path.unlink()
        self.outputs = {}
        self._open = False

    def __enter__(self) -> ExportSession:
        return self if self._open else self.open()

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        if exc_type is None:
            if self._open:
                self.close()
        else:
            self.abort()
