"""Check our point caches and USD against Blender: Mesh Cache modifier (PC2, MDD) and usd_import.

Blender is never a dependency of meshdeform; it is the tool users would otherwise open, so it
is the yardstick (DESIGN.md section 8). Two steps, because `bpy` lives in a venv of its own:

    # with the meshdeform venv: write the test data, then run the check with Blender's Python
    .venv/bin/python benchmarks/blender_check.py --bpy-python /path/to/bpy-venv/bin/python

    # or by hand
    .venv/bin/python benchmarks/blender_check.py --make DIR
    /path/to/bpy-venv/bin/python benchmarks/blender_check.py --check DIR

`--make` bakes a synthetic waving sheet (grid with a hole-free quad topology) into
`cache.pc2` / `cache.mdd` (Blender's Z-up world, `up_axis="z"`), `scene.usdc` (Y up: Blender's
importer converts it) and `expected.npz` (the Z-up positions). `--check` builds the same mesh in
Blender (vertex order kept), adds a MESH_CACHE modifier per cache, imports the USD, steps through
the frames with `scene.frame_set` and compares the evaluated world-space vertices. Exit status
1 when any difference exceeds 1e-5. Not run in CI.

Found with Blender 5.0.1: the Mesh Cache modifier reads PC2 in "Frame" time mode as sample =
scene frame - Frame Start, ignoring the header's start frame, so set the modifier's Frame Start
to the cache's start frame (1 by default); MDD plays in "Time" mode from its times in seconds.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

TOLERANCE = 1e-5


def make(folder: Path, frames: int, start_frame: int) -> None:
    """Write the caches, the USD stage and the expected positions with meshdeform."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from meshdeform.export import ExportContext, FrameData, convert_up_axis, make_exporter
    from meshdeform.mesh import grid_mesh

    mesh = grid_mesh(12, 9, size=(2.0, 1.5))
    fps = 24.0
    positions = []
    for i in range(1, frames + 1):
        pos = mesh.positions.copy()
        pos[:, 2] = 0.3 * np.sin(3.0 * pos[:, 0] + 0.5 * i) * (1.5 - pos[:, 1])
        pos[:, 0] += 0.01 * i
        positions.append(pos)
    folder.mkdir(parents=True, exist_ok=True)
    for name, up in (("pc2", "z"), ("mdd", "z"), ("usd", "y")):
        exporter = make_exporter(name)
        exporter.open(ExportContext(mesh=mesh, out_dir=folder, fps=fps, start_frame=start_frame, up_axis=up))
        for i, pos in enumerate(positions, start=1):
            exporter.write(FrameData(index=i, time=i / fps, positions=pos))
        exporter.close()
    np.savez(
        folder / "expected.npz",
        rest=convert_up_axis(mesh.positions, "z"),
        positions=np.stack([convert_up_axis(p, "z") for p in positions]),
        face_indices=mesh.face_indices,
        face_offsets=mesh.face_offsets,
        fps=fps,
        start_frame=start_frame,
    )


def check(folder: Path) -> int:
    """Inside Blender: load everything, compare per frame, print a table; 0 when all match."""
    import bpy

    data = np.load(folder / "expected.npz")
    rest, expected = data["rest"], data["positions"]
    offsets, indices = data["face_offsets"], data["face_indices"]
    start = int(data["start_frame"])
    frames = expected.shape[0]
    faces = [indices[offsets[k] : offsets[k + 1]].tolist() for k in range(len(offsets) - 1)]

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.fps = round(float(data["fps"]))
    scene.frame_start, scene.frame_end = start, start + frames - 1

    def world_positions(obj) -> np.ndarray:
        depsgraph = bpy.context.evaluated_depsgraph_get()
        evaluated = obj.evaluated_get(depsgraph)
        mesh = evaluated.to_mesh()
        co = np.empty(len(mesh.vertices) * 3)
        mesh.vertices.foreach_get("co", co)
        evaluated.to_mesh_clear()
        co = co.reshape(-1, 3)
        matrix = np.array(obj.matrix_world)
        return co @ matrix[:3, :3].T + matrix[:3, 3]

    objects = {}
    for fmt in ("PC2", "MDD"):
        mesh = bpy.data.meshes.new(f"sheet_{fmt}")
        mesh.from_pydata(rest.tolist(), [], faces)
        obj = bpy.data.objects.new(f"sheet_{fmt}", mesh)
        scene.collection.objects.link(obj)
        modifier = obj.modifiers.new("cache", "MESH_CACHE")
        modifier.cache_format = fmt
        modifier.filepath = str(folder / f"cache.{fmt.lower()}")
        if fmt == "PC2":  # Blender plays PC2 by frame and ignores the header's start: offset it here
            modifier.frame_start = float(start)
        else:  # MDD carries times in seconds: play by time
            modifier.time_mode = "TIME"
        objects[fmt] = obj
    before = set(bpy.data.objects)
    bpy.ops.wm.usd_import(filepath=str(folder / "scene.usdc"))
    usd_objects = [o for o in bpy.data.objects if o not in before and o.type == "MESH"]
    if usd_objects:
        objects["USD"] = usd_objects[0]

    worst = {name: 0.0 for name in objects}
    for k in range(frames):
        scene.frame_set(start + k)
        for name, obj in objects.items():
            got = world_positions(obj)
            if got.shape != expected[k].shape:
                print(f"{name}: frame {start + k}: {got.shape[0]} vertices, expected {expected[k].shape[0]}")
                worst[name] = float("inf")
                continue
            worst[name] = max(worst[name], float(np.abs(got - expected[k]).max()))
    print(f"Blender {bpy.app.version_string}, {frames} frames from {start}")
    status = 0
    for name in ("PC2", "MDD", "USD"):
        if name not in worst:
            print(f"  {name}: not loaded")
            status = 1
            continue
        ok = worst[name] <= TOLERANCE
        status |= not ok
        print(f"  {name}: max |difference| {worst[name]:.3g} {'ok' if ok else 'MISMATCH'}")
    return status


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument("--make", type=Path, metavar="DIR", help="write the test data into DIR")
    group.add_argument("--check", type=Path, metavar="DIR", help="compare inside Blender (needs bpy)")
    group.add_argument("--bpy-python", type=Path, help="a Python with bpy: make data, then check with it")
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--start-frame", type=int, default=1)
    args = parser.parse_args()
    if args.make:
        make(args.make, args.frames, args.start_frame)
    elif args.check:
        sys.exit(check(args.check))
    else:
        with tempfile.TemporaryDirectory() as tmp:
            make(Path(tmp), args.frames, args.start_frame)
            code = subprocess.call([str(args.bpy_python), __file__, "--check", tmp])
        sys.exit(code)


if __name__ == "__main__":
    main()
