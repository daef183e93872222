"""Verlet cloth (Jakobsen 2001, Mosegaard): Verlet integration, springs as distance constraints.

Each substep integrates positions from the previous ones (x' = x + (x - x_prev) * retention +
a dt^2) and then relaxes every spring toward its rest length in `iterations` Gauss-Seidel
sweeps (alternating direction, the first forward: from the pins outward, which carries their
hold across the cloth in one pass), slabs of the mesh in parallel (see `layout`). Default:
2 sweeps (a symmetric forward + backward step; a single forward sweep is not symmetric and can
pump energy into the cloth, see `xpbd`) and 18 substeps per frame (the measurements behind it:
docs/performance.md).

Per-kind stiffness: the spring constant k = stiffness * material.stretch_modulus of the force
based solvers (compression alike), turned into the fraction of a spring's length error a substep
removes, k dt^2 w / (1 + k dt^2 w) (`relaxation`): a spring holding a mass against a pin hangs
at the stretch m g / k whatever the step, as with `springs`, `implicit` and `xpbd`; each sweep
removes 1 - (1 - that) ** (1 / iterations) (Mueller et al. 2007), so the iteration count
changes convergence, not the material. On a mesh the sweeps reach that equilibrium only when
k dt^2 w is small; otherwise the cloth comes out softer (docs/performance.md has figures; each
frame's `force_residual` measures it). Velocities are (x - x_prev) / dt. Material spring
damping is not used; air damping is `options.damping`.
Tethers (`options.tethers`, long range attachments to the pins) are applied before and after
the sweeps so that a cloth hanging from a few pins does not stretch far near them; their
paths and slack are xpbd's (`xpbd.solver.TETHER_KINDS`, `TETHER_SLACK`: structural and shear
springs, 3 %; a tether acts only past that stretch, so it does not stiffen the material below
it). Structural paths only and no slack, as before verlet read the spring constant, clamp the
stretch below the pins to zero and make the cloth stiffer than its material.
Where a collider pushes the cloth further from its pins than the tethers allow (a plate punched
through a cloth pinned at both sides), they give way around the vertices the colliders moved
after the last substep (`Control.pushed`, `sweep_kernels.release_tethers`, as xpbd's around its
contact planes); held, the springs at the edge of the push took the whole difference.
Grips moved further apart than the tethers allow scale the limits alike (as xpbd's).

A whole substep is one compiled call (`kernels.verlet_substep`, or its parallel build, the same
bytes either way: `dispatch.SubstepPicker` runs the faster on the machine now), and
so is a whole frame when nothing happens between its substeps (`advance`: the vertices stay in
the scratch, `sweep_kernels.VERTEX` records as xpbd's, the same bytes as substep by substep).
Per spring the factors k w_a / w and k w_b / w (tension and compression) are precomputed into
one `kernels.RELAX_SPRING` row.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from meshdeform.model import SpringModel, State
from meshdeform.solvers.base import Control, Solver, velocity_retention
from meshdeform.solvers.common import SweepSolver, spring_constants
from meshdeform.solvers.options import VerletOptions
from meshdeform.solvers.verlet import kernels
from meshdeform.solvers.xpbd.solver import TETHER_KINDS, TETHER_SLACK


def relaxation(k: np.ndarray, w: np.ndarray, dt: float, iterations: int) -> np.ndarray:
    """Relaxation factor per sweep (S,) of springs of constant k (S,) N/m whose ends' inverse
    masses sum to w (S,) 1/kg, for substeps of dt s and `iterations` sweeps.

    A substep removes the fraction s = k dt^2 w / (1 + k dt^2 w) of a spring's length error: a
    spring holding a mass m against a pin then settles where (1 - s) / s = 1 / (k dt^2 w), at
    the stretch m g / k of a spring of constant k, whatever dt (the same equilibrium as the force
    based solvers). Spread over the sweeps as 1 - (1 - s) ** (1 / iterations) (Mueller et al. 2007).
    """
    kw = np.maximum(k, 0.0) * w * (dt * dt)
    keep = 1.0 / (1.0 + kw)  # 1 - s
    return 1.0 - np.power(keep, 1.0 / max(int(iterations), 1))


class VerletSolver(SweepSolver, Solver):
    """Position-based Verlet cloth with per-kind relaxation factors."""

    name: ClassVar[str] = "verlet"
    summary: ClassVar[str] = "Verlet integration, springs relaxed as distance constraints (Jakobsen 2001)"
    hint: ClassVar[str] = "keep stiffness within 0..1 or use more substeps"
    options_class: ClassVar[type[VerletOptions]] = VerletOptions
    parallel_kernels: ClassVar[bool] = True
    default_substeps: ClassVar[int] = 18
    fast_step_edges: ClassVar[float | None] = 1.0
    default_iterations: ClassVar[int] = 2
    reads_pushes: ClassVar[bool] = True
    tether_kinds: ClassVar[tuple[int, ...]] = TETHER_KINDS
    tether_slack: ClassVar[float] = TETHER_SLACK

    def _prepare(self, model: SpringModel) -> None:
        lay = self._prepare_sweeps(model, kernels.verlet_substep, kernels.verlet_substep_parallel)
        kt, kc = spring_constants(model)
        self.kt = lay.take(kt)
        self.kc = lay.take(kc)
        wa = self.inv_mass[lay.a]
        wb = self.inv_mass[lay.b]
        self.w = wa + wb
        self.share_a = np.where(self.w > 0.0, wa / np.where(self.w > 0.0, self.w, 1.0), 0.0)
        self.share_b = np.where(self.w > 0.0, wb / np.where(self.w > 0.0, self.w, 1.0), 0.0)
        p = self.params = self._buffer("params", lay.a.shape[0], kernels.RELAX_SPRING)
        p["a"] = lay.ends["a"]
        p["b"] = lay.ends["b"]
        p["rest"] = lay.rest

    def _coefficients(self, dt: float) -> None:
        """The relaxation factors of the records for substeps of dt (`relaxation`)."""
        p = self.params
        ft = relaxation(self.kt, self.w, dt, self.iterations)
        fc = relaxation(self.kc, self.w, dt, self.iterations)
        p["at"] = ft * self.share_a
        p["bt"] = ft * self.share_b
        p["ac"] = fc * self.share_a
        p["bc"] = fc * self.share_b
        self.retention = velocity_retention(self.options.damping, dt)
        self._dt = dt

    def advance(self, model: SpringModel, state: State, dt: float, control: Control, count: int) -> None:
        """`count` substeps of dt with the same accelerations, as one compiled call (the same
        result as `count` calls of `step`, without writing the State back in between)."""
        if not self._prepared(model):
            self._prepare(model)
        if dt != self._dt:
            self._coefficients(dt)
        self._starts_run(state)
        lay = self.layout
        touched = None if control.pushed is None else np.flatnonzero(control.pushed)
        release_state, release = self._release(touched)
        args = (
            state.positions, state.previous, state.velocities, self.inv_mass, control.accelerations,
            self.retention, dt, self.scratch, lay.vertex_rank, lay.vertex_order, self.params,
            self.offsets, lay.parts, self.iterations, self.tether_work, self.chunks.vertices, self.chunks.tethers,
            self.tethers, release_state, release,
        )
        self.substep(*args, count)
