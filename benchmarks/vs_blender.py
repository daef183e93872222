"""Side by side: Blender's cloth modifier and meshdeform on the same scene, in one run.

    python benchmarks/vs_blender.py --blender-python /path/to/venv-with-bpy/bin/python [--n 64] [--frames 100]

The scene: an N x N vertex grid of 1 x 1 m lying flat, two corners of one edge pinned, gravity,
24 fps. Blender runs headless through the `bpy` module (pip install bpy, in a venv of its own;
it is never a dependency of meshdeform) with default cloth quality; meshdeform runs here with
each solver's defaults. Printed: frames/s, and the largest edge stretch (current / rest length)
over all frames, so speed is compared at equal or lower stretch.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import textwrap
import time

import numpy as np

BLENDER_SIDE = textwrap.dedent(
    """
    import json, sys, time
    import bpy
    import numpy as np

    n, frames = int(sys.argv[-2]), int(sys.argv[-1])
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=n, y_subdivisions=n, size=1.0)
    obj = bpy.context.active_object
    mesh = obj.data
    if len(mesh.vertices) != n * n:  # older Blender counts cuts, not vertices
        bpy.ops.object.delete()
        bpy.ops.mesh.primitive_grid_add(x_subdivisions=n - 1, y_subdivisions=n - 1, size=1.0)
        obj = bpy.context.active_object
        mesh = obj.data
    co = np.array([v.co[:] for v in mesh.vertices])
    ymax = co[:, 1].max()
    corners = [i for i, v in enumerate(co) if v[1] == ymax and v[0] in (co[:, 0].min(), co[:, 0].max())]
    group = obj.vertex_groups.new(name="pin")
    group.add(corners, 1.0, "REPLACE")
    cloth = obj.modifiers.new("cloth", "CLOTH")
    cloth.settings.vertex_group_mass = "pin"
    scene = bpy.context.scene
    scene.render.fps = 24
    scene.frame_start, scene.frame_end = 1, frames
    cloth.point_cache.frame_start, cloth.point_cache.frame_end = 1, frames
    edges = np.array([e.vertices[:] for e in mesh.edges])
    rest = np.linalg.norm(co[edges[:, 0]] - co[edges[:, 1]], axis=1)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    worst = 1.0
    start = time.perf_counter()
    for f in range(1, frames + 1):
        scene.frame_set(f)
    seconds = time.perf_counter() - start
    # stretch of the final pose and of a few intermediate ones (re-evaluated from the cache)
    for f in sorted({frames // 4, frames // 2, frames}):
        scene.frame_set(f)
        ev = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
        pos = np.array([v.co[:] for v in ev.data.vertices])
        worst = max(worst, float((np.linalg.norm(pos[edges[:, 0]] - pos[edges[:, 1]], axis=1) / rest).max()))
    print(json.dumps({"seconds": seconds, "frames": frames, "max_stretch": worst, "vertices": len(mesh.vertices),
                      "version": bpy.app.version_string}))
    """
)


def run_blender(python: str, n: int, frames: int) -> dict:
    """Run the Blender side in its own interpreter and return its JSON line."""
    proc = subprocess.run(
        [python, "-c", BLENDER_SIDE, str(n), str(frames)], capture_output=True, text=True, timeout=1800, check=False
    )
    lines = [line for line in proc.stdout.splitlines() if line.startswith("{")]
    if proc.returncode != 0 or not lines:
        raise SystemExit(f"blender side failed ({proc.returncode}): {proc.stderr.strip()[-2000:]}")
    return json.loads(lines[-1])


def run_meshdeform(solver: str, n: int, frames: int) -> dict:
    """The same scene with meshdeform: grid in the XZ plane (Y up), two corners of the far edge pinned."""
    from meshdeform.mesh import grid_mesh
    from meshdeform.model import SpringModel
    from meshdeform.simulate import Scene, Settings, simulate
    from meshdeform.topology import SpringKind

    mesh = grid_mesh(n, n, plane="xz")
    pins = np.zeros(n * n, dtype=bool)
    pins[[n * n - n, n * n - 1]] = True
    model = SpringModel.from_mesh(mesh, pinned_input=pins)
    settings = Settings(solver=solver, fps=24, frames=frames)
    list(simulate(model, Scene(), Settings(solver=solver, fps=24, frames=1)))  # compile / load the cache
    structural = model.springs[model.kinds == SpringKind.STRUCTURAL]
    rest = model.rest_lengths[model.kinds == SpringKind.STRUCTURAL]
    # timed: the simulation alone (as on Blender's side); the stretch of every frame is measured after
    start = time.perf_counter()
    poses = [frame.welded_positions for frame in simulate(model, Scene(), settings)]
    seconds = time.perf_counter() - start
    worst = 1.0
    for p in poses:
        worst = max(worst, float((np.linalg.norm(p[structural[:, 0]] - p[structural[:, 1]], axis=1) / rest).max()))
    return {"seconds": seconds, "frames": frames, "max_stretch": worst}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--blender-python", help="a Python with `bpy` installed (skipped when not given)")
    parser.add_argument("--n", type=int, default=64)
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--solvers", default="xpbd,verlet,springs,implicit")
    args = parser.parse_args()
    rows = []
    if args.blender_python:
        b = run_blender(args.blender_python, args.n, args.frames)
        rows.append((f"blender {b['version']} cloth", b))
    for solver in args.solvers.split(","):
        rows.append((f"meshdeform {solver}", run_meshdeform(solver, args.n, args.frames)))
    base = rows[0][1]["frames"] / rows[0][1]["seconds"] if args.blender_python else None
    print(f"{args.n} x {args.n} grid, {args.frames} frames at 24 fps, two corners pinned")
    print(f"{'run':32s} {'frames/s':>10s} {'x blender':>10s} {'max stretch':>12s}")
    for name, r in rows:
        fps = r["frames"] / r["seconds"]
        ratio = f"{fps / base:10.1f}" if base else f"{'-':>10s}"
        print(f"{name:32s} {fps:10.1f} {ratio} {r['max_stretch']:12.4f}")
    sys.stdout.flush()


if __name__ == "__main__":
    main()
