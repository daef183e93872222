"""Fast contact through the recipe path: a plate punched through a lying sheet and a sheet shot
onto bumpy ground, self-collision on, each solver at its defaults.

    PYTHONPATH=. python benchmarks/fast_contact.py [--solvers implicit xpbd verlet] [--speeds 5 20 60]

Scenes (24 fps, recipes built as `meshdeform simulate` builds them: `pipeline.build.build_simulation`,
then `meshdeform.simulate`):
- plate: a 0.6 m box plate, 1 cm thick, still until 0.05 s, then rising 3 m at `--speeds` m/s
  through a 1 m sheet of 25 x 25 vertices (triangles) lying flat 0.5 m above it, no gravity;
  friction 0.5, thickness 5 mm; frames until 2 after the plate stops;
- terrain: a 30 x 30 sheet (triangles) kicked down at 53 m/s by an impact (2 ms) from 2.2 m onto
  an open 17 x 17 grid of height 0.2 + 0.15 sin(6 x) cos(5 z) m, thickness 1 cm, friction 0.5;
  16 frames.

Printed per scene and solver: the largest count over frames of intersecting triangle pairs that
share no vertex (tests/intersections.py, decided by ipctk: an oracle meshdeform did not write), the
smallest clearance of the sheet's surface from the collider (mm; the plate: every triangle
sampled on a barycentric lattice, its exact box distance; the terrain: every vertex's height
over the ground's triangle under it), the worst structural stretch, the steps each frame took
(the fast frames: `meshdeform.simulate.fast_substeps`) and the seconds the frames took, or
the error where a run stopped. Figures go to docs/performance.md ("Fast steps", "Zones carried
by a moving collider"). Not run in CI.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))  # the tests' helpers and their intersection oracle (no package)

from factories import bumpy_ground, grid_sheet, height_over_grid, punched_plate  # noqa: E402
from intersections import intersecting_pairs  # noqa: E402
from test_collider_contact import box_distance, lattice  # noqa: E402

from meshdeform.errors import MeshdeformError  # noqa: E402
from meshdeform.io import write_obj  # noqa: E402
from meshdeform.mesh import Mesh  # noqa: E402
from meshdeform.simulate import simulate  # noqa: E402
from pipeline.build import build_simulation  # noqa: E402
from pipeline.recipe import parse_recipe  # noqa: E402

GROUND_N, GROUND_SIZE = 17, 1.6


def sheet(n: int, height: float) -> Mesh:
    """A 1 m sheet of n x n vertices in XZ, centred on the Y axis at `height` (m), triangulated."""
    return grid_sheet(n, n, size=1.0, plane="xz", triangles=True, centred=True, offset=(0.0, height, 0.0))


def run(
    mesh: Mesh, text: str, clearance: Callable[[np.ndarray, np.ndarray, float], float], pairs_of: Callable
) -> str:
    """One scene's line: pairs, clearance (mm), stretch, steps, seconds; or where it stopped."""
    built = build_simulation(parse_recipe(text), mesh)
    pairs, gaps, stretch, steps = [], [], [], []
    seconds = 0.0
    tick = time.perf_counter()
    try:
        for frame in simulate(built.model, built.scene, built.settings):
            seconds += time.perf_counter() - tick
            x, triangles = frame.welded_positions, np.asarray(frame.model.triangles)
            pairs.append(pairs_of(x, triangles))
            gaps.append(clearance(x, triangles, frame.time))
            stretch.append(frame.max_stretch)
            steps.append(frame.substeps)
            tick = time.perf_counter()
    except MeshdeformError as error:
        return f"stopped: {str(error)[:90]}"
    return (
        f"{max(pairs):5d} {1000 * min(gaps):9.2f} {max(stretch):7.3f} {seconds:6.2f}  "
        + " ".join(str(s) for s in steps)
    )


def plate_line(solver: str, speed: float, pairs_of: Callable) -> str:
    plate = punched_plate(solver, speed)

    def clearance(x: np.ndarray, triangles: np.ndarray, t: float) -> float:
        rise = np.array([0.0, plate.rise(t), 0.0])
        return float(box_distance(lattice(x, triangles, n=6), plate.lo + rise, plate.hi + rise).min())

    return run(plate.mesh, plate.recipe, clearance, pairs_of)


def terrain_line(solver: str, ground: Path, vertices: np.ndarray, pairs_of: Callable) -> str:
    text = (
        f'[simulation]\nsolver = "{solver}"\nfps = 24\nframes = 16\n\n[self_collision]\n\n'
        f"[[colliders]]\nmesh = {str(ground)!r}\nfriction = 0.5\nthickness = 0.01\n\n"
        "[[impacts]]\ntime = 0.0\npoint = [0, 100, 0]\nradius = 1000.0\nstrength = 53.0\nduration = 0.002\n"
        'direction = [0, -1, 0]\nfalloff = "smooth"\n'
    )

    def clearance(x: np.ndarray, triangles: np.ndarray, t: float) -> float:
        inside = np.all(np.abs(x[:, [0, 2]]) < GROUND_SIZE / 2, axis=1)
        heights = height_over_grid(vertices, GROUND_N, GROUND_SIZE, x[inside])
        return float((x[inside, 1] - heights).min(initial=np.inf))

    return run(sheet(30, 2.2), text, clearance, pairs_of)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--solvers", nargs="+", default=["implicit", "xpbd", "verlet"])
    parser.add_argument("--speeds", nargs="+", type=float, default=[5.0, 20.0, 60.0])
    args = parser.parse_args()
    pairs_of = intersecting_pairs
    vertices, triangles = bumpy_ground(GROUND_N, GROUND_SIZE)
    with tempfile.TemporaryDirectory() as folder:
        ground = Path(folder) / "ground.obj"
        write_obj(ground, Mesh(
            positions=vertices,
            face_indices=triangles.ravel(),
            face_offsets=np.arange(0, triangles.size + 1, 3, dtype=np.int64),
        ))  # fmt: skip
        print(f"{'scene':<22} {'solver':<9} pairs clear mm stretch   secs  steps per frame")
        for solver in args.solvers:
            for speed in args.speeds:
                print(f"{f'plate {speed:g} m/s':<22} {solver:<9} {plate_line(solver, speed, pairs_of)}", flush=True)
            print(f"{'terrain 53 m/s':<22} {solver:<9} {terrain_line(solver, ground, vertices, pairs_of)}", flush=True)


if __name__ == "__main__":
    main()
