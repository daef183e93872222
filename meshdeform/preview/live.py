"""A run's previews rendered from its frames as they are simulated, instead of read back from its files.

`RunPreview` is fed the `FrameData` the run hands its exporters (the rest pose first, frame index 0).
It renders the same files `render_result(out_dir, options, mesh=input, model=model)` renders from the
folder the run writes, read with the frame range of its report.json (`start_frame`, `output_frames`):
the frames as the reader `open_result` would pick reads them back from the run's first frame on
(`meshdeform.export.results.ReadBack`: scene frame numbers, the positions at the precision the files
hold them, the base mesh, fps, pinned flags, strain and the reading errors; a point cache's copies
before the first frame are not shown), and the run's model for the pinned vertices and the strain when
the base has the input's vertex count. The run's colliders are drawn at each frame's time since the
rest pose by the run's fps (`ctx.fps`), as `render_result` given them draws them by the report's.

The video runs at the run's fps (`ctx.fps`, which its report.json records and `render_result` reads).

Memory: each frame is measured (bounds, colour range) as it comes; only the frames to render are
kept (every frame with a video), at the files' precision (float32 for all but OBJ), in memory up to
`memory_budget` bytes and past it in a scratch file in `ctx.out_dir` (`spool.ArraySpool`), deleted
once they are rendered. Errors are kept until `render`, as they came when the previews were rendered
after the run.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from meshdeform.export.base import ExportContext, FrameData
from meshdeform.mesh import Mesh
from meshdeform.preview.options import PreviewOptions, PreviewResult
from meshdeform.preview.results import frame_pinned, no_frames_found, read_back_for, welded_strain
from meshdeform.preview.sequence import SequencePreview
from meshdeform.preview.spool import MEMORY_BUDGET, ArraySpool
from meshdeform.scene.colliders import Collider


class _KeptStrain(Mapping[int, np.ndarray]):
    """The files' strain of the frames measured, by position k: the frame being measured, then the kept ones."""

    def __init__(self, spool: ArraySpool) -> None:
        self.spool = spool
        self.current: dict[int, np.ndarray] = {}

    def __getitem__(self, k: int) -> np.ndarray:
        if k in self.current:
            return self.current[k]
        return self.spool[(k, "strain")]

    def __iter__(self) -> Iterator[int]:
        yield from self.current
        yield from (key[0] for key in self.spool if key[1] == "strain")

    def __len__(self) -> int:
        return sum(1 for _ in self)


class RunPreview:
    """Previews of a run written into `ctx.out_dir` in `formats`, from its frames (`add` each, then `render`).

    options: as `render_previews` takes them (a recipe's `[output] preview` table). model: the run's
    SpringModel (its `vertex_map`, `pinned` and springs for the strain). colliders: the run's scene's
    colliders, drawn at each frame's time ((scene frame - `ctx.start_frame`) / `ctx.fps`).
    memory_budget: bytes of kept frames held in memory (module docstring). exporter_options: the run's
    `[output.<format>]` options (`OutputSpec.exporter_options`), for the file names the frames are
    read back as (usd's `ascii`: scene.usda).
    """

    def __init__(
        self,
        options: PreviewOptions | Mapping[str, Any] | Any,
        ctx: ExportContext,
        formats: Sequence[str],
        model: Any,
        colliders: Sequence[Collider] = (),
        memory_budget: int = MEMORY_BUDGET,
        exporter_options: Mapping[str, Mapping[str, Any]] | None = None,
    ) -> None:
        self.ctx = ctx
        self.colliders = list(colliders)
        self.formats = list(formats)
        self.model = model
        self._options = options
        self._read_back = read_back_for(self.formats, ctx, exporter_options)
        self._mesh: Mesh = ctx.mesh  # the mesh in force
        self._base: Mesh | None = None
        self._preview: SequencePreview | None = None
        self._spool = ArraySpool(ctx.out_dir, memory_budget)
        self._kept: dict[int, Mesh] = {}  # the mesh of each kept frame; its positions: spool (k, "positions")
        self._strain = _KeptStrain(self._spool)
        self._read_error: Exception | None = None  # reading the files back would fail
        self._error: Exception | None = None  # rendering what was read would fail

    def add(self, frame: FrameData) -> None:
        """Measure one frame (in order, from the first) and keep it if it is rendered."""
        read_back = self._read_back
        if read_back is None or self._read_error is not None:
            return
        if frame.mesh is not None:
            self._mesh = frame.mesh
        mesh = self._mesh
        try:  # errors wait for `render`, where rendering after the run raised them
            kept = read_back.keep(frame.positions)
            if self._base is None:
                self._base = read_back.start(frame, mesh, kept)
            read_back.add(frame, mesh)
            read_back.check()  # the files could not be read back: nothing is rendered
        except Exception as exc:
            self._read_error = exc
            self._drop()
            return
        if self._error is not None:
            return
        try:
            number = read_back.number(frame)
            if self._preview is None:
                self._preview = self._start(frame, self._base, number)
            strain = read_back.strain(frame)
            k = len(self._preview.numbers)
            if strain is not None:
                self._strain.current = {k: strain}
            self._preview.measure(number, read_back.item(mesh, kept))
            self._strain.current = {}
            if self._preview.wants(number):
                self._kept[k] = mesh
                self._spool.put((k, "positions"), kept)
                if strain is not None:
                    self._spool.put((k, "strain"), strain)
        except Exception as exc:
            self._error = exc
            self._drop()

    def _drop(self) -> None:
        self._kept.clear()
        self._strain.current = {}
        self._spool.close()

    @property
    def spool(self) -> ArraySpool:
        """Where the kept frames are (memory and scratch-file bytes)."""
        return self._spool

    def _start(self, first: FrameData, base: Mesh, number: int) -> SequencePreview:
        """The sequence preview on the base mesh the reader found, with what `render_result` adds
        (`number`: the first frame's)."""
        read_back = self._read_back
        assert read_back is not None
        pinned = read_back.pinned
        if pinned is None:  # as `open_result` looks in the other files (the first .vtp frame)
            pinned = frame_pinned(self.formats, first, base.vertex_count)
        strain: Any = self._strain if read_back.strain(first) is not None else None
        vertex_map = np.asarray(self.model.vertex_map)
        if vertex_map.shape == (base.vertex_count,):
            with contextlib.suppress(AttributeError):
                pinned = np.asarray(self.model.pinned)[vertex_map]
            if strain is None:
                strain = welded_strain(self.model, vertex_map)
        return SequencePreview(
            base,
            PreviewOptions.from_mapping(self._options),
            rest_positions=np.asarray(base.positions, dtype=np.float64),
            pinned=pinned,
            strain=strain,
            colliders=self.colliders,
            scene_fps=self.ctx.fps,
            first_frame=number,
            start_frame=self.ctx.start_frame,
        )

    def render(self, out_dir: str | Path | None = None) -> PreviewResult:
        """Render the kept frames into `out_dir` (default: `ctx.out_dir`), once; raises what rendering the
        written result would have raised. The kept frames and the scratch file are gone afterwards."""
        try:
            if self._read_back is None:
                raise no_frames_found(self.ctx.out_dir)
            if self._read_error is not None:
                raise self._read_error
            if self._base is None:  # no frame: nothing written to read back
                raise no_frames_found(self.ctx.out_dir)
            if self._error is not None:
                raise self._error
            assert self._preview is not None
            read_back = self._read_back
            self._preview.fps = self.ctx.fps  # the run's, as its report.json says it to `render_result`
            spool = self._spool
            frames = ((k, read_back.item(mesh, spool[(k, "positions")])) for k, mesh in sorted(self._kept.items()))
            return self._preview.render(self.ctx.out_dir if out_dir is None else out_dir, frames)
        finally:
            self._drop()
