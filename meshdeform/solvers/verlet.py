"""Verlet cloth (Jakobsen 2001, Mosegaard): Verlet integration, springs as distance constraints.

Each substep integrates positions from the previous ones (x' = x + (x - x_prev) * retention +
a dt^2) and then relaxes every spring toward its rest length `iterations` times, Gauss-Seidel.
Stiffness per spring is the relaxation factor (0..1) of its kind; pinned vertices (inv_mass 0)
never move.
"""

from __future__ import annotations

from typing import ClassVar

import numba as nb
import numpy as np

from meshdeform.model import SpringModel, State
from meshdeform.solvers.base import Control, SolverOptions, register, velocity_retention


@nb.njit(cache=True, error_model="numpy", fastmath=False)
def verlet_integrate(x: np.ndarray, prev: np.ndarray, inv_mass: np.ndarray, accel: np.ndarray, retention: float, dt2: float) -> None:
    for i in range(x.shape[0]):
        if inv_mass[i] == 0.0:
            prev[i, 0] = x[i, 0]
            prev[i, 1] = x[i, 1]
            prev[i, 2] = x[i, 2]
            continue
        for k in range(3):
            xi = x[i, k]
            x[i, k] = xi + (xi - prev[i, k]) * retention + accel[i, k] * dt2
            prev[i, k] = xi


@nb.njit(cache=True, error_model="numpy")
def relax_springs(
    x: np.ndarray,
    springs: np.ndarray,
    rest: np.ndarray,
    stiffness: np.ndarray,
    compression: np.ndarray,
    inv_mass: np.ndarray,
    iterations: int,
) -> None:
    for _ in range(iterations):
        for s in range(springs.shape[0]):
            a = springs[s, 0]
            b = springs[s, 1]
            wa = inv_mass[a]
            wb = inv_mass[b]
            w = wa + wb
            if w == 0.0:
                continue
            dx = x[b, 0] - x[a, 0]
            dy = x[b, 1] - x[a, 1]
            dz = x[b, 2] - x[a, 2]
            length = np.sqrt(dx * dx + dy * dy + dz * dz)
            if length <= 1e-300:
                continue
            diff = (length - rest[s]) / length
            k = stiffness[s] if diff > 0.0 else compression[s]
            f = diff * k / w
            x[a, 0] += dx * f * wa
            x[a, 1] += dy * f * wa
            x[a, 2] += dz * f * wa
            x[b, 0] -= dx * f * wb
            x[b, 1] -= dy * f * wb
            x[b, 2] -= dz * f * wb


@register
class VerletSolver:
    """Position-based Verlet cloth with per-kind relaxation factors."""

    name: ClassVar[str] = "verlet"

    def __init__(self, options: SolverOptions) -> None:
        self.options = options

    def step(self, model: SpringModel, state: State, dt: float, control: Control) -> None:
        retention = velocity_retention(self.options.damping, dt)
        verlet_integrate(state.positions, state.previous, model.inv_mass, control.accelerations, retention, dt * dt)
        relax_springs(
            state.positions,
            model.springs,
            model.rest_lengths,
            model.stiffness,
            model.compression,
            model.inv_mass,
            self.options.iterations,
        )
        np.subtract(state.positions, state.previous, out=state.velocities)
        state.velocities /= dt
