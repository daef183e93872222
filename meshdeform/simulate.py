"""The fixed-step simulation loop: frames split into substeps, forces and constraints around a solver.

Per substep: external accelerations (gravity plus every force of the scene) are evaluated,
animated hard pins are moved to their targets, the solver steps, then the scene's constraints
(colliders, soft pins) are projected and hard pins are restored exactly. After each frame a
guard stops the run with `SimulationDiverged` when positions are non-finite or run away.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from meshdeform.errors import SimulationDiverged
from meshdeform.model import SpringModel, State
from meshdeform.solvers.base import Control, Solver, SolverOptions, make_solver


class Force(Protocol):
    """Adds accelerations (m/s^2) for welded vertices at a time into `out` (W, 3)."""

    def accumulate(self, model: SpringModel, state: State, time: float, out: np.ndarray) -> None: ...


class Constraint(Protocol):
    """Projects positions after each solver substep (colliders, soft pins)."""

    def project(self, model: SpringModel, state: State, time: float, dt: float) -> None: ...


#: maps a time in seconds to target positions (P, 3) of the model's pinned vertices, in
#: the order of `np.flatnonzero(model.pinned)`
PinMotion = Callable[[float], np.ndarray]


@dataclass
class Scene:
    """Everything acting on the model besides its springs."""

    gravity: tuple[float, float, float] = (0.0, -9.81, 0.0)
    forces: list[Force] = field(default_factory=list)
    constraints: list[Constraint] = field(default_factory=list)
    pin_motion: PinMotion | None = None


@dataclass(frozen=True)
class Settings:
    """Time stepping: frames at fps, each split into substeps, and the solver's options."""

    solver: str = "verlet"
    fps: float = 24.0
    frames: int = 120
    substeps: int = 8
    options: SolverOptions = field(default_factory=SolverOptions)

    @property
    def dt(self) -> float:
        return 1.0 / (self.fps * self.substeps)


@dataclass(frozen=True)
class Frame:
    """One output frame: number (from 1), time, positions in the input layout and figures."""

    index: int
    time: float
    positions: np.ndarray
    welded_positions: np.ndarray
    max_stretch: float
    max_speed: float


def _runaway_limit(model: SpringModel, gravity: np.ndarray, time: float) -> float:
    extent = model.rest_positions.max(axis=0) - model.rest_positions.min(axis=0) if model.vertex_count else np.ones(3)
    diag = float(np.linalg.norm(extent)) or 1.0
    return 1000.0 * diag + float(np.linalg.norm(gravity)) * time * time + 100.0


def simulate(
    model: SpringModel,
    scene: Scene | None = None,
    settings: Settings | None = None,
    solver: Solver | None = None,
    state: State | None = None,
) -> Iterator[Frame]:
    """Yield `settings.frames` frames of the model moving under the scene, starting at rest."""
    scene = scene or Scene()
    settings = settings or Settings()
    solver = solver or make_solver(settings.solver, settings.options)
    state = state or State.at_rest(model)
    dt = settings.dt
    gravity = np.asarray(scene.gravity, dtype=np.float64)
    pinned_idx = np.flatnonzero(model.pinned)
    pinned_rest = model.rest_positions[pinned_idx]
    accelerations = np.empty_like(state.positions)
    control = Control(accelerations=accelerations)
    center = model.rest_positions.mean(axis=0) if model.vertex_count else np.zeros(3)
    step_count = 0
    for frame in range(1, settings.frames + 1):
        for _ in range(settings.substeps):
            t0 = state.time
            step_count += 1
            t1 = step_count * dt
            accelerations[:] = gravity
            for force in scene.forces:
                force.accumulate(model, state, t0, accelerations)
            if scene.pin_motion is not None and pinned_idx.size:
                state.previous[pinned_idx] = state.positions[pinned_idx]
                state.positions[pinned_idx] = scene.pin_motion(t1)
            solver.step(model, state, dt, control)
            for constraint in scene.constraints:
                constraint.project(model, state, t1, dt)
            if pinned_idx.size:
                state.positions[pinned_idx] = scene.pin_motion(t1) if scene.pin_motion is not None else pinned_rest
            state.time = t1
        positions = state.positions
        if not np.isfinite(positions).all():
            raise SimulationDiverged(
                f"simulation diverged at frame {frame} with solver {settings.solver!r}: positions became non-finite; "
                "try a smaller time step (more substeps), more iterations or lower stiffness",
                frame=frame,
                solver=settings.solver,
            )
        reach = float(np.abs(positions - center).max()) if positions.size else 0.0
        if reach > _runaway_limit(model, gravity, state.time):
            raise SimulationDiverged(
                f"simulation diverged at frame {frame} with solver {settings.solver!r}: positions ran away "
                f"({reach:.3g} from the mesh centre); try more substeps, more iterations or lower stiffness",
                frame=frame,
                solver=settings.solver,
            )
        speed = np.sqrt(np.einsum("ij,ij->i", state.velocities, state.velocities)) if positions.size else np.zeros(1)
        welded = positions.copy()
        yield Frame(
            index=frame,
            time=state.time,
            positions=model.to_input_layout(welded),
            welded_positions=welded,
            max_stretch=model.max_stretch(welded),
            max_speed=float(speed.max()) if speed.size else 0.0,
        )
