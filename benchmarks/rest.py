"""When damped scenes come to rest, for every registered solver, and where the stress ball ends.

    PYTHONPATH=<tree> python benchmarks/rest.py [--seconds 15] [--solvers implicit xpbd ...] [--scenes ...]
                                                [--raise -0.05 0 0.05 0.1]

Scenes (recipes at their defaults, air damping 0.9, built as `meshdeform simulate` builds them:
`pipeline.build.build_simulation`, then `meshdeform.simulate`), 24 fps:
- cloth: a 12 x 12 sheet of 1 m lying flat (XZ), two corners of one edge pinned;
- ball: samples/meshes/icosphere.ply (radius 0.5 m), no gravity, struck at the front by the sample
  stress ball's first impact (2 m/s along the normal); for `anchor` in both anchor frames;
- box: a 0.3 m cube of 8 vertices and 12 triangles (trimesh's box), its bottom 0.5 m above the
  ground (a light, stiff, closed solid);
- sheet on ball / sheet on big ball: a 20 x 20 / 32 x 32 sheet of 1 m, flat, 0.1 m (plus each
  `--raise`) above a ball of radius 0.25 / 0.45 m lying on the ground (friction 0.3);
- sheet laid on ball: a 12 x 12 sheet of 0.4 m, flat, 2 cm above a ball of radius 0.45 m, friction
  0.5, no ground (its edges lie at 26 degrees: friction holds it);
- slope: a 12 x 12 sheet of 1 m lying on a plane tilted 20 degrees, friction 0.5 (more than
  tan 20 = 0.36: static friction should hold it);
- crumpled sheet: a 24 x 24 sheet of 1 m lying on the ground (friction 0.5), self-collision on,
  two opposite edges pinned and pushed 0.3 m each towards the other over 1.5 s, then held;
- corner landing: one triangle of 3.45 cm legs (a shredded sheet's piece) dropped from 0.3 m onto
  the ground (friction 0.3), one corner 2 cm and another 1 cm higher than the lowest.

Prints per solver and scene the reported rest frame (`Frame.rest_frame` of the last frame, the
report's `rest_frame`) and its time, the largest distance a vertex covers between two frames from
it on times the fps (m/s, to hold against the rest speed 1e-4 m/s); the last frame's largest speed;
for the ball the largest distance of a vertex from its rest position at the end, over the radius,
and that of its centre of mass; for the box the highest the lowest vertex rose after it first came
within 2 cm of the ground (m); for the sheets on balls the highest vertex at the end (m: on the ball,
or slid off onto the ground, or fallen below it without one); for the slope how far the sheet's
centre moved along the slope (m); for the crumpled sheet its highest vertex at the end (m); for the
corner landing the highest any corner rose in the last second (m: 0.005, its thickness, at rest).
Figures go to docs/recipes.md ("Coming to rest") and docs/performance.md.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from meshdeform.io import load
from meshdeform.mesh import Mesh, grid_mesh
from meshdeform.simulate import simulate
from meshdeform.solvers import SOLVERS
from pipeline.build import BuiltSimulation, build_simulation
from pipeline.recipe import parse_recipe

FPS = 24
RADIUS = 0.5
BALL = Path(__file__).resolve().parent.parent / "samples" / "meshes" / "icosphere.ply"
STRIKE = (
    "[[impacts]]\ntime = 0.1\nray = { origin = [0, 0, 2], direction = [0, 0, -1] }\n"
    'radius = 0.15\nstrength = 2.0\nduration = 0.05\ndirection = "normal"\n'
)


#: the figure printed after the rest columns: (positions (F + 1, V, 3) from the rest pose on, the
#: built simulation) -> its text
Figure = Callable[[np.ndarray, BuiltSimulation], str]


def run(mesh: Mesh, text: str, figure: Figure | None = None) -> str:
    """One scene's figures, as a line of the table."""
    built = build_simulation(parse_recipe(text), mesh)
    frames = list(simulate(built.model, built.scene, built.settings))
    positions = np.stack([built.model.rest_positions, *(f.welded_positions for f in frames)])
    rest_frame = frames[-1].rest_frame
    if rest_frame is None:
        line = f"{'never':>6} {'':>7} {'':>9}"
    else:
        after = positions[rest_frame:]  # frame k is positions[k]
        step = np.linalg.norm(np.diff(after, axis=0), axis=2).max() if after.shape[0] > 1 else 0.0
        line = f"{rest_frame:6d} {rest_frame / FPS:6.2f}s {step * FPS:9.2e}"
    line += f" {frames[-1].max_speed:9.2e}"
    return line + (f"  {figure(positions, built)}" if figure is not None else "")


def ball_figure(positions: np.ndarray, built: BuiltSimulation) -> str:
    """The struck ball's largest vertex distance from rest, and its centre of mass's, over the radius."""
    rest, mass = built.model.rest_positions, built.model.mass
    deviation = np.linalg.norm(positions[-1] - rest, axis=1).max() / RADIUS
    drift = np.linalg.norm(mass @ (positions[-1] - rest) / mass.sum()) / RADIUS
    return f"deviation/R {deviation:.2e}, centre/R {drift:.2e}"


def rebound_figure(positions: np.ndarray, built: BuiltSimulation) -> str:
    """How high the lowest vertex rose after it first came within 2 cm of the ground (Y up)."""
    lowest = positions[:, :, 1].min(axis=1)
    touched = int(np.argmax(lowest < 0.02))
    return f"rebound {lowest[touched:].max():.3f} m" if lowest[touched] < 0.02 else "never landed"


def top_figure(positions: np.ndarray, built: BuiltSimulation) -> str:
    """The highest vertex at the end (Y up)."""
    return f"top {positions[-1, :, 1].max():.3f} m"


def slide_figure(positions: np.ndarray, built: BuiltSimulation) -> str:
    """How far the sheet's centre moved from its start."""
    return f"slid {np.linalg.norm(positions[-1].mean(axis=0) - positions[0].mean(axis=0)):.4f} m"


def box() -> Mesh:
    """`trimesh.creation.box` of 0.3 m, its bottom 0.5 m up (Y)."""
    import trimesh  # a test and benchmark dependency only

    cube = trimesh.creation.box(extents=(0.3, 0.3, 0.3))
    points = np.array(cube.vertices, dtype=np.float64)
    points[:, 1] += 0.5 - points[:, 1].min()
    faces = np.asarray(cube.faces, dtype=np.int64)
    return Mesh(positions=points, face_indices=faces.ravel(), face_offsets=np.arange(0, faces.size + 1, 3))


def sheet(n: int, height: float, size: float = 1.0) -> Mesh:
    """An n x n grid of `size` (m), flat (XZ), centred on the Y axis at `height` (m)."""
    grid = grid_mesh(n, n, size=(size, size), plane="xz")
    points = grid.positions.copy()
    points += np.array([-0.5 * size, height, -0.5 * size])
    return replace(grid, positions=points)


def corner_triangle(edge: float, height: float, tilt: float) -> Mesh:
    """One triangle with legs of `edge` (m) along X and Z, its corner at the origin `height` (m)
    up, the corner along X `tilt` (m) higher and the one along Z half that."""
    points = np.array([[0.0, height, 0.0], [edge, height + tilt, 0.0], [0.0, height + 0.5 * tilt, edge]])
    return Mesh(positions=points, face_indices=np.array([0, 1, 2]), face_offsets=np.array([0, 3]))


def late_top_figure(positions: np.ndarray, built: BuiltSimulation) -> str:
    """The highest any vertex rose over the last second of the run (m)."""
    return f"top {positions[-FPS:, :, 1].max():.3f} m in the last second"


def tilted_sheet(n: int, degrees: float, gap: float) -> Mesh:
    """An n x n grid of 1 m lying `gap` (m) above the plane through the origin tilted `degrees` about Z."""
    grid = sheet(n, 0.0)
    angle = np.radians(degrees)
    turn = np.array([[np.cos(angle), -np.sin(angle), 0.0], [np.sin(angle), np.cos(angle), 0.0], [0.0, 0.0, 1.0]])
    normal = np.array([-np.sin(angle), np.cos(angle), 0.0])
    return replace(grid, positions=grid.positions @ turn.T + gap * normal)


#: a ball of radius 0.45 m, its top 0.9 m up, friction 0.5, no ground (`tests/test_rest.py`'s
#: cloth laid on a ball)
LAID_BALL = "\n[[colliders]]\nsphere = { center = [0, 0.45, 0], radius = 0.45 }\nfriction = 0.5\n"


#: a sheet lying on the ground, self-collision on, two opposite edges pushed 30 cm towards each
#: other over 1.5 s and then held: it buckles into folds that should come to rest
CRUMPLE = (
    "\n[self_collision]\n\n[[colliders]]\nground = { height = 0.0 }\nfriction = 0.5\n"
    "\n[[pins]]\nselect = { box = { min = [-0.51, -1, -1], max = [-0.49, 1, 1] } }\n"
    "animate = [{ time = 0.0, translate = [0, 0, 0] }, { time = 1.5, translate = [0.3, 0, 0] }]\n"
    "\n[[pins]]\nselect = { box = { min = [0.49, -1, -1], max = [0.51, 1, 1] } }\n"
    "animate = [{ time = 0.0, translate = [0, 0, 0] }, { time = 1.5, translate = [-0.3, 0, 0] }]\n"
)


def ball_on_ground(radius: float) -> str:
    """The colliders of a ball of `radius` (m) lying on the ground, friction 0.3."""
    return (
        f"\n[[colliders]]\nsphere = {{ center = [0, {radius}, 0], radius = {radius} }}\nfriction = 0.3\n"
        "\n[[colliders]]\nground = { height = 0.0 }\nfriction = 0.3\n"
    )


def scenes(
    raises: tuple[float, ...] = (0.0,),
) -> dict[str, Callable[[str], list[tuple[str, Mesh, str, Figure | None]]]]:
    """Each scene's rows for a solver's recipe head: (label, mesh, recipe text, figure); the
    sheets dropped on balls once from each of their heights raised by `raises` (m)."""

    Row = tuple[str, Mesh, str, Figure | None]

    def dropped(head: str, label: str, n: int, height: float, radius: float) -> list[Row]:
        return [
            (label if up == 0.0 else f"{label} {up:+g} m", sheet(n, height + up), head + ball_on_ground(radius),
             top_figure)
            for up in raises
        ]  # fmt: skip

    slope = np.radians(20.0)
    tilt = f"[{-float(np.sin(slope))!r}, {float(np.cos(slope))!r}, 0.0]"

    def struck(head: str, name: str) -> list[tuple[str, Mesh, str, Figure | None]]:
        frames = ["world", "centroid"] if name == "anchor" else [None]
        rows = []
        for frame in frames:
            table = f'\n[simulation.anchor]\nanchor_frame = "{frame}"\n' if frame else ""
            rows.append((f"ball ({frame})" if frame else "ball", load(BALL), head + "gravity = [0, 0, 0]\n" + table +
                         "\n" + STRIKE, ball_figure))
        return rows

    pins = [11 * 12, 11 * 12 + 11]  # the two corners of the cloth's row at z = 1 m
    return {
        "cloth": lambda head: [("cloth", grid_mesh(12, 12, plane="xz"),
                                head + f"\n[[pins]]\nselect = {{ indices = {pins} }}\n", None)],
        "ball": lambda head: struck(head, head.split('"')[1]),
        "box": lambda head: [("box", box(), head + "\n[[colliders]]\nground = { height = 0.0 }\n", rebound_figure)],
        "sheet on ball": lambda head: dropped(head, "sheet on ball", 20, 0.6, 0.25),
        "sheet on big ball": lambda head: dropped(head, "sheet on big ball", 32, 1.0, 0.45),
        "sheet laid on ball": lambda head: [
            ("sheet laid on ball", sheet(12, 0.92, size=0.4), head + LAID_BALL, top_figure)
        ],
        "crumpled sheet": lambda head: [("crumpled sheet", sheet(24, 0.02), head + CRUMPLE, top_figure)],
        "corner landing": lambda head: [("corner landing", corner_triangle(0.0345, 0.3, 0.02), head +
                                         "\n[[colliders]]\nground = { height = 0.0 }\nfriction = 0.3\n",
                                         late_top_figure)],
        "slope": lambda head: [("slope", tilted_sheet(12, 20.0, 0.0101), head +
                                f"\n[[colliders]]\nplane = {{ point = [0, 0, 0], normal = {tilt} }}\nfriction = 0.5\n",
                                slide_figure)],
    }  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=15.0, help="simulated seconds per scene")
    parser.add_argument("--solvers", nargs="+", default=sorted(SOLVERS), choices=sorted(SOLVERS))
    parser.add_argument("--scenes", nargs="+", default=list(scenes()), choices=list(scenes()))
    parser.add_argument(
        "--raise", dest="raises", type=float, nargs="+", default=[0.0],
        help="drop the sheets on balls from their heights raised by each of these (m), e.g. -0.05 0 0.05 0.1",
    )  # fmt: skip
    args = parser.parse_args()
    frames = round(args.seconds * FPS)
    table = scenes(tuple(args.raises))
    print(f"{'solver':8} {'scene':17} {'rest':>6} {'at':>7} {'step*fps':>9} {'speed':>9}  figure")
    for name in args.solvers:
        head = f'[simulation]\nsolver = "{name}"\nfps = {FPS}\nframes = {frames}\n'
        for scene in args.scenes:
            for label, mesh, text, figure in table[scene](head):
                print(f"{name:8} {label:17} {run(mesh, text, figure)}", flush=True)


if __name__ == "__main__":
    main()
