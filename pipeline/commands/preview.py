"""`meshdeform preview RESULT_DIR`: render PNGs, a contact sheet and a video of an existing result.

No re-simulation: the frames are read from the result folder by the first reader that finds its files
(`meshdeform.preview.results.search_order`: `frames/*.obj|ply`, `positions.npz`, `scene.usdc`, `vtk/*.vtp`,
`cache.pc2`, `cache.mdd`), with `report.json` for the input mesh (rest pose), fps and pinned vertices.
The colliders are rebuilt from the recipe and the input mesh the report names (`run_colliders`) while their
hashes still match the report's: a result folder holds no copy of its recipe.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from pipeline.commands.errors import cli_errors, fail

if TYPE_CHECKING:
    from meshdeform.mesh import Mesh
    from meshdeform.scene.colliders import Collider


def parse_frames(text: str) -> tuple[int, ...]:
    """`1,12,24` or ranges `1-24` (mixed) -> frame numbers; a usage error otherwise."""
    numbers: list[int] = []
    for part in (p.strip() for p in text.split(",")):
        if not part:
            continue
        match = re.fullmatch(r"(\d+)(?:-(\d+))?", part)
        if match is None:
            raise fail(f"--frames: expected numbers or ranges like 1,12,20-24, got {text!r}")
        lo = int(match.group(1))
        hi = int(match.group(2)) if match.group(2) else lo
        if hi < lo:
            raise fail(f"--frames: bad range {part!r} (frame numbers are scene frames, first to last)")
        numbers.extend(range(lo, hi + 1))
    if not numbers:
        raise fail("--frames: no frame numbers given")
    return tuple(dict.fromkeys(numbers))


def parse_size(text: str) -> tuple[int, int]:
    """`800x600` -> (800, 600); a usage error otherwise."""
    match = re.fullmatch(r"\s*(\d+)\s*[xX*,]\s*(\d+)\s*", text)
    if match is None:
        raise fail(f"--size: expected WIDTHxHEIGHT like 800x600, got {text!r}")
    return int(match.group(1)), int(match.group(2))


#: what a preview writes in its folder (meshdeform.preview): `preview/...`, `preview.mp4`, `preview.gif`
_PREVIEW_ENTRIES = ("preview", "preview.mp4", "preview.gif")


def refuse_foreign_previews(folder: Path) -> None:
    """Refuse (one line, exit 2) to render into `folder` where a preview file of the same name exists
    that meshdeform did not write: previews replace only their own files."""
    from pipeline.output_folder import inspect_folder

    state = inspect_folder(folder)
    clash = [entry for entry in state.foreign if entry.split("/", 1)[0] in _PREVIEW_ENTRIES]
    if clash:
        raise fail(
            f"{folder}: {clash[0]!r} is there and meshdeform did not write it; previews would replace it, "
            "choose another --out"
        )


def record_previews(folder: Path, files: list[Path]) -> None:
    """Add the preview files just written to `folder`'s marker (made if it has none), so a later
    preview or run knows them as meshdeform's."""
    from pipeline.output_folder import file_records, marker_records, read_marker, write_marker

    real = Path(os.path.realpath(folder))
    written = [Path(os.path.realpath(f)).relative_to(real).as_posix() for f in files]
    # the records of earlier files stay as they were: a preview never vouches for a file it did not write
    write_marker(real, [*(read_marker(real) or ()), *written], {**marker_records(real), **file_records(real, written)})


def run_colliders(result_dir: Path, report: dict[str, Any]) -> tuple[list[Collider], Mesh | None, str | None]:
    """The colliders of the run that wrote `result_dir` (its `report`), the input mesh loaded for them,
    and why none could be rebuilt (None when they were, or the run had none).

    A result folder keeps no copy of its recipe: the colliders are rebuilt (`pipeline.build`) from the
    recipe file `report.json` names, with the [[assets]] rules for the input's file name as `simulate`
    applies them, on the input mesh it names, when that recipe's colliders still hash to the report's
    `colliders_sha256` (`pipeline.job.colliders_hash`: command-line overrides do not change it) and the
    input to its `input_sha256`. An edited recipe or collider mesh, a batch asset whose [[assets]] rules
    or sidecar changed its colliders, or a moved file gives no colliders and the reason.
    """
    from meshdeform.errors import MeshdeformError
    from meshdeform.io import load
    from meshdeform.preview.colliders import scene_colliders
    from meshdeform.preview.results import report_input
    from pipeline.build import build_simulation
    from pipeline.hashing import file_sha256
    from pipeline.job import colliders_hash
    from pipeline.recipe import load_recipe

    expected = report.get("colliders_sha256")
    if not isinstance(expected, str):  # the run had none (or its report predates the key)
        return [], None, None
    source = report.get("recipe")
    if not isinstance(source, str) or not Path(source).is_file():
        return [], None, f"the recipe {source} named by report.json is not there"
    input_path = report_input(result_dir, report)
    if input_path is None:
        return [], None, "the input mesh named by report.json is not there"
    try:
        if file_sha256(input_path) != report.get("input_sha256"):
            return [], None, f"the input mesh {input_path} changed since the run"
        recipe = load_recipe(source).for_asset(Path(str(report["input"])).name)
        if colliders_hash(recipe) != expected:
            return [], None, f"the colliders of {source} (or their mesh files) changed since the run"
        mesh = load(input_path)
        return scene_colliders(build_simulation(recipe, mesh).scene), mesh, None
    except (MeshdeformError, OSError) as exc:
        return [], None, f"they could not be rebuilt ({exc})"


def register(app: typer.Typer) -> None:
    @app.command()
    def preview(
        result_dir: Path = typer.Argument(..., help="A result folder written by simulate or batch."),
        out: Path | None = typer.Option(None, "--out", "-o", help="Where to write (default: RESULT_DIR)."),
        every: int = typer.Option(1, min=1, help="Save every Nth frame as PNG, from the first (the rest pose)."),
        frames: str | None = typer.Option(None, help="Frames to save as PNG, e.g. 1,12,20-24 (overrides --every)."),
        size: str = typer.Option("800x600", help="Image size WIDTHxHEIGHT in pixels."),
        view: str = typer.Option("iso", help="Camera view: iso | front | side | top."),
        color: str = typer.Option("strain", help="Colouring: strain | flat | displacement."),
        wireframe: bool = typer.Option(False, "--wireframe", help="Draw polygon edges over the surface."),
        pins: bool = typer.Option(True, "--pins/--no-pins", help="Highlight pinned vertices (when known)."),
        tears: bool = typer.Option(False, "--tears", help="Highlight torn edges (new boundary edges)."),
        background: str = typer.Option("white", help="Background colour (name or #hex)."),
        video: str = typer.Option("none", help="Also write a video of every frame: mp4 | gif | none."),
        contact_sheet: bool = typer.Option(False, "--contact-sheet", help="Write preview/contact_sheet.png."),
        pngs: bool = typer.Option(True, "--png/--no-png", help="Write the per-frame PNG files."),
        fps: float | None = typer.Option(None, min=1e-6, help="Video frame rate (default: the result's)."),
        up: str = typer.Option("y", help="Up axis of the meshes for the named views: y | z."),
        colliders: bool = typer.Option(
            True, "--colliders/--no-colliders", help="Draw the run's colliders (rebuilt from its recipe)."
        ),
        framing: str = typer.Option(
            "main", help="What the camera frames: main (a torn mesh's main pieces; pieces that fall away leave) | all."
        ),
    ) -> None:
        """Render preview PNGs, a contact sheet and an MP4/GIF of a result folder without re-simulating."""
        from meshdeform.preview import PreviewOptions, render_result
        from meshdeform.preview.results import read_report

        frame_list = parse_frames(frames) if frames else None
        width, height = parse_size(size)
        with cli_errors():
            options = PreviewOptions(
                every=every,
                frames=frame_list,
                size=(width, height),
                view=view.lower(),
                color=color.lower(),
                wireframe=wireframe,
                highlight_pins=pins,
                highlight_tears=tears,
                background=background,
                video=None if video.lower() == "none" else video.lower(),
                contact_sheet=contact_sheet,
                pngs=pngs,
                fps=fps,
                up_axis=up.lower(),
                colliders=colliders,
                framing=framing.lower(),
            )
            if not (pngs or contact_sheet or options.video):
                raise fail("nothing to render: --no-png without --contact-sheet or --video")
            target = out if out is not None else result_dir
            refuse_foreign_previews(target)
            drawn, mesh, why_not = run_colliders(result_dir, read_report(result_dir)) if colliders else ([], None, None)
            if why_not is not None:
                typer.echo(f"warning: {result_dir}: colliders not drawn: {why_not}", err=True)
            seq, result = render_result(result_dir, options, mesh=mesh, out_dir=out, colliders=drawn)
            record_previews(target, result.files)
        parts = [f"{len(result.images)} PNG" + ("" if len(result.images) == 1 else "s")]
        if result.contact_sheet is not None:
            parts.append("a contact sheet")
        if result.video is not None:
            parts.append(result.video.name)
        typer.echo(
            f"{result_dir}: {', '.join(parts)} from {seq.source} ({result.frames_rendered} "
            f"frame{'' if result.frames_rendered == 1 else 's'} rendered in {result.seconds:.1f} s)"
        )
