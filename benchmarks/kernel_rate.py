"""Kernel rate of xpbd against a plain graph-coloured parallel Gauss-Seidel XPBD peer (issue 16 item 7).

    PYTHONPATH=<tree> python benchmarks/kernel_rate.py [--n 256] [--frames 3] [--repeats 7]

The scene: the reference cloth (an N x N grid of 1 m, vertical, hanging from its two top corners,
structural, shear and bending springs: `SpringModel.from_mesh`), gravity, 24 fps, xpbd's default
sweeps and substeps (`Settings(solver="xpbd")`). Three kernels run the same substeps on it, in
turn (peer, serial, parallel, peer, ...: a drift of the shared machine's speed hits all three):

- peer: a plain coloured parallel Gauss-Seidel XPBD distance-constraint kernel in Numba, written
  here as the yardstick. Springs are graph-coloured (greedy: the smallest colour no earlier spring
  at either end has) and grouped by colour; positions are structure-of-arrays float64 (x, y, z,
  inverse mass); per spring its ends, rest length and compliance / dt^2. A substep is a Verlet
  prediction (`prange` over vertices), then per sweep one `prange` over each colour's springs
  (springs of one colour share no vertex). No damping along springs, no tethers: the plain kernel.
- xpbd serial / parallel: meshdeform's xpbd through `XPBDSolver.advance` on the same model (one
  call per frame, as `simulate` runs a gravity-only scene), with the serial and the parallel build
  forced (MESHDEFORM_PARALLEL_SUBSTEPS=0 / 1, read when a solver prepares a model).

Projections are counted alike for all three: springs x sweeps x substeps / seconds. Prints per
kernel the median rate over the repetitions (each `frames` frames after two warm-up frames) and
its min-max, the ratios to the peer, and the load average at the start and the end (the machine
is shared: quote the load beside any figure). Numba uses its default thread count (the cores).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numba as nb
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from meshdeform.mesh import grid_mesh
from meshdeform.model import SpringModel, State
from meshdeform.simulate import Settings
from meshdeform.solvers import Control, make_solver
from meshdeform.solvers.dispatch import PARALLEL_SUBSTEPS


def scene_model(n: int) -> SpringModel:
    """The reference cloth: 1 m x 1 m, vertical (XY, Y up), pinned at its two top corners."""
    mesh = grid_mesh(n, n, plane="xy")
    pinned = np.zeros(n * n, dtype=bool)
    pinned[[n * (n - 1), n * n - 1]] = True
    return SpringModel.from_mesh(mesh, pinned_input=pinned)


@nb.njit(cache=True)
def greedy_colours(a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    """(S,) colour of each spring: the smallest no earlier spring sharing an end has (at most 64)."""
    used = np.zeros(n, dtype=np.uint64)
    colour = np.empty(a.shape[0], dtype=np.int64)
    for s in range(a.shape[0]):
        taken = used[a[s]] | used[b[s]]
        c = 0
        while (taken >> np.uint64(c)) & np.uint64(1):
            c += 1
        colour[s] = c
        bit = np.uint64(1) << np.uint64(c)
        used[a[s]] |= bit
        used[b[s]] |= bit
    return colour


@nb.njit(parallel=True, fastmath=True, cache=True, error_model="numpy")
def peer_substeps(x, y, z, px, py, pz, w, ay, a, b, rest, alpha, lam, starts, retention, dt2, sweeps, count):
    """`count` XPBD substeps: Verlet prediction, then `sweeps` coloured Gauss-Seidel sweeps.

    x, y, z, px, py, pz, w: (W,) positions, previous positions, inverse masses; ay: gravity
    (m/s^2, along y); a, b, rest, alpha: (S,) ends, rest lengths, compliance / dt^2, grouped by
    colour (colour c is starts[c]:starts[c + 1]); lam: (S,) multipliers.
    """
    colours = starts.shape[0] - 1
    for _ in range(count):
        for i in nb.prange(x.shape[0]):
            if w[i] > 0.0:
                x0, y0, z0 = x[i], y[i], z[i]
                x[i] = x0 + (x0 - px[i]) * retention
                y[i] = y0 + (y0 - py[i]) * retention + ay * dt2
                z[i] = z0 + (z0 - pz[i]) * retention
                px[i], py[i], pz[i] = x0, y0, z0
        for it in range(sweeps):
            for c in range(colours):
                for s in nb.prange(starts[c], starts[c + 1]):
                    i = a[s]
                    j = b[s]
                    dx = x[j] - x[i]
                    dy = y[j] - y[i]
                    dz = z[j] - z[i]
                    length = np.sqrt(max(dx * dx + dy * dy + dz * dz, 1e-24))
                    wa = w[i]
                    wb = w[j]
                    den = wa + wb + alpha[s]
                    if den > 0.0:
                        lam_s = 0.0 if it == 0 else lam[s]
                        dlam = (rest[s] - length - alpha[s] * lam_s) / den
                        lam[s] = lam_s + dlam
                        f = dlam / length
                        x[i] -= wa * f * dx
                        y[i] -= wa * f * dy
                        z[i] -= wa * f * dz
                        x[j] += wb * f * dx
                        y[j] += wb * f * dy
                        z[j] += wb * f * dz


class Peer:
    """The coloured peer's arrays for a model and step (see `peer_substeps`)."""

    def __init__(self, model: SpringModel, dt: float, retention: float, sweeps: int) -> None:
        springs = np.asarray(model.springs, dtype=np.int64)
        colour = greedy_colours(springs[:, 0], springs[:, 1], model.vertex_count)
        order = np.argsort(colour, kind="stable")
        self.colours = int(colour.max()) + 1
        self.a = np.ascontiguousarray(springs[order, 0].astype(np.int32))
        self.b = np.ascontiguousarray(springs[order, 1].astype(np.int32))
        self.rest = np.ascontiguousarray(np.asarray(model.rest_lengths, dtype=np.float64)[order])
        k = np.maximum(np.asarray(model.stiffness, dtype=np.float64), 0.0)[order] * float(
            model.material.stretch_modulus
        )
        self.alpha = np.where(k > 0.0, 1.0 / np.where(k > 0.0, k, 1.0) / (dt * dt), 0.0)
        self.lam = np.zeros(springs.shape[0])
        self.starts = np.searchsorted(colour[order], np.arange(self.colours + 1)).astype(np.int64)
        pos = np.asarray(model.rest_positions, dtype=np.float64)
        self.x, self.y, self.z = (np.ascontiguousarray(pos[:, k]) for k in range(3))
        self.px, self.py, self.pz = self.x.copy(), self.y.copy(), self.z.copy()
        self.w = np.ascontiguousarray(model.inv_mass, dtype=np.float64)
        self.dt2 = dt * dt
        self.retention = retention
        self.sweeps = sweeps

    def frame(self, substeps: int) -> None:
        peer_substeps(
            self.x,
            self.y,
            self.z,
            self.px,
            self.py,
            self.pz,
            self.w,
            -9.81,
            self.a,
            self.b,
            self.rest,
            self.alpha,
            self.lam,
            self.starts,
            self.retention,
            self.dt2,
            self.sweeps,
            substeps,
        )


class Ours:
    """meshdeform's xpbd on the model, one `advance` call a frame, the build forced by `mode` ("0" / "1")."""

    def __init__(self, model: SpringModel, settings: Settings, mode: str) -> None:
        os.environ[PARALLEL_SUBSTEPS] = mode
        self.model = model
        self.solver = make_solver("xpbd", settings.options)
        self.state = State.at_rest(model)
        self.control = Control(np.tile(np.array([0.0, -9.81, 0.0]), (model.vertex_count, 1)))
        self.dt = settings.dt
        self.frame(int(settings.substeps))  # prepares the model: the picker reads the mode now
        self.build = self.solver.substep.build

    def frame(self, substeps: int) -> None:
        self.solver.advance(self.model, self.state, self.dt, self.control, substeps)


def load() -> str:
    return "load average " + " ".join(f"{v:.2f}" for v in os.getloadavg())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=256)
    parser.add_argument("--frames", type=int, default=3, help="frames per repetition")
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    threads = nb.get_num_threads()
    print(f"kernel rate, {args.n} x {args.n} cloth hanging from two corners; Numba threads {threads}; {load()}")
    model = scene_model(args.n)
    settings = Settings(solver="xpbd")
    substeps, sweeps = int(settings.substeps), int(settings.iterations)
    saved = os.environ.get(PARALLEL_SUBSTEPS)
    kernels = {
        "peer (coloured GS)": Peer(model, settings.dt, Ours(model, settings, "0").solver.retention, sweeps),
        "xpbd serial": Ours(model, settings, "0"),
        "xpbd parallel": Ours(model, settings, "1"),
    }
    if saved is None:
        os.environ.pop(PARALLEL_SUBSTEPS, None)
    else:
        os.environ[PARALLEL_SUBSTEPS] = saved
    per_frame = model.spring_count * sweeps * substeps
    peer = kernels["peer (coloured GS)"]
    print(
        f"{model.spring_count} springs, {model.vertex_count} vertices, {sweeps} sweeps x {substeps} substeps a frame; "
        f"peer: {peer.colours} colours; builds: {kernels['xpbd serial'].build}, {kernels['xpbd parallel'].build}"
    )
    for kernel in kernels.values():
        for _ in range(2):
            kernel.frame(substeps)
    rates: dict[str, list[float]] = {name: [] for name in kernels}
    for _ in range(args.repeats):
        for name, kernel in kernels.items():
            t0 = time.perf_counter()
            for _ in range(args.frames):
                kernel.frame(substeps)
            rates[name].append(per_frame * args.frames / (time.perf_counter() - t0))
    base = statistics.median(rates["peer (coloured GS)"])
    for name, values in rates.items():
        median = statistics.median(values)
        print(
            f"{name:20} {median / 1e6:7.1f} M projections/s (min-max {min(values) / 1e6:.1f}-{max(values) / 1e6:.1f}), "
            f"{median / base:.2f}x the peer"
        )
    print(load())


if __name__ == "__main__":
    main()
