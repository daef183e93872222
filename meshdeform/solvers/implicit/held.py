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
what eliminating the constraints from the matrix would give, without refactorising it).
C A^-1 C^T (m x m, m constraints) is dense and small: G_ij = (A^-1)_{r_i r_j} (n_i . n_j)
(`held_matrix`), factorised by the coarse space's dense Cholesky (`coarse.factor_spd`, serial and
in a fixed order: the same bytes on any thread count, no BLAS; a constraint the others already
hold is left out) and kept while the constraint set stays. Its entries come from the columns of
A^-1 at the held rows, each one solve with the factor (three a solve), of which only the entries
at the other held rows are kept (a row's among every row kept, `CACHED_ROWS`, until the factor
changes: `forget`), so a contact held for many steps costs its column once. The correction
itself is one more solve, of C^T lambda with lambda = G^-1 C u (`held_push`): on a 160 x 160
sheet that is 1.7 ms where the product of 96 kept columns took 2.5, and no column is stored.

At most `MAX_CONSTRAINTS` constraints are treated exactly, and a call computes the columns of at
most `new_rows` rows it has none for (`NEW_COLUMN_FLOATS` floats, at least `MIN_NEW_ROWS` rows:
a large cloth lying on its obstacles holds thousands of rows, and a column costs a third of a
solve). Where more rows are held, or more are new, the ones whose unconstrained answer moves them
the most against their constraints are chosen (the rest keep the filter alone); a cloth lying on
the ground holds hundreds, and there the contact anchors of the matrix do the rest (`anchors`).
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
#: the most rows whose entries of A^-1 among each other are kept from call to call (a cloth's held
#: set moves on and comes back; 8 MB)
CACHED_ROWS = 1024
#: the columns of A^-1 a call may compute for rows it has none for, in floats (a column is a float a
#: free row): unbounded in practice below 2 000 rows, 7 rows a call on a 160 x 160 cloth, where
#: without a bound its held set's churn took 20 solves a step (3.7x slower than without held
#: contacts; docs/performance.md, "Held contacts on a large cloth")
NEW_COLUMN_FLOATS = 200_000
#: ... and at least this many rows a call
MIN_NEW_ROWS = 6
#: the unit axes: a contact that static friction holds keeps its place along all three
_AXES = np.eye(3)


class HeldContacts:
    """The held-contact correction of the preconditioner's solves for a matrix of `rows` free
    rows (`project`), with the entries of A^-1 among the rows it has computed columns for (a slot
    each) and the factor of the last system it solved."""

    def __init__(self, rows: int) -> None:
        self.rows = rows
        #: the most rows kept: at least a full set of constraints' rows, at most every row
        self.cached = max(1, min(max(CACHED_ROWS, MAX_CONSTRAINTS), rows))
        #: the most constraints treated exactly
        self.capacity = MAX_CONSTRAINTS
        #: the most rows a call computes columns for
        self.new_rows = max(MIN_NEW_ROWS, NEW_COLUMN_FLOATS // max(rows, 1))
        self._among: np.ndarray | None = None  # (cached, cached) on first use: A^-1 between slots' rows
        self._used_at = np.full(self.cached, -1, dtype=np.int64)  # the call each slot was last used in, -1 never
        self._row_of_slot = np.full(self.cached, -1, dtype=np.int64)
        self._slot_of_row = np.full(rows, -1, dtype=np.int64)
        self._calls = 0
        self._unit = np.zeros((rows, 3))
        self._solved = np.zeros((rows, 3))
        #: (F + 1,) all False between calls: rows marked for a membership test (index -1, an
        #: empty slot's row, is the extra one, never marked)
        self._marked = np.zeros(rows + 1, dtype=np.bool_)
        #: the last system's constraints (rows, unit directions) and its Cholesky factor (lower
        #: triangle, pivots left out: `coarse.factor_spd`)
        self._system: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None

    def forget(self) -> None:
        """The factor changed: every entry computed so far is void."""
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
        Where there are more than `capacity` constraints, or more than `new_rows` rows without
        a column, those of the rows whose entry moves them the most against their constraints."""
        if not rows.shape[0] and not fixed.shape[0]:
            return
        # one entry a row: fixed rows along the axes, the others along their normal
        along, along_normals = rows, normals
        if fixed.shape[0]:
            self._marked[fixed] = True
            alone = ~self._marked[rows]
            self._marked[fixed] = False
            along, along_normals = rows[alone], normals[alone]
        new = np.count_nonzero(self._slot_of_row[along] < 0) + np.count_nonzero(self._slot_of_row[fixed] < 0)
        if along.shape[0] + 3 * fixed.shape[0] > self.capacity or new > self.new_rows:
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
            held_matrix(self._among, constraint_slots, constraint_normals, system)
            factor_spd(system, skip)  # a constraint the others already hold (rounding) is left out
            self._system = last = (constraint_rows, constraint_normals, system, skip)
        m = constraint_rows.shape[0]
        # C^T lambda into the zero scratch, its solve taken from the direction, the scratch zeroed
        held_push(direction, constraint_rows, constraint_normals, last[2], last[3], np.empty(m), np.empty(m),
                  np.empty(m), self._unit)  # fmt: skip
        factor.solve(self._unit, self._solved)
        direction -= self._solved
        self._unit[constraint_rows] = 0.0

    def _chosen(
        self, direction: np.ndarray, along: np.ndarray, along_normals: np.ndarray, fixed: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The rows held along a normal (and their normals) and the fixed rows whose entry in
        direction (F, 3) moves them the most against their constraints, as many as make at most
        `capacity` constraints with at most `new_rows` rows without a column, each list in its
        given order."""
        against = np.concatenate(
            [np.abs(np.einsum("ij,ij->i", direction[along], along_normals)), np.linalg.norm(direction[fixed], axis=1)]
        )
        cost = np.concatenate([np.ones(along.shape[0], dtype=np.int64), np.full(fixed.shape[0], 3, dtype=np.int64)])
        fresh = self._slot_of_row[np.concatenate([along, fixed])] < 0
        order = np.argsort(-against, kind="stable")
        # in that order, while the constraints fit: every row with a column, the first `new_rows` without
        admitted = ~fresh[order] | (np.cumsum(fresh[order]) <= self.new_rows)
        order = order[admitted]
        keep = np.sort(order[np.cumsum(cost[order]) <= self.capacity])
        count = along.shape[0]
        return along[keep[keep < count]], along_normals[keep[keep < count]], fixed[keep[keep >= count] - count]

    def _slots(self, factor: SparseCholesky | CholmodFactor, rows: np.ndarray) -> np.ndarray:
        """The slot of each row (rows distinct, at most `cached`), computing the missing rows'
        columns three a solve and keeping their entries at every kept row, in the slots unused
        the longest."""
        if self._among is None:
            self._among = np.zeros((self.cached, self.cached))
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
            self._row_of_slot[order] = missing
            self._slot_of_row[missing] = order
            kept = np.flatnonzero(self._row_of_slot >= 0)
            kept_rows = self._row_of_slot[kept]
            for start in range(0, missing.shape[0], 3):
                batch, targets = missing[start : start + 3], order[start : start + 3]
                units = (batch, np.arange(batch.shape[0]))
                self._unit[units] = 1.0  # the scratch is zero between uses
                factor.solve(self._unit, self._solved)
                self._unit[units] = 0.0
                entries = self._solved[kept_rows, : batch.shape[0]].T  # (batch, kept): A^-1 at the kept rows
                self._among[np.ix_(targets, kept)] = entries
                self._among[np.ix_(kept, targets)] = entries.T
            slots = self._slot_of_row[rows]
        self._used_at[slots] = self._calls
        return slots


@nb.njit(**JIT)
def held_matrix(among, slots, normals, system):  # pragma: no cover - compiled
    """system (m, m) = G = C A^-1 C^T for m constraints, each a unit normal (m, 3) at a row whose
    slot is slots (m,), among (S, S) A^-1 between the slots' rows (symmetric to the solves'
    rounding): G_ij = (A^-1)_{r_i r_j} (n_i . n_j), read once for both places of the pair."""
    m = slots.shape[0]
    for i in range(m):
        for j in range(i + 1):
            dot = normals[i, 0] * normals[j, 0] + normals[i, 1] * normals[j, 1] + normals[i, 2] * normals[j, 2]
            value = among[slots[i], slots[j]] * dot
            system[i, j] = value
            system[j, i] = value


@nb.njit(**JIT)
def held_push(direction, rows, normals, lower, skip, rhs, forward, lam, push):  # pragma: no cover - compiled
    """push (F, 3), zero on entry, += C^T lambda with lambda = G^-1 C direction for the m
    constraints (rows (m,), unit normals (m, 3)), G's factor lower, skip (m, m), (m,)
    (`coarse.factor_spd` of `held_matrix`'s G): the correction is A^-1 of it. rhs, forward,
    lam (m,) are scratch."""
    m = rows.shape[0]
    for i in range(m):
        r = rows[i]
        rhs[i] = direction[r, 0] * normals[i, 0] + direction[r, 1] * normals[i, 1] + direction[r, 2] * normals[i, 2]
    solve_factored(lower, skip, rhs, forward, lam)
    for i in range(m):
        r = rows[i]
        push[r, 0] += lam[i] * normals[i, 0]
        push[r, 1] += lam[i] * normals[i, 1]
        push[r, 2] += lam[i] * normals[i, 2]
