"""Cost of collider contact on the whole cloth surface against vertices only, and what it finds.

    python benchmarks/colliders.py [--n 40] [--frames 48] [--solver implicit]

Scenes (the solver given, by default the default solver; 24 fps, its default substeps): an
n x n sheet dropped on a ball and the ground (the drop sample), the same sheet on a mesh ball
(icosphere, 1280 triangles) and the ground, and the sheet shot at 50 m/s onto a 1 cm plate.
Each runs twice: with the colliders as they are (triangles, edges and vertices, swept) and with
vertex contacts only (swept too: the sweep is the same code on vertex primitives). Prints
frames per CPU second (process time, steadier than wall time on a shared machine; the per-frame
check not counted), each collider's CPU milliseconds per substep and `ContactStats` (contacts,
swept, crossed, extra rounds, vertices put back), and the nearest approach of the cloth's
surface to the ball, sampled on every triangle.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import trimesh

from meshdeform.mesh import grid_mesh
from meshdeform.model import SpringModel, State
from meshdeform.scene.colliders import Box, Collider, Plane, Sphere, TriangleMesh
from meshdeform.simulate import Scene, Settings, simulate
from meshdeform.solvers.registry import DEFAULT_SOLVER, SOLVERS


class VertexCollider(Collider):
    """The same collider tested at the cloth's vertices only (what colliders did before)."""

    def _primitives(self, model: SpringModel) -> np.ndarray:
        super()._primitives(model)
        assert self._prims is not None
        return self._prims.points


class Timed:
    """Sums the CPU seconds a collider's projections take (process time: steadier than wall time
    on a shared machine) and counts them, by timing its `project` in place: the collider itself
    stays in the scene (a wrapper around it would hide it from what the run asks of colliders
    alone, such as the contact planes some solvers read)."""

    def __init__(self, inner: Collider) -> None:
        self.inner = inner
        self.seconds = 0.0
        self.calls = 0
        project = inner.project

        def timed(model: SpringModel, state: State, time_: float, dt: float) -> None:
            start = time.process_time()
            project(model, state, time_, dt)
            self.seconds += time.process_time() - start
            self.calls += 1

        inner.project = timed  # type: ignore[method-assign]


def sheet(n: int, height: float) -> SpringModel:
    mesh = grid_mesh(n, n, size=(1.5, 1.5), plane="xz")
    return SpringModel.from_mesh(mesh.with_positions(mesh.positions + [-0.75, height, -0.75]))


def samples_distance(positions: np.ndarray, triangles: np.ndarray, centre: np.ndarray, radius: float) -> float:
    i, j = np.meshgrid(np.arange(9), np.arange(9), indexing="ij")
    keep = i + j <= 8
    u, v = i[keep] / 8, j[keep] / 8
    w = np.stack([1 - u - v, u, v], axis=1)
    points = np.einsum("lk,tkd->tld", w, positions[triangles]).reshape(-1, 3)
    return float((np.linalg.norm(points - centre, axis=1) - radius).min())


def run(
    name: str, model: SpringModel, colliders: list[Collider], frames: int, state: State | None, ball, solver: str
) -> None:
    timed = [Timed(c) for c in colliders]
    settings = Settings(solver=solver, fps=24, frames=frames)
    nearest = np.inf
    checking = 0.0  # the check of each frame, not counted in the run
    start = time.process_time()
    for frame in simulate(model, Scene(constraints=colliders), settings, state=state.copy() if state else None):
        if ball is not None:
            check = time.process_time()
            nearest = min(nearest, samples_distance(frame.welded_positions, model.triangles, *ball))
            checking += time.process_time() - check
    total = time.process_time() - start - checking
    print(f"  {name:<14} {frames / total:7.1f} frames per CPU second", end="")
    print(f", nearest face point to the ball {1000 * nearest:6.2f} mm" if ball is not None else "")
    for t in timed:
        ms = 1000 * t.seconds / max(t.calls, 1)
        print(f"      {type(t.inner.shape).__name__:<12} {ms:6.3f} ms a substep  {t.inner.stats}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=40, help="sheet side: n x n vertices")
    parser.add_argument("--frames", type=int, default=48)
    parser.add_argument("--solver", default=DEFAULT_SOLVER, choices=sorted(SOLVERS))
    args = parser.parse_args()
    icosphere = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    icosphere.apply_translation([0, 0.45, 0])
    plate_lo, plate_hi = np.array([-1.0, 0.0, -1.0]), np.array([1.0, 0.01, 1.0])
    scenes = {
        "sphere + ground": (
            lambda c: [c(Sphere((0, 0.45, 0), 0.3), 0.3, 0.01), c(Plane((0, 0, 0), (0, 1, 0)), 0.6, 0.005)]
        ),
        "mesh + ground": (
            lambda c: [
                c(TriangleMesh(icosphere.vertices, icosphere.faces), 0.3, 0.01),
                c(Plane((0, 0, 0), (0, 1, 0)), 0.6, 0.005),
            ]
        ),
        "50 m/s plate": (lambda c: [c(Box(plate_lo, plate_hi), 0.3, 0.01)]),
    }
    warm = sheet(6, 0.8)
    for make in scenes.values():  # compile / load the Numba cache: run until the sheet lies on them
        list(simulate(warm, Scene(constraints=make(Collider)), Settings(solver=args.solver, frames=24)))
    for title, make in scenes.items():
        model = sheet(args.n, 1.0)
        state = None
        if title == "50 m/s plate":
            state = State.at_rest(model)
            state.velocities[:] = (0.0, -50.0, 0.0)
            state.previous[:] = state.positions - state.velocities * Settings(solver=args.solver).dt
        ball = (np.array([0.0, 0.45, 0.0]), 0.3) if "ground" in title else None
        print(f"{title} ({args.n} x {args.n} sheet, {args.frames} frames)")
        for label, cls in (("surface", Collider), ("vertices only", VertexCollider)):
            colliders = make(lambda shape, mu, h, cls=cls: cls(shape, mu, h))
            run(label, model, colliders, args.frames, state, ball, args.solver)


if __name__ == "__main__":
    main()
