"""Previews of a result folder: which format's reader to use for it, and rendering what it read.

The readers sit beside their writers in `meshdeform.export`, and each exporter class declares how its
format is read back (`BaseExporter.reading`: a `meshdeform.export.results.ResultReading`); this module
searches the registry's readings in priority order (`search_order`), picks the first that finds frames
and adds what `report.json` knows.
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from meshdeform.errors import MeshLoadError
from meshdeform.export.base import ExportContext, FrameData
from meshdeform.export.registry import EXPORTERS
from meshdeform.export.results import FrameItem, ReadBack, ResultReading, turns_for
from meshdeform.mesh import Mesh
from meshdeform.preview.options import PreviewOptions, PreviewResult
from meshdeform.preview.render import as_pinned_mask
from meshdeform.preview.sequence import render_previews
from meshdeform.scene.colliders import Collider


def readings(
    formats: Iterable[str], exporter_options: Mapping[str, Mapping[str, Any]] | None = None
) -> list[ResultReading]:
    """The readings of the registered `formats` previews can read back, in priority order (names the
    registry does not know are skipped); `exporter_options`: a run's `[output.<format>]` options."""
    options = exporter_options or {}
    found = (EXPORTERS[name].reading(**options.get(name, {})) for name in dict.fromkeys(formats) if name in EXPORTERS)
    return sorted((r for r in found if r is not None), key=lambda r: r.priority)


def search_order() -> list[ResultReading]:
    """What a result folder is searched for, in order: one reading per kind of files (formats writing the
    same files share a reader), the first whose files are there wins."""
    first: dict[str, ResultReading] = {}
    for reading in readings(EXPORTERS):
        first.setdefault(reading.looks_for, reading)
    return list(first.values())


def read_back_for(
    formats: Sequence[str], ctx: ExportContext, exporter_options: Mapping[str, Mapping[str, Any]] | None = None
) -> ReadBack | None:
    """The `ReadBack` of what `open_result` reads from a folder a run writes in `formats` (on `ctx`, with
    the run's `[output.<format>]` `exporter_options`), or None when it reads none of them (xdmf alone)."""
    chosen = readings(formats, exporter_options)
    return chosen[0].read_back(ctx) if chosen else None


def folder_pinned(root: Path, n: int) -> np.ndarray | None:
    """The pinned mask (n,) the files of a result folder carry apart from those the frames were read from
    (the first `.vtp` frame's `pinned` array), or None."""
    for reading in readings(EXPORTERS):
        if reading.folder_pinned is not None and (mask := reading.folder_pinned(root, n)) is not None:
            return mask
    return None


def frame_pinned(formats: Sequence[str], frame: FrameData, n: int) -> np.ndarray | None:
    """`folder_pinned` for a run in `formats` from its first frame in memory."""
    for reading in readings(formats):
        if reading.frame_pinned is not None and (mask := reading.frame_pinned(frame, n)) is not None:
            return mask
    return None


@dataclass
class ResultSequence:
    """A result folder's frames, ready for `render_previews`.

    frame_numbers: the frames' scene frame numbers. start_frame: the scene frame of the run's rest
    pose (simulation time 0): the report's `start_frame`, else the first frame's number.
    """

    mesh: Mesh
    frames: Sequence[FrameItem]
    frame_numbers: list[int]
    start_frame: int
    fps: float
    rest_positions: np.ndarray
    pinned: np.ndarray | None
    strain: Sequence[np.ndarray] | None
    source: str
    report: dict[str, Any]


def read_report(result_dir: Path) -> dict[str, Any]:
    path = result_dir / "report.json"
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise MeshLoadError(f"{path}: cannot read the report: {exc}") from exc
    return data if isinstance(data, dict) else {}


def _report_fps(report: Mapping[str, Any]) -> float | None:
    for value in (report.get("fps"), (report.get("settings") or {}).get("fps")):
        if isinstance(value, int | float) and value > 0:
            return float(value)
    return None


def _report_int(value: Any) -> int | None:
    return value if isinstance(value, int) and not isinstance(value, bool) else None


def report_frames(report: Mapping[str, Any]) -> tuple[int | None, int | None]:
    """(the scene frame of the rest pose, the first scene frame written) a run's report says (keys
    `start_frame` and `output_frames` = [first, last]), None for what it does not say; the first frame
    written is the start frame unless `output_frames` says otherwise."""
    start = _report_int(report.get("start_frame"))
    written = report.get("output_frames")
    first = _report_int(written[0]) if isinstance(written, list) and len(written) == 2 else None
    return start, first if first is not None else start


def _report_pinned(report: Mapping[str, Any], n: int) -> np.ndarray | None:
    for key in ("pinned", "pinned_indices"):
        value = report.get(key)
        if isinstance(value, list):
            return as_pinned_mask(np.asarray(value, dtype=np.int64), n)
    return None


def no_frames_found(root: Path) -> MeshLoadError:
    """The error for a folder none of the readers finds frames in."""
    looked_for = ", ".join(reading.looks_for for reading in search_order())
    return MeshLoadError(f"{root}: no frames found (looked for {looked_for})")


def report_input(root: Path, report: Mapping[str, Any]) -> Path | None:
    """The input mesh `report.json` names (key `input`) if it is still a file: as written (relative to
    the current folder), else relative to the result folder; None otherwise."""
    if not isinstance(report.get("input"), str):
        return None
    candidate = Path(report["input"])
    if not candidate.is_absolute() and not candidate.exists():
        candidate = root / candidate
    return candidate if candidate.is_file() else None


def open_result(result_dir: str | Path, mesh: Mesh | None = None, up_axis: str | None = None) -> ResultSequence:
    """Find a result folder's frames with the first reader of `search_order` that finds its files (the
    exporters' `ResultReading.priority`: per-frame files first, point caches last).

    The rest pose is `mesh` if given, else the input mesh named by `report.json` (key `input`)
    when it still exists, else the first frame. Point caches need that mesh for the topology;
    their axis convention is `up_axis` (the world they were written in from a Y-up input), or
    whichever turn makes the first frame closest to the rest pose (`detect_turns`). Pinned vertices
    come from the files read (`ResultFrames.pinned`),
    else the report (`pinned`: vertex indices), else another format's files in the folder
    (`folder_pinned`); fps from the report, else the files read. Frame numbers are scene frames; the
    frames before the first one the run wrote (the report's `output_frames`, else `start_frame`: a point
    cache's copies of its first frame for the scene frames before it) are dropped, so that a folder's
    previews show the same frames whatever format it holds; without a report every frame read is kept.
    Raises MeshLoadError when nothing is found.
    """
    from meshdeform.io import load

    root = Path(result_dir)
    if not root.is_dir():
        raise MeshLoadError(f"{root}: no such result folder")
    report = read_report(root)
    input_mesh = mesh
    if input_mesh is None and (candidate := report_input(root, report)) is not None:
        with contextlib.suppress(MeshLoadError):
            input_mesh = load(candidate)
    turns = turns_for(up_axis)
    # the first reader that finds its files wins
    found = next((f for f in (r.read(root, input_mesh, turns) for r in search_order()) if f is not None), None)
    if found is None:
        raise no_frames_found(root)
    start_frame, first_written = report_frames(report)
    if first_written is not None:
        found = found.from_frame(first_written)
        if not found.numbers:
            raise MeshLoadError(f"{root}: no frames from frame {first_written} on, the first the report names")
    base = found.base
    pinned = found.pinned
    if pinned is None:
        pinned = _report_pinned(report, base.vertex_count)
    if pinned is None:
        pinned = folder_pinned(root, base.vertex_count)
    return ResultSequence(
        mesh=base,
        frames=found.frames,
        frame_numbers=found.numbers,
        start_frame=start_frame if start_frame is not None else (found.numbers or [0])[0],
        fps=_report_fps(report) or found.fps or 24.0,
        rest_positions=np.asarray(base.positions, dtype=np.float64),
        pinned=pinned,
        strain=found.strain,
        source=found.source,
        report=report,
    )


def render_result(
    result_dir: str | Path,
    options: PreviewOptions | Mapping[str, Any] | None = None,
    *,
    mesh: Mesh | None = None,
    model: Any = None,
    out_dir: str | Path | None = None,
    up_axis: str | None = None,
    colliders: Sequence[Collider] = (),
) -> tuple[ResultSequence, PreviewResult]:
    """Render previews of a result folder's frames (see `open_result`) into it (or `out_dir`).

    With the SpringModel of the run (`model`), pinned vertices and strain come from it exactly
    (strain: the largest stretch of each vertex's structural springs, as in the VTK output).
    `up_axis` is the convention point caches were written in (default: detected). `colliders`: the
    run's scene's colliders, drawn at each frame's time ((frame number - `start_frame`) / the result's
    fps: `ResultSequence.start_frame`).
    Returns the sequence read and what was rendered.
    """
    seq = open_result(result_dir, mesh=mesh, up_axis=up_axis)
    pinned = seq.pinned
    strain: Any = seq.strain
    if model is not None:
        vertex_map = np.asarray(model.vertex_map)
        if vertex_map.shape == (seq.mesh.vertex_count,):
            with contextlib.suppress(AttributeError):
                pinned = np.asarray(model.pinned)[vertex_map]
            if strain is None:
                strain = welded_strain(model, vertex_map)
    result = render_previews(
        seq.mesh,
        seq.frames,
        out_dir if out_dir is not None else result_dir,
        options,
        frame_numbers=seq.frame_numbers,
        fps=seq.fps,
        rest_positions=seq.rest_positions,
        pinned=pinned,
        strain=strain,
        colliders=colliders,
        start_frame=seq.start_frame,
    )
    return seq, result


def render_result_previews(
    result_dir: str | Path,
    options: PreviewOptions | Mapping[str, Any] | None = None,
    *,
    mesh: Mesh | None = None,
    model: Any = None,
    out_dir: str | Path | None = None,
    up_axis: str | None = None,
    colliders: Sequence[Collider] = (),
) -> list[Path]:
    """`render_result`, returning only the files written."""
    _, result = render_result(
        result_dir, options, mesh=mesh, model=model, out_dir=out_dir, up_axis=up_axis, colliders=colliders
    )
    return result.files


def welded_strain(model: Any, vertex_map: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """Input-layout strain from the model's structural springs (positions gathered to welded)."""
    from meshdeform.strain import VertexStrain

    vertex_strain = VertexStrain(model)
    welded_count = int(model.vertex_count)

    def strain(positions: np.ndarray) -> np.ndarray:
        welded = np.zeros((welded_count, 3))
        welded[vertex_map] = positions
        return vertex_strain(welded)[vertex_map]

    return strain
