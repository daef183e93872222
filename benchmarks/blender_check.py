"""Check a real bake against Blender at its default settings: OBJ importer, Mesh Cache modifier
(PC2, MDD), USD importer and glTF importer, scene frame by scene frame, for either `up_axis`.

Blender is never a dependency of meshdeform; it is the tool users would otherwise open, so it is the
yardstick (DESIGN.md section 8). Two steps, because `bpy` lives in a venv of its own:

    # with the meshdeform venv: bake, then check with Blender's Python
    .venv/bin/python benchmarks/blender_check.py --bpy-python /path/to/bpy-venv/bin/python [--start-frame 1]

    # or by hand
    .venv/bin/python benchmarks/blender_check.py --make DIR
    /path/to/bpy-venv/bin/python benchmarks/blender_check.py --check DIR

`--make` bakes a flag (a 12 x 9 grid pinned along one side, gravity and wind) with `meshdeform
simulate` into obj frames, `cache.pc2`, `cache.mdd`, `scene.usdc` and `scene.glb`, with `[output]
up_axis` "y", "z" or left at its default (`--up-axis y|z|default`), from a Y-up input (vertical in
XY) or a Z-up one (`--input-up z`: vertical in XZ, `simulation.up = "z"`; imported in Blender with
Up Z, Forward Y, the one importer setting not at its default).

`--check` imports, with every importer option and modifier setting at its default, the OBJ file of
every frame (the reference: what a user sees importing the frames), the USD stage and the glTF
scene, and puts a Mesh Cache modifier for each point cache on the object the caches are for, then at
every scene frame F compares evaluated world positions with those of the OBJ file of frame F:

- `up_axis` = the input's (the OBJ workflow): the caches go on the imported rest-pose OBJ. Blender's OBJ
  importer keeps the file's coordinates and turns the object to Z up (+90 degrees about X), and
  the modifier replaces the object's own coordinates, so the caches hold the OBJ's coordinates.
- `up_axis = "z"` from a Y-up input (the Blender-scene workflow): the caches go on a mesh in Blender's Z-up world
  with no turn on its object, the mesh the input OBJ was exported from by Blender's OBJ exporter at
  its defaults. The check makes it by applying the imported rest OBJ's rotation to its mesh
  (Blender's Apply Rotation), and proves it is that mesh by exporting it with Blender's OBJ exporter
  at its defaults: the written vertices equal the input's.
- USD carries `upAxis` (Y or Z) and its points in that world; Blender's importer turns a Y-up stage
  to Z up, so both agree with the OBJ frames.
- glTF is Y up by specification whatever `up_axis` (a Z-up input turned); Blender's importer
  converts it to Z up. glTF
  time 0 is the rest pose, and Blender keys glTF time t at scene frame t x 24 from frame 0 (its
  fps is not changed by the import), so scene frame F of the OBJ frames is glTF frame
  (F - start) at Blender frame (F - start) x 24 / fps.

Exit status 1 when any difference exceeds 1e-5 m. Not run in CI
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
up = "{input_up}"

[[pins]]
select = {{ box = {{ min = [-1, -1, -1], max = [0.001, 2, 1] }} }}

[wind]
velocity = [2.0, 0.0, 1.0]

[output]
formats = ["obj", "pc2", "mdd", "usd", "gltf"]
{up_axis_line}
"""


def make(folder: Path, frames: int, start_frame: int, up_axis: str | None = "y", input_up: str = "y") -> None:
    """Bake the flag with the meshdeform command line into `folder`/out: a Y-up input (vertical in XY)
    or a Z-up one (`input_up = "z"`: vertical in XZ, `simulation.up = "z"`); `up_axis` None leaves
    `[output] up_axis` at its default."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from dataclasses import replace

    from meshdeform.io import save
    from meshdeform.mesh import grid_mesh

    folder.mkdir(parents=True, exist_ok=True)
    flag = grid_mesh(12, 9, size=(1.2, 0.9))
    if input_up == "z":  # the same flag standing in a Z-up world: (x, y, z) -> (x, -z, y)
        p = flag.positions
        flag = replace(flag, positions=np.stack([p[:, 0], -p[:, 2], p[:, 1]], axis=1))
    save(folder / "flag.obj", flag)
    line = "" if up_axis is None else f'up_axis = "{up_axis}"'
    recipe = RECIPE.format(frames=frames, start_frame=start_frame, up_axis_line=line, input_up=input_up)
    (folder / "flag.toml").write_text(recipe)
    subprocess.run(
        [sys.executable, "-c", "from pipeline.cli import app; app()", "simulate", str(folder / "flag.obj"),
         "-r", str(folder / "flag.toml"), "--out", str(folder / "out"), "--quiet"],
        check=True,
    )  # fmt: skip


def obj_vertices(path: Path) -> np.ndarray:
    """The `v` lines of an OBJ file, (V, 3) in metres, read as text (independent of any importer)."""
    rows = [line.split()[1:4] for line in path.read_text().splitlines() if line.startswith("v ")]
    return np.array(rows, dtype=np.float64)


def check(folder: Path) -> int:
    """Inside Blender: import everything at default settings, compare per scene frame; 0 when all match."""
    import tomllib

    import bpy

    recipe = tomllib.loads((folder / "flag.toml").read_text())
    fps = float(recipe["simulation"]["fps"])
    input_up = recipe["simulation"].get("up", "y")
    up_axis = recipe["output"].get("up_axis", input_up)
    out = folder / "out"
    files = sorted((out / "frames").glob("frame_*.obj"))
    numbers = [int(f.stem.split("_")[1]) for f in files]
    start, last = numbers[0], numbers[-1]

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.fps = int(fps)
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

    def new_objects(importer, path: Path) -> list:
        before = set(bpy.data.objects)
        importer(filepath=str(path))
        return [o for o in bpy.data.objects if o not in before and o.type == "MESH"]

    def obj_importer(filepath: str) -> None:  # a Z-up file is imported as Z up (the one non-default)
        axes = {"forward_axis": "Y", "up_axis": "Z"} if input_up == "z" else {}
        bpy.ops.wm.obj_import(filepath=filepath, **axes)

    def import_obj(path: Path):
        (obj,) = new_objects(obj_importer, path)
        return obj

    def select_only(obj) -> None:
        for other in bpy.context.view_layer.objects:
            other.select_set(other is obj)
        bpy.context.view_layer.objects.active = obj

    expected = {}
    for number, path in zip(numbers, files, strict=True):  # Blender's own reading of every OBJ frame
        obj = import_obj(path)
        expected[number] = world_positions(obj)
        bpy.data.objects.remove(obj)
    notes = []
    status = 0
    objects = {}
    for fmt in ("PC2", "MDD"):
        obj = import_obj(files[0])
        if up_axis == "z" and input_up == "y":  # the Z-up mesh the input was exported from: the turn applied
            select_only(obj)
            bpy.ops.object.transform_apply(location=False, rotation=True, scale=False)
            if fmt == "PC2":
                exported = folder / "exported_from_blender.obj"
                bpy.ops.wm.obj_export(filepath=str(exported), export_selected_objects=True)
                gap = float(np.abs(obj_vertices(exported) - obj_vertices(files[0])).max())
                notes.append(f"the Z-up mesh exported by Blender's OBJ exporter: max |v - input v| {gap:.3g} m")
                status |= gap > TOLERANCE
        modifier = obj.modifiers.new("cache", "MESH_CACHE")  # every setting at its default
        modifier.cache_format = fmt
        modifier.filepath = str(out / f"cache.{fmt.lower()}")
        objects[fmt] = obj
    usd_objects = new_objects(bpy.ops.wm.usd_import, out / "scene.usdc")
    if usd_objects:
        objects["USD"] = usd_objects[0]
    gltf_objects = new_objects(bpy.ops.import_scene.gltf, out / "scene.glb")

    worst = {name: 0.0 for name in (*objects, "glTF")}

    def compare(name: str, got: np.ndarray, want: np.ndarray, number: int) -> None:
        if got.shape != want.shape:
            print(f"{name}: frame {number}: {got.shape[0]} vertices, expected {want.shape[0]}")
            worst[name] = float("inf")
            return
        worst[name] = max(worst[name], float(np.abs(got - want).max()))

    for number in numbers:
        scene.frame_set(number)
        for name, obj in objects.items():
            compare(name, world_positions(obj), expected[number], number)
    if gltf_objects:
        for number in numbers:
            frame = (number - start) * 24.0 / fps  # Blender keys glTF time t at frame t * 24, from 0
            scene.frame_set(int(np.floor(frame)), subframe=float(frame - np.floor(frame)))
            got = world_positions(gltf_objects[0])[: expected[number].shape[0]]  # seam copies follow
            compare("glTF", got, expected[number], number)
    else:
        worst["glTF"] = float("inf")
    rest_moved = float(np.abs(expected[numbers[1]] - expected[start]).max())
    print(
        f"Blender {bpy.app.version_string}, input up {input_up}, up_axis {up_axis}, OBJ frames {start} to {last} "
        f"(frame {start} is the rest pose)"
    )
    for name in ("PC2", "MDD", "USD", "glTF"):
        if name not in worst or worst[name] == float("inf"):
            print(f"  {name}: not loaded or wrong vertex count")
            status = 1
            continue
        ok = worst[name] <= TOLERANCE
        status |= not ok
        verdict = "ok" if ok else "MISMATCH"
        print(f"  {name}: max |difference| to the OBJ of the same scene frame {worst[name]:.3g} m {verdict}")
    for note in notes:
        print(f"  {note}")
    print(f"  (one frame apart the OBJ frames differ by up to {rest_moved:.3g} m)")
    return int(status)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument("--make", type=Path, metavar="DIR", help="write the test data into DIR")
    group.add_argument("--check", type=Path, metavar="DIR", help="compare inside Blender (needs bpy)")
    group.add_argument("--bpy-python", type=Path, help="a Python with bpy: make data, then check with it")
    parser.add_argument("--frames", type=int, default=12)
    parser.add_argument("--start-frame", type=int, default=1)
    parser.add_argument("--up-axis", choices=("y", "z", "default"), default="y", help="the recipe's [output] up_axis")
    parser.add_argument("--input-up", choices=("y", "z"), default="y", help="the input's up axis (simulation.up)")
    args = parser.parse_args()
    up_axis = None if args.up_axis == "default" else args.up_axis
    if args.make:
        make(args.make, args.frames, args.start_frame, up_axis, args.input_up)
    elif args.check:
        sys.exit(check(args.check))
    else:
        with tempfile.TemporaryDirectory() as tmp:
            make(Path(tmp), args.frames, args.start_frame, up_axis, args.input_up)
            code = subprocess.call([str(args.bpy_python), __file__, "--check", tmp])
        sys.exit(code)


if __name__ == "__main__":
    main()
