"""Tearing cost: a 128 x 128 cloth torn by a moving pin, against the same scene without tearing.

    .venv/bin/python benchmarks/tearing.py [--n 128] [--frames 96] [--interval S] [--burst N] [--repeat 1]
        [--self-collision]

The scene: a 1 m square cloth (N x N vertices, quads) in the XY plane, held along its left edge;
a pin holding its right edge waits half a second, then drags it 0.5 m away (and 0.3 m out of
the plane) over three seconds. A band down the middle (6 % of the width) is weaker: it tears
beyond 1.3 times the rest length, stretch averaged over 4 substeps ([[tears]] with a `select`),
so the cloth comes apart there while the rest holds. Both runs build the scene from the same
recipe through `pipeline.build` (xpbd with its defaults, tethers off in both); the tearing run
adds the `[[tears]]` table. Only the simulation loop is timed (no export), after a one-frame
warm-up that compiles the kernels. Prints both frames/s figures, their ratio, and what tore.
With `--self-collision` both runs add `[self_collision]` (its defaults), and the tearing run's
self-collision work is printed too (the two sides of a tear are parted and guarded like any
other pair: docs/contact.md, "Solvers and tearing").

The requirement it checks: tearing keeps at least half the frames/s of the same scene without
tearing. Every topology update hands the solver a new model to prepare; xpbd and verlet derive
its spring order from the one they have (`layout.inherited_layout`, about 3 ms at this size
where sorting afresh takes 25) and reuse their buffers. Updates are budgeted
(`simulation.tear_interval`, `tear_burst`, see meshdeform.tearing) so that heavy tearing costs
at most about one preparation per frame.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

RECIPE = """
[simulation]
solver = "xpbd"
fps = 24
frames = {frames}
damping = 0.2
{interval}

[simulation.xpbd]
tethers = 0                # off in both runs (a recipe that tears has them off by default)

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
{tears}{self_collision}
[output]
formats = ["obj"]
"""

TEARS = """
[[tears]]
select = { box = { min = [0.47, 0, 0], max = [0.53, 1, 1] }, relative = true }
max_stretch = 1.3
average = 4
"""


def write_grid(path: Path, n: int) -> None:
    from meshdeform.io import save
    from meshdeform.mesh import grid_mesh

    save(path, grid_mesh(n, n, plane="xy"))


def run(mesh_path: Path, text: str, frames: int) -> tuple[float, object]:
    from meshdeform.contact.self_collision import ContactWork
    from meshdeform.io import load
    from meshdeform.simulate import simulate
    from pipeline.build import build_simulation
    from pipeline.recipe import parse_recipe

    mesh = load(mesh_path)
    built = build_simulation(parse_recipe(text, "bench.toml"), mesh)
    started = time.perf_counter()
    frames_out = list(simulate(built.model, built.scene, built.settings))
    last = frames_out[-1]
    seconds = time.perf_counter() - started
    work = ContactWork()  # self-collision's work over the frames (none without it)
    for frame in frames_out:
        if frame.contact is not None:
            work.add(frame.contact)
    return frames / seconds, (built, last, work)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--n", type=int, default=128, help="vertices per side")
    parser.add_argument("--frames", type=int, default=96)
    parser.add_argument("--interval", type=float, default=None, help="simulation.tear_interval (s)")
    parser.add_argument("--burst", type=int, default=None, help="simulation.tear_burst")
    parser.add_argument("--repeat", type=int, default=1, help="runs of each; the best is kept")
    parser.add_argument("--self-collision", action="store_true", help="both runs with [self_collision]")
    args = parser.parse_args()
    contact = "\n[self_collision]\n" if args.self_collision else ""
    interval = "" if args.interval is None else f"tear_interval = {args.interval}"
    if args.burst is not None:
        interval += f"\ntear_burst = {args.burst}"
    with tempfile.TemporaryDirectory() as tmp:
        mesh_path = Path(tmp) / "cloth.obj"
        write_grid(mesh_path, args.n)
        plain = RECIPE.format(frames=args.frames, interval=interval, tears="", self_collision=contact)
        tearing = RECIPE.format(frames=args.frames, interval=interval, tears=TEARS, self_collision=contact)
        run(mesh_path, RECIPE.format(frames=1, interval=interval, tears=TEARS, self_collision=contact), 1)  # compile
        plain_fps = max(run(mesh_path, plain, args.frames)[0] for _ in range(args.repeat))
        best = None
        for _ in range(args.repeat):
            fps, (built, last, work) = run(mesh_path, tearing, args.frames)
            if best is None or fps > best[0]:
                best = (fps, built, last, work)
    assert best is not None
    tear_fps, built, last, work = best
    tearer = built.scene.tearing
    s = tearer.settings
    print(
        f"cloth {args.n} x {args.n}, {args.frames} frames, xpbd {built.settings.substeps} substeps"
        f"{', self-collision' if args.self_collision else ''}; "
        f"tear updates: burst {s.burst}, then one per {s.interval:.4g} s"
    )
    print(f"without tearing: {plain_fps:7.2f} frames/s")
    print(f"with tearing:    {tear_fps:7.2f} frames/s  ({tear_fps / plain_fps:.2f} of it)")
    print(
        f"torn: {tearer.total_split} vertices added, {tearer.total_broken} springs broken, "
        f"{tearer.updates} topology updates, {last.pieces} pieces at the end"
    )
    if args.self_collision:
        print(
            f"self-collision over the run: {work.zone_rounds} zone rounds, {work.flagged_pairs} flagged pairs, "
            f"{work.pair_builds} pair builds, {work.unresolved} unresolved"
        )


if __name__ == "__main__":
    main()
