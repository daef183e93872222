"""Side by side: Blender's cloth modifier and meshdeform on the same scene, measured alike, in one run.

    python benchmarks/vs_blender.py --blender-python /path/to/venv-with-bpy/bin/python \\
        [--n 64] [--frames 100] [--scene flat|hanging] [--repeats 3] \\
        [--blender quality=5 quality=10 quality=5:tension_stiffness=75 ...] \\
        [--configs xpbd xpbd:substeps=44 implicit:iterations=6 ...]

The scene: an N x N vertex grid of 1 x 1 m, two corners pinned, gravity, 24 fps. "flat" (default)
lies horizontal and falls, pinned at two corners of one edge; "hanging" is vertical, in the plane
of gravity, pinned at its two top corners. Blender runs headless through the `bpy` module (pip
install bpy, in a venv of its own; it is never a dependency of meshdeform), one process per run,
with each setting of `--blender` (fields of Blender's `ClothSettings`, colon separated: `quality`
is steps per frame, Blender's default 5; `tension_stiffness=75` etc.; every field not given at
Blender's default); meshdeform runs in this process with each setting of
`--configs` (`solver` alone is the solver's defaults; `solver:substeps=44:iterations=3` or any
field of the solver's options, e.g. `springs:strain_limit=1.05`, or the material's stretch_modulus,
`implicit:stretch_modulus=10000`).

Both sides are measured alike:
- FRAMES frames are simulated on each side and counted. Blender's frame 1 is the cache start (the
  rest pose, where Blender builds its cloth), so Blender steps through frames 1 .. FRAMES + 1;
  meshdeform's `simulate` yields frames 1 .. FRAMES, each simulated. The time of each side is
  from the start of its run to its last frame: it includes each side's set-up (Blender's frame 1;
  meshdeform's model preparation, solver set-up and factorisation), not the process start-up or
  meshdeform's Numba compilation (a one-frame run beforehand loads the kernels).
- Stretch: the longest mesh edge (the grid's edges are meshdeform's structural springs) over its
  rest length, read after EVERY simulated frame outside the timed span, worst frame reported.
- Repeats: every run of the list, one after the other, `--repeats` times; each run's speed is
  divided by that of Blender's first setting in the same repeat (the ratios cancel some of a
  shared machine's drift). Printed: median frames/s, the ratios' median (and range), the worst and
  the last frame's stretch.
- The quality-adjusted table: for each side (Blender, and each meshdeform solver), the fastest of
  its settings whose worst frame stretches at most 1.10 (then 1.05), or "not reached".
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import textwrap
import time
from dataclasses import dataclass, field, fields, replace

import numpy as np

#: stretch bounds of the quality-adjusted table: worst-frame longest edge / rest length
BOUNDS = (1.10, 1.05)

#: Blender's cloth settings run by default: its defaults (quality 5 steps a frame), more steps, stiffer
#: springs (the default tension and compression stiffness is 15)
DEFAULT_BLENDER = (
    "quality=5",
    "quality=10",
    "quality=20",
    "quality=5:tension_stiffness=150:compression_stiffness=150",
    "quality=5:tension_stiffness=500:compression_stiffness=500",
)

#: the meshdeform settings run by default: each solver's defaults, finer steps, a strain limit, and
#: softer and stiffer springs (the material's stretch_modulus, 10 000 N/m by default)
DEFAULT_CONFIGS = (
    "xpbd",
    "xpbd:substeps=44",
    "xpbd:substeps=88",
    "verlet",
    "verlet:substeps=36",
    "verlet:substeps=72",
    "springs",
    "springs:strain_limit=1.05",
    "implicit",
    "implicit:substeps=16",
    "implicit:iterations=6",
    "implicit:stretch_modulus=1000",
    "implicit:stretch_modulus=30000",
)

BLENDER_SIDE = textwrap.dedent(
    """
    import json, sys, time
    import bpy
    import numpy as np

    n, frames, scene_kind, settings = int(sys.argv[-4]), int(sys.argv[-3]), sys.argv[-2], json.loads(sys.argv[-1])
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=n, y_subdivisions=n, size=1.0)
    obj = bpy.context.active_object
    mesh = obj.data
    if len(mesh.vertices) != n * n:  # older Blender counts cuts, not vertices
        bpy.ops.object.delete()
        bpy.ops.mesh.primitive_grid_add(x_subdivisions=n - 1, y_subdivisions=n - 1, size=1.0)
        obj = bpy.context.active_object
        mesh = obj.data
    co = np.empty(len(mesh.vertices) * 3)
    mesh.vertices.foreach_get("co", co)
    co = co.reshape(-1, 3)
    if scene_kind == "hanging":  # stand the grid up in the XZ plane (Z up), in the plane of gravity
        co = np.stack([co[:, 0], np.zeros(len(co)), co[:, 1]], axis=1)
        mesh.vertices.foreach_set("co", co.ravel())
        mesh.update()
    up = 2 if scene_kind == "hanging" else 1  # the coordinate whose largest value marks the pinned edge
    top = co[:, up].max()
    corners = [i for i, v in enumerate(co) if v[up] == top and v[0] in (co[:, 0].min(), co[:, 0].max())]
    group = obj.vertex_groups.new(name="pin")
    group.add(corners, 1.0, "REPLACE")
    cloth = obj.modifiers.new("cloth", "CLOTH")
    cloth.settings.vertex_group_mass = "pin"
    for key, value in settings.items():
        setattr(cloth.settings, key, value)
    scene = bpy.context.scene
    scene.render.fps = 24
    last = frames + 1  # frame 1 is the cache start (rest pose): frames 2 .. frames + 1 are simulated
    scene.frame_start, scene.frame_end = 1, last
    cloth.point_cache.frame_start, cloth.point_cache.frame_end = 1, last
    edges = np.empty(len(mesh.edges) * 2, dtype=np.int64)
    mesh.edges.foreach_get("vertices", edges)
    edges = edges.reshape(-1, 2)
    rest = np.linalg.norm(co[edges[:, 0]] - co[edges[:, 1]], axis=1)
    pos = np.empty(len(mesh.vertices) * 3)
    seconds, stretch = 0.0, []
    for f in range(1, last + 1):
        start = time.perf_counter()
        scene.frame_set(f)
        seconds += time.perf_counter() - start
        if f == 1:
            continue
        evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
        evaluated_mesh = evaluated.to_mesh()
        evaluated_mesh.vertices.foreach_get("co", pos)
        evaluated.to_mesh_clear()
        p = pos.reshape(-1, 3)
        stretch.append(float((np.linalg.norm(p[edges[:, 0]] - p[edges[:, 1]], axis=1) / rest).max()))
    print(json.dumps({"seconds": seconds, "frames": len(stretch), "max_stretch": max(stretch),
                      "last_stretch": stretch[-1], "vertices": len(mesh.vertices), "version": bpy.app.version_string}))
    """
)


@dataclass(frozen=True)
class Run:
    """One measured run: which side and setting, simulated frames, seconds, worst and last frame stretch."""

    side: str
    setting: str
    frames: int
    seconds: float
    max_stretch: float
    last_stretch: float

    @property
    def fps(self) -> float:
        return self.frames / self.seconds


@dataclass
class Row:
    """The runs of one setting over the repeats, and their speed ratios to the reference runs."""

    side: str
    setting: str
    runs: list[Run] = field(default_factory=list)
    ratios: list[float] = field(default_factory=list)

    @property
    def fps(self) -> float:
        return statistics.median(r.fps for r in self.runs)

    @property
    def max_stretch(self) -> float:
        return max(r.max_stretch for r in self.runs)

    @property
    def last_stretch(self) -> float:
        return max(r.last_stretch for r in self.runs)


def edge_stretch(positions: np.ndarray, edges: np.ndarray, rest: np.ndarray) -> float:
    """Longest edge over its rest length. positions (V, 3) m, edges (E, 2) vertex indices, rest (E,) m."""
    return float((np.linalg.norm(positions[edges[:, 0]] - positions[edges[:, 1]], axis=1) / rest).max())


def run_blender(python: str, n: int, frames: int, scene: str, spec: str) -> tuple[Run, str]:
    """Run the Blender side in its own interpreter with the cloth settings `spec` ('key=value:...',
    see `parse_config`); the run and Blender's version."""
    _, _, settings = parse_config(":" + spec)
    proc = subprocess.run(
        [python, "-c", BLENDER_SIDE, str(n), str(frames), scene, json.dumps(settings)],
        capture_output=True,
        text=True,
        timeout=3600,
        check=False,
    )
    lines = [line for line in proc.stdout.splitlines() if line.startswith("{")]
    if proc.returncode != 0 or not lines:
        raise SystemExit(f"blender side failed ({proc.returncode}): {proc.stderr.strip()[-2000:]}")
    b = json.loads(lines[-1])
    setting = ", ".join(f"{k.removesuffix('_stiffness')} {v}" for k, v in settings.items())
    run = Run("blender", setting, b["frames"], b["seconds"], b["max_stretch"], b["last_stretch"])
    return run, b["version"]


def parse_config(spec: str) -> tuple[str, int | None, dict[str, object]]:
    """'solver[:key=value...]' -> (solver, substeps or None, options fields). Values are numbers,
    true/false, none or else strings."""
    solver, *pairs = spec.split(":")
    substeps: int | None = None
    options: dict[str, object] = {}
    for pair in pairs:
        key, _, text = pair.partition("=")
        lowered = text.lower()
        value: object
        if lowered in ("true", "false"):
            value = lowered == "true"
        elif lowered == "none":
            value = None
        else:
            try:
                value = float(text) if any(c in text for c in ".e") else int(text)
            except ValueError:  # a word: a string option such as implicit's method=local_global
                value = text
        if key == "substeps":
            substeps = int(text)
        else:
            options[key] = value
    return solver, substeps, options


def meshdeform_inputs(n: int, scene: str, stretch_modulus: float | None = None):
    """The scene's meshdeform model (Y up): grid, two corners of the far / top edge pinned; the default
    material, or its stretch_modulus (N/m) changed."""
    from meshdeform.material import Material
    from meshdeform.mesh import grid_mesh
    from meshdeform.model import SpringModel

    mesh = grid_mesh(n, n, plane="xy" if scene == "hanging" else "xz")
    pins = np.zeros(n * n, dtype=bool)
    pins[[n * n - n, n * n - 1]] = True  # row j = n - 1: z = 1 (flat) or y = 1 (hanging, the top)
    material = Material() if stretch_modulus is None else Material(stretch_modulus=float(stretch_modulus))
    return SpringModel.from_mesh(mesh, material=material, pinned_input=pins)


def run_meshdeform(spec: str, n: int, frames: int, scene: str) -> Run:
    """The same scene with meshdeform at the setting `spec` (see `parse_config`; `stretch_modulus`
    is the material's, every other key a field of the solver's options)."""
    from meshdeform.simulate import Scene, Settings, simulate, steps_for
    from meshdeform.solvers.registry import solver_class
    from meshdeform.topology import SpringKind

    solver, substeps, changes = parse_config(spec)
    option_changes = {k: v for k, v in changes.items() if k != "stretch_modulus"}
    defaults = solver_class(solver).options_class()
    unknown = set(option_changes) - {f.name for f in fields(defaults)}
    if unknown:
        raise SystemExit(f"{spec}: {solver} has no option {sorted(unknown)}")
    options = replace(defaults, **option_changes)
    modulus = changes.get("stretch_modulus")
    # the steps a run of this scene takes (a solver's calm steps where both counts are its defaults)
    settings = steps_for(Settings(solver=solver, fps=24, frames=frames, substeps=substeps, options=options), Scene())
    # compile / load the kernels on a model of its own, so the timed run prepares its model afresh
    list(simulate(meshdeform_inputs(n, scene, modulus), Scene(), replace(settings, frames=1)))
    model = meshdeform_inputs(n, scene, modulus)
    structural = model.kinds == SpringKind.STRUCTURAL
    edges, rest = model.springs[structural], model.rest_lengths[structural]
    # timed: the simulation alone (as on Blender's side); the stretch of every frame is measured after
    start = time.perf_counter()
    poses = [frame.welded_positions for frame in simulate(model, Scene(), settings)]
    seconds = time.perf_counter() - start
    stretch = [edge_stretch(p, edges, rest) for p in poses]
    iterations = settings.options.iterations_for(solver_class(solver))
    name = f"{iterations} x {settings.substeps}" if iterations else f"{settings.substeps} substeps"
    extra = ", ".join(f"{k}={v}" for k, v in changes.items() if k != "iterations")
    setting = f"{name}{', ' + extra if extra else ''}"
    return Run(solver, setting, len(poses), seconds, max(stretch), stretch[-1])


def fastest_within(rows: list[Row], bound: float) -> dict[str, Row | None]:
    """For each side, in the order met, its fastest row whose worst-frame stretch is <= bound (None: none)."""
    best: dict[str, Row | None] = {}
    for row in rows:
        best.setdefault(row.side, None)
        if row.max_stretch <= bound and (best[row.side] is None or row.fps > best[row.side].fps):
            best[row.side] = row
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--blender-python", help="a Python with `bpy` installed (skipped when not given)")
    parser.add_argument("--n", type=int, default=64)
    parser.add_argument("--frames", type=int, default=100, help="simulated frames on each side")
    parser.add_argument("--scene", choices=("flat", "hanging"), default="flat")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument(
        "--blender", nargs="*", default=list(DEFAULT_BLENDER), help="Blender's cloth settings ('key=value:...')"
    )
    parser.add_argument("--configs", nargs="*", default=list(DEFAULT_CONFIGS), help="meshdeform settings")
    args = parser.parse_args()
    blender = args.blender if args.blender_python else []
    rows: dict[str, Row] = {}
    version = ""
    for repeat in range(args.repeats):
        reference = None
        for spec in blender:
            run, version = run_blender(args.blender_python, args.n, args.frames, args.scene, spec)
            reference = reference or run
            rows.setdefault(f"blender {spec}", Row(run.side, run.setting)).runs.append(run)
        for spec in args.configs:
            run = run_meshdeform(spec, args.n, args.frames, args.scene)
            rows.setdefault(spec, Row(run.side, run.setting)).runs.append(run)
        for row in rows.values():
            if reference is not None and len(row.ratios) == repeat:
                row.ratios.append(row.runs[-1].fps / reference.fps)
        print(f"repeat {repeat + 1} of {args.repeats} done", file=sys.stderr, flush=True)
    table = list(rows.values())
    print(
        f"{args.n} x {args.n} grid, {args.scene}, {args.frames} simulated frames at 24 fps, two corners pinned, "
        f"{args.repeats} repeat(s){', Blender ' + version if version else ''}"
    )
    head = f"{'side':8s} {'setting (iter x substeps)':42s} {'frames/s':>9s} {'x Blender 1st':>19s}"
    print(f"{head} {'worst stretch':>14s} {'last':>7s}")
    for row in table:
        ratio = "-"
        if row.ratios:
            ratio = f"{statistics.median(row.ratios):.2f} ({min(row.ratios):.2f}-{max(row.ratios):.2f})"
        line = f"{row.side:8s} {row.setting:42s} {row.fps:9.2f} {ratio:>19s}"
        print(f"{line} {row.max_stretch:14.3f} {row.last_stretch:7.3f}")
    for bound in BOUNDS:
        best = fastest_within(table, bound)
        blender_best = best.get("blender")
        print(f"\nworst-frame stretch <= {bound:.2f}: the fastest setting of each side")
        for side, row in best.items():
            if row is None:
                print(f"  {side:8s} not reached")
                continue
            versus = ""
            if blender_best is not None and side != "blender":  # the same repeat's runs paired
                pairs = zip(row.runs, blender_best.runs, strict=True)
                paired = statistics.median(r.fps / b.fps for r, b in pairs)
                versus = f" ({paired:.1f} x Blender's, median of the repeats)"
            print(f"  {side:8s} {row.setting:42s} {row.fps:9.2f} frames/s at {row.max_stretch:.3f}{versus}")
    sys.stdout.flush()


if __name__ == "__main__":
    main()
