"""When damped scenes come to rest, for every registered solver, and where the stress ball ends.

    PYTHONPATH=<tree> python benchmarks/rest.py [--seconds 15]

Scenes (recipes at their defaults, air damping 0.9, built as `meshdeform simulate` builds them:
`pipeline.build.build_simulation`, then `meshdeform.simulate`):
- cloth: a 12 x 12 sheet of 1 m lying flat (XZ), two corners of one edge pinned, 24 fps;
- ball: samples/meshes/icosphere.ply (radius 0.5 m), no gravity, struck at the front by the sample
  stress ball's first impact (2 m/s along the normal), 24 fps; for `anchor` in both anchor frames.

Prints per solver and scene the reported rest frame (`Frame.rest_frame` of the last frame, the
report's `rest_frame`) and its time, the largest distance a vertex covers between two frames from
it on times the fps (m/s, to hold against the rest speed 1e-4 m/s), and for the ball the largest
distance of a vertex from its rest position at the end, over the radius, and that of its centre of
mass. Figures go to docs/recipes.md ("Coming to rest").
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from meshdeform.io import load
from meshdeform.mesh import Mesh, grid_mesh
from meshdeform.simulate import simulate
from meshdeform.solvers import SOLVERS
from pipeline.build import build_simulation
from pipeline.recipe import parse_recipe

FPS = 24
RADIUS = 0.5
BALL = Path(__file__).resolve().parent.parent / "samples" / "meshes" / "icosphere.ply"
STRIKE = (
    "[[impacts]]\ntime = 0.1\nray = { origin = [0, 0, 2], direction = [0, 0, -1] }\n"
    'radius = 0.15\nstrength = 2.0\nduration = 0.05\ndirection = "normal"\n'
)


def run(mesh: Mesh, text: str, ball: bool) -> str:
    """One scene's figures, as a line of the table."""
    built = build_simulation(parse_recipe(text), mesh)
    frames = list(simulate(built.model, built.scene, built.settings))
    positions = np.stack([f.welded_positions for f in frames])
    rest_frame = frames[-1].rest_frame
    if rest_frame is None:
        line = f"{'never':>6} {'':>7} {'':>9}"
    else:
        step = (
            np.linalg.norm(np.diff(positions[rest_frame - 1 :], axis=0), axis=2).max()
            if rest_frame < len(frames)
            else 0.0
        )
        line = f"{rest_frame:6d} {rest_frame / FPS:6.2f}s {step * FPS:9.2e}"
    if ball:
        rest, mass = built.model.rest_positions, built.model.mass
        deviation = np.linalg.norm(positions[-1] - rest, axis=1).max() / RADIUS
        drift = np.linalg.norm(mass @ (positions[-1] - rest) / mass.sum()) / RADIUS
        line += f" {deviation:11.2e} {drift:9.2e}"
    return line


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=15.0, help="simulated seconds per scene")
    args = parser.parse_args()
    frames = round(args.seconds * FPS)
    cloth = grid_mesh(12, 12, plane="xz")
    pins = [11 * 12, 11 * 12 + 11]  # the two corners of the row at z = 1 m
    ball = load(BALL)
    print(f"{'solver':8} {'scene':15} {'rest':>6} {'at':>7} {'step*fps':>9} {'deviation/R':>11} {'centre/R':>9}")
    for name in sorted(SOLVERS):
        head = f'[simulation]\nsolver = "{name}"\nfps = {FPS}\nframes = {frames}\n'
        text = head + f"\n[[pins]]\nselect = {{ indices = {pins} }}\n"
        print(f"{name:8} {'cloth':15} {run(cloth, text, False)}")
        anchors = ["world", "centroid"] if name == "anchor" else [None]
        for frame in anchors:
            table = f'\n[simulation.anchor]\nanchor_frame = "{frame}"\n' if frame else ""
            text = head + "gravity = [0, 0, 0]\n" + table + "\n" + STRIKE
            scene = f"ball ({frame})" if frame else "ball"
            print(f"{name:8} {scene:15} {run(ball, text, True)}")


if __name__ == "__main__":
    main()
