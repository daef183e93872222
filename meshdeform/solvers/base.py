"""The solver interface: a small object with `step(model, state, dt, control)`.

Solvers only advance positions under spring forces or constraints and the external
accelerations in `Control`; pins with inv_mass 0 are never moved by a solver. Gravity,
wind, impacts, colliders and pin animation are evaluated outside (see `meshdeform.simulate`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Protocol

import numpy as np

from meshdeform.errors import MeshdeformError
from meshdeform.model import SpringModel, State


@dataclass
class Control:
    """Per-substep inputs from outside the solver: external accelerations (W, 3), m/s^2."""

    accelerations: np.ndarray


class Solver(Protocol):
    """Advances a State by dt in place; keeps `state.previous` and `state.velocities` consistent."""

    name: ClassVar[str]

    def step(self, model: SpringModel, state: State, dt: float, control: Control) -> None: ...


@dataclass(frozen=True)
class SolverOptions:
    """Options shared by all solvers; each solver reads what applies to it.

    iterations: constraint relaxation sweeps per substep (verlet, xpbd).
    damping: fraction of velocity removed per second of simulated time (air/velocity damping),
        0 <= damping < 1 applied per substep as (1 - damping) ** dt.
    strain_limit: optional maximum stretch ratio (springs solver, Provot 1995), e.g. 1.1.
    """

    iterations: int = 10
    damping: float = 0.01
    strain_limit: float | None = None


SOLVERS: dict[str, type] = {}


def register(cls: type) -> type:
    """Class decorator adding a solver to the registry under its `name`."""
    SOLVERS[cls.name] = cls
    return cls


def make_solver(name: str, options: SolverOptions | None = None) -> Solver:
    """A solver instance by registry name; unknown names raise MeshdeformError listing the known ones."""
    import meshdeform.solvers  # noqa: F401  (registers the built-in solvers)

    try:
        cls = SOLVERS[name]
    except KeyError:
        raise MeshdeformError(f"unknown solver {name!r}; choose one of: {', '.join(sorted(SOLVERS))}") from None
    return cls(options or SolverOptions())


def velocity_retention(damping: float, dt: float) -> float:
    """Velocity factor for one substep given a damping fraction per second."""
    return float((1.0 - min(max(damping, 0.0), 0.999999)) ** dt)
