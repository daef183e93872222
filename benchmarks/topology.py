"""Spring building time on large quad grids (weld + structural + shear + bending).

    python benchmarks/topology.py [--n 1000]
"""

from __future__ import annotations

import argparse
import time

from meshdeform.mesh import grid_mesh
from meshdeform.topology import build_springs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=1000, help="grid side: n x n vertices")
    args = parser.parse_args()
    build_springs(grid_mesh(8, 8))  # compile / load the Numba cache
    mesh = grid_mesh(args.n, args.n)
    best = float("inf")
    for _ in range(3):
        start = time.perf_counter()
        _, springs = build_springs(mesh)
        best = min(best, time.perf_counter() - start)
    print(f"{args.n} x {args.n} grid ({mesh.vertex_count:,} vertices): {springs.counts()} in {best:.2f} s (best of 3)")


if __name__ == "__main__":
    main()
