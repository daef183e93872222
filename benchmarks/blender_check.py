"""Check a real bake against Blender at its default settings: OBJ importer, Mesh Cache modifier
(PC2, MDD) and USD importer, scene frame by scene frame.

Blender is never a dependency of meshdeform; it is the tool users would otherwise open, so it is the
yardstick (DESIGN.md section 8). Two steps, because `bpy` lives in a venv of its own:

    # with the meshdeform venv: bake, then check with Blender's Python
    .venv/bin/python benchmarks/blender_check.py --bpy-python /path/to/bpy-venv/bin/python [--start-frame 1]

    # or by hand
    .venv/bin/python benchmarks/blender_check.py --make DIR
    /path/to/bpy-venv/bin/python benchmarks/blender_check.py --check DIR

`--make` bakes a flag (a 12 x 9 grid pinned along one side, gravity and wind) with `meshdeform
simulate` into obj frames, `cache.pc2`, `cache.mdd` and `scene.usdc` with the default `up_axis =
"y"`: Blender's OBJ importer keeps the file's coordinates and turns the object to Z up (a +90 degree
rotation about X), so the caches for it hold the OBJ's own coordinates (`up_axis = "z"` caches are
for a mesh made in Blender's Z-up world, which the importer's object is not). `--check` imports,
with every importer option and modifier setting at its default, the rest-pose OBJ (the file of the
start frame) and puts a Mesh Cache modifier for each cache on a copy of it, imports the USD stage,
and at every scene frame F compares the evaluated world positions with those of the OBJ file of
frame F imported by Blender. Exit status 1 when any difference exceeds 1e-5 m. Not run in CI
(tests/test_blender.py runs it where a Python with bpy is named by MESHDEFORM_BPY_PYTHON)."""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

TOLERANCE = 1e-5


RECIPE = """
[simulation]
fps = 24
frames = {frames}
start_frame = {start_frame}

[[pins]]
select = {{ box = {{ min = [-1, -1, -1], max = [0.001, 2, 1] }} }}

[wind]
velocity = [2.0, 0.0, 1.0]

[output]
formats = ["obj", "pc2", "mdd", "usd"]
up_axis = "{up_axis}"
"""


def make(folder: Path, frames: int, start_frame: int, up_axis: str = "y") -> None:
    """Bake the flag with the meshdeform command line into `folder`/out."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from meshdeform.io import save
    from meshdeform.mesh import grid_mesh

    folder.mkdir(parents=True, exist_ok=True)
    save(folder / "flag.obj", grid_mesh(12, 9, size=(1.2, 0.9)))
    (folder / "flag.toml").write_text(RECIPE.format(frames=frames, start_frame=start_frame, up_axis=up_axis))
    subprocess.run(
        [sys.executable, "-c", "from pipeline.cli import app; app()", "simulate", str(folder / "flag.obj"),
         "-r", str(folder / "flag.toml"), "--out", str(folder / "out"), "--quiet"],
        check=True,
    )  # fmt: skip


def check(folder: Path) -> int:
    """Inside Blender: import everything at default settings, compare per scene frame; 0 when all match."""
    import bpy

    out = folder / "out"
    files = sorted((out / "frames").glob("frame_*.obj"))
    numbers = [int(f.stem.split("_")[1]) for f in files]
    start, last = numbers[0], numbers[-1]

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.fps = 24
    scene.frame_start, scene.frame_end = start, last

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

    def import_obj(path: Path):
        before = set(bpy.data.objects)
        bpy.ops.wm.obj_import(filepath=str(path))
        (obj,) = [o for o in bpy.data.objects if o not in before]
        return obj

    expected = {}
    for number, path in zip(numbers, files, strict=True):  # Blender's own reading of every OBJ frame
        obj = import_obj(path)
        expected[number] = world_positions(obj)
        bpy.data.objects.remove(obj)
    objects = {}
    for fmt in ("PC2", "MDD"):
        obj = import_obj(files[0])
        modifier = obj.modifiers.new("cache", "MESH_CACHE")  # every setting at its default
        modifier.cache_format = fmt
        modifier.filepath = str(out / f"cache.{fmt.lower()}")
        objects[fmt] = obj
    before = set(bpy.data.objects)
    bpy.ops.wm.usd_import(filepath=str(out / "scene.usdc"))
    usd_objects = [o for o in bpy.data.objects if o not in before and o.type == "MESH"]
    if usd_objects:
        objects["USD"] = usd_objects[0]

    worst = {name: 0.0 for name in objects}
    for number in numbers:
        scene.frame_set(number)
        for name, obj in objects.items():
            got = world_positions(obj)
            if got.shape != expected[number].shape:
                print(f"{name}: frame {number}: {got.shape[0]} vertices, expected {expected[number].shape[0]}")
                worst[name] = float("inf")
                continue
            worst[name] = max(worst[name], float(np.abs(got - expected[number]).max()))
    rest_moved = float(np.abs(expected[numbers[1]] - expected[start]).max())
    print(f"Blender {bpy.app.version_string}, OBJ frames {start} to {last} (frame {start} is the rest pose)")
    status = 0
    for name in ("PC2", "MDD", "USD"):
        if name not in worst:
            print(f"  {name}: not loaded")
            status = 1
            continue
        ok = worst[name] <= TOLERANCE
        status |= not ok
        verdict = "ok" if ok else "MISMATCH"
        print(f"  {name}: max |difference| to the OBJ of the same scene frame {worst[name]:.3g} m {verdict}")
    print(f"  (one frame apart the OBJ frames differ by up to {rest_moved:.3g} m)")
    return status


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument("--make", type=Path, metavar="DIR", help="write the test data into DIR")
    group.add_argument("--check", type=Path, metavar="DIR", help="compare inside Blender (needs bpy)")
    group.add_argument("--bpy-python", type=Path, help="a Python with bpy: make data, then check with it")
    parser.add_argument("--frames", type=int, default=12)
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
