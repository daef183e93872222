"""XPBD cloth (Macklin, Mueller, Chentanez 2016): compliant distance constraints per spring kind.

Each substep predicts positions (Verlet form, x' = x + (x - x_prev) * retention + a dt^2),
resets the Lagrange multipliers and runs `iterations` symmetric Gauss-Seidel sweeps of

    dlam = (-C - alpha~ lam - gamma grad C . (x - x_prev)) / ((1 + gamma) (w_a + w_b) + alpha~)

with C = |x_b - x_a| - L, alpha~ = alpha / dt^2 and gamma = alpha beta / dt (eq. 26 of the
paper). Compliance alpha = 1 / k with k = stiffness * material.stretch_modulus (N/m), the same
spring constant as `springs` and `implicit`: the equilibrium does not depend on the step
size or the iteration count once the sweeps converge. The default is the "small steps"
style (Macklin et al. 2019): many substeps (16 per frame) with few sweeps (2: one forward,
one backward), which converges better per unit of work than many sweeps per substep. A
single sweep per substep always in one direction was measured to pump energy into stiff
cloth (it blew up within seconds), so sweeps alternate direction and the default is 2.
beta = c = 2 z sqrt(k m_red) from the kind's damping ratio z. Springs are ordered from the
pins outward and slabs of the mesh are swept in parallel (see `layout`). Tethers
(`options.tethers`, long range attachments to the pins) are applied before and after the
sweeps; they cap stretch along paths from the pins (set them off to see the compliance alone).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from meshdeform.model import SpringModel, State
from meshdeform.solvers import kernels
from meshdeform.solvers.base import Control, SolverOptions, register, velocity_retention
from meshdeform.solvers.common import ModelCache, damping_coefficients, spring_constants
from meshdeform.solvers.layout import spring_layout, tethers


@register
class XPBDSolver(ModelCache):
    """Extended position-based dynamics with per-kind compliance and constraint damping."""

    name: ClassVar[str] = "xpbd"
    default_substeps: ClassVar[int] = 16
    default_iterations: ClassVar[int] = 2

    def __init__(self, options: SolverOptions) -> None:
        self.options = options
        self.iterations = options.iterations_for(self)
        self._dt = -1.0

    def _prepare(self, model: SpringModel) -> None:
        self.layout = spring_layout(model, self.options.partitions)
        kt, kc = spring_constants(model)
        self.kt = self.layout.take(kt)
        self.kc = self.layout.take(kc)
        self.c = self.layout.take(damping_coefficients(model, kt))
        self.inv_mass = np.ascontiguousarray(model.inv_mass, dtype=np.float64)
        ratio = self.options.tethers
        self.tethers = tethers(model, ratio) if ratio is not None and ratio > 0 else None
        self.lam = np.zeros(self.layout.a.shape[0])
        self._dt = -1.0

    def _coefficients(self, dt: float) -> None:
        inv_dt2 = 1.0 / (dt * dt)
        with np.errstate(divide="ignore"):
            self.at = np.where(self.kt > 0.0, inv_dt2 / np.where(self.kt > 0.0, self.kt, 1.0), -1.0)
            self.ac = np.where(self.kc > 0.0, inv_dt2 / np.where(self.kc > 0.0, self.kc, 1.0), -1.0)
            self.gamma = np.where(self.kt > 0.0, self.c / (np.where(self.kt > 0.0, self.kt, 1.0) * dt), 0.0)
        self._dt = dt

    def step(self, model: SpringModel, state: State, dt: float, control: Control) -> None:
        if not self._prepared(model):
            self._prepare(model)
        if dt != self._dt:
            self._coefficients(dt)
        lay = self.layout
        kernels.predict_verlet(
            state.positions, state.previous, self.inv_mass, control.accelerations,
            velocity_retention(self.options.damping, dt), dt * dt,
        )
        if self.tethers is not None:
            t = self.tethers
            kernels.apply_tethers(state.positions, t.vertex, t.pin, t.limit)
        solve = kernels.xpbd_solve if lay.parts > 1 else kernels.xpbd_solve_serial
        solve(
            state.positions, state.previous, lay.a, lay.b, lay.rest, self.inv_mass,
            self.at, self.ac, self.gamma, self.lam, lay.offsets, lay.parts, self.iterations, 0,
        )
        if self.tethers is not None:
            t = self.tethers
            kernels.apply_tethers(state.positions, t.vertex, t.pin, t.limit)
        kernels.velocities_from_positions(state.positions, state.previous, state.velocities, 1.0 / dt)
