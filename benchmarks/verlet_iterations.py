"""Issue #2's figure: frames/s of the Verlet cloth on a 64 x 64 grid at 10 iterations per substep.

    python benchmarks/verlet_iterations.py [--n 64] [--iterations 10]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from meshdeform.mesh import grid_mesh
from meshdeform.model import SpringModel
from meshdeform.simulate import Scene, Settings, simulate
from meshdeform.solvers import VerletOptions


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=64)
    parser.add_argument("--iterations", type=int, default=10)
    parser.add_argument("--frames", type=int, default=100)
    args = parser.parse_args()
    n = args.n
    pins = np.zeros(n * n, dtype=bool)
    pins[[n * n - n, n * n - 1]] = True
    model = SpringModel.from_mesh(grid_mesh(n, n, plane="xz"), pinned_input=pins)
    options = VerletOptions(iterations=args.iterations)
    list(simulate(model, Scene(), Settings(solver="verlet", frames=1, options=options)))  # compile / load cache
    settings = Settings(solver="verlet", frames=args.frames, options=options)
    best = float("inf")
    for _ in range(3):
        start = time.perf_counter()
        frames = list(simulate(model, Scene(), settings))
        best = min(best, time.perf_counter() - start)
    projections = model.spring_count * args.iterations * settings.substeps * args.frames / best
    print(
        f"verlet {n}x{n}, {settings.substeps} substeps x {args.iterations} iterations: "
        f"{args.frames / best:.1f} frames/s, {projections / 1e6:.0f} M proj/s, "
        f"max stretch {max(f.max_stretch for f in frames):.3f}, load {os.getloadavg()[0]:.2f}"
    )


if __name__ == "__main__":
    main()
