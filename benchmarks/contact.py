"""Contact side by side: meshdeform with and without self-collision and Blender's cloth, in one run.

    python benchmarks/contact.py --blender-python /path/to/venv-with-bpy/bin/python [--frames 60] [--repeats 3] [--n 40]

Three scenes, each a 40 x 40 (`--n`) vertex sheet of 1 x 1 m (quads), 24 fps, gravity only (Y up here):

- drop: the sheet held flat 0.5 m up, dropped onto a sphere (r 0.15 m) resting on the ground;
- collapse: the sheet standing upright on the ground with a 1 cm ripple (two waves up its height),
  collapsing onto the ground in folds;
- fold: the sheet dropped flat onto a thin bar (4 cm wide, 70 cm up), off centre, so its two
  unequal halves swing down past the vertical and into each other under the bar.

Sides, each on the same vertices and quads:

- meshdeform through its CLI (`simulate` with a recipe written to a temporary folder, `npz` output
  read back), each of `--solvers` (default xpbd) at its defaults, `[self_collision]` off and on;
  the same process runs once untimed first so that Numba's cache is warm.
- Blender's cloth modifier through `bpy` (pip install bpy, in a venv of its own: it is never a
  dependency of meshdeform) with self-collision on; the colliders are meshes with a collision
  modifier (a 50 m plane, a 64 x 32 UV sphere, an 8-vertex box), Blender's default cloth otherwise.
  The scene is built Z up (x, -z, y) and its vertices read back into Y up.

The sides run in rounds, one run of each side a round (`--repeats` rounds, after meshdeform's
untimed warm-up runs), so that a machine whose speed drifts during the minutes of a scene slows
both sides of a round alike. Printed per scene and side: frames/s of the simulated frames alone
(meshdeform: report.json's `seconds`; Blender: the `frame_set` calls from frame 2 on, frame 1
being the rest pose), the median of the rounds; x Blender, the median of the rounds' ratios to
Blender's run of the same round; the worst structural stretch (a quad side's length over its rest length)
over the frames; the largest count over frames of intersecting triangle pairs that share no
vertex (tests/intersections.py, decided by ipctk; quads split along their 0-2 diagonal) and the
frame it occurs in; the smallest distance over frames of any cloth vertex to each collider's
exact surface minus the collider's thickness (negative: closer than the thickness), in mm; and
the ratios meshdeform self-collision off/on frames/s (its cost) and meshdeform/Blender frames/s.

Contact distances: meshdeform colliders keep `thickness` (10 mm) and self-collision keeps
`SELF_THICKNESS` (5 mm). Blender keeps its cloth's `distance_min` plus the collider's
`thickness_outer` from a collider (tried on the drop scene: 10 + 20 mm and 30 + 1 mm both settle at
26-31 mm), so its colliders get `thickness_outer` = 1 mm (its minimum) and its cloth
`distance_min` = 10 - 1 = 9 mm, and `self_distance_min` = 5 mm. Not run in CI.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import statistics
import subprocess
import sys
import tempfile
import textwrap
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from meshdeform.io import write_obj  # noqa: E402
from meshdeform.mesh import Mesh, grid_mesh  # noqa: E402

N = 40  # vertices along each side of the sheet (`--n`)
FPS = 24
COLLIDER_THICKNESS = 0.01  # m, kept by the cloth from every collider
COLLIDER_FRICTION = 0.3
SELF_THICKNESS = 0.005  # m, kept between non-neighbouring parts of the cloth
SELF_FRICTION = 0.2
BLENDER_OUTER_THICKNESS = 0.001  # m, Blender's smallest collider `thickness_outer`


def _load_oracle() -> Callable[[np.ndarray, np.ndarray], int]:
    """tests/intersections.py's `intersecting_pairs`, imported by path (tests/ is no package)."""
    spec = importlib.util.spec_from_file_location("intersections", REPO / "tests" / "intersections.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.intersecting_pairs


@dataclass(frozen=True)
class Collider:
    """One obstacle, Y up: `shape` "ground" (height), "sphere" (center, radius) or "box" (min, max)."""

    shape: str
    values: dict[str, float | tuple[float, float, float]]
    thickness: float = COLLIDER_THICKNESS
    friction: float = COLLIDER_FRICTION

    def recipe(self) -> str:
        """Its `[[colliders]]` table."""
        fields = ", ".join(f"{key} = {_toml(value)}" for key, value in self.values.items())
        return (
            f"[[colliders]]\n{self.shape} = {{ {fields} }}\nfriction = {self.friction}\nthickness = {self.thickness}\n"
        )

    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        """(..., 3) points -> (...) distance to the exact surface, negative inside (m)."""
        if self.shape == "ground":
            return points[..., 1] - float(self.values["height"])
        if self.shape == "sphere":
            return np.linalg.norm(points - np.asarray(self.values["center"]), axis=-1) - float(self.values["radius"])
        low, high = np.asarray(self.values["min"]), np.asarray(self.values["max"])
        centre, half = (low + high) / 2, (high - low) / 2
        q = np.abs(points - centre) - half
        return np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(q.max(axis=-1), 0.0)

    def blender(self) -> dict:
        """Its description for the Blender side, Z up."""
        if self.shape == "ground":
            return {"shape": "ground", "height": float(self.values["height"])}
        if self.shape == "sphere":
            return {"shape": "sphere", "center": _z_up(self.values["center"]), "radius": float(self.values["radius"])}
        low, high = _z_up(self.values["min"]), _z_up(self.values["max"])
        return {"shape": "box", "min": np.minimum(low, high).tolist(), "max": np.maximum(low, high).tolist()}


@dataclass(frozen=True)
class ContactScene:
    """A sheet (positions (V, 3) Y up, quads (Q, 4) int) and its colliders."""

    name: str
    summary: str
    positions: np.ndarray
    quads: np.ndarray
    colliders: tuple[Collider, ...]

    def triangles(self) -> np.ndarray:
        """(2Q, 3): each quad split along its 0-2 diagonal, for the intersection count."""
        return np.concatenate([self.quads[:, [0, 1, 2]], self.quads[:, [0, 2, 3]]])


def _toml(value: float | tuple[float, float, float]) -> str:
    return f"[{', '.join(repr(float(v)) for v in value)}]" if isinstance(value, tuple) else repr(float(value))


def _z_up(value: object) -> list[float]:
    x, y, z = (float(v) for v in value)  # type: ignore[union-attr]
    return [x, -z, y]


def _sheet(plane: str, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The n x n grid over 1 m in `plane` ("xz" flat, "xy" upright) and its quads."""
    mesh = grid_mesh(n, n, size=(1.0, 1.0), plane=plane)
    return mesh.positions.copy(), mesh.face_indices.reshape(-1, 4)


def scenes(n: int = N) -> tuple[ContactScene, ...]:
    """The three scenes of the module docstring."""
    ground = Collider("ground", {"height": 0.0})
    flat, quads = _sheet("xz", n)
    drop = flat + [-0.5, 0.5, -0.5]
    upright, _ = _sheet("xy", n)
    collapse = upright + [-0.5, 0.02, 0.0]
    collapse[:, 2] = 0.01 * np.sin(4.0 * np.pi * upright[:, 1])
    fold = flat + [-0.4, 0.8, -0.5]
    return (
        ContactScene(
            "drop",
            "dropped flat from 0.5 m onto a sphere (r 0.15 m) on the ground",
            drop,
            quads,
            (Collider("sphere", {"center": (0.0, 0.15, 0.0), "radius": 0.15}), ground),
        ),
        ContactScene("collapse", "standing upright on the ground, collapsing in folds", collapse, quads, (ground,)),
        ContactScene(
            "fold",
            "dropped off centre onto a 4 cm bar 0.7 m up, its halves swinging into each other",
            fold,
            quads,
            (Collider("box", {"min": (-0.02, 0.66, -0.7), "max": (0.02, 0.7, 0.7)}), ground),
        ),
    )


@dataclass
class Side:
    """One side's outcome on one scene: frames/s of each repetition and the first run's frames."""

    label: str
    frames_per_second: list[float]
    positions: np.ndarray | None  # (frames, V, 3) Y up
    #: self-collision's work in the first timed run, summed over its frames (report.json's
    #: `self_collision` lists: pair_builds, projections, flagged_pairs, zone_rounds, unresolved), the
    #: largest zone its largest
    work: dict[str, int] = field(default_factory=dict)

    @property
    def median(self) -> float:
        return statistics.median(self.frames_per_second)

    def paired_ratio(self, base: Side) -> float:
        """The median over the rounds of this side's frames/s over `base`'s in the same round."""
        return statistics.median(a / b for a, b in zip(self.frames_per_second, base.frames_per_second, strict=True))

    def then(self, later: Side) -> Side:
        """This side with a later round's runs added (the first round's frames and work kept)."""
        return Side(self.label, [*self.frames_per_second, *later.frames_per_second], self.positions, self.work)


# ---------------------------------------------------------------------------------------------- meshdeform


def recipe(scene: ContactScene, frames: int, self_collision: bool, solver: str = "xpbd") -> str:
    """The recipe of one meshdeform run: `solver` at its defaults, or a spec `name:key=value:...`
    whose `substeps` and `iterations` go to [simulation], `stretch_modulus` to [material] and other
    keys to the solver's own table (e.g. `implicit:substeps=2:iterations=4:coarse=5`)."""
    name, *fields = solver.split(":")
    common, own, material = [], [], []
    for item in fields:
        key, _, value = item.partition("=")
        table = common if key in ("substeps", "iterations") else material if key == "stretch_modulus" else own
        table.append(f"{key} = {value}\n")
    text = f'[simulation]\nsolver = "{name}"\nfps = {FPS}\nframes = {frames}\n{"".join(common)}\n'
    if own:
        text += f"[simulation.{name}]\n{''.join(own)}\n"
    if material:
        text += f"[material]\n{''.join(material)}\n"
    text += "\n".join(collider.recipe() for collider in scene.colliders)
    if self_collision:
        text += f"\n[self_collision]\nthickness = {SELF_THICKNESS}\nfriction = {SELF_FRICTION}\n"
    return text + '\n[output]\nformats = ["npz"]\n'


def run_meshdeform(
    scene: ContactScene, frames: int, repeats: int, self_collision: bool, folder: Path, solver: str = "xpbd",
    warm: bool = True, round_tag: int = 0,
) -> Side:
    """`simulate` through the CLI, once untimed to warm the cache (where `warm`), then `repeats`
    timed runs (their files tagged with `round_tag`)."""
    label = f"meshdeform {solver}, self-collision {'on' if self_collision else 'off'}"
    mesh = Mesh(
        positions=scene.positions,
        face_indices=scene.quads.ravel().astype(np.int64),
        face_offsets=np.arange(0, scene.quads.size + 1, 4, dtype=np.int64),
    )
    tag = f"{scene.name}_{solver}_{'on' if self_collision else 'off'}_{round_tag}"
    obj = folder / f"{scene.name}.obj"
    write_obj(obj, mesh)
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep),
    }
    rates: list[float] = []
    positions = None
    work: dict[str, int] = {}
    for run in range(0 if warm else 1, repeats + 1):
        toml = folder / f"{tag}_{run}.toml"
        toml.write_text(recipe(scene, 2 if run == 0 else frames, self_collision, solver))
        out = folder / f"{tag}_{run}"
        command = [sys.executable, "-c", "from pipeline.cli import app; app()", "simulate", str(obj)]
        proc = subprocess.run(
            [*command, "-r", str(toml), "-o", str(out), "-q"], capture_output=True, text=True, env=env, check=False
        )
        if proc.returncode != 0:
            raise SystemExit(f"meshdeform failed on {scene.name} ({proc.returncode}): {proc.stderr.strip()[-2000:]}")
        if run == 0:
            continue
        report = json.loads((out / "report.json").read_text())
        rates.append(report["frames"] / report["seconds"])
        if positions is None:
            with np.load(out / "positions.npz") as data:
                positions = data["positions"].astype(np.float64)
            lists = report.get("self_collision", {})
            work = {
                key: max(values, default=0) if key == "largest_zone" else sum(values)
                for key, values in lists.items()
                if isinstance(values, list)
            }
    return Side(label, rates, positions, work=work)


# ---------------------------------------------------------------------------------------------- Blender

BLENDER_SIDE = textwrap.dedent(
    """
    import json, sys, time
    import bpy
    import numpy as np

    spec = json.loads(open(sys.argv[-2]).read())
    out = sys.argv[-1]
    frames = spec["frames"]
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.fps = spec["fps"]
    scene.frame_start, scene.frame_end = 1, frames + 1

    def add_mesh(name, vertices, faces):
        mesh = bpy.data.meshes.new(name)
        mesh.from_pydata(vertices, [], faces)
        mesh.update()
        obj = bpy.data.objects.new(name, mesh)
        scene.collection.objects.link(obj)
        return obj

    for k, c in enumerate(spec["colliders"]):
        if c["shape"] == "ground":
            bpy.ops.mesh.primitive_plane_add(size=50.0, location=(0.0, 0.0, c["height"]))
            obj = bpy.context.active_object
        elif c["shape"] == "sphere":
            bpy.ops.mesh.primitive_uv_sphere_add(segments=64, ring_count=32, radius=c["radius"], location=c["center"])
            obj = bpy.context.active_object
        else:
            (x0, y0, z0), (x1, y1, z1) = c["min"], c["max"]
            corners = [(x, y, z) for z in (z0, z1) for y in (y0, y1) for x in (x0, x1)]
            sides = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
            obj = add_mesh(f"box{k}", corners, sides)
        obj.modifiers.new("collision", "COLLISION")
        obj.collision.thickness_outer = spec["outer_thickness"]

    sheet = add_mesh("sheet", spec["vertices"], spec["quads"])
    cloth = sheet.modifiers.new("cloth", "CLOTH")
    cloth.collision_settings.use_collision = True
    cloth.collision_settings.distance_min = spec["thickness"]
    cloth.collision_settings.use_self_collision = spec["self_collision"]
    cloth.collision_settings.self_distance_min = spec["self_thickness"]
    cloth.point_cache.frame_start, cloth.point_cache.frame_end = 1, frames + 1
    count = len(spec["vertices"])
    positions = np.empty((frames, count * 3))
    seconds = 0.0
    scene.frame_set(1)  # the rest pose
    for f in range(2, frames + 2):
        start = time.perf_counter()
        scene.frame_set(f)
        seconds += time.perf_counter() - start
        evaluated = sheet.evaluated_get(bpy.context.evaluated_depsgraph_get())
        evaluated.data.vertices.foreach_get("co", positions[f - 2])
    np.save(out, positions.reshape(frames, count, 3))
    print(json.dumps({"seconds": seconds, "frames": frames, "version": bpy.app.version_string}))
    """
)


def run_blender(
    python: str, scene: ContactScene, frames: int, repeats: int, folder: Path, round_tag: int = 0
) -> Side:
    """Blender's cloth with self-collision on, `repeats` runs, each in a fresh interpreter (their
    files tagged with `round_tag`)."""
    spec = {
        "frames": frames,
        "fps": FPS,
        "vertices": [_z_up(p) for p in scene.positions],
        "quads": scene.quads.tolist(),
        "colliders": [c.blender() for c in scene.colliders],
        "thickness": COLLIDER_THICKNESS - BLENDER_OUTER_THICKNESS,
        "self_thickness": SELF_THICKNESS,
        "outer_thickness": BLENDER_OUTER_THICKNESS,
        "self_collision": True,
    }
    spec_path = folder / f"{scene.name}_blender.json"
    spec_path.write_text(json.dumps(spec))
    rates: list[float] = []
    positions = None
    version = ""
    for run in range(repeats):
        out = folder / f"{scene.name}_blender_{round_tag}_{run}.npy"
        proc = subprocess.run(
            [python, "-c", BLENDER_SIDE, str(spec_path), str(out)], capture_output=True, text=True, check=False
        )
        lines = [line for line in proc.stdout.splitlines() if line.startswith("{")]
        if proc.returncode != 0 or not lines:
            raise SystemExit(f"blender side failed on {scene.name} ({proc.returncode}): {proc.stderr.strip()[-2000:]}")
        result = json.loads(lines[-1])
        version = result["version"]
        rates.append(result["frames"] / result["seconds"])
        if positions is None:
            z_up = np.load(out)
            positions = np.stack([z_up[..., 0], z_up[..., 2], -z_up[..., 1]], axis=-1)
    return Side(f"blender {version}, self-collision on", rates, positions)


# ---------------------------------------------------------------------------------------------- report


def describe(
    scene: ContactScene, side: Side, oracle: Callable[[np.ndarray, np.ndarray], int], base: Side | None
) -> str:
    """One table row: frames/s, x Blender (the rounds' paired ratios' median), worst structural
    stretch over the frames, max intersecting pairs (frame), clearance per collider."""
    assert side.positions is not None
    triangles = scene.triangles()
    counts = [oracle(frame, triangles) for frame in side.positions]
    worst = int(np.argmax(counts))
    at = f"{worst + 1:6d}" if counts[worst] else f"{'-':>6s}"
    clearance = [1000.0 * (float(c.signed_distance(side.positions).min()) - c.thickness) for c in scene.colliders]
    ratio = f"{side.paired_ratio(base):9.2f}" if base else f"{'-':>9s}"
    gaps = "  ".join(f"{value:8.2f}" for value in clearance)
    stretch = max(structural_stretch(scene, frame) for frame in side.positions)
    return f"  {side.label:40s} {side.median:9.1f} {ratio} {stretch:8.3f} {counts[worst]:9d} {at}   {gaps}"


def structural_stretch(scene: ContactScene, positions: np.ndarray) -> float:
    """The largest length over rest length of the grid's edges (the quads' sides) at positions (V, 3)."""
    edges = np.concatenate([scene.quads[:, [k, (k + 1) % 4]] for k in range(4)])
    rest = np.linalg.norm(scene.positions[edges[:, 0]] - scene.positions[edges[:, 1]], axis=1)
    return float((np.linalg.norm(positions[edges[:, 0]] - positions[edges[:, 1]], axis=1) / rest).max())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--blender-python", help="a Python with `bpy` installed (Blender skipped when not given)")
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--scenes", default="drop,collapse,fold", help="comma-separated scene names")
    parser.add_argument("--save", type=Path, help="write each side's frames (Y up) to DIR/<scene>_<side>.npy")
    parser.add_argument(
        "--solvers", default="xpbd",
        help="comma-separated meshdeform solvers, each at its defaults or as name:key=value:... (see `recipe`)",
    )
    parser.add_argument("--n", type=int, default=N, help="vertices along each side of the sheet (a finer cloth)")
    args = parser.parse_args()
    oracle = _load_oracle()
    wanted = args.scenes.split(",")
    chosen = [s for s in scenes(args.n) if s.name in wanted]
    print(f"{args.n} x {args.n} sheet, 1 m, {args.frames} frames at {FPS} fps, medians of {args.repeats} rounds")
    print(f"collider thickness {1000 * COLLIDER_THICKNESS:g} mm, self-collision thickness {1000 * SELF_THICKNESS:g} mm")
    with tempfile.TemporaryDirectory(prefix="meshdeform-contact-") as tmp:
        folder = Path(tmp)
        for scene in chosen:
            runs: dict[str, Side] = {}
            for round_tag in range(args.repeats):  # a run of each side a round (the module docstring)
                this_round: dict[str, Side] = {}
                for solver in args.solvers.split(","):
                    for self_collision in (False, True):
                        this_round[f"{solver}_{'on' if self_collision else 'off'}"] = run_meshdeform(
                            scene, args.frames, 1, self_collision, folder, solver, round_tag == 0, round_tag
                        )
                if args.blender_python:
                    this_round["blender"] = run_blender(args.blender_python, scene, args.frames, 1, folder, round_tag)
                runs = {key: runs[key].then(side) if key in runs else side for key, side in this_round.items()}
            base = runs.get("blender")
            names = "  ".join(f"{c.shape:>8s}" for c in scene.colliders)
            print(f"\n{scene.name}: {scene.summary}")
            heading = f"{'side':40s} {'frames/s':>9s} {'x blender':>9s} {'stretch':>8s} {'max pairs':>9s} {'frame':>6s}"
            print(f"  {heading}   clearance mm: {names}")
            for key, side in runs.items():
                print(describe(scene, side, oracle, base))
                if args.save and side.positions is not None:
                    args.save.mkdir(parents=True, exist_ok=True)
                    np.save(args.save / f"{scene.name}_{key}.npy", side.positions)
            for solver in args.solvers.split(","):
                off, on = runs[f"{solver}_off"], runs[f"{solver}_on"]
                print(f"  {solver}: self-collision cost (frames/s off / on): {off.paired_ratio(on):.2f}x")
                done = ", ".join(f"{key} {value}" for key, value in on.work.items())
                print(f"  {solver}: self-collision work over the {args.frames} frames: {done}")
            sys.stdout.flush()


if __name__ == "__main__":
    main()
