"""One job: one mesh through one recipe into one output folder.

load -> build (model, scene, settings) -> simulate -> exporters (one `ExportSession`, streamed frame by
frame; previews measured from the same frames and rendered once the files are complete, as they would be
read back from them: `meshdeform.preview.live`) -> report.json. Everything is written into a staging
folder beside the target and renamed into place only when the whole job succeeded, so a failed or
interrupted job never leaves an output folder that looks complete (`pipeline.output_folder`: which
folders may be written, the `.meshdeform.json` marker, staging, locks).
"""

from __future__ import annotations

import hashlib
import json
import subprocess
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from meshdeform.atomic import write_text_atomic
from meshdeform.errors import MeshdeformError
from meshdeform.mesh import Mesh
from pipeline import __version__
from pipeline.hashing import file_sha256
from pipeline.interrupts import raise_if_lost, unwritten_on_failure
from pipeline.output_folder import REPORT_NAME, check_output_folder, staged_directory
from pipeline.recipe import Recipe, recipe_hash
from pipeline.recipe.digest import add_collider_files

if TYPE_CHECKING:
    from meshdeform.model import SpringModel
    from meshdeform.preview.live import RunPreview
    from meshdeform.scene.colliders import Collider
    from meshdeform.simulate import Frame

#: report keys that hold wall-clock timings (the only ones allowed to differ between identical runs)
TIMING_KEYS = ("seconds", "setup_seconds", "export_seconds", "preview_seconds", "total_seconds", "frames_per_second")

#: called after each frame with (frame number, frame count)
FrameCallback = Callable[[int, int], None]


@dataclass(frozen=True)
class JobResult:
    """Where a finished job wrote, and its report."""

    out_dir: Path
    report: dict[str, Any]
    outputs: list[Path]


def _point_data(model: Any, strain: Any, frame: Any) -> dict[str, np.ndarray]:
    """Per-vertex data in the input layout for exporters that carry it (VTK)."""
    welded_strain = strain(frame.welded_positions)
    return {
        "strain": welded_strain[model.vertex_map],
        "displacement": np.linalg.norm(frame.welded_positions - model.rest_positions, axis=1)[model.vertex_map],
        "pinned": model.pinned[model.vertex_map].astype(np.uint8),
    }


def output_indices(recipe: Recipe) -> tuple[int, int]:
    """The frame indices (0: the rest pose) a run writes, first and last included: `[output]
    frames` (scene frames) less `[simulation] start_frame`, else all of them."""
    sim = recipe.simulation
    if recipe.output.frames is None:
        return 0, sim.frames
    first, last = recipe.output.frames
    return first - sim.start_frame, last - sim.start_frame


def run_job(
    mesh_path: Path,
    recipe: Recipe,
    out_dir: Path,
    *,
    on_frame: FrameCallback | None = None,
    mesh: Mesh | None = None,
    overwrite: bool = False,
) -> JobResult:
    """Simulate one mesh with a recipe and write every requested output into `out_dir`.

    Raises the engine's typed errors (MeshLoadError, RecipeError, SimulationDiverged,
    ExportError), and OutputFolderError before anything is read when `out_dir` may not be written
    (`check_output_folder`: the input's or the recipe's folder, a non-folder, a folder holding files
    meshdeform did not write unless `overwrite`); nothing is left in `out_dir` when it does. Two runs
    on one folder at once are the caller's to prevent (`output_lock`, as `meshdeform simulate` does).
    """
    ahead: list[threading.Thread | subprocess.Popen[bytes]] = []  # compiling ahead (`pipeline.compile_ahead`)
    try:
        with unwritten_on_failure(Path(out_dir)):  # also before the staging folder exists: the CLI's line names it
            return _run_job(mesh_path, recipe, out_dir, on_frame=on_frame, mesh=mesh, overwrite=overwrite, ahead=ahead)
    finally:
        # whatever happens: the stand-in thread joined (a process that ends while it still compiles
        # or holds a factorisation crashes or reports leaked objects on its way out), the
        # compiling process stopped
        from pipeline import compile_ahead

        for work in ahead:
            if isinstance(work, threading.Thread):
                work.join()
            else:
                compile_ahead.stop_compiler(work)


def _run_job(
    mesh_path: Path,
    recipe: Recipe,
    out_dir: Path,
    *,
    on_frame: FrameCallback | None,
    mesh: Mesh | None,
    overwrite: bool,
    ahead: list[threading.Thread | subprocess.Popen[bytes]],
) -> JobResult:
    """`run_job`'s work; the compile-ahead thread and process it starts go into `ahead` (run_job
    joins the one and stops the other)."""
    from meshdeform.export import ExportContext, ExportSession, FrameData
    from meshdeform.io import load
    from meshdeform.preview.colliders import scene_colliders
    from meshdeform.preview.live import RunPreview
    from meshdeform.scene.colliders import ContactStats
    from meshdeform.simulate import converged, convergence_warning, initial_frame, simulate, steps_vary
    from meshdeform.strain import VertexStrain
    from pipeline import compile_ahead
    from pipeline.build import build_simulation
    from pipeline.estimate import estimate_run, require_disk_space

    started = time.perf_counter()
    mesh_path = Path(mesh_path)
    check_output_folder(out_dir, overwrite=overwrite, protect={"input": mesh_path, "recipe": recipe.source})
    mesh = mesh if mesh is not None else load(mesh_path)
    built = build_simulation(recipe, mesh)
    model, settings = built.model, built.settings
    # kernels compiled in the background while the run prepares (pipeline.compile_ahead), and in
    # a process of their own on the other core (the solver's and self-collision's) while this one
    # compiles the colliders'.
    thread = compile_ahead.start(settings, built.scene, model.vertex_count)
    if thread is not None:
        ahead.append(thread)
    compiler = compile_ahead.start_compiler(settings, built.scene, model.vertex_count)
    if compiler is not None:
        ahead.append(compiler)
        compile_ahead.compile_colliders(built.scene)  # meanwhile the process compiles the solver's
    first, last = output_indices(recipe)
    if last < settings.frames:  # nothing after the last frame written is simulated
        settings = settings.with_frames(last)
    require_disk_space(estimate_run(recipe, mesh, model).total_bytes, Path(out_dir))  # before any frame is run
    formats = list(dict.fromkeys(recipe.output.formats or ["obj"]))
    # made now: opened on the staging folder once it exists
    session = ExportSession(formats, options=recipe.output.exporter_options)
    strain = VertexStrain(model)
    setup_seconds = time.perf_counter() - started

    max_stretch: list[float] = []
    max_speed: list[float] = []
    frame_substeps: list[int] = []  # the steps each frame took (`meshdeform.simulate.steps_vary`)
    force_residual: list[float] = []
    last_frame = None
    rest_frame: int | None = None
    broken_springs: list[int] = []
    split_vertices: list[int] = []
    pieces: list[int] = []
    contact: dict[str, list[int]] = {}  # self-collision's ContactWork figures, frame by frame
    colliders = scene_colliders(built.scene)
    collider_seen = ContactStats()
    collider_contact: dict[str, list[int]] = {}  # the colliders' ContactStats summed, frame by frame
    collider_clearance: list[float | None] = []  # mm, frame by frame: the free vertices' least (`frame_clearance`)
    contact_failed: list[int] = []  # frames a free vertex ended within a collider's thickness (`contact_warning`)
    extra_work: list[int] = []  # frames whose contact needed more than one pass or more steps (docs/recipes.md)
    first_tear_frame: int | None = None
    output_vertices = mesh.vertex_count
    strain_model = model
    sim_seconds = 0.0
    export_seconds = 0.0
    preview_seconds = 0.0
    with staged_directory(out_dir, overwrite=overwrite) as stage:
        context = ExportContext(
            mesh=mesh,
            out_dir=stage,
            fps=settings.fps,
            start_frame=recipe.simulation.start_frame,
            up_axis=recipe.up_axis,
            input_up=recipe.simulation.up,
            frame_count=settings.frames,
        )
        preview = (
            RunPreview(
                recipe.output.preview, context, formats, model, colliders,
                exporter_options=recipe.output.exporter_options,
            )
            if recipe.output.preview
            else None
        )

        def export(frame: Frame) -> None:
            """Hand one frame (index 0: the rest pose) to the exporters and the previews."""
            nonlocal export_seconds, preview_seconds, strain, strain_model
            if not first <= frame.index <= last:
                return
            frame_model = frame.model if frame.model is not None else model
            if frame_model is not strain_model:  # the mesh opened: strain over the new springs
                strain, strain_model = VertexStrain(frame_model), frame_model
            data = FrameData(
                index=frame.index,
                time=frame.time,
                positions=frame.positions,
                mesh=frame.mesh,
                point_data=_point_data(frame_model, strain, frame),
                subframes=frame.subframes,
            )
            tick = time.perf_counter()
            session.write(data)
            export_seconds += time.perf_counter() - tick
            if preview is not None:  # measured now, rendered once the files are complete
                tick = time.perf_counter()
                preview.add(data)
                preview_seconds += time.perf_counter() - tick

        with session.open(context):  # an exception in the block aborts every exporter
            export(initial_frame(model))
            tick = time.perf_counter()
            for frame in simulate(model, built.scene, settings):
                sim_seconds += time.perf_counter() - tick
                max_stretch.append(round(frame.max_stretch, 9))
                max_speed.append(round(frame.max_speed, 9))
                frame_substeps.append(frame.substeps)
                force_residual.append(round(frame.force_residual, 6))
                last_frame = frame
                rest_frame = frame.rest_frame  # first frame of the still run that lasts to the end
                if frame.pieces is not None:  # tearing: what broke, what came apart
                    broken_springs.append(frame.broken_springs)
                    split_vertices.append(frame.split_vertices)
                    pieces.append(frame.pieces)
                    if first_tear_frame is None and frame.mesh is not None:
                        first_tear_frame = frame.index
                    output_vertices = int(frame.positions.shape[0])
                extra = False
                if frame.contact is not None:  # self-collision: what each frame took
                    for key, value in asdict(frame.contact).items():
                        contact.setdefault(key, []).append(int(value))
                    extra = frame.contact.zone_rounds > 0
                if colliders:  # the colliders: what this frame took (their counters are running sums)
                    total = sum((c.stats for c in colliders), ContactStats())
                    done, collider_seen = total - collider_seen, total
                    for key, value in asdict(done).items():
                        if key != "substeps":
                            collider_contact.setdefault(key, []).append(int(value))
                    extra = extra or done.swept > 0 or done.rounds > 0 or done.reverted > 0
                    clearance, failed = frame_clearance(colliders, frame, model)
                    collider_clearance.append(clearance)
                    if failed:
                        contact_failed.append(frame.index)
                extra = extra or frame.substeps > settings.substeps  # a fast frame's extra steps
                if extra:
                    extra_work.append(frame.index)
                export(frame)
                raise_if_lost()  # a signal whose Interrupted a finalizer swallowed still stops the run
                if on_frame is not None:
                    on_frame(frame.index, settings.frames)
                tick = time.perf_counter()
            tick = time.perf_counter()
            session.close()
            export_seconds += time.perf_counter() - tick
        outputs: list[Path] = session.files
        if preview is not None:
            tick = time.perf_counter()
            outputs += render_job_previews(preview, stage)
            preview_seconds += time.perf_counter() - tick
        # what the run itself found: a shape settled unconverged, contact self-collision could not hold
        run_warnings = [
            warning
            for warning in (
                convergence_warning(last_frame, built.scene, settings.options) if last_frame is not None else None,
                unresolved_contact_warning(contact.get("unresolved", [])),
                contact_warning(contact_failed, collider_clearance),
                stretch_warning(max_stretch),
            )
            if warning is not None
        ]
        relative = sorted({str(Path(p).resolve().relative_to(stage.resolve())) for p in outputs})
        start = recipe.simulation.start_frame
        report = {
            "tool": "meshdeform",
            "version": __version__,
            "input": str(mesh_path),
            "input_sha256": file_sha256(mesh_path) if mesh_path.is_file() else None,
            "recipe": str(recipe.source) if recipe.source else None,
            "recipe_sha256": recipe_hash(recipe),
            "colliders_sha256": colliders_hash(recipe) if recipe.colliders else None,
            "solver": settings.solver,
            "fps": settings.fps,
            "substeps": settings.substeps,
            "iterations": settings.iterations,
            **({"frame_substeps": frame_substeps} if steps_vary(settings, built.scene) else {}),
            "damping": settings.options.damping,
            "frames": len(max_stretch),
            "start_frame": recipe.simulation.start_frame,
            # the scene frames written, first and last: the rest pose is scene frame start_frame,
            # the state after k frames start_frame + k (per-frame lists below start at k = 1)
            "output_frames": [start + first, start + min(last, len(max_stretch))],
            "vertices": mesh.vertex_count,
            "welded_vertices": model.vertex_count,
            "faces": mesh.face_count,
            "springs": model.spring_counts(),
            "pinned_vertices": int(np.count_nonzero(model.pinned_input_mask())),
            "pinned": np.flatnonzero(model.pinned_input_mask()).tolist(),
            "selections": built.selections,
            "max_stretch": max_stretch,
            "max_speed": max_speed,
            "rest_frame": rest_frame,
            "force_residual": force_residual,
            "converged": converged(last_frame, built.scene) if last_frame is not None else None,
            **(
                {
                    "first_tear_frame": first_tear_frame,
                    "broken_springs": broken_springs,
                    "split_vertices": split_vertices,
                    "pieces": pieces,
                    "output_vertices": output_vertices,
                    "topology_updates": built.scene.tearing.updates if built.scene.tearing is not None else 0,
                }
                if recipe.changes_topology
                else {}
            ),
            **(
                {"self_collision": {"thickness": built.scene.self_collision.thickness, **contact}}
                if built.scene.self_collision is not None
                else {}
            ),
            **(
                {"collider_contact": collider_contact, "collider_clearance_mm": collider_clearance}
                if colliders
                else {}
            ),
            **({"contact_extra_work_frames": extra_work} if colliders or built.scene.self_collision else {}),
            "formats": formats,
            "outputs": [*relative, REPORT_NAME],
            "warnings": [*mesh.warnings, *built.warnings, *run_warnings],
            "seconds": round(sim_seconds, 4),
            "frames_per_second": round(len(max_stretch) / sim_seconds, 3) if sim_seconds > 0 else None,
            "setup_seconds": round(setup_seconds, 4),
            "export_seconds": round(export_seconds, 4),
            "preview_seconds": round(preview_seconds, 4),
            "total_seconds": round(time.perf_counter() - started, 4),
        }
        write_text_atomic(stage / REPORT_NAME, json.dumps(report, indent=2) + "\n")
    return JobResult(out_dir=Path(out_dir), report=report, outputs=[Path(out_dir) / r for r in report["outputs"]])


#: frames a warning lists at most
LISTED_FRAMES = 10
#: a frame whose structural springs are longer than this many times their rest length gets a
#: warning (`stretch_warning`): woven cloth stretches a few per cent, a knit a few tens; half again
#: its length looks rubbery or torn, though a run stops only at 10x (`meshdeform.simulate`)
STRETCH_WARNING = 1.5


def _listed_frames(frames: list[int]) -> str:
    """Frame numbers as a warning lists them: the first `LISTED_FRAMES`, then "..."."""
    listed = ", ".join(str(index) for index in frames[:LISTED_FRAMES])
    return listed + ", ..." if len(frames) > LISTED_FRAMES else listed


def stretch_warning(max_stretch: list[float]) -> str | None:
    """The report's sentence where some frame's structural springs stretched past
    `STRETCH_WARNING` (max_stretch: the report's list, per frame from frame 1), else None."""
    frames = [index for index, stretch in enumerate(max_stretch, start=1) if stretch > STRETCH_WARNING]
    if not frames:
        return None
    listed = _listed_frames(frames)
    worst = max(frames, key=lambda index: max_stretch[index - 1])
    return (
        f"stretched: in {len(frames)} frame(s) ({listed}) structural springs were longer than "
        f"{STRETCH_WARNING:g}x their rest length, {max_stretch[worst - 1]:.3g}x in frame {worst}; the cloth looks "
        "rubbery or torn there: more substeps or iterations, or a stiffer material, hold it (where it wraps a "
        "collider narrower than its edges, a finer mesh does)"
    )


#: m: a vertex this deep within a collider's thickness (or its fail-safe floor, where deeper) at a
#: frame's end is a contact that did not hold (`frame_clearance`): what the contact checks allow
#: (issue 15: no cloth point nearer a collider than its thickness less 1 mm); steps after the
#: colliders (a tear's parting, self-collision's last zones) may leave a vertex a little within it
CONTACT_SLACK = 0.001


def frame_clearance(colliders: Sequence[Collider], frame: Frame, model: SpringModel) -> tuple[float | None, bool]:
    """(the least `Collider.clearance` (mm, rounded to the micron) of the frame's free vertices
    over `colliders`, None without free vertices; whether one lies deeper within a collider's
    thickness than its own fail-safe floor, `FAIL_FRACTION` of the thickness, and than
    `CONTACT_SLACK`: its contact did not hold).
    Pinned vertices are left out (a pin may hold the cloth on a body's surface). `model`: the
    run's model, where the frame carries none (no tearing)."""
    from meshdeform.scene.colliders import FAIL_FRACTION

    in_force = frame.model if frame.model is not None else model
    points = frame.welded_positions[np.asarray(in_force.inv_mass) > 0.0]
    if not points.shape[0]:
        return None, False
    nearest, failed = np.inf, False
    for collider in colliders:
        clearance = float(collider.clearance(points, frame.time).min())
        nearest = min(nearest, clearance)
        failed = failed or clearance < -max(FAIL_FRACTION * collider.thickness, CONTACT_SLACK) - 1e-9
    return round(nearest * 1000.0, 3), failed


def contact_warning(failed: list[int], clearance: list[float | None]) -> str | None:
    """The report's sentence where a free vertex ended a frame within a collider's thickness beyond
    the colliders' fail-safe floor (`failed`: those frames; `clearance`: the report's
    `collider_clearance_mm`, per frame from frame 1), else None."""
    if not failed:
        return None
    worst = min(failed, key=lambda index: clearance[index - 1] or 0.0)
    return (
        f"contact: in {len(failed)} frame(s) ({_listed_frames(failed)}) a vertex ended within a collider's "
        f"thickness, {-(clearance[worst - 1] or 0.0):.3g} mm deep in frame {worst}: the contact did not hold "
        "there (the cloth squeezed between colliders, pulled in by pins, or started inside a body; more "
        "substeps may help)"
    )


def unresolved_contact_warning(unresolved: list[int]) -> str | None:
    """The report's sentence where self-collision's impact zones ran out of rounds (`unresolved`,
    per frame from frame 1: `ContactWork.unresolved`), else None."""
    frames = [index for index, count in enumerate(unresolved, start=1) if count]
    if not frames:
        return None
    listed = _listed_frames(frames)
    return (
        f"self_collision: in {len(frames)} frame(s) ({listed}) impact zones ran out of rounds with pairs the "
        "continuous check could not prove apart, so the cloth may pass through itself there; check that "
        "animated pins do not drive it through itself (no contact can undo that), else more substeps leave "
        "each step fewer contacts to resolve"
    )


def colliders_hash(recipe: Recipe) -> str:
    """sha256 of what a run's colliders are built from: the recipe's [[colliders]] tables (normalised),
    its up axis (the ground's) and the contents of the collider mesh files and their point caches
    (`pipeline.recipe.digest.add_collider_files`). Command-line overrides do not
    reach them, so `meshdeform preview` rebuilds a run's colliders from its recipe file while this matches
    the report's `colliders_sha256` (the input mesh, which relative colliders need, is checked apart)."""
    content = {"colliders": [c.model_dump(mode="json") for c in recipe.colliders], "up": recipe.simulation.up}
    digest = hashlib.sha256(json.dumps(content, sort_keys=True, separators=(",", ":")).encode("utf-8"))
    add_collider_files(digest, recipe)
    return digest.hexdigest()


def render_job_previews(preview: RunPreview, stage: Path) -> list[Path]:
    """Render the recipe's previews into the staging folder from the frames the run measured and kept
    (the same files as rendering the folder's frames read back: `meshdeform.preview.live`)."""
    try:
        return list(preview.render(stage).files)
    except MeshdeformError:
        raise
    except Exception as exc:  # a rendering backend failure is an export error, not a crash
        raise MeshdeformError(f"{stage.name}: preview rendering failed: {exc}") from exc
