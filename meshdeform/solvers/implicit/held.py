"""Held contacts in the implicit solver's preconditioner: the prefactored matrix's inverse on the
motions that keep them.

Why: `implicit`'s L-BFGS iterations precondition with the prefactored projective-dynamics matrix
A (F x F, the same for x, y and z), which knows nothing of contact, and then take each held
contact's motion along its push out of the direction (`kernels.remove_normal`). Where part of a
stiff cloth is stopped within a long step, the matrix answers the springs compressed against
the stopped vertices as if those could follow: the stopped vertex is moved into its obstacle and
its free neighbours away from it, and the filter then removes the first half of that answer but
keeps the second. A triangle landing on one corner was lifted off the ground by its own springs
in every step and bounced for seconds; a sheet laid on a ball was thrown off it
(docs/performance.md, "Held contacts in the preconditioner").

What: the exact inverse of A on the subspace of motions that keep the held contacts, C z = 0
(C: one row per constraint, a unit direction n at a free row r: the contact's push, or the three
axes of a contact static friction holds in place),

    z = u - A^-1 C^T (C A^-1 C^T)^-1 C u,   u = A^-1 g,

a low-rank correction of the usual solve u (Woodbury's identity for the constrained system; it is
what eliminating the constraints from the matrix would give, without refactorising it). A^-1 C^T
needs the columns of A^-1 at the held rows: each is one solve with the factor, kept for as long as
the factor is (`forget` when it changes), so a contact held for many steps costs its column once.
C A^-1 C^T (m x m, m constraints) is dense and small: G_ij = (A^-1)_{r_i r_j} (n_i . n_j)
(`held_matrix`), factorised by the coarse space's dense Cholesky (`coarse.factor_spd`, serial and
in a fixed order: the same bytes on any thread count, no BLAS; a constraint the others already
hold is left out) and kept while the constraint set stays; `held_correct` applies it.

The columns cost F floats each; at most `MAX_CONSTRAINTS` constraints are treated exactly (fewer
on a large cloth: `BUDGET` floats in all). Where more rows are held, the ones whose unconstrained
answer moves them the most against their constraints are chosen (the rest keep the filter alone);
a cloth lying on the ground holds hundreds, and there the contact anchors of the matrix do the
rest (`anchors`).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from meshdeform.solvers.implicit.cholesky import CholmodFactor, SparseCholesky
from meshdeform.solvers.implicit.coarse import factor_spd, solve_factored
from meshdeform.solvers.jit import JIT

#: the most constraints treated exactly (a row held along its normal is one, a row static
#: friction holds three): the dense system's factorisation costs O(m^3); measured in
#: docs/performance.md
MAX_CONSTRAINTS = 96
#: the most columns of A^-1 kept from call to call (each row's until the factor changes or its slot
#: is needed): a cloth's held set moves on and comes back, and the rows treated exactly change
#: from iteration to iteration where more than `MAX_ROWS` are held
CACHED_ROWS = 1024
#: floats the columns may take in all (16 MB): a cloth of F free rows keeps at most BUDGET / F
BUDGET = 2_000_000
#: the unit axes: a contact that static friction holds keeps its place along all three
_AXES = np.eye(3)


class HeldContacts:
    """The held-contact correction of the preconditioner's solves for a matrix of `rows` free
    rows (`project`), with the columns of A^-1 it has computed (a slot each) and the factor of
    the last system it solved."""

    def __init__(self, rows: int) -> None:
        self.rows = rows
        #: the most columns kept: rows held now and again keep theirs
        self.cached = max(MAX_CONSTRAINTS, min(CACHED_ROWS, BUDGET // max(rows, 1)))
        #: the most constraints treated exactly
        self.capacity = min(MAX_CONSTRAINTS, self.cached)
        self._columns: np.ndarray | None = None  # (cached, F) on first use: a slot's column is a row
        self._used_at = np.full(self.cached, -1, dtype=np.int64)  # the call each slot was last used in, -1 never
        self._row_of_slot = np.full(self.cached, -1, dtype=np.int64)
        self._slot_of_row = np.full(rows, -1, dtype=np.int64)
        self._calls = 0
        self._unit = np.zeros((rows, 3))
        self._solved = np.zeros((rows, 3))
        self._push = np.zeros((self.cached, 3))
        #: (F + 1,) all False between calls: rows marked for a membership test (index -1, an
        #: empty slot's row, is the extra one, never marked)
        self._marked = np.zeros(rows + 1, dtype=np.bool_)
        #: the last system's constraints (rows, unit directions) and its Cholesky factor (lower
        #: triangle, pivots left out: `coarse.factor_spd`)
        self._system: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None

    def forget(self) -> None:
        """The factor changed: every column computed so far is void."""
        self._used_at[:] = -1
        self._row_of_slot[:] = -1
        self._slot_of_row[:] = -1
        self._system = None

    def project(
        self,
        factor: SparseCholesky | CholmodFactor,
        direction: np.ndarray,
        rows: np.ndarray,
        normals: np.ndarray,
        fixed: np.ndarray,
    ) -> None:
        """direction (F, 3) = A^-1 g on entry (the factor's solve), in place the inverse on the
        motions that keep the held contacts: rows (K,) distinct free rows held along their unit
        normals (K, 3), fixed (J,) distinct rows held along every axis (a row may be in both).
        Where there are more than `capacity` constraints, those of the rows whose entry moves
        them the most against their constraints."""
        if not rows.shape[0] and not fixed.shape[0]:
            return
        # one entry a row: fixed rows along the axes, the others along their normal
        along, along_normals = rows, normals
        if fixed.shape[0]:
            self._marked[fixed] = True
            alone = ~self._marked[rows]
            self._marked[fixed] = False
            along, along_normals = rows[alone], normals[alone]
        if along.shape[0] + 3 * fixed.shape[0] > self.capacity:
            along, along_normals, fixed = self._chosen(direction, along, along_normals, fixed)
        constraint_rows = np.concatenate([along, np.repeat(fixed, 3)]).astype(np.int64)
        constraint_normals = np.ascontiguousarray(np.concatenate([along_normals, np.tile(_AXES, (fixed.shape[0], 1))]))
        slots = self._slots(factor, np.concatenate([along, fixed]).astype(np.int64))
        constraint_slots = np.concatenate([slots[: along.shape[0]], np.repeat(slots[along.shape[0] :], 3)])
        last = self._system
        if last is None or not (
            np.array_equal(last[0], constraint_rows) and np.array_equal(last[1], constraint_normals)
        ):
            m = constraint_rows.shape[0]
            system, skip = np.empty((m, m)), np.empty(m, dtype=np.bool_)
            held_matrix(self._columns, constraint_rows, constraint_slots, constraint_normals, system)
            factor_spd(system, skip)  # a constraint the others already hold (rounding) is left out
            self._system = last = (constraint_rows, constraint_normals, system, skip)
        m = constraint_rows.shape[0]
        held_correct(
            direction, self._columns, constraint_rows, constraint_slots, constraint_normals, slots, last[2], last[3],
            np.empty(m), np.empty(m), np.empty(m), self._push,
        )  # fmt: skip

    def _chosen(
        self, direction: np.ndarray, along: np.ndarray, along_normals: np.ndarray, fixed: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The rows held along a normal (and their normals) and the fixed rows whose entry in
        direction (F, 3) moves them the most against their constraints, as many as make at most
        `capacity` constraints, each list in its given order."""
        against = np.concatenate(
            [np.abs(np.einsum("ij,ij->i", direction[along], along_normals)), np.linalg.norm(direction[fixed], axis=1)]
        )
        cost = np.concatenate([np.ones(along.shape[0], dtype=np.int64), np.full(fixed.shape[0], 3, dtype=np.int64)])
        order = np.argsort(-against, kind="stable")
        keep = np.sort(order[np.cumsum(cost[order]) <= self.capacity])
        count = along.shape[0]
        return along[keep[keep < count]], along_normals[keep[keep < count]], fixed[keep[keep >= count] - count]

    def _slots(self, factor: SparseCholesky | CholmodFactor, rows: np.ndarray) -> np.ndarray:
        """The slot of each row's column of A^-1 (rows distinct, at most `cached`), computing the
        missing ones three a solve into the slots unused the longest."""
        if self._columns is None:
            self._columns = np.zeros((self.cached, self.rows))
        self._calls += 1
        slots = self._slot_of_row[rows]
        missing = rows[slots < 0]
        if missing.shape[0]:
            # never used first, then the least recently used, none whose row is held now
            order = np.argsort(self._used_at, kind="stable")
            self._marked[rows] = True
            order = order[~self._marked[self._row_of_slot[order]]][: missing.shape[0]]
            self._marked[rows] = False
            evicted = self._row_of_slot[order]
            self._slot_of_row[evicted[evicted >= 0]] = -1
            for start in range(0, missing.shape[0], 3):
                batch, targets = missing[start : start + 3], order[start : start + 3]
                self._unit[:] = 0.0
                self._unit[batch, np.arange(batch.shape[0])] = 1.0
                factor.solve(self._unit, self._solved)
                self._columns[targets] = self._solved[:, : batch.shape[0]].T
            self._row_of_slot[order] = missing
            self._slot_of_row[missing] = order
            slots = self._slot_of_row[rows]
        self._used_at[slots] = self._calls
        return slots


@nb.njit(**JIT)
def held_matrix(columns, rows, slots, normals, system):  # pragma: no cover - compiled
    """system (m, m) = G = C A^-1 C^T for m constraints, each a unit normal (m, 3) at a free row
    (m,) whose column of A^-1 is columns[slot] ((S, F), slots (m,)): G_ij = (A^-1)_{r_i r_j}
    (n_i . n_j), the mean of its two computed copies (the solves' rounding)."""
    m = rows.shape[0]
    for i in range(m):
        for j in range(i + 1):
            dot = normals[i, 0] * normals[j, 0] + normals[i, 1] * normals[j, 1] + normals[i, 2] * normals[j, 2]
            value = 0.5 * (columns[slots[j], rows[i]] + columns[slots[i], rows[j]]) * dot
            system[i, j] = value
            system[j, i] = value


@nb.njit(**JIT)
def held_correct(  # pragma: no cover - compiled
    direction, columns, rows, slots, normals, used, lower, skip, rhs, forward, lam, push
):
    """direction (F, 3) -= A^-1 C^T G^-1 C direction, in place, with G's factor lower, skip (m, m),
    (m,) (`coarse.factor_spd` of `held_matrix`'s G) for the m constraints (rows, slots (m,),
    normals (m, 3)); used (U,): the distinct slots among them. rhs, forward, lam (m,) are
    scratch, push (S, 3) too (left zero): each slot's summed lambda_i n_i, taken from direction
    through its column."""
    m = rows.shape[0]
    for i in range(m):
        r = rows[i]
        rhs[i] = direction[r, 0] * normals[i, 0] + direction[r, 1] * normals[i, 1] + direction[r, 2] * normals[i, 2]
    solve_factored(lower, skip, rhs, forward, lam)
    for i in range(m):
        push[slots[i], 0] += lam[i] * normals[i, 0]
        push[slots[i], 1] += lam[i] * normals[i, 1]
        push[slots[i], 2] += lam[i] * normals[i, 2]
    for u in range(used.shape[0]):  # a slot's column at a time: contiguous
        s = used[u]
        p0, p1, p2 = push[s, 0], push[s, 1], push[s, 2]
        column = columns[s]
        for f in range(direction.shape[0]):
            weight = column[f]
            direction[f, 0] -= weight * p0
            direction[f, 1] -= weight * p1
            direction[f, 2] -= weight * p2
    for u in range(used.shape[0]):
        s = used[u]
        push[s, 0] = 0.0
        push[s, 1] = 0.0
        push[s, 2] = 0.0
