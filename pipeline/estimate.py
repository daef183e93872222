"""What a run will cost before it starts: solver work and output bytes, and a disk-space check.

`estimate_run(recipe, mesh, model)` counts the spring projections (springs x substeps x iterations
x frames) and the bytes each output format will write; without a mesh only the frames and the
solver sweeps per frame are known. `meshdeform check` prints it; `require_disk_space` refuses a
run whose outputs would not fit on the disk before anything is simulated or written.

The bytes of each format are its exporter's own estimate (`BaseExporter.estimated_bytes` in
`meshdeform.export`): exact for the point caches (a header plus 12 bytes per vertex per frame) and
approximate, on the high side, for the text and container formats. A run that tears
adds vertices as it goes; its estimate counts the input's vertices. A run whose previews keep more
frames than fit in their memory budget (a video of a big mesh) also needs room for their scratch file
while it runs ("preview scratch").
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from meshdeform.errors import ExportError, MeshdeformError
from meshdeform.export import EXPORTERS

if TYPE_CHECKING:
    from meshdeform.mesh import Mesh
    from meshdeform.model import SpringModel
    from meshdeform.simulate import Settings
    from pipeline.recipe import Recipe

__all__ = ["InsufficientDiskSpace", "RunEstimate", "estimate_run", "human_bytes", "output_bytes", "require_disk_space"]

#: bytes per pixel of a rendered preview PNG (measured 0.02 on a white background: a mesh and flat colour)
PNG_BYTES_PER_PIXEL = 0.1
#: bytes per pixel per frame of a preview video by kind (measured: mp4 0.0006, the encoder keeps only changes)
VIDEO_BYTES_PER_PIXEL = {"mp4": 0.01, "gif": 0.1}


class InsufficientDiskSpace(MeshdeformError):
    """The outputs of a run would not fit in the free space of the disk they go to."""


@dataclass(frozen=True)
class RunEstimate:
    """The cost of one run.

    substeps / iterations: per frame and per substep in force (the solver's defaults when the
    recipe gives none; iterations 1 for solvers without sweeps).
    springs / vertices: of the built model / the input mesh (None without a mesh).
    output_bytes: estimated bytes per output format, plus "preview" and "preview scratch" (the previews'
        scratch file while the run lasts, when there is one) (None without a mesh).
    """

    frames: int
    substeps: int
    iterations: int
    springs: int | None = None
    vertices: int | None = None
    output_bytes: dict[str, int] | None = field(default=None)

    @property
    def sweeps(self) -> int:
        """Solver sweeps over the springs for the whole run (substeps x iterations x frames)."""
        return self.substeps * self.iterations * self.frames

    @property
    def spring_projections(self) -> int | None:
        """springs x substeps x iterations x frames: the work of the solver's inner loop."""
        if self.springs is None:
            return None
        return self.springs * self.sweeps

    @property
    def total_bytes(self) -> int | None:
        """All outputs together (None without a mesh)."""
        return None if self.output_bytes is None else int(sum(self.output_bytes.values()))

    def summary(self) -> str:
        """One line for `meshdeform check`."""
        work = f"{self.substeps} substeps x {self.iterations} iterations x {self.frames} frames"
        if self.spring_projections is None or self.output_bytes is None:
            return f"estimate: {work} = {_count(self.sweeps)} sweeps; springs and output size need --mesh"
        parts = ", ".join(f"{name} {human_bytes(n)}" for name, n in self.output_bytes.items())
        return (
            f"estimate: {_count(self.springs or 0)} springs x {work} = {_count(self.spring_projections)} spring "
            f"projections; outputs about {human_bytes(self.total_bytes or 0)} ({parts})"
        )


def _count(n: int) -> str:
    """12_345_678 -> '12.3 million' (exact below ten thousand)."""
    for size, word in ((10**12, "trillion"), (10**9, "billion"), (10**6, "million")):
        if n >= size:
            return f"{n / size:.3g} {word}"
    return f"{n:,}"


def human_bytes(n: float) -> str:
    """Bytes in decimal units: 12_300_000_000 -> '12.3 GB'."""
    for size, unit in ((1e12, "TB"), (1e9, "GB"), (1e6, "MB"), (1e3, "KB")):
        if n >= size:
            return f"{n / size:.1f} {unit}"
    return f"{int(n)} bytes"


def output_bytes(recipe: Recipe, mesh: Mesh) -> dict[str, int]:
    """Estimated bytes each of the recipe's output formats writes for `mesh`, plus "preview" (and "preview
    scratch" when the previews' frames overflow their memory budget)."""
    written = scene_frames_written(recipe)  # the rest pose, then every simulated frame
    frames = len(written)
    sizes: dict[str, int] = {}
    for name in dict.fromkeys(recipe.output.formats):
        exporter = EXPORTERS.get(name)
        # point caches also hold copies of the rest pose for scene frames 0 .. start_frame - 1
        if exporter is None:
            continue
        lead = written.start if exporter.pads_to_scene_frame_zero else 0  # copies for scene frames 0 ..
        # motion blur: every frame after the first written one also holds the states between it and the one before
        between = (frames - 1) * (recipe.output.subframes - 1) if exporter.writes_subframes else 0
        size = exporter.estimated_bytes(mesh, frames + lead + between, **recipe.output.exporter_options.get(name, {}))
        if size is not None:
            sizes[name] = int(size)
    preview = _preview_bytes(recipe)
    if preview:
        sizes["preview"] = preview
    scratch = _preview_scratch_bytes(recipe, mesh)
    if scratch:
        sizes["preview scratch"] = scratch
    return sizes


def _preview_scratch_bytes(recipe: Recipe, mesh: Mesh) -> int:
    """Bytes a run's previews keep past their memory budget in a scratch file in the staging folder until
    they are rendered (`meshdeform.preview.spool`, deleted then): the frames to render (every frame with a
    video) at 8 bytes a coordinate (OBJ's precision, the most any format keeps) and 4 of strain a vertex."""
    table = recipe.output.preview_options
    if table is None:
        return 0
    from meshdeform.preview import PreviewOptions
    from meshdeform.preview.spool import MEMORY_BUDGET

    options = PreviewOptions.from_mapping(table)  # checked by _preview_bytes
    written = scene_frames_written(recipe)
    kept = len(written) if options.video is not None else len(options.png_frames(written))
    return max(0, kept * mesh.vertex_count * (3 * 8 + 4) - MEMORY_BUDGET)


def _preview_bytes(recipe: Recipe) -> int:
    """PNGs, video and contact sheet of `[output] preview` (0 without a preview)."""
    table = recipe.output.preview_options
    if table is None:
        return 0
    from meshdeform.preview import PreviewOptions

    try:
        options = PreviewOptions.from_mapping(table)
    except ExportError as exc:
        raise recipe.error(("output", "preview"), str(exc).removeprefix("preview: ")) from None
    written = scene_frames_written(recipe)
    frames = len(written)
    pixels = options.size[0] * options.size[1]
    pngs = len(options.png_frames(written)) if options.pngs else 0
    size = int(pngs * pixels * PNG_BYTES_PER_PIXEL)
    if options.video is not None:
        size += int(frames * pixels * VIDEO_BYTES_PER_PIXEL.get(options.video, max(VIDEO_BYTES_PER_PIXEL.values())))
    if options.contact_sheet:
        tile = options.sheet_tile_width
        size += int(len(options.png_frames(written)) * tile * tile * PNG_BYTES_PER_PIXEL)
    return size


def scene_frames_written(recipe: Recipe) -> range:
    """The scene frames a run writes: `[output] frames`, else the rest pose at the start frame and
    every simulated frame after it."""
    sim = recipe.simulation
    if recipe.output.frames is not None:
        return range(recipe.output.frames[0], recipe.output.frames[1] + 1)
    return range(sim.start_frame, sim.start_frame + sim.frames + 1)


def estimate_run(
    recipe: Recipe, mesh: Mesh | None = None, model: SpringModel | None = None, settings: Settings | None = None
) -> RunEstimate:
    """The run's cost: sweeps per frame from the recipe (and the solver's defaults), or from the
    settings a built simulation runs with (`BuiltSimulation.settings`: a calm scene's steps,
    `meshdeform.simulate.steps_for`, which the recipe alone cannot tell); springs and output bytes
    when the mesh and its built model are given."""
    substeps, iterations = recipe.simulation.sweeps_per_frame(settings)
    return RunEstimate(
        frames=recipe.simulation.frames,
        substeps=substeps,
        iterations=iterations,
        springs=None if model is None else int(model.spring_count),
        vertices=None if mesh is None else int(mesh.vertex_count),
        output_bytes=None if mesh is None else output_bytes(recipe, mesh),
    )


def _existing_ancestor(folder: Path) -> Path:
    """`folder` or its nearest ancestor that exists (the disk the outputs will go to)."""
    path = Path(os.path.abspath(folder))
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def _mount_point(path: Path) -> Path:
    while not os.path.ismount(path) and path != path.parent:
        path = path.parent
    return path


def require_disk_space(estimated_bytes: int | None, folder: Path) -> None:
    """Refuse a run whose outputs (about `estimated_bytes`) would not fit in the free space of the
    disk `folder` is on (its nearest existing ancestor): InsufficientDiskSpace with one line.
    Refuses only when the estimate exceeds the free space (estimates are on the high side)."""
    if estimated_bytes is None or estimated_bytes <= 0:
        return
    where = _existing_ancestor(Path(folder))
    free = shutil.disk_usage(where).free
    if estimated_bytes > free:
        raise InsufficientDiskSpace(
            f"{folder}: the outputs need about {human_bytes(estimated_bytes)} but only {human_bytes(free)} "
            f"is free on {_mount_point(where)}"
        )
