"""The solver contract: the `Solver` base class (`step`, `advance`, `follow_tear`) and its `Control`.

Solvers only advance positions under spring forces or constraints and the external
accelerations in `Control`; pins with inv_mass 0 are never moved by a solver. Gravity,
wind, impacts, colliders and pin animation are evaluated outside (see `meshdeform.simulate`).

A solver instance caches data derived from the model it last stepped (spring order,
partitions, per-spring constants, a factorisation); stepping another model (for example
after tearing) rebuilds the cache. One instance serves one simulation at a time.

Damping (`SolverOptions.damping`) means the same for every solver: the fraction of a
vertex's velocity that air/velocity damping removes per second of simulated time, applied
per step as a factor `(1 - damping) ** dt` (so it does not depend on the step size). 0 is
no damping; the default 0.9 (a decay rate of ln 10 = 2.3 per second, about the air drag of
a light cloth: terminal velocity g / 2.3 = 4.3 m/s) makes a hanging cloth come to rest
(max vertex speed below 1e-4 m/s) within a few seconds. Spring damping along springs is a
material property (`KindMaterial.damping`, a damping ratio, see `meshdeform.material`).
Free fall is only exact without air damping (damping = 0).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from meshdeform.model import SpringModel, State


@dataclass
class Control:
    """Per-substep inputs from outside the solver: external accelerations (W, 3), m/s^2.

    Solvers read but never modify it. A velocity kick dv over one substep of length dt
    (an impact) is the acceleration dv / dt during that substep; every solver turns it
    into the same change of momentum.
    """

    accelerations: np.ndarray


class Solver(ABC):
    """Advances a State by dt in place; keeps `state.previous` and `state.velocities` consistent.

    Subclasses (one folder each, listed in `registry.SOLVERS`) set the class attributes:
    name: registry key, the recipe's `solver` value.
    summary: one line of help text (the CLI's `--solver` help, the docs).
    hint: what to try when a run with this solver diverges (quoted by `simulate`'s guard).
    default_substeps: substeps per frame when `Settings.substeps` is None.
    default_iterations: iterations when `options.iterations` is None (0: the solver has none).
    options_class: the options it takes (`meshdeform.solvers.options`).

    `state.time` is the caller's: `simulate` sets it after every `step` and after `advance`.
    """

    name: ClassVar[str]
    summary: ClassVar[str]
    hint: ClassVar[str]
    default_substeps: ClassVar[int]
    default_iterations: ClassVar[int] = 0
    options_class: ClassVar[type[SolverOptions]]

    def __init__(self, options: SolverOptions) -> None:
        self.options = options

    @abstractmethod
    def step(self, model: SpringModel, state: State, dt: float, control: Control) -> None:
        """One substep of dt under the external accelerations of `control`."""

    def advance(self, model: SpringModel, state: State, dt: float, control: Control, count: int) -> None:
        """`count` substeps of dt with the same `control` (nothing runs between them), the same
        bytes as `count` calls of `step`; `simulate` calls it for scenes of gravity alone.

        This default calls `step` `count` times and moves `state.time` on by dt after each, as
        `simulate` does between substeps (a step may read it: `implicit` checks that the state
        continues its last step). Solvers override it to run the substeps in one compiled call.
        """
        start = state.time
        for k in range(1, count + 1):
            self.step(model, state, dt, control)
            state.time = start + k * dt

    def follow_tear(  # noqa: B027 - a deliberate no-op default, not a forgotten abstract method
        self, previous: SpringModel, model: SpringModel, index_map: np.ndarray, parent: np.ndarray
    ) -> None:
        """`model` replaces `previous` after a tear (index_map: (W',) new vertex -> previous one;
        parent: (S',) new spring -> previous one), before `model` is first stepped. Solvers that
        can derive their per-model data from the previous model's override it; by default the
        next step rebuilds them from `model`."""


@dataclass(frozen=True)
class SolverOptions:
    """Options shared by all solvers; each solver reads what applies to it.

    iterations: constraint sweeps per substep (verlet, xpbd) or local/global iterations per
        step (implicit); None means the solver's default (verlet 2, xpbd 2, implicit 6;
        springs and anchor have none).
    damping: fraction of velocity removed per second of simulated time (air/velocity
        damping, 0 <= damping < 1), applied per substep as (1 - damping) ** dt. See the module
        docstring; default 0.9.
    strain_limit: maximum stretch ratio of structural springs (Provot 1995) for `springs`
        and `anchor` with neighbour springs, e.g. 1.1 for 10 %; None switches it off.
    strain_iterations: at most this many Gauss-Seidel passes enforce the strain limit per step
        (it stops as soon as no structural spring exceeds it).
    stable_substeps: `springs` and `anchor` split a substep into as many explicit steps as
        the stiffest spring needs to stay stable (from a Gershgorin bound on k/m); False
        trusts the given substeps (and may explode, which the guard in simulate reports).
    anchor_stiffness: `anchor` spring constant per unit mass (1/s^2, as Catlike Coding's
        "spring force"): acceleration -anchor_stiffness * uniform_scale * (x - anchor).
    anchor_damping: `anchor`: the original deformer's damping (1/s, Catlike Coding's
        `velocity *= 1 - damping dt`, default 5 as there): each vertex's velocity relative to
        its anchor decays as exp(-anchor_damping t) (exactly, whatever the step), on top of the
        air damping `damping`. In the "centroid" frame it acts on velocities relative to the
        centre of mass, so the body still falls freely. 0 switches it off.
    uniform_scale: `anchor`: the object's uniform scale; displacements are multiplied by it
        before the anchor spring acts, as in the original deformer.
    anchor_frame: `anchor`: "world" anchors each vertex to its rest position; "centroid"
        anchors it to its rest position moved with the centre of mass (the body keeps its
        momentum and can fall freely, its shape springs back); "auto" (default) is "world"
        when any vertex is pinned and "centroid" otherwise.
    neighbour_springs: `anchor`: also apply the mesh's springs (as the `springs` solver does)
        so that pinned vertices hold the rest of the mesh.
    partitions: `verlet` / `xpbd`: slabs of springs swept in parallel, one thread each
        (Gauss-Seidel inside each, the springs between slabs after them); results depend on
        this number, not on the thread count, so runs are reproducible on any machine.
        1 runs serially (no parallel runtime); 0 (default, auto) uses 2 slabs from 4096
        springs up (about a 27 x 27 grid) and 1 below. Whether a step then runs on one thread
        or several is measured while it runs (`dispatch.KernelPicker`), never a result change.
    tethers: `verlet` and `xpbd`: long range attachments (Kim, Tang, Mueller 2012): after the
        sweeps, every vertex connected to a pin is kept within this ratio of its rest distance
        along the mesh to the nearest pin (1.0: no stretch along that path). Plain sweeps
        propagate a pin's hold one spring per sweep, so a cloth hanging from its corners
        stretches far near them; tethers fix that at the cost of one projection per vertex.
        None switches them off.
    """

    iterations: int | None = None
    damping: float = 0.9
    strain_limit: float | None = None
    strain_iterations: int = 500
    stable_substeps: bool = True
    anchor_stiffness: float = 20.0
    anchor_damping: float = 5.0
    uniform_scale: float = 1.0
    anchor_frame: str = "auto"
    neighbour_springs: bool = False
    partitions: int = 0
    tethers: float | None = 1.0

    def iterations_for(self, solver: type | object) -> int:
        """The iteration count in force for a solver class or instance."""
        return int(self.iterations) if self.iterations is not None else int(solver.default_iterations)


def velocity_retention(damping: float, dt: float) -> float:
    """Velocity factor for one substep given a damping fraction per second."""
    return float((1.0 - min(max(damping, 0.0), 0.999999)) ** dt)
