"""Solver options: the fields every solver takes, and each solver's own class of options.

Each solver declares its options class (`Solver.options_class`); the recipe's
`[simulation.<solver>]` table is read into it field by field, and a key that is not a field of
the solver in force is an error, not ignored. The constraints on each field are declared here,
once, as `annotated_types` metadata (which pydantic reads when a recipe is validated):
`Ge(1)` means >= 1, `Gt(0)` > 0, `Interval(ge=0, lt=1)` 0 <= value < 1.

Damping means the same for every solver: the fraction of a vertex's velocity that air/velocity
damping removes per second of simulated time, applied per step as a factor `(1 - damping) ** dt`
(so it does not depend on the step size). 0 is no damping; the default 0.9 (a decay rate of
ln 10 = 2.3 per second, about the air drag of a light cloth: terminal velocity g / 2.3 = 4.3 m/s)
makes a hanging cloth come to rest (max vertex speed below 1e-4 m/s) within a few seconds. Spring
damping along springs is a material property (`KindMaterial.damping`, a damping ratio, see
`meshdeform.material`). Free fall is only exact without air damping (damping = 0).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Literal

from annotated_types import Ge, Gt, Interval

#: the implicit solver's coarse lattice nodes (along the longest side) in a run at its calm steps
#: (`ImplicitOptions.coarse`)
CALM_COARSE = 5
#: the frames the `anchor` solver can anchor its vertices in (see `AnchorOptions.anchor_frame`)
ANCHOR_FRAMES = ("auto", "world", "centroid")
AnchorFrame = Literal["auto", "world", "centroid"]


@dataclass(frozen=True)
class SolverOptions:
    """Options every solver takes.

    iterations: constraint sweeps per substep (verlet, xpbd) or local/global iterations per
        step (implicit); None means the solver's default (`Solver.default_iterations`; springs
        and anchor have none and ignore it).
    damping: fraction of velocity removed per second of simulated time (air/velocity damping,
        0 <= damping < 1), applied per substep as (1 - damping) ** dt. See the module docstring.
    """

    iterations: Annotated[int, Ge(1)] | None = None
    damping: Annotated[float, Interval(ge=0, lt=1)] = 0.9

    @property
    def holds_beyond_springs(self) -> bool:
        """Whether the solver holds the cloth by more than its springs and the forces (its own
        tethers): a shape at rest out of balance may then be theirs, not unconverged sweeps'
        (`meshdeform.simulate.convergence_warning`)."""
        return False

    def iterations_for(self, solver: type | object) -> int:
        """The iteration count in force for a solver class or instance: 0 for one without
        iterations (`default_iterations` 0: springs, anchor) whatever `iterations` says."""
        if not solver.default_iterations:
            return 0
        return int(self.iterations) if self.iterations is not None else int(solver.default_iterations)


@dataclass(frozen=True)
class SweepOptions(SolverOptions):
    """Options of the position solvers that sweep springs as constraints (`verlet`, `xpbd`).

    partitions: slabs of springs that share no vertex (Gauss-Seidel inside each, the springs
        between slabs after them), swept one after another, or one thread each where the parallel
        build runs (`meshdeform.solvers.dispatch`); results depend on this number, not on
        the thread count or the build, so runs are reproducible on any machine. 0 (default, auto)
        uses 2 slabs from 4096 springs up (about a 27 x 27 grid) and 1 below.
    tethers: long range attachments (Kim, Tang, Mueller 2012): after the sweeps, every vertex
        connected to a pin is kept within this ratio of its rest distance along the mesh to the
        nearest pin (1.0: no stretch along that path). Plain sweeps propagate a pin's hold one
        spring per sweep, so a cloth hanging from its corners stretches far near them; tethers fix
        that at the cost of one projection per vertex. None or 0 switches them off; values
        between 0 and 1 are refused (they would pull vertices closer than their rest distance).
    """

    partitions: Annotated[int, Ge(0)] = 0
    tethers: Annotated[float, Ge(0)] | None = 1.0

    @property
    def holds_beyond_springs(self) -> bool:
        """Tethers on: they hold the cloth within its rest distances to the pins."""
        return bool(self.tethers)


@dataclass(frozen=True)
class VerletOptions(SweepOptions):
    """Options of the `verlet` solver (see `SweepOptions`)."""


@dataclass(frozen=True)
class XPBDOptions(SweepOptions):
    """Options of the `xpbd` solver (see `SweepOptions`).

    warm_start: each substep starts its sweeps from the last substep's multipliers times this
        factor, applied to the positions first (0: from zero, as in Macklin et al. 2016). A cloth
        at rest then keeps its spring forces from one substep to the next and its sweeps correct
        only what changed, so its shape no longer depends on the iteration and substep counts
        (from zero, too few sweeps leave it softer than its material). See `xpbd.solver`.
    """

    warm_start: Annotated[float, Interval(ge=0, le=1)] = 0.0


@dataclass(frozen=True)
class ImplicitOptions(SolverOptions):
    """Options of the `implicit` solver: `iterations` (per step) and `damping`, as for every
    solver, and

    method: how each step's minimisation is iterated (see `meshdeform.solvers.implicit.solver`):
        "lbfgs" (default) quasi-Newton steps with the prefactored matrix as the initial inverse
        Hessian and a line search (Liu, Bouaziz, Kavan 2017), which also converge where springs
        turn rather than stretch; "local_global" the plain local/global iterations of projective
        dynamics (Liu et al. 2013), cheaper per iteration but slow to converge for stiff springs.
    preconditioner: which springs the prefactored matrix of "lbfgs" holds (its initial inverse
        Hessian): "in_plane" (default) the structural and shear springs, whose sparse Cholesky
        factor has half the fill of one with the bending springs too (9 instead of 13 entries a
        row on a grid; 10 instead of 20 ms a back-substitution at 256 x 256), while the bending
        springs act through the energy and its gradient and L-BFGS's history supplies their
        curvature; "all" every spring, as the local/global iterations need (their matrix must be
        exact: "local_global" always uses every spring).
    coarse: lattice nodes along the longest side of the cloth of the coarse space whose Newton
        steps precede each step's L-BFGS iterations (`meshdeform.solvers.implicit.coarse`): they
        carry the smooth turning motions (a fall about a pinned edge, a swing) that the
        prefactored matrix slows like a strong damping in long steps. Values below 2 switch it
        off; "lbfgs" only. None (default): `CALM_COARSE` in a run at the calm steps (2 a frame:
        `ImplicitSolver.calm_options`), off otherwise (at 8 steps a frame the fine iterations lose
        little of a turn, and the coarse steps would double a step's time).
    """

    method: Literal["lbfgs", "local_global"] = "lbfgs"
    preconditioner: Literal["in_plane", "all"] = "in_plane"
    coarse: Annotated[int, Ge(0)] | None = None


@dataclass(frozen=True)
class SpringsOptions(SolverOptions):
    """Options of the explicit `springs` solver.

    strain_limit: maximum stretch ratio of structural springs (Provot 1995), e.g. 1.1 for 10 %;
        None switches it off.
    strain_iterations: at most this many Gauss-Seidel passes enforce the strain limit per step
        (it stops as soon as no structural spring exceeds it).
    stable_substeps: split a substep into as many explicit steps as the stiffest spring needs to
        stay stable (from a Gershgorin bound on k/m); False trusts the given substeps (and may
        explode, which the guard in simulate reports).
    """

    strain_limit: Annotated[float, Ge(1)] | None = None
    strain_iterations: Annotated[int, Ge(0)] = 500
    stable_substeps: bool = True


@dataclass(frozen=True)
class AnchorOptions(SpringsOptions):
    """Options of the `anchor` (stress ball) solver; with `neighbour_springs` the mesh's springs
    act as in `springs`, with its strain limit and stable substeps.

    anchor_stiffness: spring constant per unit mass (1/s^2, as Catlike Coding's "spring force"):
        acceleration -anchor_stiffness * uniform_scale * (x - anchor).
    anchor_damping: the original deformer's damping (1/s, Catlike Coding's
        `velocity *= 1 - damping dt`, default 5 as there): each vertex's velocity relative to its
        anchor decays as exp(-anchor_damping t) (exactly, whatever the step), on top of the air
        damping `damping`. In the "centroid" frame it acts on velocities relative to the centre of
        mass, so the body still falls freely. 0 switches it off.
    uniform_scale: the object's uniform scale; displacements are multiplied by it before the
        anchor spring acts, as in the original deformer.
    anchor_frame: "world" (default) anchors each vertex to its rest position, as the original
        deformer: a struck stress ball springs back to its rest shape and place. "centroid"
        anchors it to its rest position moved with the centre of mass: the body keeps the
        momentum an impact gives it and can fall freely under gravity while its shape springs
        back (a falling soft body; a struck ball drifts away). "auto" is "world" when any vertex
        is pinned and "centroid" otherwise (the former default).
    neighbour_springs: also apply the mesh's springs (as the `springs` solver does) so that pinned
        vertices hold the rest of the mesh.
    """

    anchor_stiffness: Annotated[float, Ge(0)] = 20.0
    anchor_damping: Annotated[float, Ge(0)] = 5.0
    uniform_scale: Annotated[float, Gt(0)] = 1.0
    anchor_frame: AnchorFrame = "world"
    neighbour_springs: bool = False
