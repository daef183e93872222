"""Which springs fail: the per-substep stretch test over the tearable springs.

A spring is tested when either end may tear (its threshold is the lower of its ends', its
averaging window the longer, see `TearSettings`). The test is one compiled pass over the
tested springs, with a ring buffer of the last substeps' stretch ratios (current / rest length)
when a window averages over several substeps, so one-substep spikes do not tear. Failures are
not applied here: they collect in `SpringState.pending` (the largest stretch seen) until the
tearer's update budget allows a topology update. Everything is rebuilt per model (each tear
gives a new one), and springs inherit the thresholds and stretch history of the spring they
descend from.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from meshdeform.arrays import argsort_int
from meshdeform.model import SpringModel
from meshdeform.solvers.jit import JIT
from meshdeform.tearing.settings import TearSettings
from meshdeform.topology import SpringKind


@nb.njit(**JIT)
def _over_threshold(x, a, b, inv_rest, thr, window, ring, step, out_index, out_ratio):  # pragma: no cover
    """Stretch of each tested spring (averaged over its window with the ring buffer, whose rows
    are substeps); writes the springs above their threshold to out_*, returns how many."""
    rows = ring.shape[0]
    slot = step % rows
    count = 0
    for i in range(a.shape[0]):
        ia = a[i]
        ib = b[i]
        dx = x[ib, 0] - x[ia, 0]
        dy = x[ib, 1] - x[ia, 1]
        dz = x[ib, 2] - x[ia, 2]
        r = np.sqrt(dx * dx + dy * dy + dz * dz) * inv_rest[i]
        w = window[i]
        if rows > 1:
            ring[slot, i] = r
            if w > 1:
                total = 0.0
                for j in range(w):
                    total += ring[(step - j) % rows, i]
                r = total / w
        if r > thr[i]:
            out_index[count] = i
            out_ratio[count] = r
            count += 1
    return count


@dataclass
class SpringState:
    """Per-model data of the tested springs (rebuilt on every topology change).

    index: tested springs (into the model's springs); a, b, inv_rest, thr, window: theirs;
    ring: (rows, tested) stretch of the last substeps; stuck: failed springs no end of which
    can split (not tested again until the topology changes); pending: largest stretch of
    springs that failed since the last update (0: none); all_thr, all_window: (S,) of every
    spring (inf: not tested); any_pending: whether any failed since the last update;
    any_overdue: whether one of those is overdue (`record_failures`); by_vertex: the tested
    structural springs by vertex, built on first use (`tested_structural`).
    """

    index: np.ndarray
    a: np.ndarray
    b: np.ndarray
    inv_rest: np.ndarray
    thr: np.ndarray
    window: np.ndarray
    ring: np.ndarray
    stuck: np.ndarray
    pending: np.ndarray
    all_thr: np.ndarray
    all_window: np.ndarray
    any_pending: bool = False
    any_overdue: bool = False
    by_vertex: tuple[np.ndarray, np.ndarray] | None = None


def spring_state(
    model: SpringModel, settings: TearSettings | None, parent: np.ndarray | None, old: SpringState | None
) -> SpringState:
    """The tested springs of `model`; with `old` and `parent` ((S,) new spring -> old spring),
    thresholds, windows and stretch history come from the springs they descend from."""
    s = settings
    springs = np.asarray(model.springs, dtype=np.int64)
    if s is None or springs.shape[0] == 0:
        e = np.zeros(0, dtype=np.int64)
        f = np.zeros(0)
        return SpringState(e, e, e, f, f, e, np.ones((1, 0)), np.zeros(0, bool), f, f, e)
    if old is not None and parent is not None and old.all_thr.shape[0]:
        # a spring descends from one spring between the originals of its ends: same values
        all_thr = old.all_thr[parent]
        all_window = old.all_window[parent]
    else:
        kinds = np.asarray(model.kinds, dtype=np.int64)
        a, b = springs[:, 0], springs[:, 1]
        all_thr = np.minimum(s.thresholds[kinds, a], s.thresholds[kinds, b])
        all_window = np.maximum(s.window[a], s.window[b]).astype(np.int64)
    index = np.flatnonzero(np.isfinite(all_thr))
    rows = int(s.window.max()) if s.window.size else 1
    ring = np.ones((rows, index.shape[0]))
    if old is not None and parent is not None and rows > 1 and old.ring.shape[0] == rows and old.index.size:
        # springs inherit the stretch history of the spring they descend from
        slot = np.full(int(max(old.index.max(), parent.max(initial=0))) + 1, -1, dtype=np.int64)
        slot[old.index] = np.arange(old.index.shape[0])
        src = slot[parent[index]]
        known = src >= 0
        ring[:, known] = old.ring[:, src[known]]
    tested = springs[index]
    rest = np.asarray(model.rest_lengths, dtype=np.float64)[index]
    return SpringState(
        index=index,
        a=np.ascontiguousarray(tested[:, 0]),
        b=np.ascontiguousarray(tested[:, 1]),
        inv_rest=np.ascontiguousarray(1.0 / np.maximum(rest, 1e-300)),
        thr=np.ascontiguousarray(all_thr[index]),
        window=np.ascontiguousarray(all_window[index]),
        ring=ring,
        stuck=np.zeros(index.shape[0], dtype=bool),
        pending=np.zeros(index.shape[0]),
        all_thr=all_thr,
        all_window=all_window,
    )


#: a failed spring waiting for the update budget is overdue once it has stretched this many times
#: as far past its rest length as its threshold allows (2: at 1.04 for a threshold of 1.02, 1.6
#: for 1.3): the tearer then updates at once (`Tearer.after_substep`). A cloth shredding faster
#: than the budget let its springs stretch on while they waited, and a small piece cut loose with
#: a spring at 2.35x (a threshold of 1.02) flew apart under implicit (docs/performance.md, "A
#: sheet shredded into single quads")
OVERDUE_FACTOR = 2.0


def record_failures(sp: SpringState, positions: np.ndarray, step: int) -> None:
    """Test every tested spring at positions (W, 3) on substep `step` (the ring buffer's row);
    failing springs not stuck raise their `pending` stretch, and mark the state overdue where one
    is `OVERDUE_FACTOR` times as far past 1 as its threshold."""
    out_index = np.empty(sp.index.shape[0], dtype=np.int64)
    out_ratio = np.empty(sp.index.shape[0])
    count = _over_threshold(positions, sp.a, sp.b, sp.inv_rest, sp.thr, sp.window, sp.ring, step, out_index, out_ratio)
    if count:
        idx = out_index[:count]
        fresh = ~sp.stuck[idx]
        if fresh.any():
            idx = idx[fresh]
            ratio = out_ratio[:count][fresh]
            sp.pending[idx] = np.maximum(sp.pending[idx], ratio)
            sp.any_pending = True
            sp.any_overdue = sp.any_overdue or bool(np.any(ratio - 1.0 > OVERDUE_FACTOR * (sp.thr[idx] - 1.0)))


def tested_structural(sp: SpringState, model: SpringModel) -> tuple[np.ndarray, np.ndarray]:
    """Tested structural springs by vertex: (indptr (W+1,), tested-spring slots); cached in `sp`."""
    if sp.by_vertex is None:
        n = model.vertex_count
        slots = np.flatnonzero(np.asarray(model.kinds)[sp.index] == SpringKind.STRUCTURAL)
        ends = np.concatenate([sp.a[slots], sp.b[slots]])
        order = argsort_int(ends)
        indptr = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(np.bincount(ends, minlength=n), out=indptr[1:])
        sp.by_vertex = (indptr, np.concatenate([slots, slots])[order])
    return sp.by_vertex
