"""Implicit springs: projective dynamics (Liu, Bargteil, O'Brien, Kavan 2013) with BDF2.

Stiff springs without exploding. Each step solves the implicit (BDF2, second order, A-stable)
update, with air damping as a drag force -c v_n+1 taken implicitly, as the minimisation

    x' = argmin q / (2 b^2) |x - y|_M^2 + sum_s k_s / 2 (|x_a - x_b| - L_s)^2,   b = 2 dt / 3,
    y  = 4/3 x_n - 1/3 x_n-1 + (2 dt / 9 (4 v_n - v_n-1) + b^2 a_ext) / q,     q = 1 + b c

by quasi-Newton iterations (`method = "lbfgs"`, the default: L-BFGS whose initial inverse
Hessian is the projective-dynamics matrix below, with an Armijo line search; Liu, Bouaziz, Kavan
2017, "Quasi-Newton methods for real-time simulation of hyperelastic materials") or by Liu et
al.'s local/global iterations (`method = "local_global"`): the local step projects every spring
onto its rest length (a closed form), the global step solves one sparse linear system whose
matrix q M / b^2 + sum_s k_s (e_a - e_b)(e_a - e_b)^T does not change, so it is factorised once
and each iteration is a back-substitution for x, y and z together (one (n, 3) right-hand side).
One local/global iteration is exactly one preconditioned gradient step (the matrix times x minus
the local step's right-hand side is the energy's gradient), so L-BFGS without history is that
iteration; its history of the last steps adds the curvature the matrix lacks where springs turn
(below), so a stiff cloth converges in a few iterations of one step a frame
(docs/performance.md, "The implicit solver's quasi-Newton iterations"). As L-BFGS only needs a
good initial inverse Hessian, not the exact matrix, its matrix leaves the bending springs out by
default (`preconditioner`): the factor of the in-plane (structural and shear) springs has half
the fill of one that also couples skip-one neighbours (9 instead of 13 entries a row on a grid),
and bending springs, soft next to the in-plane ones, still act fully through the energy and
gradient. (A matrix of the structural springs alone, 5 entries a row, is faster again, but a
few iterations then barely resist shear, and a cloth crumpling on a collider collapsed into a
ball: docs/performance.md.) The matrix is symmetric
positive definite (mass > 0 on every free vertex, weights > 0), so it is factorised by sparse
Cholesky (`cholesky.factorise`: CHOLMOD through cholespy for small cloths, our own two-threaded
nested-dissection factor for large ones): one triangle L instead of SuperLU's L and U, less
memory and a faster back-substitution. Only the lower triangle of the matrix is passed (CSC,
duplicates summed by SciPy), a new step length or anchored set refactorises on the same
pattern, and
nothing but the factor and (n, 3) buffers is kept (one for local/global, 2 HISTORY + 5 for
L-BFGS: 15 MB at 65k vertices); docs/performance.md has the
sizes. Pinned vertices are eliminated (their current positions go to the right-hand side). Then
v' = 3 / (2 dt) (x' - 4/3 x_n + 1/3 x_n-1).

On a large cloth (`SPLIT_SPRINGS` springs or more) the step energy is summed over two slabs of
vertices along the rest shape's longest axis and then the few springs between them, and the
coarse Hessian over two halves of its groups; the two slabs, and the two halves, run on a thread
each while `threads.ThreadPicker` measures two faster than one, and so do the large factor's two
halves. The splits are decided by the model alone, so the bytes do not depend on the threads.
Such a cloth's coarse space is set up on the pool thread while the first step factorises.

Air damping: c = -ln(1 - damping) (1/s), so that velocity decays as (1 - damping) ** t as with
every solver (`meshdeform.solvers.options`); a free vertex falls at exactly the terminal
velocity g / c. The drag is part of the step's equations (v' (1 + b c) = 4/3 v_n - 1/3 v_n-1 +
b a), which is what BDF2 makes of dv/dt = a - c v. A factor (1 - damping) ** dt on v' after the
step instead compounds through BDF2's velocity history (v' = r (4/3 v_n - 1/3 v_n-1)): it
removes velocity 1.5 times as fast as the option says (97 % a second instead of 90 %).

k = stiffness * material.stretch_modulus (N/m), compression separately (a spring shorter than
rest projects onto a length that makes its force k_c (l - L) under the common matrix weight).
The first step (and any step after the state was replaced) starts BDF2 from a history
consistent with constant external acceleration, so free fall without damping is exact.
Material spring damping is not used: BDF2 damps the highest frequencies and air damping the
rest. Every iteration lowers the step's energy, so the step cannot explode; too few
local/global iterations for very stiff springs make the cloth look softer than k (Liu et al.),
not unstable, and they slow down motion across the springs: the global matrix holds every spring
with its full stiffness in every direction, so a swing or a fold (which turns springs rather
than stretching them) moves each iteration only by about m / (b^2 k) of the way, and the rest
of the way is lost like motion to a strong damping (a swinging cloth creeps towards rest).
Shorter steps raise that fraction as 1 / dt^2 where more iterations add to it only linearly;
L-BFGS recovers most of it, and the coarse space (`coarse`, option `coarse`; on by default in
runs at the calm steps) more: before the L-BFGS iterations of a step without contact, up to
`COARSE_STEPS` Newton steps move the cloth by smooth lattice fields with the springs' true
stiffness, soft across a spring, so a turn is not lost. The defaults are 8 steps a frame of 3
iterations each: 4 steps settle and rest as well, but under collider contact a step that stops
part of the cloth is too long for a few iterations to resolve (a sheet draped over a sphere
flickered between 1.05 and 1.7 stretch at 4 steps a frame; docs/performance.md has the figures).
Where nothing touches the cloth (no constraint, self-collision or tearing) and neither count is
given, 2 steps of 3 iterations run instead (`calm_steps`, `meshdeform.simulate.steps_for`): with
the coarse steps they follow a falling, swinging sheet as closely as 8 x 3 without them did, at
three times the speed (4 iterations: the same path and stretch, 1.15-1.25x slower; the knit
rests sooner, the woven default later: docs/performance.md, "Calm steps of 3 iterations").
Where something touches the cloth, the frames in which it moves slowly take 4 steps of 5
iterations (`slow_steps`, `meshdeform.simulate.slow_steps_for`; with the contact
anchors below a cloth lying or draping on its obstacles holds at those): a step of another
length than the last starts BDF2's history afresh, as at the first step (its contacts stay held),
on that length's matrix: the factor of the length before is kept aside (`_StepLength`), so a run
switching between its contact and its slow steps assembles and factorises each once, and again
only where the anchored set was renewed in between (one more factor in memory; the drop scene of
benchmarks/contact.py switched 44 times in 120 frames, 8 % of its time, docs/performance.md).
A frame expected to move the fastest vertex more than `fast_step_edges` (half a) median edge a step
takes a whole multiple of the 8 steps instead (`meshdeform.simulate.fast_substeps`): a vertex an
obstacle stops leaves its springs stretched by what its neighbours move on in the step, which a
few iterations cannot pull back from several edges (a sheet shot at 53 m/s onto bumpy ground and
a plate punched at 20 m/s through a lying sheet diverged).

Constraints (colliders, self-collision, tethers) move vertices after the step; BDF2 would
extrapolate those vertices' former path through the correction (a landed vertex still falling
in its history bounces back up), so a vertex whose position or velocity is not what the last
step left starts its history afresh where it is, as at the first step; a change within rounding
(`kernels.MOVE_TOLERANCE`: self-collision projects two layers closer than its thickness back to
the distance they already have) restarts nothing, as a restart drops the air drag from the
vertex's history and so moves it apart from its neighbours. Contact is also taken
into the next step's L-BFGS iterations (Baraff and Witkin 1998's filtered directions, as an
active set; `local_global` does not): a vertex the last constraints pushed is held along that
push (the contact normal) while the forces press it into the obstacle (after an impact on a
collider, a push deeper than a resting vertex sinks in a step, `IMPACT_SINKS`: while its own
momentum does, so that the compression of a stiff body landing is not held and returned as a
bounce), in every iteration (self-collision's in all but the last), and the preconditioner's
solve in each iteration is the matrix's inverse on the motions that keep them (`held`: without
it the matrix answers springs compressed against a stopped vertex by moving that vertex into the
obstacle and its neighbours away, and the filter keeps the second half: a triangle landing on a
corner was lifted by its own springs and bounced for seconds); after them each held,
pressed obstacle contact is sunk into its obstacle by what its pressing force would move it
alone (`_sink_pressed`, at most `SINK_FRACTION` of an edge), so the collider's push after the
step carries the contact's normal impulse and friction; and each iteration
moves no vertex further than a quarter of an edge while there is contact (`TRUST_FRACTION`), so
a cloth stopped by a thin bar within a long step is not pulled through it or slung across it
(it hooked around the bar at 4 to 7x stretch). The vertices held in recent steps whose springs
pressed them into the obstacle, and on a closed surface those of an impact, are tied down in the
prefactored matrix (`anchors`; `held` treats at most `held.MAX_CONSTRAINTS` contacts exactly): a
matrix that knows nothing of the contact sends their free
neighbours into the obstacle, so a stiff cloth lying on it stalls stretched and a small stiff solid
landing is driven in whole and stopped at its contacts alone, compressed, then thrown back up; a
contact that its weight alone presses is not, as the tie would hold it against sliding too
(`ANCHOR_SPRING_SHARE`).
"""

from __future__ import annotations

import functools
from concurrent.futures import Future
from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np
from scipy.sparse import coo_matrix

from meshdeform.model import SpringModel, State
from meshdeform.solvers.base import Control, LargeKernels, Solver, velocity_retention
from meshdeform.solvers.common import ModelCache, spring_constants
from meshdeform.solvers.implicit import cholesky, coarse, kernels
from meshdeform.solvers.implicit.anchors import ContactAnchors
from meshdeform.solvers.implicit.held import HeldContacts
from meshdeform.solvers.layout import vertex_slabs
from meshdeform.solvers.options import CALM_COARSE, ImplicitOptions
from meshdeform.solvers.threads import ThreadPicker, beside, helper_pool, split_threads
from meshdeform.topology import SpringKind, is_closed


class ImplicitSolver(ModelCache, Solver):
    """Projective dynamics with a prefactored global matrix and BDF2 time integration."""

    name: ClassVar[str] = "implicit"
    summary: ClassVar[str] = (
        "projective dynamics (Liu et al. 2013) with BDF2, prefactored: stiff springs in few steps, the default"
    )
    hint: ClassVar[str] = "use more substeps or iterations, or check the forces for non-finite values"
    options_class: ClassVar[type[ImplicitOptions]] = ImplicitOptions
    default_substeps: ClassVar[int] = 8
    default_iterations: ClassVar[int] = 3
    calm_steps: ClassVar[tuple[int, int] | None] = (2, 3)
    slow_steps: ClassVar[tuple[int, int] | None] = (4, 5)
    fast_step_edges: ClassVar[float | None] = 0.5
    holds_contacts: ClassVar[bool] = True

    @classmethod
    def large_kernels(cls, vertices: int) -> LargeKernels | None:
        """From `cholesky.OWN_FACTOR_ROWS` vertices, those of our own Cholesky factor."""
        if vertices < cholesky.OWN_FACTOR_ROWS:
            return None
        return LargeKernels(compile=cholesky.compile_kernels, cached=cholesky.kernels_cached)

    @classmethod
    def calm_options(cls, options: ImplicitOptions) -> ImplicitOptions:
        """At the calm steps (2 a frame) the coarse space is on unless the options say otherwise:
        it is what keeps long steps from holding a turn back (`ImplicitOptions.coarse`)."""
        return options if options.coarse is not None else replace(options, coarse=CALM_COARSE)

    def __init__(self, options: ImplicitOptions) -> None:
        super().__init__(options)
        self.iterations = max(1, options.iterations_for(self))
        self._dt = -1.0
        self._state_key: tuple[int, float] | None = None

    def _prepare(self, model: SpringModel) -> None:
        # per-spring data are the model's own arrays where every spring takes part (no copies:
        # N = 256 has 390k springs); the ratio k / weight is formed in the kernel
        kt, kc = spring_constants(model)
        weight = np.maximum(kt, kc)
        del kt, kc
        springs, rest = model.springs, model.rest_lengths
        stiff_t, stiff_c, kinds = model.stiffness, model.compression, model.kinds
        keep = weight > 0.0
        if not keep.all():
            index = np.flatnonzero(keep)
            springs, rest, stiff_t, stiff_c, weight, kinds = (
                springs[index], rest[index], stiff_t[index], stiff_c[index], weight[index], kinds[index]
            )
        # the springs of the global matrix: every one for local/global (its fixed point needs the
        # exact matrix), the in-plane ones for the L-BFGS preconditioner unless asked otherwise
        if self.options.method == "lbfgs" and self.options.preconditioner == "in_plane":
            self.in_matrix: np.ndarray | None = kinds != SpringKind.BENDING
        else:
            self.in_matrix = None
        self.a = np.ascontiguousarray(springs[:, 0], dtype=np.int32)
        self.b = np.ascontiguousarray(springs[:, 1], dtype=np.int32)
        self.rest = np.ascontiguousarray(rest, dtype=np.float64)
        self.weight = weight
        self.stiff_t = np.ascontiguousarray(stiff_t, dtype=np.float64)
        self.stiff_c = np.ascontiguousarray(stiff_c, dtype=np.float64)
        self.modulus = float(model.material.stretch_modulus)
        self.free_vertices = np.flatnonzero(np.asarray(model.inv_mass) > 0.0).astype(np.int32)
        self.free = np.full(model.vertex_count, -1, dtype=np.int32)
        self.free[self.free_vertices] = np.arange(self.free_vertices.shape[0], dtype=np.int32)
        # a large cloth's energy over two slabs that share no vertex, then the springs between them
        # (`_energy`: a slab a thread), from copies of its springs in that order beside the model's
        # order of the other kernels; decided by the model alone, so the bytes are the same on any
        # thread count
        every_row = np.arange(self.free_vertices.shape[0], dtype=np.int32)
        springs = tuple(_read_only(array) for array in (self.a, self.b, self.rest, self.stiff_t, self.stiff_c))
        slab: np.ndarray | None = None
        #: the calls of `kernels.step_energy` that make the energy: (free rows whose inertia it adds,
        #: spring ends a and b, rest lengths, tension and compression stiffnesses) for the whole
        #: cloth, or for each slab and then the springs between them (no rows)
        self.energy_parts: tuple[tuple[np.ndarray, ...], ...] = ((every_row, *springs),)
        if self.a.shape[0] >= SPLIT_SPRINGS:
            slab = vertex_slabs(np.asarray(model.rest_positions, dtype=np.float64), 2)
            group = np.where(slab[self.a] == slab[self.b], slab[self.a], 2)
            order = np.concatenate([np.flatnonzero(group == part) for part in range(3)])  # stable, by part
            ordered = [_read_only(np.ascontiguousarray(array[order])) for array in springs]
            bounds = np.concatenate([[0], np.cumsum(np.bincount(group, minlength=3))])
            rows = [np.flatnonzero(slab[self.free_vertices] == side).astype(np.int32) for side in (0, 1)]
            rows.append(every_row[:0])
            self.energy_parts = tuple(
                (rows[part], *(array[bounds[part] : bounds[part + 1]] for array in ordered)) for part in range(3)
            )
        # two threads for the slabs and our own factor's halves where measured faster (a busy
        # machine: one), steps timed in windows of a few (a step of such a cloth is tens of
        # milliseconds), switching at a smaller gain than the picker's default: two threads make a
        # step only 10-20 % faster
        halves = slab is not None or self.free_vertices.shape[0] >= cholesky.OWN_FACTOR_ROWS
        self._picker = ThreadPicker(
            split_threads() if halves else 1, window=PICKER_WINDOW, interval=4 * PICKER_WINDOW, margin=PICKER_MARGIN
        )
        self._threads = 1
        self.free_mass = np.asarray(model.mass, dtype=np.float64)[self.free_vertices]
        #: (F, 3) rest positions of the free vertices (m): the factor's ordering splits them in space
        self.free_rest = np.asarray(model.rest_positions, dtype=np.float64)[self.free_vertices]
        self.rhs = np.zeros((self.free_vertices.shape[0], 3))
        shape = self.rhs.shape
        if self.options.method == "local_global":  # the global step's result, (F, 3)
            self.solution = np.zeros(shape)
        else:  # L-BFGS buffers, (F, 3) each, HISTORY pairs of them
            self.grad, self.trial_grad = np.zeros(shape), np.zeros(shape)
            self.direction, self.base, self.residual = np.zeros(shape), np.zeros(shape), np.zeros(shape)
            self.step_history, self.gradient_history = np.zeros((HISTORY, *shape)), np.zeros((HISTORY, *shape))
            self.rho = np.zeros(HISTORY)
        self.factor: cholesky.SparseCholesky | cholesky.CholmodFactor | None = None
        #: the anchors' `version` the factor was made at
        self._factored_version = 0
        #: the quantities and factor of the step length before the current one (`_factorise`):
        #: a run switching between its contact and its slow steps (`meshdeform.simulate`) does not
        #: assemble and factorise the matrix at every switch
        self._other_length: _StepLength | None = None
        self.coarse_inertia: np.ndarray | None = None
        #: the matrix's lower triangle as CSC (indptr, indices, values), each column's diagonal first
        self._matrix: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        #: the held contacts tied down in the matrix (L-BFGS only: local/global's matrix is exact)
        #: whether the model is a closed surface (a solid): its impacts are tied down too (`anchors`)
        self.solid = is_closed(np.asarray(model.triangles))
        self.anchors = (
            ContactAnchors(self.free_vertices.shape[0], self.solid) if self.options.method == "lbfgs" else None
        )
        #: the held contacts' correction of the preconditioner's solves (L-BFGS only), its entries
        #: of the factor's inverse among the held rows kept while the factor is
        self.held = HeldContacts(self.free_vertices.shape[0]) if self.options.method == "lbfgs" else None
        self.coarse_space: coarse.CoarseSpace | None = None
        self._coarse_building: Future[coarse.CoarseSpace | None] | None = None
        if self.options.method == "lbfgs":
            build = functools.partial(
                coarse.coarse_space, self.free_rest, self.free, self.a, self.b,
                kinds != SpringKind.BENDING, int(self.options.coarse or 0), halves=slab is not None,
            )
            if halves and split_threads() >= 2:  # built on the pool thread while the first step factorises
                self._coarse_building = helper_pool().submit(build)
            else:
                self.coarse_space = build()
        edges = rest[kinds == SpringKind.STRUCTURAL]
        edges = edges if edges.size else rest
        #: the longest move an L-BFGS iteration may give a vertex (m): a fraction of the median edge
        self.trust = TRUST_FRACTION * float(np.median(edges)) if edges.size else np.inf
        #: the deepest a held contact is sunk into its obstacle after a step (m; `_sink_pressed`)
        self.sink_cap = SINK_FRACTION * float(np.median(edges)) if edges.size else 0.0
        self._forget_contacts()
        # scratch of `kernels.constrained_rows`: each pushed vertex's unit push (V, 3) and its length (V,),
        # which vertices moved and which were pushed (V,) bool each
        self._normal, self._depth = np.zeros((model.vertex_count, 3)), np.zeros(model.vertex_count)
        self._moved = np.zeros(model.vertex_count, dtype=np.bool_)
        # the vertices whose contact the springs pressed into its obstacle at the end of the last step
        # (V,) bool (`_sink_pressed`), the ones `anchors` ties down
        self._spring_pressed = np.zeros(model.vertex_count, dtype=np.bool_)
        self._pushed = np.zeros(model.vertex_count, dtype=np.bool_)
        #: (V,) m: how deep `_sink_pressed` sank each vertex into its obstacle at the last step's end
        self._sunk = np.zeros(model.vertex_count)
        # (V, 3) each: a step's BDF2 prediction x_hat and inertial target y; what it left, x_out and v_out
        self.x_hat, self.y, self.x_out, self.v_out = (np.zeros((model.vertex_count, 3)) for _ in range(4))
        # two pairs of (V, 3) arrays for the step's start (x_n, v_n), which becomes the next step's
        # history (x_prev, v_prev): each step writes the pair that history is not (no array made
        # in a step: a fresh array is a page fault for each of its pages where large arrays are mmapped)
        self._starts = tuple((np.zeros((model.vertex_count, 3)), np.zeros((model.vertex_count, 3))) for _ in range(2))
        self._dt = -1.0
        self._state_key = None

    def _factorise(self, dt: float) -> None:
        """The step-length quantities and the factor for steps of dt (s): the last length's, kept
        aside (`_StepLength`), where dt is that one (refactorised where the anchored set was renewed
        since); otherwise assembled and factorised, and the current length's kept aside in turn."""
        if self.held is not None:
            self.held.forget()  # its entries are of the last length's factor
        current = self._current_length() if self._dt > 0.0 else None
        other, self._other_length = self._other_length, current
        if other is not None and other.dt == dt:
            self._use_length(other)
            if other.anchors_version != self._anchors_version():
                self._factor()
            return
        self.factor = None  # the one kept aside is not refactorised in place
        beta = 2.0 * dt / 3.0
        beta2 = beta * beta
        # air damping as an implicit drag force of rate c = -ln(1 - damping) (1/s)
        self.drag_factor = 1.0 - beta * np.log(velocity_retention(self.options.damping, 1.0))
        # a restarted history's velocity a step back is v / (the air damping's factor over a step): the
        # velocity a damped path had then (with v alone, a vertex restarted every step lost a third of the drag)
        self.undamped = 1.0 / velocity_retention(self.options.damping, dt)
        nf = self.free_vertices.shape[0]
        self.inertia = self.drag_factor * self.free_mass / beta2
        fa = self.free[self.a]
        fb = self.free[self.b]
        w = self.weight
        if self.in_matrix is not None:
            fa, fb, w = fa[self.in_matrix], fb[self.in_matrix], w[self.in_matrix]
        both = (fa >= 0) & (fb >= 0)
        diag = self.inertia.copy()
        diag += np.bincount(fa[fa >= 0], weights=w[fa >= 0], minlength=nf)
        diag += np.bincount(fb[fb >= 0], weights=w[fb >= 0], minlength=nf)
        # lower triangle (row >= column) as COO, summed into CSC below
        fa, fb = fa[both], fb[both]
        off = np.where(fa == fb, -2.0, -1.0) * w[both]  # a spring from a vertex to itself adds 0
        diagonal = np.arange(nf, dtype=np.int32)
        rows = np.concatenate([diagonal, np.maximum(fa, fb)])
        cols = np.concatenate([diagonal, np.minimum(fa, fb)])
        vals = np.concatenate([diag, off])
        del fa, fb, off, both, diag, diagonal
        if nf:
            lower = coo_matrix((vals, (rows, cols)), shape=(nf, nf)).tocsc()
            del rows, cols, vals
            lower.sum_duplicates()  # sorted rows: each column's diagonal entry comes first
            self._matrix = (lower.indptr.astype(np.int32), lower.indices.astype(np.int32), lower.data)
            self._factor()
        self.beta2 = beta2
        self._dt = dt
        if self._coarse_building is not None:
            self.coarse_space, self._coarse_building = self._coarse_building.result(), None
        if self.coarse_space is not None:
            self.coarse_inertia = self.coarse_space.inertia_matrix(self.inertia)

    def _current_length(self) -> _StepLength:
        """The quantities of the current step length, to be kept aside (`_factorise`)."""
        return _StepLength(
            dt=self._dt, beta2=self.beta2, drag_factor=self.drag_factor, undamped=self.undamped, inertia=self.inertia,
            matrix=self._matrix, factor=self.factor, anchors_version=self._factored_version,
            coarse_inertia=self.coarse_inertia,
        )  # fmt: skip

    def _use_length(self, length: _StepLength) -> None:
        """Make `length`'s quantities and factor the current ones."""
        self._dt, self.beta2 = length.dt, length.beta2
        self.drag_factor, self.undamped = length.drag_factor, length.undamped
        self.inertia, self._matrix, self.factor = length.inertia, length.matrix, length.factor
        self._factored_version, self.coarse_inertia = length.anchors_version, length.coarse_inertia

    def _anchors_version(self) -> int:
        """How many times the anchored set was renewed (0 without anchors)."""
        return self.anchors.version if self.anchors is not None else 0

    def _factor(self) -> None:
        """Factorise the matrix `_factorise` assembled, the anchored rows' diagonal raised
        (`anchors` module docstring)."""
        self._factored_version = self._anchors_version()
        if self.held is not None:
            self.held.forget()
        indptr, indices, data = self._matrix
        if self.anchors is not None and self.anchors.anchored.any():
            data = data.copy()
            data[indptr[:-1]] = self.anchors.raised_diagonal(data[indptr[:-1]])
        if self.factor is not None and self.factor.has_pattern(indptr, indices):
            self.factor.refactor(data)  # the ordering and symbolic analysis kept
        else:
            self.factor = None  # free the old factor before building the new one
            # L-BFGS's matrix is its preconditioner (single-precision blocks), local/global's exact
            single = self.options.method == "lbfgs"
            self.factor = cholesky.factorise(indptr, indices, data, self.free_rest, self._threads, single)

    def step(self, model: SpringModel, state: State, dt: float, control: Control) -> None:
        if not self._prepared(model):
            self._prepare(model)
        self._picker.timed(lambda threads: self._step(state, dt, control, threads))

    def _step(self, state: State, dt: float, control: Control, threads: int) -> None:
        """One step (the module docstring), its energy's slabs on `threads` threads."""
        self._threads = threads
        if self.factor is not None:
            self.factor.threads = threads
        iterations = control.iterations or self.iterations
        new_length = dt != self._dt
        if new_length:
            self._factorise(dt)
        x, v = state.positions, state.velocities
        accel = control.accelerations
        # a history starts as if the external acceleration had been acting before, but a kick had not
        # (an impact's velocity change taken into the history carries on as 1.5 times itself)
        kicks = control.kicks
        key = self._state_key
        if key is None or key[0] != id(state) or abs(key[1] - state.time) > 1e-6 * dt:
            # BDF2 history consistent with constant external acceleration and the air damping (exact free fall)
            acted = accel if kicks is None else accel - kicks
            self.x_prev = x - dt * v + 0.5 * dt * dt * acted
            self.v_prev = self.undamped * v - dt * acted
            self._forget_contacts()
        else:
            # vertices a constraint moved since this solver's last step (a collider, self-
            # collision, tethers) start their history afresh from where they are: BDF2's
            # extrapolation of their former path would carry on through the contact
            moved, pushed = self._moved, self._pushed
            kernels.constrained_rows(
                x, v, self.x_out, self.v_out, self.free, kernels.MOVE_TOLERANCE / dt, self._normal, self._depth, moved,
                pushed,
            )
            if control.pulled is not None:  # a soft pin's pull is no obstacle: never held against
                pushed &= ~control.pulled
            if new_length:  # BDF2's history is of steps of another length: every row starts afresh
                moved[:] = True
            if moved.any():
                acted = accel[moved] if kicks is None else accel[moved] - kicks[moved]
                self.x_prev[moved] = x[moved] - dt * v[moved] + 0.5 * dt * dt * acted
                self.v_prev[moved] = self.undamped * v[moved] - dt * acted
            pushed_vertices = np.flatnonzero(pushed)
            self.contact_rows = self.free[pushed_vertices].astype(np.int64)
            self.contact_normals = np.ascontiguousarray(self._normal[pushed_vertices])
            # an impact on an obstacle: a push deeper than IMPACT_SINKS times what the external
            # acceleration alone sinks a resting vertex in a step, not by self-collision; on a sheet
            # the push back out of this solver's own sink (`_sunk`) is no impact: judged one, the
            # vertex would be held only while its momentum pressed it, and its springs would drive
            # it in again every step. A solid counts it: held while its springs press, a stiff
            # body is sunk by forces far above its weight and springs back (docs/performance.md,
            # "A sheet's own sink is no impact")
            sink = 0.5 * dt * dt * np.linalg.norm(accel[pushed_vertices], axis=1)
            own = self._depth[pushed_vertices] - (0.0 if self.solid else self._sunk[pushed_vertices])
            self.contact_impacts = own > IMPACT_SINKS * sink
            self.contact_self = np.zeros(pushed_vertices.shape[0], dtype=np.bool_)
            self.contact_friction = np.zeros(pushed_vertices.shape[0])
            if control.friction is not None and control.friction.shape[0] == x.shape[0]:
                self.contact_friction = control.friction[pushed_vertices]
            # sliding faster along its surface than its friction stops in `STICK_STEPS` steps: no
            # static friction for it this step (held where it is along every axis, a crumpled
            # sheet's rows sliding at 1 m/s were stopped dead and stretched the cloth 40 %)
            normal = np.einsum("ij,ij->i", v[pushed_vertices], self.contact_normals)
            sliding = v[pushed_vertices] - normal[:, None] * self.contact_normals
            self.contact_sliding = np.einsum("ij,ij->i", sliding, sliding) > (
                STICK_STEPS * self.contact_friction * np.linalg.norm(accel[pushed_vertices], axis=1) * dt
            ) ** 2
            self.contact_still = np.zeros(pushed_vertices.shape[0], dtype=np.bool_)
            if control.still_contact is not None and control.still_contact.shape[0] == x.shape[0]:
                self.contact_still = control.still_contact[pushed_vertices]
            if control.self_contact is not None and control.self_contact.shape[0] == x.shape[0]:
                self.contact_self = control.self_contact[pushed_vertices]
                self.contact_impacts &= ~self.contact_self
        # the contacts the springs press into the obstacle, a solid's impacts and self-collision's are tied down
        tied = self._spring_pressed[self.free_vertices[self.contact_rows]] | self.contact_self
        if self.solid:
            tied |= self.contact_impacts
        if self.anchors is not None and self.anchors.update(self.contact_rows[tied]) and self.factor is not None:
            self._factor()  # the held set changed enough: its rows tied down in the matrix (`anchors`)
        self._spring_pressed[:] = False  # read: this step's end sets them afresh
        self._sunk[:] = 0.0
        # the step's start (x_n, v_n) becomes the next step's history: the pair of arrays it is not
        x_n, v_n = next(pair for pair in self._starts if pair[0] is not self.x_prev and pair[1] is not self.v_prev)
        x_hat, y = self.x_hat, self.y
        kernels.bdf2_start(
            x, v, self.x_prev, self.v_prev, accel, dt, self.beta2, self.drag_factor, self.free_vertices,
            x_n, v_n, x_hat, y,
        )
        if not self.a.shape[0]:  # no springs: the step's minimum is the inertial target
            x[self.free_vertices] = y[self.free_vertices]
        elif self.factor is not None:
            if self.options.method == "lbfgs":
                gradient = self._quasi_newton(x, y, iterations, x_n)
                if self.contact_rows.shape[0]:
                    self._sink_pressed(x, y, gradient)
            else:
                self._local_global(x, y, iterations)
        kernels.bdf2_finish(x, v, x_hat, x_n, state.previous, self.free, dt, self.x_out)
        self.x_prev = x_n
        self.v_prev = v_n
        np.copyto(self.v_out, v)
        self._state_key = (id(state), state.time + dt)

    def _sink_pressed(self, x: np.ndarray, y: np.ndarray, gradient: np.ndarray) -> None:
        """After the iterations, in place: each obstacle contact still held and pressed (its row's
        gradient (F, 3) at x along the push, F_n = grad . n > 0, in N) is moved into its obstacle
        by how far that force would move the vertex alone within the step, against its inertia
        (F_n / inertia, m), at most `self.sink_cap`. The constraint's push after the step takes it
        back out: that push is the contact's normal impulse, which scales its friction, and keeps
        the vertex in the contact set. Self-collision's contacts are left as they are (released
        in the last iteration). Records which of the pressed vertices their springs press
        (`_spring_pressed`: the ones the next step's `anchors` tie down)."""
        fv = self.free_vertices
        held = self._pressed(gradient, x, y) & ~self.contact_self
        if not held.any():
            return
        rows, normals = self.contact_rows[held], self.contact_normals[held]
        force = np.maximum(np.einsum("ij,ij->i", gradient[rows], normals), 0.0)
        # the springs' share of the press: the gradient less its inertia term, inertia (x - y)
        spring_force = gradient[rows] - self.inertia[rows, None] * (x[fv[rows]] - y[fv[rows]])
        springs = np.einsum("ij,ij->i", spring_force, normals)
        self._spring_pressed[fv[rows]] = springs > ANCHOR_SPRING_SHARE * force
        depth = np.minimum(force / self.inertia[rows], self.sink_cap)
        x[fv[rows]] -= normals * depth[:, None]
        self._sunk[fv[rows]] = depth

    def _pressed(self, gradient: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """(K,) bool: which contact rows are pressed into their obstacle at x, given the step
        energy's gradient (F, 3) there (`kernels.pressing`: the force rule, or the momentum rule
        after an impact)."""
        held = np.empty(self.contact_rows.shape[0], dtype=np.bool_)
        kernels.pressing(
            gradient, x, y, self.free_vertices, self.contact_rows, self.contact_normals, self.contact_impacts, held
        )
        return held

    def _stuck(self, gradient: np.ndarray) -> np.ndarray | None:
        """(K,) bool: the obstacle contacts that static friction holds in this step, from the step
        energy's gradient (F, 3) at the iterations' start: pressed in (F_n = grad . n > 0, the
        force the obstacle takes) with the rest of the force, momentum included, within the
        friction's cone (|F_t| <= friction F_n), and not sliding at the step's start faster than
        its friction stops in `STICK_STEPS` steps (`contact_sliding`); None where none is. Such a contact is held where
        it is along every axis, not only its normal: held along the normal alone, a cloth on a
        slope slid within every step by what gravity gives it along the slope, and the
        velocity friction after the step took the speed but not the way (docs/performance.md,
        "Static friction in the implicit solver")."""
        friction = self.contact_friction
        candidates = (friction > 0.0) & ~self.contact_self & ~self.contact_impacts & ~self.contact_sliding
        if not candidates.any():
            return None
        rows, normals = self.contact_rows, self.contact_normals
        force = gradient[rows]
        pressing = np.einsum("ij,ij->i", force, normals)
        sliding = force - pressing[:, None] * normals
        stuck = candidates & (pressing > 0.0)
        stuck &= np.einsum("ij,ij->i", sliding, sliding) <= (friction * pressing) ** 2
        return stuck if stuck.any() else None

    def _forget_contacts(self) -> None:
        """No vertex held: the free rows (K,) of F a constraint pushed before this step and the unit
        push of each (K, 3) are empty together, with whether each is an impact, whether
        self-collision pushed it, whether a still collider did and whether it slides faster than
        its friction stops in `STICK_STEPS` steps (K,) bool each, and that collider's friction (K,)."""
        self.contact_rows = np.zeros(0, dtype=np.int64)
        self.contact_normals = np.zeros((0, 3))
        self.contact_impacts = np.zeros(0, dtype=np.bool_)
        self.contact_self = np.zeros(0, dtype=np.bool_)
        self.contact_friction = np.zeros(0)
        self.contact_still = np.zeros(0, dtype=np.bool_)
        self.contact_sliding = np.zeros(0, dtype=np.bool_)

    def _local_global(self, x: np.ndarray, y: np.ndarray, iterations: int) -> None:
        """Liu et al.'s `iterations`: project every spring, solve the prefactored system, repeat."""
        for _ in range(iterations):
            kernels.pd_rhs(
                x, self.a, self.b, self.rest, self.weight, self.stiff_t, self.stiff_c, self.modulus,
                self.free, self.inertia, y, self.rhs,
            )
            self.factor.solve(self.rhs, self.solution)
            kernels.scatter_free(x, self.free_vertices, self.solution)

    def _energy(self, x: np.ndarray, y: np.ndarray, grad: np.ndarray) -> float:
        """The step's energy at x (V, 3) and its gradient into grad (F, 3) (`kernels.step_energy`
        over `energy_parts`): one call, or the two slabs (beside each other on two threads) and then
        the springs between them, summed in that order whatever the threads."""

        def part(rows: np.ndarray, a: np.ndarray, b: np.ndarray, rest: np.ndarray, stiff_t: np.ndarray,
                 stiff_c: np.ndarray) -> float:
            return kernels.step_energy(
                x, a, b, rest, stiff_t, stiff_c, self.modulus, self.free, self.free_vertices, rows, self.inertia, y,
                grad,
            )

        if len(self.energy_parts) == 1:
            return float(part(*self.energy_parts[0]))
        slab_0, slab_1, between = self.energy_parts
        if self._threads >= 2:
            first, second = beside(functools.partial(part, *slab_0), functools.partial(part, *slab_1))
        else:
            first, second = part(*slab_0), part(*slab_1)
        return float(first + second + part(*between))

    def _coarse_correction(self, x: np.ndarray, y: np.ndarray) -> float:
        """Up to `COARSE_STEPS` Newton steps on the coarse space's displacements (`coarse` module
        docstring) from x, in place, each with an Armijo line search on the step's energy, a later one
        only while it promises a share of the first's decrease (`COARSE_SLOPE_FRACTION`); its
        matrix Z^T H Z is assembled and factorised once, at x. Returns the energy at the x it leaves, whose
        gradient is in `self.grad` (the L-BFGS iterations start from both)."""
        space = self.coarse_space
        fv = self.free_vertices
        matrix = self.coarse_inertia.copy()
        space.add_spring_hessian(x, self.a, self.b, self.rest, self.weight, matrix, self._threads)
        skip = space.skip
        coarse.factor_spd(matrix, skip)
        gradient = np.empty(3 * space.count)
        energy = self._energy(x, y, self.grad)
        first_slope = 0.0
        for _ in range(COARSE_STEPS):
            slope = coarse.newton_move(
                self.grad, space.vertex_nodes, space.vertex_weights, matrix, skip, gradient, space.forward, space.move
            )
            # a later step whose Newton decrease (-slope / 2) is a sliver of the first's is not worth an energy
            if not slope < COARSE_SLOPE_FRACTION * first_slope:
                break
            first_slope = first_slope or slope
            coarse.prolong(space.move, space.vertex_nodes, space.vertex_weights, self.direction)
            kernels.gather_rows(x, fv, self.base)
            step = 1.0
            for _ in range(COARSE_HALVINGS):
                kernels.place(x, fv, self.base, self.direction, step)
                trial = self._energy(x, y, self.trial_grad)
                if trial <= energy + ARMIJO * step * slope:
                    break
                step *= 0.5
            else:  # no decrease along the coarse direction: x stays where it was
                kernels.place(x, fv, self.base, self.direction, 0.0)
                break
            energy = trial
            self.grad, self.trial_grad = self.trial_grad, self.grad
        return energy

    def _two_loop(
        self, grad: np.ndarray, held_contacts: tuple[np.ndarray, ...], order: np.ndarray,
        history: tuple[np.ndarray, ...],
    ) -> float:
        """L-BFGS's two-loop recursion: `self.direction` (F, 3) = H grad, H0 the prefactored
        matrix's inverse on the motions that keep the held contacts (`held`); returns the slope
        of the step -direction. held_contacts: the rows (K,) and unit directions (K, 3) the
        filters take out (a row per normal, three per fixed row), the rows held along their
        normal alone and their normals, and the rows held along every axis; order: the history
        slots, newest first; history: (rho, step history, gradient history, alpha)."""
        rows, normals, along, along_normals, fixed = held_contacts
        kernels.lbfgs_first_loop(grad, rows, normals, order, *history, self.residual)
        self.factor.solve(self.residual, self.direction)
        if rows.shape[0]:
            self.held.project(self.factor, self.direction, along, along_normals, fixed)
        return kernels.lbfgs_second_loop(self.direction, rows, normals, order, *history, grad)

    def _quasi_newton(self, x: np.ndarray, y: np.ndarray, iterations: int, start: np.ndarray) -> np.ndarray:
        """`iterations` of L-BFGS on the step's energy from x (= y on the free vertices), in place; returns the
        energy's gradient (F, 3) at the x it leaves (one of the solver's buffers). start (V, 3): where
        the step started, to which the contacts static friction holds go back along their surface.

        The initial inverse Hessian is the prefactored matrix's inverse: one L-BFGS iteration
        without history is exactly one local/global iteration (the matrix times x minus the
        local step's right-hand side is the energy's gradient), and the history of the last
        `HISTORY` steps adds the curvature that matrix lacks, above all for springs that turn
        (it holds every spring at full stiffness in every direction). Each direction is tried at
        step 1, halved until the energy falls by the Armijo condition. The history is per step.

        Contacts: a vertex a constraint pushed before this step is held in every iteration where
        the forces press it into the obstacle (its motion along the push taken out of the
        direction) and may lift off where they pull it away; self-collision's are released in the
        last iteration. Letting every contact go in the last iteration (so that the collider's
        push after the step, and its friction, take place) would let a stiff cloth's springs drive
        whole regions into the obstacle, whose pushes then store energy; `_sink_pressed` gives the
        push instead (docs/performance.md has the figures).
        """
        fv = self.free_vertices
        if self.coarse_space is not None and not self.contact_rows.shape[0]:
            energy = self._coarse_correction(x, y)
        else:
            energy = self._energy(x, y, self.grad)
        grad, trial_grad, direction, base = self.grad, self.trial_grad, self.direction, self.base
        trust = self.trust if self.contact_rows.shape[0] else np.inf  # only a step with contact is bounded
        slots: list[int] = []  # history slots, newest first
        alpha = np.zeros(HISTORY)
        no_rows, no_normals = self.contact_rows[:0], self.contact_normals[:0]
        stuck = self._stuck(grad) if self.contact_rows.shape[0] else None
        if stuck is not None:  # they start where the step started along their surface
            vertices = fv[self.contact_rows[stuck]]
            normals = self.contact_normals[stuck]
            way = x[vertices] - start[vertices]
            x[vertices] -= way - np.einsum("ij,ij->i", way, normals)[:, None] * normals
            energy = self._energy(x, y, self.grad)
            grad = self.grad
        for iteration in range(iterations):
            # contacts held while pressed (the docstring); self-collision's released in the last
            if self.contact_rows.shape[0]:
                held = self._pressed(grad, x, y)
                if iteration + 1 == iterations:
                    held &= ~self.contact_self
                rows, normals, fixed = self.contact_rows[held], self.contact_normals[held], no_rows
                # a still collider's and the cloth's own layers': the preconditioner keeps them exactly
                exact = held & (self.contact_still | self.contact_self)
                along, along_normals = self.contact_rows[exact], self.contact_normals[exact]
                if stuck is not None and (stuck & held).any():  # held along every axis: static friction
                    fixed = self.contact_rows[stuck & held]
                    rows = np.concatenate([rows, np.repeat(fixed, 3)])
                    normals = np.concatenate([normals, np.tile(_AXES, (fixed.shape[0], 1))])
            else:
                rows, normals = no_rows, no_normals
                along, along_normals, fixed = no_rows, no_normals, no_rows
            # two-loop recursion: direction = H grad, H0 = matrix^-1 (the step is -direction)
            order = np.array(slots, dtype=np.int64)
            history = (self.rho, self.step_history, self.gradient_history, alpha)
            held_contacts = (rows, normals, along, along_normals, fixed)
            slope = self._two_loop(grad, held_contacts, order, history)
            if not slope < 0.0 and slots:  # the history spoilt the direction: start it afresh
                slots.clear()
                slope = self._two_loop(grad, held_contacts, order[:0], history)
            if not slope < 0.0:  # a stationary point
                return grad
            kernels.gather_rows(x, fv, base)
            step = 1.0
            if trust < np.inf and kernels.longest_row(direction) > trust:
                slope, step = _bounded_rows(direction, grad, trust, slope)
            for _ in range(LINE_SEARCH_HALVINGS):
                kernels.place(x, fv, base, direction, -step)
                trial = self._energy(x, y, trial_grad)
                if trial <= energy + ARMIJO * step * slope:
                    break
                step *= 0.5
            else:  # no decrease even at the smallest step: x is as good as this direction gets
                kernels.place(x, fv, base, direction, 0.0)
                return grad
            if iteration + 1 == iterations:
                return trial_grad
            slot = next(k for k in range(HISTORY) if k not in slots) if len(slots) < HISTORY else slots.pop()
            curvature = kernels.lbfgs_remember(
                direction, step, trial_grad, grad, rows, normals, self.step_history[slot], self.gradient_history[slot]
            )
            if curvature > 0.0:
                self.rho[slot] = 1.0 / curvature
                slots.insert(0, slot)
            grad, trial_grad = trial_grad, grad
            energy = trial
        return grad


def _read_only(array: np.ndarray) -> np.ndarray:
    """A read-only view of `array`: `kernels.step_energy` is then compiled for one signature
    whether a cloth's energy is summed whole or by slabs (their copies would be writable, the
    model's arrays are not), so a large run loads the build that `pipeline.compile_ahead`'s
    small stand-in compiled, where it compiled another of its own (0.35 s with an empty cache)."""
    view = array.view()
    view.setflags(write=False)
    return view


def _bounded_rows(direction: np.ndarray, grad: np.ndarray, trust: float, slope: float) -> tuple[float, float]:
    """An L-BFGS direction (F, 3) whose longest row moves further than `trust` (m) bounded,
    in place where it can be: each row longer than `trust` shortened to it alone, so that a few
    fast rows (a small torn piece flying apart) do not shrink every other row's move, nor the
    fast rows' own correction to a sliver of what they need; where that is no descent direction
    of the energy (its slope -grad . direction (grad (F, 3)) not negative), the direction stays
    and the step is scaled as a whole to `trust` over the longest row. Returns the slope and the
    step."""
    lengths = np.sqrt(np.einsum("ij,ij->i", direction, direction))
    clipped = direction * np.minimum(1.0, trust / np.maximum(lengths, 1e-300))[:, None]
    clipped_slope = -float(np.einsum("ij,ij->", grad, clipped))
    if clipped_slope < 0.0:
        direction[:] = clipped
        return clipped_slope, 1.0
    return slope, trust / float(lengths.max())


@dataclass
class _StepLength:
    """What a step length dt (s) fixes in `ImplicitSolver`: beta^2 (s^2), the drag factor q, the
    restarted history's velocity factor, the free rows' inertia q m / beta^2 (F,) (kg/s^2), the
    matrix's lower triangle (CSC) and its factor made at the anchors' `version`, and the coarse
    space's inertia matrix (None without one)."""

    dt: float
    beta2: float
    drag_factor: float
    undamped: float
    inertia: np.ndarray
    matrix: tuple[np.ndarray, np.ndarray, np.ndarray] | None
    factor: cholesky.SparseCholesky | cholesky.CholmodFactor | None
    anchors_version: int
    coarse_inertia: np.ndarray | None


#: the unit axes: a contact held along all three (`_stuck`) keeps its place
_AXES = np.eye(3)
#: the longest move of a vertex in one L-BFGS iteration of a step with contact, as a fraction of
#: the median structural rest length: a cloth stretched around an obstacle otherwise slings a
#: vertex across it in one step (29 m/s on the fold scene, then divergence); steps without
#: contact are not bounded (at 256 x 256 the bound slowed a hanging cloth's convergence). Each
#: row is bounded alone (`_bounded_rows`)
TRUST_FRACTION = 0.25
#: the deepest `_sink_pressed` moves a held contact into its obstacle, as a fraction of the median
#: structural rest length: pressed by stiff springs, a vertex would otherwise be sunk deep and
#: pushed back out as a strong, sticking friction that stretches the cloth (docs/performance.md)
SINK_FRACTION = 1.0 / 16.0
#: a contact sliding at its step's start faster than its friction stops in this many steps
#: (STICK_STEPS friction |a| dt) takes no static friction in the step (`contact_sliding`): 1 let
#: a sheet collapsing onto the ground slide and stretch 1.065 (1.018 held), 8 let a crumpled
#: sheet's sliding rows be stopped dead and stretch it 40 % (docs/performance.md, "Static
#: friction for contacts that do not slide")
STICK_STEPS = 4.0
#: the share of a held contact's press that its springs must give for the matrix to tie it down
#: (`anchors`): a cloth the springs pull into an obstacle needs its contacts tied, but tying one
#: that only its weight presses stiffens the matrix against its sliding by the springs' stiffness
#: over its inertia (docs/performance.md, "Sliding, and the air damping of restarted vertices")
ANCHOR_SPRING_SHARE = 0.5
#: a collider's push deeper than this many times the sink of a resting vertex in one step (1/2 |a|
#: dt^2) is an impact, whose vertex is held only while its own momentum presses it in, not while
#: springs do: a stiff body's compression would be held and given back as a bounce (the values
#: tried and what they did: docs/performance.md, "Faster implicit steps, a woven default tried")
IMPACT_SINKS = 4.0
#: springs from which a model's energy is evaluated in two slabs, a thread each where measured
#: faster (`_energy`): below it, handing a slab to a thread costs about what it saves
SPLIT_SPRINGS = 50_000
#: steps in each window of the thread count's trials (`threads.ThreadPicker`), the first after 4 windows
PICKER_WINDOW = 5
#: the gain (a fraction of a window's seconds) at which the picker switches the thread count
PICKER_MARGIN = 0.05
#: Newton steps on the coarse space before each step's L-BFGS iterations (`_coarse_correction`)
COARSE_STEPS = 2
#: a coarse Newton step after the first is taken only while its slope is at least this fraction of
#: the first's (its predicted decrease, -slope / 2, likewise): each costs an energy evaluation, and
#: on a large hanging cloth the second one mostly promises a sliver (the slopes measured and the
#: fractions tried: docs/performance.md, "A second coarse Newton step only where it promises something")
COARSE_SLOPE_FRACTION = 3e-4
#: L-BFGS history length (Liu, Bouaziz, Kavan 2017 use 5)
HISTORY = 5
#: sufficient decrease of the line search: the energy must fall by this fraction of the slope
ARMIJO = 1e-4
#: halvings of the step before the line search gives up on a direction
LINE_SEARCH_HALVINGS = 12
#: halvings before a coarse Newton step is given up (the L-BFGS iterations follow it anyway): on
#: the 256 x 256 woven cloth 11 of 85 coarse directions found no decrease at all, 132 of its 227
#: energy evaluations at 2 ms each; 4 gives the same cloth (docs/performance.md)
COARSE_HALVINGS = 4
