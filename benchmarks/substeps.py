"""Substep speed of the position-based solvers, with the code on PYTHONPATH (to compare two trees).

    PYTHONPATH=<tree> python benchmarks/substeps.py [--solver xpbd] [--n 64] [--frames 100]
        [--scene hang|tear] [--partitions P] [--fresh-layouts] [--busy]

Prints one line: the solver, the scene, frames/s over the frames after the first (the first
compiles the kernels or loads them from Numba's cache and prepares the model) and the first
frame's seconds, the substep build the run ended with, its switches and the share of substeps
each build ran (`dispatch.SubstepPicker`, where the tree has it), then the load average at the
start and at the end (put it beside any figure).

Scenes:
- hang: an N x N cloth, 1 m square, vertical (XY, Y up), pinned at its two top corners, gravity,
  24 fps, the solver's defaults (the reference scene of docs/performance.md).
- tear: the scene of `benchmarks/tearing.py` (an N x N cloth held along its left edge, its right
  edge dragged away, a weaker band down the middle tearing), built through the recipe with xpbd's
  defaults; every topology update hands the solver a new model to prepare.

Knobs, each an alternative the solvers' defaults were measured against (docs/performance.md,
"Serial or parallel substeps"):
- NUMBA_NUM_THREADS=1 in the environment: one Numba thread (the serial build whatever else).
- MESHDEFORM_PARALLEL_SUBSTEPS=0 / 1 in the environment: the serial / the parallel build of the
  substep throughout (the parallel one where the layout has more than one slab and Numba more
  than one thread); unset, the picker chooses while the run goes on (`meshdeform.solvers.dispatch`).
- --busy: one core held by another process (`python -c 'while True: pass'`) from before the
  first frame to the end, then killed.
- --partitions P: P slabs instead of the automatic count (P changes the results; the per-solver
  options API is needed, so not with the code before issue #14).
- --fresh-layouts: after a tear, sort the torn model's springs afresh instead of inheriting the
  previous order (`layout.inherited_layout`; results differ, the speed is what is compared).

Only the public API is used (`meshdeform.simulate`, `SpringModel.from_mesh`, the recipe and
`pipeline.build` for the tearing scene), plus the one module attribute --fresh-layouts replaces,
so the same file times the code before and after a change. Nothing is written to disk.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import subprocess
import sys
import time
from collections.abc import Iterator

import numpy as np

#: the tearing scene's recipe: benchmarks/tearing.py's, with its defaults (xpbd, tethers off)
TEAR_RECIPE = """
[simulation]
solver = "xpbd"
fps = 24
frames = {frames}
damping = 0.2
tethers = 0

[material]
structural = {{ stiffness = 1.0 }}
shear      = {{ stiffness = 0.5 }}
bending    = {{ stiffness = 0.02 }}
density = 0.2

[[pins]]
select = {{ box = {{ min = [0, 0, 0], max = [0.001, 1, 1] }}, relative = true }}

[[pins]]
select = {{ box = {{ min = [0.999, 0, 0], max = [1, 1, 1] }}, relative = true }}
animate = [
  {{ time = 0.0, translate = [0, 0, 0] }},
  {{ time = 0.5, translate = [0, 0, 0] }},
  {{ time = 3.5, translate = [0.5, 0, 0.3] }},
]

[[tears]]
select = {{ box = {{ min = [0.47, 0, 0], max = [0.53, 1, 1] }}, relative = true }}
max_stretch = 1.3
average = 4

[output]
formats = ["obj"]
"""


def hanging(solver: str, n: int, frames: int, partitions: int | None):
    """(model, scene, settings) of the hanging cloth."""
    from meshdeform.mesh import grid_mesh
    from meshdeform.model import SpringModel
    from meshdeform.simulate import Scene, Settings

    mesh = grid_mesh(n, n, plane="xy")
    pinned = np.zeros(n * n, dtype=bool)
    pinned[[n * (n - 1), n * n - 1]] = True
    model = SpringModel.from_mesh(mesh, pinned_input=pinned)
    if partitions is None:
        return model, Scene(), Settings(solver=solver, frames=frames)
    from meshdeform.solvers import solver_class

    options = solver_class(solver).options_class(partitions=partitions)
    return model, Scene(), Settings(solver=solver, frames=frames, options=options)


def tearing(n: int, frames: int):
    """(model, scene, settings) of the tearing cloth, built from `TEAR_RECIPE`."""
    from meshdeform.mesh import grid_mesh
    from pipeline.build import build_simulation
    from pipeline.recipe import parse_recipe

    built = build_simulation(parse_recipe(TEAR_RECIPE.format(frames=frames), "substeps.toml"), grid_mesh(n, n))
    return built.model, built.scene, built.settings


def load() -> str:
    return " ".join(f"{v:.2f}" for v in os.getloadavg())


@contextlib.contextmanager
def busy_core(busy: bool) -> Iterator[None]:
    """With `busy`, a process spinning on one core for the duration of the block."""
    if not busy:
        yield
        return
    spinner = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        time.sleep(0.5)  # let it get its core
        yield
    finally:
        spinner.kill()
        spinner.wait()


def solvers_made() -> list:
    """The solvers `simulate` makes from now on (to read their substep picker after the run)."""
    import meshdeform.simulate as simulate_module

    made: list = []
    make = simulate_module.make_solver

    def making(*args, **kwargs):
        made.append(make(*args, **kwargs))
        return made[-1]

    simulate_module.make_solver = making
    return made


def picker_summary(solvers: list) -> str:
    """The build the run ended with, its switches and the share of substeps of each build."""
    picker = getattr(solvers[0], "substep", None) if solvers else None
    if not hasattr(picker, "switches"):
        return "build: no picker"
    total = max(1, sum(picker.substeps.values()))
    shares = ", ".join(f"{build} {100 * n / total:.0f} %" for build, n in picker.substeps.items())
    return f"ended {picker.build}, {picker.switches} switches ({shares})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--solver", default="xpbd", choices=("xpbd", "verlet"))
    parser.add_argument("--n", type=int, default=64, help="vertices per side")
    parser.add_argument("--frames", type=int, default=100, help="frames timed (after the first)")
    parser.add_argument("--scene", default="hang", choices=("hang", "tear"))
    parser.add_argument("--partitions", type=int, default=None)
    parser.add_argument("--fresh-layouts", action="store_true")
    parser.add_argument("--busy", action="store_true", help="one core held by another process")
    args = parser.parse_args()
    before = load()
    if args.fresh_layouts:
        from meshdeform.solvers import common

        common.inherited_layout = lambda *_: None  # the caller then sorts afresh
    from meshdeform.simulate import simulate

    if args.scene == "hang":
        model, scene, settings = hanging(args.solver, args.n, args.frames + 1, args.partitions)
        name = args.solver
    else:
        model, scene, settings = tearing(args.n, args.frames + 1)
        name = settings.solver
    solvers = solvers_made()
    with busy_core(args.busy):
        frames = simulate(model, scene, settings)
        start = time.perf_counter()
        next(frames)
        first = time.perf_counter() - start
        start = time.perf_counter()
        count = sum(1 for _ in frames)
        seconds = time.perf_counter() - start
    print(
        f"{name} {args.scene} {args.n}x{args.n}: {count / seconds:.2f} frames/s over {count} frames "
        f"(first frame {first:.2f} s); {picker_summary(solvers)}; load average {before} -> {load()}",
        flush=True,
    )


if __name__ == "__main__":
    main()
