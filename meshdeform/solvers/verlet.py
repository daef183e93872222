"""Verlet cloth (Jakobsen 2001, Mosegaard): Verlet integration, springs as distance constraints.

Each substep integrates positions from the previous ones (x' = x + (x - x_prev) * retention +
a dt^2) and then relaxes every spring toward its rest length in `iterations` symmetric
Gauss-Seidel sweeps (alternating direction), slabs of the mesh in parallel (see `layout`).

Per-kind stiffness: a kind's stiffness s (0..1, compression separately) is the fraction of a
spring's length error removed per substep; each sweep uses 1 - (1 - s) ** (1 / iterations)
(Mueller et al. 2007) so that changing the iteration count changes convergence, not the
material. s = 1 makes a spring as stiff as the sweeps can make it. Velocities are
(x - x_prev) / dt. Material spring damping is not used; air damping is `options.damping`.
Tethers (`options.tethers`, long range attachments to the pins) are applied before and after
the sweeps so that a cloth hanging from a few pins does not stretch far near them.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from meshdeform.model import SpringModel, State
from meshdeform.solvers import kernels
from meshdeform.solvers.base import Control, SolverOptions, register, velocity_retention
from meshdeform.solvers.common import ModelCache
from meshdeform.solvers.layout import spring_layout, tethers


def per_iteration(stiffness: np.ndarray, iterations: int) -> np.ndarray:
    """Relaxation factor per sweep so that `iterations` sweeps remove the fraction `stiffness`."""
    s = np.maximum(np.asarray(stiffness, dtype=np.float64), 0.0)
    soft = 1.0 - np.power(np.clip(1.0 - s, 0.0, 1.0), 1.0 / max(iterations, 1))
    return np.where(s >= 1.0, s, soft)


@register
class VerletSolver(ModelCache):
    """Position-based Verlet cloth with per-kind relaxation factors."""

    name: ClassVar[str] = "verlet"
    default_substeps: ClassVar[int] = 16
    default_iterations: ClassVar[int] = 2

    def __init__(self, options: SolverOptions) -> None:
        self.options = options
        self.iterations = options.iterations_for(self)

    def _prepare(self, model: SpringModel) -> None:
        self.layout = spring_layout(model, self.options.partitions)
        self.kt = self.layout.take(per_iteration(model.stiffness, self.iterations))
        self.kc = self.layout.take(per_iteration(model.compression, self.iterations))
        self.inv_mass = np.ascontiguousarray(model.inv_mass, dtype=np.float64)
        ratio = self.options.tethers
        self.tethers = tethers(model, ratio) if ratio is not None and ratio > 0 else None

    def step(self, model: SpringModel, state: State, dt: float, control: Control) -> None:
        if not self._prepared(model):
            self._prepare(model)
        lay = self.layout
        kernels.predict_verlet(
            state.positions, state.previous, self.inv_mass, control.accelerations,
            velocity_retention(self.options.damping, dt), dt * dt,
        )
        if self.tethers is not None:
            t = self.tethers
            kernels.apply_tethers(state.positions, t.vertex, t.pin, t.limit)
        solve = kernels.relax_springs if lay.parts > 1 else kernels.relax_springs_serial
        solve(
            state.positions, lay.a, lay.b, lay.rest, self.inv_mass, self.kt, self.kc,
            lay.offsets, lay.parts, self.iterations, 0,
        )
        if self.tethers is not None:
            t = self.tethers
            kernels.apply_tethers(state.positions, t.vertex, t.pin, t.limit)
        kernels.velocities_from_positions(state.positions, state.previous, state.velocities, 1.0 / dt)
