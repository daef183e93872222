"""Issue 16 item 2: does the settled shape depend on the iteration and substep counts?

    python benchmarks/convergence.py [--sizes 12 48] [--solvers xpbd implicit ...]
                                     [--iterations 2 5 10 20 40] [--substeps N ...] [--frames 240]
                                     [--warm-start 0]

A vertical 1 m cloth of n x n vertices (the default material) hangs from its two top corners
and settles under gravity; for every solver of the registry (or those given), at each iteration
count (solvers without iterations: once) and at the solver's default and twice its default
substeps (or the --substeps given), it prints the settled sag, how far that is from the material's equilibrium and the
last frame's force residual (`Frame.force_residual`, the report's figure).

Sag: the mean downward displacement (mm) of the free vertices from the rest sheet at the last
frame. The rest sheet is where an inextensible cloth would hang (the shear springs keep the
grid rigid in its plane, and gravity lies in it), so the sag is the material's stretch alone.
The reference is the `springs` solver at its default substeps (explicit Hooke springs: at rest
its positions balance the springs against gravity exactly, whatever its step); "off" is the
sag relative to it. A run stops 10 frames after the cloth came to rest (max speed below
1e-4 m/s), or after --frames frames (then "rest" is "-": still moving).
Timings are wall-clock seconds of the run (compilation excluded by a warm-up run).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from meshdeform.mesh import grid_mesh
from meshdeform.model import SpringModel
from meshdeform.simulate import CONVERGED_RESIDUAL, Scene, Settings, simulate
from meshdeform.solvers.registry import SOLVERS

#: frames a run goes on after the cloth came to rest
SETTLED_FRAMES = 10


def hanging_cloth(n: int) -> SpringModel:
    """A vertical 1 m cloth of n x n vertices (plane xy, Y up), pinned at its two top corners."""
    pins = np.zeros(n * n, dtype=bool)
    pins[[n * n - n, n * n - 1]] = True
    return SpringModel.from_mesh(grid_mesh(n, n, plane="xy"), pinned_input=pins)


def settle(
    model: SpringModel, solver: str, substeps: int, iterations: int | None, frames: int, warm_start: float
) -> tuple[float, float, int | None, float]:
    """(sag in mm, last force residual, rest frame or None, seconds) of one run."""
    cls = SOLVERS[solver]
    fields = cls.options_class.__dataclass_fields__
    options: dict[str, object] = {}
    if iterations is not None:
        options["iterations"] = iterations
    if "warm_start" in fields:
        options["warm_start"] = warm_start
    settings = Settings(solver=solver, frames=frames, substeps=substeps, options=cls.options_class(**options))
    start = time.perf_counter()
    last = None
    for frame in simulate(model, Scene(), settings):
        last = frame
        if frame.rest_frame is not None and frame.index - frame.rest_frame >= SETTLED_FRAMES:
            break
    seconds = time.perf_counter() - start
    drop = model.rest_positions[:, 1] - last.welded_positions[:, 1]
    sag = float(drop[~model.pinned].mean()) * 1e3
    return sag, last.force_residual, last.rest_frame, seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[12, 48])
    parser.add_argument("--solvers", nargs="+", default=list(SOLVERS))
    parser.add_argument("--iterations", type=int, nargs="+", default=[2, 5, 10, 20, 40])
    parser.add_argument("--substeps", type=int, nargs="+", help="substep counts (default: the solver's and twice it)")
    parser.add_argument("--frames", type=int, default=240)
    parser.add_argument("--warm-start", type=float, default=0.0, help="xpbd's warm_start option")
    args = parser.parse_args()
    settle(hanging_cloth(4), "springs", 2, None, 2, 0.0)  # compile / load the caches
    for name in args.solvers:
        settle(hanging_cloth(4), name, 2, None, 2, args.warm_start)
    print(f"force residual tolerance {CONVERGED_RESIDUAL:g}; sag in mm; off: against springs at its default")
    print("| solver | n | substeps | iterations | sag mm | off | residual | rest frame | s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for n in args.sizes:
        model = hanging_cloth(n)
        reference = settle(model, "springs", SOLVERS["springs"].default_substeps, None, args.frames, 0.0)[0]
        for name in args.solvers:
            cls = SOLVERS[name]
            counts = args.iterations if cls.default_iterations else [None]
            for substeps in args.substeps or (cls.default_substeps, 2 * cls.default_substeps):
                for iterations in counts:
                    try:
                        sag, residual, rest, seconds = settle(
                            model, name, substeps, iterations, args.frames, args.warm_start
                        )
                    except Exception as error:  # a diverged run is a figure too
                        print(f"| {name} | {n} | {substeps} | {iterations or '-'} | {type(error).__name__} |||||")
                        continue
                    off = (sag - reference) / reference
                    print(
                        f"| {name} | {n} | {substeps} | {iterations or '-'} | {sag:.3f} | {off:+.1%} | "
                        f"{residual:.3g} | {rest if rest is not None else '-'} | {seconds:.1f} |",
                        flush=True,
                    )


if __name__ == "__main__":
    main()
