"""The implicit solver's contact anchors: which held rows its matrix ties down, and how rarely it
refactorises for them (`meshdeform/solvers/implicit/anchors.py`; the physics they fix is tested in
tests/test_contact_solvers.py, the stiff sheet folded over a bar)."""

from __future__ import annotations

import numpy as np

from meshdeform.solvers.implicit.anchors import ANCHOR, ANCHOR_WINDOW, LARGE_ROWS, ContactAnchors


def test_a_lasting_contact_is_anchored_once_and_released_after_the_window() -> None:
    """200 rows held for 100 steps: one renewal (a refactorisation), not one a step; after the
    contact ends the rows stay anchored for the window, then the set is renewed to none."""
    anchors = ContactAnchors(1000)
    held = np.arange(100, 300)
    renewals = [anchors.update(held) for _ in range(100)]
    assert renewals[0] and sum(renewals) == 1
    assert np.array_equal(np.flatnonzero(anchors.anchored), held)
    none = held[:0]
    released = [anchors.update(none) for _ in range(2 * ANCHOR_WINDOW)]
    assert not any(released[: ANCHOR_WINDOW - 1])  # still anchored within the window
    assert sum(released) == 1 and not anchors.anchored.any()


def test_a_spreading_contact_renews_the_set_only_when_a_quarter_is_loose() -> None:
    """A contact growing by 5 rows a step from 100 to 600 rows: far fewer renewals than steps, and
    never more than a quarter of the held rows (or a few) left unanchored after a step."""
    anchors = ContactAnchors(1000)
    steps = 100
    renewals = 0
    for step in range(steps):
        held = np.arange(100 + 5 * step)
        renewals += anchors.update(held)
        loose = np.count_nonzero(~anchors.anchored[held])
        assert loose <= max(0.25 * held.shape[0], 32)
    assert 1 < renewals < steps // 5


def test_a_contact_of_a_few_rows_is_not_anchored() -> None:
    """Up to `ANCHOR_FLOOR` held rows never refactorise the matrix, however long they are held."""
    anchors = ContactAnchors(1000)
    assert not any(anchors.update(np.arange(20)) for _ in range(50))
    assert not anchors.anchored.any()


def test_the_raised_diagonal_touches_the_anchored_rows_only() -> None:
    anchors = ContactAnchors(50)
    assert anchors.update(np.arange(40))
    diagonal = np.linspace(1.0, 2.0, 50)
    raised = anchors.raised_diagonal(diagonal)
    assert np.array_equal(raised[:40], diagonal[:40] * (1.0 + ANCHOR))
    assert np.array_equal(raised[40:], diagonal[40:])


def test_a_large_cloth_keeps_its_anchors_longer() -> None:
    """From `LARGE_ROWS` rows (a factorisation costs several steps) the window and the slack are
    doubled: the same spreading contact renews the set less often than on a small cloth."""
    def renewals(rows: int) -> int:
        anchors = ContactAnchors(rows)
        return sum(anchors.update(np.arange(100 + 20 * step)) for step in range(100))

    assert renewals(LARGE_ROWS) < renewals(LARGE_ROWS - 1)


def test_a_closed_surface_anchors_its_few_contacts() -> None:
    """On a closed surface (a solid) the floor is a small share of its rows: the 4 held rows of an
    8-vertex box landing renew the set at once, where a sheet's 4 of 8 would not."""
    solid, sheet = ContactAnchors(8, solid=True), ContactAnchors(8)
    held = np.arange(4)
    assert solid.update(held) and np.array_equal(np.flatnonzero(solid.anchored), held)
    assert not sheet.update(held) and not sheet.anchored.any()
