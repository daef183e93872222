"""XPBD cloth (Macklin, Mueller, Chentanez 2016): compliant distance constraints per spring kind.

Each substep predicts positions (Verlet form, x' = x + (x - x_prev) * retention + a dt^2),
resets the Lagrange multipliers and runs `iterations` Gauss-Seidel sweeps of

    dlam = (-C - alpha~ lam - gamma grad C . (x - x_prev)) / ((1 + gamma) (w_a + w_b) + alpha~)

with C = |x_b - x_a| - L, alpha~ = alpha / dt^2 and gamma = alpha beta / dt (eq. 26 of the
paper). Compliance alpha = 1 / k with k = stiffness * material.stretch_modulus (N/m), the same
spring constant as `springs` and `implicit`: the equilibrium does not depend on the step
size or the iteration count once the sweeps converge. beta = c = 2 z sqrt(k m_red) from the
kind's damping ratio z.

Springs are ordered from the pins outward (see `layout`), so a forward sweep carries the pins'
hold across the whole cloth in one pass. Sweeps alternate direction inside a substep, the
first forward, so an even count is a symmetric Gauss-Seidel step: a single forward sweep per
substep is not symmetric and pumps energy into stiff cloth. The default is the "small steps"
style (Macklin et al. 2019): 2 sweeps (one forward, one backward) and 22 substeps per frame
(the measurements behind it: docs/performance.md).

Convergence: the multipliers start from zero every substep (`options.warm_start` = 0, the
default), so a cloth at rest rebuilds its spring forces in every substep's few sweeps; where a
substep's Gauss-Seidel does not converge (k dt^2 (w_a + w_b) well above 1: fine meshes, stiff
materials, long substeps) the cloth settles softer than its material, more so with fewer sweeps
or longer substeps. `warm_start` = 1 starts each substep from the last one's multipliers (a pass
applying them to the positions, then the sweeps): a cloth at rest then keeps its forces and its
shape no longer depends on the counts, but the sweeps must then damp every mode the step
cannot resolve, which needs short substeps (it diverges on the defaults once k dt^2 w is
above about 2). docs/performance.md has the figures; each frame's `force_residual`
(`meshdeform.simulate`) says how far from equilibrium a cloth at rest is.

Contact: after the sweeps, the colliders' contact planes of the last substep (`Control.planes`,
`sweep_kernels.hold_planes`) put each contact point its springs pulled behind its plane back
onto it, with Coulomb friction, before the velocities are taken from the positions: a resting
contact then ends the substep on the obstacle (the colliders' pass after the substep, still the
guarantee, finds nothing to push), where the springs' pull sank it a quarter millimetre every
substep and the colliders' push-back cycled on it, so a draped sheet never came to rest.

Where a collider pushes the cloth further from its pins than the tethers allow (a plate
punched through a cloth pinned at both sides), they give way around the push
(`sweep_kernels.release_tethers`: a touched vertex keeps the distance it started the substep
at, a neighbour of a released vertex that distance less the path between them, spreading one
neighbour a substep; never in a cloth within its tethers); held, the vertices next to the pushed
ones were kept back and the springs between took the whole difference, up to the divergence
guard. Grips (pins of two groups) moved further apart than the tethers allow scale
each vertex's limits by that ratio, so the cloth between them stretches evenly, not at the row
next to one grip (9.4x where it stretched 1.3x as a whole).

Tethers (`options.tethers`, long range attachments to the pins) are applied before and after
the sweeps. Their distances run along `TETHER_KINDS`, structural and shear springs (the octile
distance on a grid: a vertex diagonal from a pin cannot stretch 41 % before its tether acts, as
it can along structural springs only), times `TETHER_SLACK`: tethers to two pins that are both
nearly exact (a vertex straight below one pin and diagonal from the other) make the alternating
projections onto two spheres through the rest position ratchet it upward, and neighbours near
the line between the pins fight; the slack removes both. They cap stretch along paths from the
pins (set them off to see the compliance alone).

A whole substep (prediction, tethers, sweeps, velocities) is one compiled call
(`kernels.xpbd_substep`, or its parallel build, bit for bit the same result:
`dispatch.SubstepPicker` runs the faster on the machine now), and so is a whole frame when nothing
happens between its substeps (`advance`: the vertices stay in the scratch from one substep to
the next, the State is read once and written once per frame, the same bytes as substep by
substep). The scratch holds one cache line per vertex (`sweep_kernels.VERTEX`: position, inverse
mass, previous position); per spring the constants (rest length, compliances, 1 / denominators,
damping) are precomputed once per step size into a `kernels.XPBD_CONSTANTS` record, springs with
the same six values sharing one, and the spring's `kernels.XPBD_SPRING` record holds its ends and
the index of its constants: a projection streams 12 bytes of spring record (and its multiplier)
and costs one square root and one division. The first sweep of
a substep writes the multipliers without reading them (they start at zero).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from meshdeform.model import SpringModel, State
from meshdeform.solvers.base import Control, Solver, velocity_retention
from meshdeform.solvers.common import SweepSolver
from meshdeform.solvers.options import XPBDOptions
from meshdeform.solvers.xpbd import kernels
from meshdeform.topology import SpringKind

#: tether paths run along these spring kinds, with this slack (see the module docstring)
TETHER_KINDS = (int(SpringKind.STRUCTURAL), int(SpringKind.SHEAR))
TETHER_SLACK = 1.03


class XPBDSolver(SweepSolver, Solver):
    """Extended position-based dynamics with per-kind compliance and constraint damping."""

    name: ClassVar[str] = "xpbd"
    summary: ClassVar[str] = "compliant distance constraints in small steps (Macklin et al. 2016/2019)"
    hint: ClassVar[str] = "use more substeps or check the forces for non-finite values"
    options_class: ClassVar[type[XPBDOptions]] = XPBDOptions
    parallel_kernels: ClassVar[bool] = True
    default_substeps: ClassVar[int] = 22
    reads_planes: ClassVar[bool] = True
    fast_step_edges: ClassVar[float | None] = 1.0
    default_iterations: ClassVar[int] = 2
    tether_kinds: ClassVar[tuple[int, ...]] = TETHER_KINDS
    tether_slack: ClassVar[float] = TETHER_SLACK

    def _prepare(self, model: SpringModel) -> None:
        lay = self._prepare_sweeps(model, kernels.xpbd_substep, kernels.xpbd_substep_parallel)
        self.params = self._buffer("params", lay.a.shape[0], kernels.XPBD_SPRING)
        self.params["a"] = lay.ends["a"]
        self.params["b"] = lay.ends["b"]
        self.constants = self._buffer("constants", lay.a.shape[0], kernels.XPBD_CONSTANTS)
        self.lam = self._buffer("lam", lay.a.shape[0], np.float64)
        self.lam[:] = 0.0

    def _coefficients(self, dt: float) -> None:
        """Per-spring constants (`kernels.XPBD_CONSTANTS`, indexed by the `kernels.XPBD_SPRING`
        records) for this step size, in one compiled pass (`kernels.xpbd_constants`)."""
        model = self._model
        damped, self.constant_count = kernels.xpbd_constants(
            self.layout.order, model.springs, model.rest_lengths, model.stiffness, model.compression,
            model.damping, self.inv_mass, float(model.material.stretch_modulus), dt, self.params,
            self.constants, self.constants.view(np.uint64),
        )
        self.damped = bool(damped)
        self.retention = velocity_retention(self.options.damping, dt)
        self._dt = dt

    def advance(self, model: SpringModel, state: State, dt: float, control: Control, count: int) -> None:
        """`count` substeps of dt with the same accelerations, as one compiled call (the same
        result as `count` calls of `step`, without writing the State back in between)."""
        if not self._prepared(model):
            self._prepare(model)
        if dt != self._dt:
            if self._dt > 0.0:
                self.lam *= (dt / self._dt) ** 2  # a multiplier is a force times dt^2
            self._coefficients(dt)
        if self._starts_run(state):  # another run: its multipliers start from zero
            self.lam[:] = 0.0
        lay = self.layout
        release_state, release = self._release(self._touching(control))
        args = (
            state.positions, state.previous, state.velocities, self.inv_mass, control.accelerations,
            self.retention, dt, self.scratch, lay.vertex_rank, lay.vertex_order, self.params, self.constants,
            self.lam, self.offsets, lay.parts, self.iterations, self.damped,
            self.tether_work, self.chunks.vertices, self.chunks.tethers, float(self.options.warm_start),
            self._planes(control, dt), self.tethers,
            release_state, release,
        )
        self.substep(*args, count)

    def _touching(self, control: Control) -> np.ndarray | None:
        """The model vertices a contact plane holds (`Control.planes`, weight above 0), whose
        tethers give way to the collider; None without planes."""
        planes = control.planes
        if planes is None or planes.offsets.shape[0] == 0:
            return None
        return planes.vertices[planes.weights > 0.0]
