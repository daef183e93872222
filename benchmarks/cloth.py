"""Cloth benchmark: N x N quad grid hanging from its two top corners, gravity, 24 fps, 100 frames.

For each solver and N (64, 128, 256 by default) prints: frames/s (warm, after the first
step, whole simulate loop, without tracemalloc; also from the median frame time, which a
moment of load on this shared machine moves less than the total), the first step's time separately (Numba
compile or cache load, LU factorisation), spring projections per second (springs x
iterations x substeps x frames / seconds; the explicit solvers count their stability steps
as substeps and one force evaluation per spring as a projection), peak memory (tracemalloc
peak of Python/NumPy allocations over a second, traced run of a few frames, and the max RSS
of the process up to the end of the timed run, which runs that one solver and size only unless
--no-isolate; with glibc's mmap threshold fixed as the `meshdeform` command fixes it, see
`pipeline.memory`), and the
structural max stretch over all frames and at the last frame. A vectorised-NumPy Jacobi
reference kernel (np.bincount scatter) and each position-based solver alone (whole frames
through `advance`, best of 5 repeats, no simulate loop) are measured at the end, then the cold and warm start of
`meshdeform simulate` on the flag sample (an empty Numba cache, then that cache). The machine
is shared: the load average is printed at the start and the end, put it beside any figure
you quote.

    .venv/bin/python benchmarks/cloth.py [--sizes 64,128,256] [--solvers xpbd,verlet,...] [--frames 100]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from meshdeform.mesh import grid_mesh
from meshdeform.model import SpringModel, State
from meshdeform.simulate import Scene, Settings, simulate
from meshdeform.solvers import Control, make_solver
from pipeline.memory import tune_malloc

ALL = ("xpbd", "verlet", "implicit", "springs", "anchor")


def scene_model(n: int) -> SpringModel:
    """The benchmark cloth: 1 m x 1 m, vertical (XY, Y up), pinned at its two top corners."""
    mesh = grid_mesh(n, n, plane="xy")
    pinned = np.zeros(n * n, dtype=bool)
    pinned[[n * (n - 1), n * n - 1]] = True
    return SpringModel.from_mesh(mesh, pinned_input=pinned)


def projections_per_frame(solver, settings: Settings, model: SpringModel) -> float:
    springs = model.spring_count
    if settings.solver in ("springs", "anchor"):
        use = settings.solver == "springs" or settings.options.neighbour_springs
        return float(springs * getattr(solver, "inner_steps", 1) * settings.substeps) if use else 0.0
    return float(springs * settings.iterations * settings.substeps)


def run(name: str, n: int, frames: int) -> dict:
    tune_malloc()  # as the `meshdeform` command does (pipeline.memory)
    model = scene_model(n)
    settings = Settings(solver=name, frames=frames + 1)
    solver = make_solver(name, settings.options)
    # cold start: the first frame (compile / cache load / factorisation)
    it = simulate(model, Scene(), settings, solver=solver)
    t0 = time.perf_counter()
    first = next(it)
    cold = time.perf_counter() - t0
    stretch = [first.max_stretch]
    t0 = time.perf_counter()
    last = first
    frame_seconds = []
    tick = t0
    for frame in it:
        stretch.append(frame.max_stretch)
        last = frame
        now = time.perf_counter()
        frame_seconds.append(now - tick)
        tick = now
    warm = time.perf_counter() - t0
    median = float(np.median(frame_seconds)) if frame_seconds else warm
    per_frame = projections_per_frame(solver, settings, model)
    rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # before tracemalloc adds its own
    del it, solver
    # memory: a fresh solver over a few frames under tracemalloc (it slows the loop down)
    tracemalloc.start()
    for _ in simulate(model, Scene(), Settings(solver=name, frames=min(frames, 5))):
        pass
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return {
        "solver": name,
        "n": n,
        "springs": model.spring_count,
        "substeps": settings.substeps,
        "iterations": settings.iterations,
        "cold": cold,
        "fps": frames / warm,
        "proj": per_frame * frames / warm,
        "fps_median": 1.0 / median,
        "proj_median": per_frame / median,
        "peak_mb": peak / 2**20,
        "rss_mb": rss_mb,
        "stretch": max(stretch),
        "stretch_last": last.max_stretch,
        "rest_frame": last.rest_frame,
    }


def run_isolated(name: str, n: int, frames: int) -> dict:
    """`run` in a fresh interpreter, so that its max RSS is this solver's and size's alone."""
    code = (
        "import json, sys; sys.path.insert(0, sys.argv[1]); import cloth; "
        "print(json.dumps(cloth.run(sys.argv[2], int(sys.argv[3]), int(sys.argv[4]))))"
    )
    here = str(Path(__file__).resolve().parent)
    proc = subprocess.run(
        [sys.executable, "-c", code, here, name, str(n), str(frames)], capture_output=True, text=True, check=False
    )
    lines = [line for line in proc.stdout.splitlines() if line.startswith("{")]
    if proc.returncode != 0 or not lines:
        raise SystemExit(f"{name} N={n} failed: {proc.stderr.strip()[-2000:]}")
    return json.loads(lines[-1])


def numpy_jacobi(x: np.ndarray, a: np.ndarray, b: np.ndarray, rest: np.ndarray, w: np.ndarray, sweeps: int) -> None:
    """Reference: vectorised Jacobi distance projection with np.bincount scatter (averaged)."""
    n = x.shape[0]
    wa, wb = w[a], w[b]
    ws = wa + wb
    ok = ws > 0
    count = np.bincount(a, weights=ok * 1.0, minlength=n) + np.bincount(b, weights=ok * 1.0, minlength=n)
    count = np.maximum(count, 1.0)[:, None]
    ws = np.where(ok, ws, 1.0)
    for _ in range(sweeps):
        d = x[b] - x[a]
        length = np.sqrt(np.einsum("ij,ij->i", d, d))
        f = np.where(ok, (length - rest) / (np.maximum(length, 1e-12) * ws), 0.0)
        corr = d * f[:, None]
        delta = np.empty_like(x)
        for k in range(3):
            delta[:, k] = np.bincount(a, weights=corr[:, k] * wa, minlength=n) - np.bincount(
                b, weights=corr[:, k] * wb, minlength=n
            )
        x += delta / count


def reference(n: int, sweeps: int = 160) -> float:
    model = scene_model(n)
    x = np.array(model.rest_positions)
    x[:, 1] *= 1.01
    a = np.asarray(model.springs[:, 0], dtype=np.int64)
    b = np.asarray(model.springs[:, 1], dtype=np.int64)
    t0 = time.perf_counter()
    numpy_jacobi(x, a, b, np.asarray(model.rest_lengths), np.asarray(model.inv_mass), sweeps)
    return model.spring_count * sweeps / (time.perf_counter() - t0)


def kernel_rate(name: str, n: int, frames: int = 0, repeats: int = 5) -> float:
    """The solver alone (no simulate loop): best projections per second over `repeats` runs of
    `frames` frames, each frame one `advance` call (as `simulate` runs a gravity-only scene)."""
    model = scene_model(n)
    solver = make_solver(name)
    settings = Settings(solver=name)
    state = State.at_rest(model)
    control = Control(np.tile(np.array([0.0, -9.81, 0.0]), (model.vertex_count, 1)))
    dt, substeps = settings.dt, int(settings.substeps)
    frames = frames or max(2, int(10 * (64 / n) ** 2))
    for _ in range(2):
        solver.advance(model, state, dt, control, substeps)
    best = 0.0
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(frames):
            solver.advance(model, state, dt, control, substeps)
        seconds = time.perf_counter() - t0
        best = max(best, model.spring_count * settings.iterations * substeps * frames / seconds)
    return best


def start_times(mesh: Path, solver: str, frames: int = 24) -> tuple[float, float, float]:
    """(import, cold, warm) seconds: `import meshdeform.simulate`, then `meshdeform simulate` on a
    small mesh with an empty Numba cache (every kernel compiled) and again with that cache."""
    import tempfile

    exe = Path(sys.executable).with_name("meshdeform")
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "NUMBA_CACHE_DIR": str(Path(tmp) / "numba")}

        def timed(cmd: list[str]) -> float:
            t0 = time.perf_counter()
            subprocess.run(cmd, env=env, check=True, capture_output=True)
            return time.perf_counter() - t0

        base = timed([sys.executable, "-c", "import meshdeform.simulate, meshdeform.io, pipeline.cli"])
        cmd = [str(exe), "simulate", str(mesh), "--solver", solver, "--frames", str(frames), "-q",
               "--pin", "box:0,0.95,0,1,1,1", "--out", str(Path(tmp) / "out")]
        cold = timed(cmd)
        warm = timed(cmd)
    return base, cold, warm


def load() -> str:
    return "load average " + " ".join(f"{v:.2f}" for v in os.getloadavg())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="64,128,256")
    parser.add_argument("--solvers", default=",".join(ALL))
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--no-isolate", action="store_true", help="run everything in this process (RSS accumulates)")
    args = parser.parse_args()
    sizes = [int(s) for s in args.sizes.split(",")]
    names = [s for s in args.solvers.split(",") if s]
    print(f"cloth benchmark: N x N grid, 2 top corners pinned, gravity, 24 fps, {args.frames} frames; {load()}")
    header = (
        f"{'solver':9} {'N':>4} {'springs':>8} {'sub':>4} {'it':>3} {'first s':>8} {'frames/s':>9} "
        f"{'Mproj/s':>8} {'med f/s':>8} {'med Mp/s':>9} {'peak MB':>8} {'RSS MB':>7} {'stretch':>8} {'last':>7} "
        f"{'rest':>5}"
    )
    print(header)
    for name in names:
        for n in sizes:
            if name == "springs" and n > 64:
                print(f"{name:9} {n:>4}  skipped: explicit, its stable step shrinks with 1 / N (springs.py)")
                continue
            r = run(name, n, args.frames) if args.no_isolate else run_isolated(name, n, args.frames)
            print(
                f"{r['solver']:9} {r['n']:>4} {r['springs']:>8} {r['substeps']:>4} {r['iterations']:>3} "
                f"{r['cold']:>8.3f} {r['fps']:>9.1f} {r['proj'] / 1e6:>8.1f} {r['fps_median']:>8.1f} "
                f"{r['proj_median'] / 1e6:>9.1f} {r['peak_mb']:>8.1f} "
                f"{r['rss_mb']:>7.0f} {r['stretch']:>8.4f} {r['stretch_last']:>7.4f} {r['rest_frame']!s:>5}",
                flush=True,
            )
    print()
    for n in sizes:
        ref = reference(n)
        line = f"N={n}: NumPy Jacobi reference {ref / 1e6:.1f} M proj/s"
        for name in ("xpbd", "verlet"):
            if name in names:
                rate = kernel_rate(name, n)
                line += f"; {name} alone {rate / 1e6:.1f} M proj/s ({rate / ref:.1f}x)"
        print(line, flush=True)
    mesh = Path(__file__).resolve().parents[1] / "samples" / "meshes" / "flag.obj"
    if mesh.exists():
        for name in ("xpbd", "verlet"):
            if name in names:
                base, cold, warm = start_times(mesh, name)
                print(
                    f"start, `meshdeform simulate {mesh.name} --solver {name} --frames 24`: cold (empty Numba "
                    f"cache) {cold:.1f} s, warm {warm:.1f} s; importing alone {base:.1f} s",
                    flush=True,
                )
    print(load())


if __name__ == "__main__":
    main()
