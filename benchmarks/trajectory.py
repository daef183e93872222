"""How far each solver setting moves from a reference run of the same scene, and how its cloth looks.

    PYTHONPATH=. python benchmarks/trajectory.py [--n 64] [--frames 60] [--scene flat|hanging] \\
        [--reference springs] [--configs implicit implicit:coarse=0 implicit:substeps=8:iterations=3 xpbd ...]

The scenes of benchmarks/vs_blender.py (an N x N sheet of 1 m, two corners pinned, 24 fps, the
default material) through `meshdeform.simulate`, each setting written as there (`solver`, or
`solver:substeps=8:iterations=3:coarse=5`, any option of the solver or the material's
`stretch_modulus`); a setting that names neither substeps nor iterations runs the steps
`simulate.steps_for` gives it (a solver's calm steps). The reference is the first setting of
`--reference` (default `springs`: explicit Hooke springs in short, stable steps, another integrator
than the ones compared).

Printed per setting: frames/s over the timed run (a one-frame run beforehand loads the kernels), the
largest distance (m) of any vertex from the reference in any frame and that frame, the lowest point
at frames 12 and 24 and at the last, the last frame's largest speed (m/s), the worst structural
stretch (longest edge / rest length) over the frames with its 99th percentile and median in the
last frame, and the last frame's surface roughness: the 99th percentile over interior vertices of
|4 x_ij - x_i-1,j - x_i+1,j - x_i,j-1 - x_i,j+1| times (N - 1), about 0 on a smooth sheet, above 1
where neighbours kink at the scale of the grid.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from meshdeform.simulate import Scene, Settings, simulate, steps_for
from meshdeform.solvers.registry import solver_class

try:  # run as a script: its folder is on sys.path
    from vs_blender import meshdeform_inputs, parse_config
except ImportError:  # imported from elsewhere
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from vs_blender import meshdeform_inputs, parse_config


def run(spec: str, n: int, frames: int, scene: str) -> tuple[np.ndarray, float, float, str]:
    """(positions (F, N * N, 3) of every frame, seconds, the last frame's largest speed, label)."""
    solver, substeps, changes = parse_config(spec)
    modulus = changes.pop("stretch_modulus", None)
    options = solver_class(solver).options_class(**changes)
    settings = steps_for(Settings(solver=solver, fps=24, frames=frames, substeps=substeps, options=options), Scene())
    list(simulate(meshdeform_inputs(n, scene, modulus), Scene(), replace(settings, frames=1)))
    model = meshdeform_inputs(n, scene, modulus)
    start = time.perf_counter()
    poses, speed = [], 0.0
    for frame in simulate(model, Scene(), settings):
        poses.append(frame.welded_positions.copy())
        speed = frame.max_speed
    seconds = time.perf_counter() - start
    iterations = settings.iterations
    label = f"{spec} ({iterations} x {settings.substeps})" if iterations else f"{spec} ({settings.substeps} substeps)"
    return np.array(poses), seconds, speed, label


def structural_edges(n: int) -> np.ndarray:
    """(E, 2) the grid's row and column neighbours (meshdeform's structural springs on a grid)."""
    grid = np.arange(n * n).reshape(n, n)
    rows = np.stack([grid[:, :-1].ravel(), grid[:, 1:].ravel()], axis=1)
    columns = np.stack([grid[:-1].ravel(), grid[1:].ravel()], axis=1)
    return np.concatenate([rows, columns])


def roughness(positions: np.ndarray, n: int) -> float:
    """99th percentile of the interior vertices' second difference times (n - 1)."""
    g = positions.reshape(n, n, 3)
    second = 4.0 * g[1:-1, 1:-1] - g[:-2, 1:-1] - g[2:, 1:-1] - g[1:-1, :-2] - g[1:-1, 2:]
    return float(np.percentile(np.linalg.norm(second, axis=2) * (n - 1), 99))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=64)
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--scene", choices=("flat", "hanging"), default="flat")
    parser.add_argument("--reference", default="springs")
    parser.add_argument("--configs", nargs="*", default=["implicit", "implicit:coarse=0", "xpbd"])
    args = parser.parse_args()
    edges = structural_edges(args.n)
    rest = np.linalg.norm(np.diff(meshdeform_inputs(args.n, args.scene).rest_positions[edges], axis=1)[:, 0], axis=1)
    reference, *_ = run(args.reference, args.n, args.frames, args.scene)
    print(f"{args.n} x {args.n}, {args.scene}, {args.frames} frames at 24 fps; reference {args.reference}")
    print(
        f"{'setting (iterations x substeps)':52s} {'frames/s':>9s} {'off (m)':>8s} {'at':>4s} "
        f"{'low 12':>7s} {'low 24':>7s} {'low end':>7s} {'speed end':>10s} {'worst':>6s} {'p99':>6s} "
        f"{'median':>7s} {'rough':>6s}"
    )
    for spec in [args.reference, *args.configs]:
        poses, seconds, speed, label = run(spec, args.n, args.frames, args.scene)
        off = np.linalg.norm(poses - reference, axis=2).max(axis=1)
        stretch = [np.linalg.norm(np.diff(p[edges], axis=1)[:, 0], axis=1) / rest for p in poses]
        last = stretch[-1]
        low = [poses[min(k, args.frames) - 1][:, 1].min() for k in (12, 24, args.frames)]
        print(
            f"{label:52s} {args.frames / seconds:9.1f} {off.max():8.3f} {int(off.argmax()) + 1:4d} "
            f"{low[0]:7.3f} {low[1]:7.3f} {low[2]:7.3f} {speed:10.2e} {max(s.max() for s in stretch):6.3f} "
            f"{np.percentile(last, 99):6.3f} {np.median(last):7.4f} {roughness(poses[-1], args.n):6.3f}"
        )


if __name__ == "__main__":
    main()
