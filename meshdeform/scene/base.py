"""The scene's contracts: what acts on the model besides its springs, and how the loop drives it.

`simulate` (meshdeform/simulate.py) calls, per substep of length dt (s) ending at time t1:
every `Force.accumulate(model, state, t0, dt, out)` (t0: the substep's start) into the external
accelerations (a force that `kicks` into `Control.kicks` as well), then the solver step, then
every `Constraint.project(model, state, t1, dt)` in the order of `Scene.constraints`.
`Scene.pin_motion(t1)` gives the hard pins' targets.

Tearing replaces the model by one with more vertices (copies of split vertices appended after
the old ones). Every force or constraint that holds per-vertex data (W,) must then follow the
split, so each of them implements `Remappable`: the loop calls `remap(model, index_map)` once
per object, on the items `Scene.remappables()` lists. The scene's remappable items:

- `forces.Wind`: its cached inverse masses (masses change where a vertex splits);
- `forces.Impact`: its vertex mask (copies inherit it);
- `effects.Plasticity`: its rest copy (copies inherit the dented rest position);
- `effects.NearestPinTethers`: its anchors and rest path distances (measured again over the
  springs left, so a torn-off piece is no longer held);
- `pins.SoftPins`: its pinned vertices (copies of a soft-pinned vertex are pulled to the same target);
- `colliders.Collider`: the side of an open mesh collider each vertex was last seen on.

`effects.Pressure` holds no per-vertex data (rest volume, orientation) and is not remappable.
A Force or Constraint written elsewhere declares the same by subclassing `Remappable` (or by
having a `remap` method of that signature: the protocol is checked at run time).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np

from meshdeform.model import SpringModel, State

if TYPE_CHECKING:
    from meshdeform.contact.self_collision import SelfCollision
    from meshdeform.tearing import Tearer


class Force(Protocol):
    """Adds accelerations (m/s^2) for welded vertices over the substep [time, time + dt) (s) into
    `out` (W, 3).

    kicks: whether its accelerations are short kicks (an impact: a velocity change spread over a
    few milliseconds) rather than a field that acted before the substep as well; `simulate` hands
    them to the solver apart too (`Control.kicks`), so that a solver starting a step history from
    the accelerations (implicit's BDF2) does not take a kick for one that had been acting.
    """

    kicks: bool = False

    def accumulate(self, model: SpringModel, state: State, time: float, dt: float, out: np.ndarray) -> None: ...

    def largest_kick(self, start: float, end: float) -> float:
        """The largest velocity change (m/s) it may give a vertex over [start, end) (s): a bound,
        read before a frame to choose its steps (`meshdeform.simulate.fast_steps_for`); 0 for a
        force that is no kick (this default)."""
        return 0.0


class Constraint(Protocol):
    """Projects positions after each solver substep (colliders, soft pins)."""

    def project(self, model: SpringModel, state: State, time: float, dt: float) -> None: ...


@runtime_checkable
class Pulling(Protocol):
    """A constraint that pulls vertices toward targets like zero-length springs (soft pins), where
    a collider pushes them out of an obstacle: solvers must not hold these vertices as contacts."""

    def pulled_vertices(self) -> np.ndarray:
        """(P,) int64: the welded vertices it pulls."""
        ...


@runtime_checkable
class Remappable(Protocol):
    """A force or constraint with per-vertex data follows a tear: `index_map` (W',) gives the
    previous vertex of every vertex of the new `model` (copies appended after the old ones)."""

    def remap(self, model: SpringModel, index_map: np.ndarray) -> None: ...


#: m/s^2, the default gravity's magnitude
STANDARD_GRAVITY = 9.81


def gravity_vector(up: str = "y", g: float = STANDARD_GRAVITY) -> tuple[float, float, float]:
    """Gravity pointing down the up axis: Y-up (OBJ) -> (0, -g, 0), Z-up -> (0, 0, -g)."""
    if up == "y":
        return (0.0, -g, 0.0)
    if up == "z":
        return (0.0, 0.0, -g)
    raise ValueError(f"up axis must be 'y' or 'z', not {up!r}")


def up_vector(up: str = "y") -> np.ndarray:
    """The unit up axis (3,): Y-up (OBJ) -> (0, 1, 0), otherwise Z-up -> (0, 0, 1)."""
    return np.array([0.0, 1.0, 0.0]) if up == "y" else np.array([0.0, 0.0, 1.0])


#: maps a time in seconds to target positions (P, 3) of the model's pinned vertices, in
#: the order of `np.flatnonzero(model.pinned)`
PinMotion = Callable[[float], np.ndarray]


@dataclass
class Scene:
    """Everything acting on the model besides its springs.

    gravity: m/s^2, added to every vertex's external acceleration (default 9.81 down Y).
    forces / constraints: see `Force`, `Constraint` (constraints run in this order).
    pin_motion: targets of the hard pins (None: they stay at rest). tearing: a `Tearer` or None.
    self_collision: the cloth's contact with itself (`meshdeform.contact.SelfCollision`), run
        after every constraint of a substep, or None (off).
    initial_velocity: m/s, the velocity every vertex that is not hard-pinned has when a run
        starts (`meshdeform.simulate.simulate`), or None (at rest): a cloth thrown, or shot at
        an obstacle, without a scripted impact doing it in the first frame.
    """

    gravity: tuple[float, float, float] = gravity_vector()
    forces: list[Force] = field(default_factory=list)
    constraints: list[Constraint] = field(default_factory=list)
    pin_motion: PinMotion | None = None
    tearing: Tearer | None = None
    self_collision: SelfCollision | None = None
    initial_velocity: tuple[float, float, float] | None = None

    def pulled(self, vertex_count: int) -> np.ndarray | None:
        """(vertex_count,) bool: the vertices a `Pulling` constraint pulls; None where none does."""
        pulling = [c for c in self.constraints if isinstance(c, Pulling)]
        if not pulling:
            return None
        mask = np.zeros(vertex_count, dtype=bool)
        for constraint in pulling:
            mask[constraint.pulled_vertices()] = True
        return mask

    def remappables(self) -> list[Remappable]:
        """The forces and constraints that follow a tear, each object once (an effect such as
        `Plasticity` is both a force and a constraint), forces first, in scene order, then
        self-collision."""
        after = (self.self_collision,) if self.self_collision is not None else ()
        unique = {id(item): item for item in (*self.forces, *self.constraints, *after)}
        return [item for item in unique.values() if isinstance(item, Remappable)]
