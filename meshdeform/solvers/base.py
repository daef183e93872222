"""The solver contract: the `Solver` base class (`step`, `advance`, `follow_tear`) and its `Control`.

Solvers only advance positions under spring forces or constraints and the external
accelerations in `Control`; pins with inv_mass 0 are never moved by a solver. Gravity,
wind, impacts, colliders and pin animation are evaluated outside (see `meshdeform.simulate`).

A solver instance caches data derived from the model it last stepped (spring order,
partitions, per-spring constants, a factorisation); stepping another model (for example
after tearing) rebuilds the cache. One instance serves one simulation at a time.

Each solver takes its own options (`Solver.options_class`, see `meshdeform.solvers.options`).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar, NamedTuple

import numpy as np

from meshdeform.model import ContactPlanes, SpringModel, State
from meshdeform.solvers.options import SolverOptions


class LargeKernels(NamedTuple):
    """Kernels a large run compiles beyond those of a small cloth's step (`Solver.large_kernels`):
    `compile()` compiles (or loads) them, `cached()` says whether Numba's disk cache holds them."""

    compile: Callable[[], None]
    cached: Callable[[], bool]


@dataclass
class Control:
    """Per-substep inputs from outside the solver: external accelerations (W, 3), m/s^2.

    Solvers read but never modify it. A velocity kick dv over one substep of length dt
    (an impact) is the acceleration dv / dt during that substep; every solver turns it
    into the same change of momentum.
    """

    accelerations: np.ndarray
    #: (W,) bool or None: vertices a constraint pulls toward a target like a spring after each step
    #: (soft pins), not out of an obstacle; a solver that takes the vertices constraints moved for
    #: contacts (implicit: held against the push in its iterations) leaves these out
    pulled: np.ndarray | None = None
    #: (W,) bool or None: the vertices self-collision moved after the last substep (the cloth's own
    #: layers, set by `simulate` each substep); a collider's push that is not among them is an
    #: obstacle's, which implicit judges as an impact where it is deep (`IMPACT_SINKS`) and sinks
    #: back into the obstacle after its iterations (`_sink_pressed`); the cloth's own layers it
    #: releases in the last iteration
    self_contact: np.ndarray | None = None
    #: (W,) float or None: the friction coefficient of the collider that pushed each vertex out
    #: after the last substep (0 where none did; set by `simulate` each substep for a solver that
    #: holds contacts, `Solver.holds_contacts`): implicit holds a pushed vertex whose forces lie
    #: within that friction's cone where it is (static friction)
    friction: np.ndarray | None = None
    #: (W,) bool or None: the vertices a still collider pushed out after the last substep (set
    #: with `friction`): implicit keeps these contacts, and self-collision's, exactly in its
    #: preconditioner's solves, not those of a moving collider (a hold along the push of its
    #: moving, turning surface caught a cloth wrapping around a rising plate's rim)
    still_contact: np.ndarray | None = None
    #: the colliders' contacts after the last substep as planes (set by `simulate` each substep for
    #: a solver that reads them, `Solver.reads_planes`; None before the first or after a tear)
    planes: ContactPlanes | None = None
    #: (W,) bool or None: the vertices a collider moved after the last substep (set by `simulate`
    #: each substep for a solver that reads them, `Solver.reads_pushes`; None before the first or
    #: after a tear): verlet's tethers give way where a collider holds the cloth
    #: (`sweep_kernels.release_tethers`)
    pushed: np.ndarray | None = None
    #: (W, 3) or None: the part of `accelerations` from kicks this substep (impacts,
    #: `Force.kicks`; set by `simulate` each substep where the scene has any): a solver that starts
    #: a step history from the accelerations leaves it out (a kick had not been acting before)
    kicks: np.ndarray | None = None
    #: iterations of this step in place of the solver's options (None: the options'); `simulate`
    #: sets it for a frame at the solver's `slow_steps`
    iterations: int | None = None


class Solver(ABC):
    """Advances a State by dt in place; keeps `state.previous` and `state.velocities` consistent.

    Subclasses (one folder each, listed in `registry.SOLVERS`) set the class attributes:
    name: registry key, the recipe's `solver` value.
    summary: one line of help text (the CLI's `--solver` help, the docs).
    hint: what to try when a run with this solver diverges (quoted by `simulate`'s guard).
    default_substeps: substeps per frame when `Settings.substeps` is None.
    default_iterations: iterations when `options.iterations` is None (0: the solver has none).
    calm_steps: (substeps, iterations) per frame that replace both defaults where nothing touches
        the cloth (no constraint such as a collider, no self-collision, no tearing) and neither
        was given (`meshdeform.simulate.steps_for`); None: the defaults everywhere. A solver
        whose defaults are set by contact (implicit: a long step that stops part of the cloth
        needs more iterations than a few give) runs a calm scene in fewer, longer steps.
    slow_steps: (substeps, iterations) per frame for the frames of a scene that is not calm in
        which the cloth moves slowly (`meshdeform.simulate.moves_slowly`), where neither count
        was given; the frames in which it moves fast keep the defaults (`steps_for`), which an
        impact on an obstacle needs. None: the same steps in every frame. The solver then meets
        steps of two lengths in one run (and `Control.iterations`).
    fast_step_edges: where something touches the cloth and the substeps were not given, the most
        median structural rest lengths its fastest vertex may move in a substep: a frame expected
        faster takes more substeps (`meshdeform.simulate.fast_substeps`). A vertex an obstacle
        stops within a step leaves its springs stretched by what its neighbours move on: a solver
        that recovers from a few edges of that only (implicit's few iterations) sets it. None: the
        same steps however fast the cloth moves.
    options_class: the options it takes (`meshdeform.solvers.options`).
    parallel_kernels: whether its steps launch Numba's parallel builds (xpbd, verlet): those
        must not be launched from two threads at once under Numba's workqueue threading layer,
        so nothing steps such a solver beside a run (`pipeline.compile_ahead`).
    holds_contacts: whether its step holds the vertices the constraints pushed against their
        obstacle (implicit), finding the obstacle from how they moved them: the colliders then
        leave its positions along the surface alone, its own static friction holding them
        (`scene.colliders.hold_contacts_still`).
    reads_planes: whether its step reads `Control.planes` (the explicit solvers, whose many
        steps between two collider passes keep the contacts on them; xpbd, whose sweeps would
        otherwise pull a resting contact into the obstacle every substep).
    reads_pushes: whether its step reads `Control.pushed` (verlet, whose tethers give way to a
        collider that pushes the cloth further from its pins than they allow; xpbd finds those
        contacts in its planes).

    `state.time` is the caller's: `simulate` sets it after every `step` and after `advance`.
    """

    name: ClassVar[str]
    summary: ClassVar[str]
    hint: ClassVar[str]
    default_substeps: ClassVar[int]
    default_iterations: ClassVar[int] = 0
    calm_steps: ClassVar[tuple[int, int] | None] = None
    slow_steps: ClassVar[tuple[int, int] | None] = None
    fast_step_edges: ClassVar[float | None] = None
    options_class: ClassVar[type[SolverOptions]]
    parallel_kernels: ClassVar[bool] = False
    holds_contacts: ClassVar[bool] = False
    reads_planes: ClassVar[bool] = False
    reads_pushes: ClassVar[bool] = False

    def __init__(self, options: SolverOptions) -> None:
        self.options = options

    @abstractmethod
    def step(self, model: SpringModel, state: State, dt: float, control: Control) -> None:
        """One substep of dt under the external accelerations of `control`."""

    def contact_substeps(self, model: SpringModel, fps: float) -> int:
        """The fewest substeps a frame at `fps` (frames/s) that this solver needs on `model` where
        something touches the cloth (a constraint such as a collider, self-collision, tearing) and
        the substeps were not given (`meshdeform.simulate.steps_for`); 0: its defaults do. A
        solver whose step runs many steps of its own between the constraints (the explicit
        ones) asks for more: constraints act only between substeps."""
        return 0

    @classmethod
    def large_kernels(cls, vertices: int) -> LargeKernels | None:
        """The kernels a run of `vertices` vertices compiles beyond those a small cloth's step does
        (the compile-ahead stand-in's, `pipeline.compile_ahead`), None where there are none (this
        default)."""
        return None

    @classmethod
    def calm_options(cls, options: SolverOptions) -> SolverOptions:
        """The options of a run at the calm steps (`calm_steps`), from those in force with the calm
        iterations set: these by default; a solver whose options depend on the step length fills
        them in."""
        return options

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


def velocity_retention(damping: float, dt: float) -> float:
    """Velocity factor for one substep given a damping fraction per second (`SolverOptions.damping`)."""
    return float((1.0 - min(max(damping, 0.0), 0.999999)) ** dt)
