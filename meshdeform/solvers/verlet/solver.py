"""Verlet cloth (Jakobsen 2001, Mosegaard): Verlet integration, springs as distance constraints.

Each substep integrates positions from the previous ones (x' = x + (x - x_prev) * retention +
a dt^2) and then relaxes every spring toward its rest length in `iterations` Gauss-Seidel
sweeps (alternating direction, the first forward: from the pins outward, which carries their
hold across the cloth in one pass), slabs of the mesh in parallel (see `layout`). Default:
2 sweeps (a symmetric forward + backward step; a single forward sweep is not symmetric and can
pump energy into the cloth, see `xpbd`) and 18 substeps per frame (the measurements behind it:
docs/performance.md).

Per-kind stiffness: a kind's stiffness s (0..1, compression separately) is the fraction of a
spring's length error removed per substep; each sweep uses 1 - (1 - s) ** (1 / iterations)
(Mueller et al. 2007) so that changing the iteration count changes convergence, not the
material. s = 1 makes a spring as stiff as the sweeps can make it. Velocities are
(x - x_prev) / dt. Material spring damping is not used; air damping is `options.damping`.
Tethers (`options.tethers`, long range attachments to the pins) are applied before and after
the sweeps so that a cloth hanging from a few pins does not stretch far near them; their
distances run along structural springs only (tighter, octile tethers as in `xpbd` fight the
fully stiff relaxation here and raise the stretch).

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
from meshdeform.solvers.common import SweepSolver
from meshdeform.solvers.options import VerletOptions
from meshdeform.solvers.verlet import kernels


def per_iteration(stiffness: np.ndarray, iterations: int) -> np.ndarray:
    """Relaxation factor per sweep so that `iterations` sweeps remove the fraction `stiffness`."""
    s = np.maximum(np.asarray(stiffness, dtype=np.float64), 0.0)
    soft = 1.0 - np.power(np.clip(1.0 - s, 0.0, 1.0), 1.0 / max(iterations, 1))
    return np.where(s >= 1.0, s, soft)


class VerletSolver(SweepSolver, Solver):
    """Position-based Verlet cloth with per-kind relaxation factors."""

    name: ClassVar[str] = "verlet"
    summary: ClassVar[str] = "Verlet integration, springs relaxed as distance constraints (Jakobsen 2001)"
    hint: ClassVar[str] = "keep stiffness within 0..1 or use more substeps"
    options_class: ClassVar[type[VerletOptions]] = VerletOptions
    default_substeps: ClassVar[int] = 18
    default_iterations: ClassVar[int] = 2

    def _prepare(self, model: SpringModel) -> None:
        lay = self._prepare_sweeps(model, kernels.verlet_substep, kernels.verlet_substep_parallel)
        self.kt = lay.take(per_iteration(model.stiffness, self.iterations))
        self.kc = lay.take(per_iteration(model.compression, self.iterations))
        wa = self.inv_mass[lay.a]
        wb = self.inv_mass[lay.b]
        w = wa + wb
        share_a = np.where(w > 0.0, wa / np.where(w > 0.0, w, 1.0), 0.0)
        share_b = np.where(w > 0.0, wb / np.where(w > 0.0, w, 1.0), 0.0)
        p = self.params = self._buffer("params", lay.a.shape[0], kernels.RELAX_SPRING)
        p["a"] = lay.ends["a"]
        p["b"] = lay.ends["b"]
        p["rest"] = lay.rest
        p["at"] = self.kt * share_a
        p["bt"] = self.kt * share_b
        p["ac"] = self.kc * share_a
        p["bc"] = self.kc * share_b

    def advance(self, model: SpringModel, state: State, dt: float, control: Control, count: int) -> None:
        """`count` substeps of dt with the same accelerations, as one compiled call (the same
        result as `count` calls of `step`, without writing the State back in between)."""
        if not self._prepared(model):
            self._prepare(model)
        if dt != self._dt:
            self.retention = velocity_retention(self.options.damping, dt)
            self._dt = dt
        lay = self.layout
        args = (
            state.positions, state.previous, state.velocities, self.inv_mass, control.accelerations,
            self.retention, dt, self.scratch, lay.vertex_rank, lay.vertex_order, self.params,
            self.offsets, lay.parts, self.iterations, self.tethers, self.chunks.vertices, self.chunks.tethers,
        )
        self.substep(*args, count)
