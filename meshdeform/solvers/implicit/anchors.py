"""Contact anchors: the held contacts of the implicit solver's steps, tied down in its matrix.

Why: `implicit`'s L-BFGS iterations precondition with the prefactored projective-dynamics matrix,
which knows nothing of contact, and then remove from the direction the motion of each held
contact along its push (`kernels.remove_normal`). Where a stiff cloth lies on an obstacle, its
free vertices next to the held ones are pulled towards the obstacle by their springs; the matrix
answers that pull as if the held vertices could follow, with the whole patch moving into the
obstacle almost rigidly (against its inertia only), and the filter then holds the held vertices
back while their free neighbours keep a move of up to a metre within a step of 5 ms. The trust
region (`TRUST_FRACTION`) scales every such step down to millimetres, so the iterations stall and
the cloth stays stretched: a 10 000 N/m sheet folded over a bar onto the ground reached 2.8x its
rest lengths (docs/performance.md, "Contact anchors in the implicit solver's matrix").

What: the matrix's diagonal is raised by `ANCHOR` times itself on the rows of the vertices held
recently that their springs pressed into the obstacle, or on a closed surface an impact (the solver
passes those: `solver.ANCHOR_SPRING_SHARE`, `solver.IMPACT_SINKS`; a contact that only its weight
presses is left untied, as the tie also holds it against sliding), so the preconditioner moves them
little and their neighbours as if tied to them (an elastic tie, in every direction: the filter and
the L-BFGS history still let a held vertex slide); the energy, its gradient and the filters are
unchanged, so the step minimises the same energy, only better preconditioned. Refactorising costs a
numeric factorisation (CHOLMOD's through cholespy a whole one), so the anchored set follows the
contacts loosely: a row stays anchored for `ANCHOR_WINDOW` steps after it was last held, and the
matrix is refactorised only when more than `ANCHOR_SLACK` of the held rows (and more than
`ANCHOR_FLOOR` rows, or `SOLID_FLOOR_FRACTION` of a closed surface's rows) are not anchored, or more
than `ANCHOR_SLACK` of the anchored rows were not held within the window (the scenes of
benchmarks/contact.py refactorise 5 to 30 times in their 480 steps, a 128 x 128 sheet draping over a
sphere 13 times in 576; from `LARGE_ROWS` rows, where a factorisation costs several steps, the
window and the slack are doubled). The set depends on the simulation alone: the same bytes on any
thread count.
"""

from __future__ import annotations

import numpy as np

#: the fraction of its own diagonal added to an anchored row of the matrix (0.1 to 1 held a stiff
#: cloth on an obstacle alike; 10 and more made the anchors stick, stretching the cloth elsewhere)
ANCHOR = 0.5
#: steps a row stays anchored after it was last held (3 frames at the contact steps, 8 a frame)
ANCHOR_WINDOW = 24
#: the fraction of held rows not anchored (or of anchored rows no longer held) that refactorises
ANCHOR_SLACK = 0.25
#: held rows that may stay unanchored whatever their fraction: a contact of a few vertices does not
#: refactorise (docs/performance.md has the floors tried)
ANCHOR_FLOOR = 32
#: ... but on a closed surface (a solid) at most this fraction of its rows: the 4 to 16 held rows
#: of a small box landing are all its contact, and unanchored they let the matrix drive it into the
#: ground as one rigid body that the filter then stops at its bottom alone, compressing it
#: (docs/performance.md, "A light, stiff, coarse solid comes to rest under implicit"). A sheet
#: keeps `ANCHOR_FLOOR`: tying a few of its rows holds a small sheet on a ball it would slide off
SOLID_FLOOR_FRACTION = 0.02
#: from this many rows a factorisation costs several steps (0.37 s at 256 x 256 against 60 ms a
#: step), so the set is kept twice as long and renewed at twice the slack: a 256 x 256 woven sheet
#: draped on a sphere renewed it 37 times in 24 frames (14 of its 24 s), now 16 (16 s), at the same
#: worst stretch
LARGE_ROWS = 32_768


class ContactAnchors:
    """Which free rows (F of them) the matrix anchors, and when that set is renewed.

    `anchored` (F,) bool: the rows whose diagonal the current factor raises by `ANCHOR`.
    """

    def __init__(self, rows: int, solid: bool = False) -> None:
        """rows: the free rows; solid: whether they make a closed surface (`SOLID_FLOOR_FRACTION`)."""
        self.anchored = np.zeros(rows, dtype=np.bool_)
        #: how many times `anchored` was renewed: a factor made at another count is out of date
        self.version = 0
        large = rows >= LARGE_ROWS
        #: steps a row stays anchored after it was last held, and the slack of a renewal
        self.window = 2 * ANCHOR_WINDOW if large else ANCHOR_WINDOW
        self.slack = 2 * ANCHOR_SLACK if large else ANCHOR_SLACK
        #: held rows that may stay unanchored whatever their fraction
        self.floor = min(ANCHOR_FLOOR, int(SOLID_FLOOR_FRACTION * rows)) if solid else ANCHOR_FLOOR
        self._last_held = np.full(rows, -self.window - 1, dtype=np.int64)
        self._step = 0

    def update(self, held: np.ndarray) -> bool:
        """Record one step's held rows `held` (K,) int (free rows). Returns True when the anchored
        set was renewed (to the rows held within the window): the caller refactorises."""
        self._step += 1
        self._last_held[held] = self._step
        recent = self._last_held > self._step - self.window
        loose = int(np.count_nonzero(~self.anchored[held]))
        anchored = int(np.count_nonzero(self.anchored))
        stale = int(np.count_nonzero(self.anchored & ~recent))
        if loose > max(self.slack * held.shape[0], self.floor) or stale > self.slack * anchored:
            self.anchored = recent
            self.version += 1
            return True
        return False

    def raised_diagonal(self, diagonal: np.ndarray) -> np.ndarray:
        """The matrix diagonal (F,) with the anchored rows raised by `ANCHOR` of themselves."""
        return np.where(self.anchored, (1.0 + ANCHOR) * diagonal, diagonal)
