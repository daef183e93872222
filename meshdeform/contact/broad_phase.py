"""Broad phase: which axis-aligned boxes overlap, through a hashed uniform grid (Numba).

Elements (triangles, edges) are entered into every grid cell their box touches; a query box
visits the cells it touches and reports each element whose box overlaps it exactly once: in
the cell holding the lower corner of the two boxes' overlap (Teschner et al. 2003, "Optimized
spatial hashing"). The grid is a counting sort of (cell hash, element) entries, filled in
element order, so every query reports its elements in one fixed order and the pairs come out
the same whatever the thread count or the run: contact stays byte-for-byte reproducible.

Boxes are (M, 3) lower and upper corners in metres; `cell` is the grid spacing in metres,
chosen by `cell_size` from the element and the query boxes so that a typical box of either
touches at most two cells per axis.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from meshdeform.solvers.jit import JIT

_P1, _P2, _P3 = 73856093, 19349663, 83492791  # Teschner et al.'s hash primes
#: a grid is dense (no hashing) where the cells of its elements' range are at most this many per
#: entry: a crumpled or draped cloth (compact), not a sheet spread over a large volume
DENSE_FACTOR = 4.0
#: the most grid cells a box may touch on average, element and query boxes together, before the
#: cell grows (`bounded_inv_cell`): a typical box touches at most 8, so the cell never grows in a
#: sound scene, but one vertex thrown kilometres away inside a diverging substep no longer makes
#: a grid of billions of entries (24 GB once) before the frame's divergence guard can stop the run
CELLS_PER_BOX = 64
#: the cells the boxes may touch in any case (about 32 MB of grid entries)
MIN_CELL_BUDGET = 1 << 20
#: a box touching more cells than this, and than the boxes of the other kind there are, is long: an
#: element kept out of the cells (every query reads its box), a query that reads every element's
#: box (`query_box`); as many as `LONG_MOST` of each are (more, and the cell grows instead:
#: `bounded_inv_cell`): one box thrown 1e14 m no longer makes the cell 1e12 m and the search all pairs
LONG_CELLS = 64
#: the most long boxes of either kind a grid sets apart (each costs a pass over the other kind's boxes)
LONG_MOST = 256
#: the largest cell index (per axis) a coordinate maps to: beyond it cells are clamped, so a
#: coordinate of 1e300 m gives an index in range rather than an undefined integer conversion
_MAX_INDEX = float(1 << 60)


def cell_size(lo: np.ndarray, hi: np.ndarray) -> float:
    """Grid spacing (m) for element boxes (M, 3): the 90th percentile of their largest side, so
    nearly every element spans at most two cells per axis while a few long ones span more."""
    if lo.shape[0] == 0:
        return 1.0
    extent = _largest_sides(lo, hi)
    size = _percentile_90(extent)
    return size if size > 1e-9 else max(float(extent.max()), 1e-6)


@nb.njit(**JIT)
def _largest_sides(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Each box's largest side (M,), m, of boxes lo, hi (M, 3), in one pass without temporaries
    (the same values as NumPy's maximum over the sides)."""
    extent = np.empty(lo.shape[0])
    for e in range(lo.shape[0]):
        extent[e] = max(max(hi[e, 0] - lo[e, 0], hi[e, 1] - lo[e, 1]), hi[e, 2] - lo[e, 2])
    return extent


def _percentile_90(values: np.ndarray) -> float:
    """`np.percentile(values, 90)` (its linear method, the same bits) by one partial sort: the
    general function's overhead was a tenth of a contact substep's broad phase."""
    position = 0.9 * (values.shape[0] - 1)
    below = int(np.floor(position))
    above = min(below + 1, values.shape[0] - 1)
    ordered = np.partition(values, [below, above])
    low, high = float(ordered[below]), float(ordered[above])
    fraction = position - below
    span = high - low
    return low + span * fraction if fraction < 0.5 else high - span * (1.0 - fraction)


@nb.njit(**JIT)
def cell_index(coordinate: float, inv_cell: float) -> int:
    """The grid cell index along one axis of `coordinate` (m) at 1 / cell `inv_cell` (1/m):
    clamped to +-2^60 (monotonic in any finite coordinate, however far), and 0 for a coordinate
    that is not finite (a diverged vertex: its element is entered in one cell, its pairs are left
    to the divergence guard)."""
    if not np.isfinite(coordinate):
        return 0
    scaled = coordinate * inv_cell  # +-inf past the float range: clamped below
    return int(np.floor(min(max(scaled, -_MAX_INDEX), _MAX_INDEX)))


@nb.njit(**JIT)
def _touched_cells(lo: np.ndarray, hi: np.ndarray, inv_cell: float) -> float:
    """How many grid cells the boxes lo, hi (M, 3) touch together at 1 / cell `inv_cell` (a float:
    the count of a far-flung box overflows an integer)."""
    total = 0.0
    for count in _cell_counts(lo, hi, inv_cell):  # summed in order
        total += count
    return total


@nb.njit(**JIT)
def _cell_counts(lo: np.ndarray, hi: np.ndarray, inv_cell: float) -> np.ndarray:
    """How many grid cells each box of lo, hi (M, 3) touches at 1 / cell `inv_cell` (M,) (floats,
    as `_touched_cells`)."""
    counts = np.empty(lo.shape[0])
    for e in range(lo.shape[0]):
        count = 1.0
        for k in range(3):
            count *= float(max(cell_index(hi[e, k], inv_cell) - cell_index(lo[e, k], inv_cell), 0) + 1)
        counts[e] = count
    return counts


@nb.njit(**JIT)
def _most_cells(lo: np.ndarray, hi: np.ndarray, inv_cell: float) -> float:
    """An upper bound on the grid cells the boxes lo, hi (M, 3) touch together at 1 / cell
    `inv_cell` (1/m): their count times the cells of a box as long as the longest along each axis
    (inf where a box is not finite). One pass without a floor: a third of `_touched_cells`."""
    longest = np.zeros(3)
    for e in range(lo.shape[0]):
        for k in range(3):
            longest[k] = max(longest[k], hi[e, k] - lo[e, k])  # NaN: max keeps longest, isfinite below
    cells = 1.0
    for k in range(3):
        cells *= longest[k] * inv_cell + 2.0
    finite = True
    for e in range(lo.shape[0]):
        for k in range(3):
            finite &= np.isfinite(lo[e, k]) & np.isfinite(hi[e, k])
    return lo.shape[0] * cells if finite else np.inf


def cell_budget(boxes: int) -> float:
    """The grid cells `boxes` boxes may touch together (`CELLS_PER_BOX` each, at least `MIN_CELL_BUDGET`)."""
    return max(float(CELLS_PER_BOX * boxes), float(MIN_CELL_BUDGET))


def bounded_inv_cell(
    qlo: np.ndarray, qhi: np.ndarray, elo: np.ndarray, ehi: np.ndarray, inv_cell: float
) -> float:
    """`inv_cell` (1/m), or a coarser one where at it the element and query boxes would touch
    more than `CELLS_PER_BOX` cells a box (at least `MIN_CELL_BUDGET`): a grid's memory and a
    query's cell visits stay bounded whatever the positions. The same pairs at any cell."""
    sets = ((elo, ehi),) if qlo is elo else ((elo, ehi), (qlo, qhi))  # a self-search's boxes once
    budget = cell_budget(sum(lo.shape[0] for lo, _ in sets))
    if sum(_most_cells(lo, hi, inv_cell) for lo, hi in sets) <= budget:
        return inv_cell  # a sound scene: no box near that long
    touched = sum(_touched_cells(lo, hi, inv_cell) for lo, hi in sets)
    while touched > budget:  # each box's count falls to 8 or fewer as the cell outgrows it
        inv_cell /= max(2.0, (touched / budget) ** (1.0 / 3.0))
        touched = sum(_touched_cells(lo, hi, inv_cell) for lo, hi in sets)
    return inv_cell


@nb.njit(**JIT)
def _hash(ix: int, iy: int, iz: int, mask: int) -> int:
    return ((ix * _P1) ^ (iy * _P2) ^ (iz * _P3)) & mask


@nb.njit(**JIT)
def build_grid(
    lo: np.ndarray,
    hi: np.ndarray,
    members: np.ndarray,
    long: np.ndarray,
    long_query: float,
    inv_cell: float,
    dense_factor: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The grid of the element boxes lo, hi (M, 3) of `members` (K,) int64, ascending (all M, or
    `near_elements`' few): dense (one bucket per cell of the members' bounding range) where that
    range has at most `dense_factor` cells per entry, else hashed. The `long` elements (L,) int64,
    ascending, are kept out of the cells and follow the entries (every query reads their boxes),
    and a query box touching more than `long_query` cells reads every element's box instead of
    its cells (`query_box`).

    Returns bucket_start (H + 1,) int64; per entry, sorted by bucket and within a bucket by
    element, the element (E + L,) int64 (the long elements after the E entries) and, hashed, its
    cell (E, 3) int64 ((0, 3) when dense); and `box` (7,) int64: the dense range, its first cell
    and its size in cells per axis (sizes 0: hashed, H a power of two), then `long_query`. Either
    way a bucket's entries of one cell come in element order, so a query reports the same pairs
    in the same order from both.
    """
    m = members.shape[0]
    cells = np.empty((m, 6), dtype=np.int64)  # row j: member j's first and last cell per axis
    total = 0
    low = np.full(3, np.iinfo(np.int64).max, dtype=np.int64)
    high = np.full(3, np.iinfo(np.int64).min, dtype=np.int64)
    for j in range(m):
        e = members[j]
        for k in range(3):
            cells[j, k] = cell_index(lo[e, k], inv_cell)
            cells[j, 3 + k] = max(cell_index(hi[e, k], inv_cell), cells[j, k])  # (not finite: one cell)
            low[k] = min(low[k], cells[j, k])
            high[k] = max(high[k], cells[j, 3 + k])
        total += (cells[j, 3] - cells[j, 0] + 1) * (cells[j, 4] - cells[j, 1] + 1) * (cells[j, 5] - cells[j, 2] + 1)
    box = np.zeros(7, dtype=np.int64)
    if m:
        span = float(high[0] - low[0] + 1) * float(high[1] - low[1] + 1) * float(high[2] - low[2] + 1)
        if span <= dense_factor * total:
            for k in range(3):
                box[k] = low[k]
                box[3 + k] = high[k] - low[k] + 1
    box[6] = int(min(long_query, 2.0**62))
    dense = box[3] > 0
    if dense:
        size = box[3] * box[4] * box[5]
        mask = 0
    else:
        size = 1
        while size < 2 * total:
            size *= 2
        mask = size - 1
    start = np.zeros(size + 1, dtype=np.int64)
    for j in range(m):
        for ix in range(cells[j, 0], cells[j, 3] + 1):
            for iy in range(cells[j, 1], cells[j, 4] + 1):
                for iz in range(cells[j, 2], cells[j, 5] + 1):
                    start[_bucket(ix, iy, iz, box, mask) + 1] += 1
    for h in range(size):
        start[h + 1] += start[h]
    fill = start[:-1].copy()
    element = np.empty(total + long.shape[0], dtype=np.int64)
    for j in range(long.shape[0]):  # a loop: a slice assignment's shape check compiles 2 s of string formatting
        element[total + j] = long[j]
    cell = np.empty((0 if dense else total, 3), dtype=np.int64)
    for j in range(m):
        for ix in range(cells[j, 0], cells[j, 3] + 1):
            for iy in range(cells[j, 1], cells[j, 4] + 1):
                for iz in range(cells[j, 2], cells[j, 5] + 1):
                    h = _bucket(ix, iy, iz, box, mask)
                    slot = fill[h]
                    fill[h] += 1
                    element[slot] = members[j]
                    if not dense:
                        cell[slot, 0] = ix
                        cell[slot, 1] = iy
                        cell[slot, 2] = iz
    return start, element, cell, box


@nb.njit(**JIT)
def _bucket(ix: int, iy: int, iz: int, box: np.ndarray, mask: int) -> int:
    """The bucket of cell (ix, iy, iz): its place in the dense range `box`, else its hash."""
    if box[3] > 0:
        return ((ix - box[0]) * box[4] + (iy - box[1])) * box[5] + (iz - box[2])
    return _hash(ix, iy, iz, mask)


@nb.njit(**JIT)
def dense_cell(h: int, box: np.ndarray) -> tuple[int, int, int]:
    """The cell (ix, iy, iz) of bucket h of a dense grid whose range is `box` (`_bucket`'s inverse)."""
    return h // (box[5] * box[4]) + box[0], (h // box[5]) % box[4] + box[1], h % box[5] + box[2]


@nb.njit(**JIT)
def query_box(
    qlo: np.ndarray,
    qhi: np.ndarray,
    q: int,
    elo: np.ndarray,
    ehi: np.ndarray,
    inv_cell: float,
    start: np.ndarray,
    element: np.ndarray,
    cell: np.ndarray,
    box: np.ndarray,
    above: int,
    found: np.ndarray,
) -> int:
    """The elements whose boxes overlap query box q of qlo, qhi (Q, 3), each once, in the grid's
    fixed order, written to found (S,) int64; only elements > `above` (-1: all). The grid is
    `build_grid`'s (start, element, cell, box). Returns their count, which may exceed S: then
    found holds the first S and the caller asks again with room. A query box touching more than
    box[6] cells reads every element's box instead (in element order), and the long elements
    after the entries are read by every other query (after its cells)."""
    dense = box[3] > 0
    mask = 0 if dense else start.shape[0] - 2
    capacity = found.shape[0]
    count = 0
    x0 = cell_index(qlo[q, 0], inv_cell)
    y0 = cell_index(qlo[q, 1], inv_cell)
    z0 = cell_index(qlo[q, 2], inv_cell)
    x1 = cell_index(qhi[q, 0], inv_cell)
    y1 = cell_index(qhi[q, 1], inv_cell)
    z1 = cell_index(qhi[q, 2], inv_cell)
    if float(x1 - x0 + 1) * float(y1 - y0 + 1) * float(z1 - z0 + 1) > float(box[6]):  # a long query
        for e in range(above + 1, elo.shape[0]):
            if _overlap(qlo, qhi, q, elo, ehi, e):
                if count < capacity:
                    found[count] = e
                count += 1
        return count
    # a dense grid has no entries outside its range: visit only the cells inside it
    ax0, ay0, az0 = (max(x0, box[0]), max(y0, box[1]), max(z0, box[2])) if dense else (x0, y0, z0)
    ax1 = min(x1, box[0] + box[3] - 1) if dense else x1
    ay1 = min(y1, box[1] + box[4] - 1) if dense else y1
    az1 = min(z1, box[2] + box[5] - 1) if dense else z1
    for ix in range(ax0, ax1 + 1):
        for iy in range(ay0, ay1 + 1):
            for iz in range(az0, az1 + 1):
                h = _bucket(ix, iy, iz, box, mask)
                for slot in range(start[h], start[h + 1]):
                    if not dense and (cell[slot, 0] != ix or cell[slot, 1] != iy or cell[slot, 2] != iz):
                        continue
                    e = element[slot]
                    if e <= above:
                        continue
                    if not _overlap(qlo, qhi, q, elo, ehi, e):
                        continue
                    # report once: in the cell of the overlap's lower corner (clamped to the query's cells)
                    cx = min(max(cell_index(max(qlo[q, 0], elo[e, 0]), inv_cell), x0), x1)
                    cy = min(max(cell_index(max(qlo[q, 1], elo[e, 1]), inv_cell), y0), y1)
                    cz = min(max(cell_index(max(qlo[q, 2], elo[e, 2]), inv_cell), z0), z1)
                    if cx != ix or cy != iy or cz != iz:
                        continue
                    if count < capacity:
                        found[count] = e
                    count += 1
    for slot in range(start[-1], element.shape[0]):  # the long elements: in no cell
        e = element[slot]
        if e > above and _overlap(qlo, qhi, q, elo, ehi, e):
            if count < capacity:
                found[count] = e
            count += 1
    return count


@nb.njit(**JIT)
def _overlap(qlo: np.ndarray, qhi: np.ndarray, q: int, elo: np.ndarray, ehi: np.ndarray, e: int) -> bool:
    """Whether query box q of qlo, qhi and element box e of elo, ehi overlap (touching counts)."""
    return not (
        elo[e, 0] > qhi[q, 0] or ehi[e, 0] < qlo[q, 0]
        or elo[e, 1] > qhi[q, 1] or ehi[e, 1] < qlo[q, 1]
        or elo[e, 2] > qhi[q, 2] or ehi[e, 2] < qlo[q, 2]
    )  # fmt: skip


@nb.njit(**JIT)
def query_grown(
    qlo: np.ndarray,
    qhi: np.ndarray,
    q: int,
    elo: np.ndarray,
    ehi: np.ndarray,
    inv_cell: float,
    start: np.ndarray,
    element: np.ndarray,
    cell: np.ndarray,
    box: np.ndarray,
    above: int,
    found: np.ndarray,
) -> tuple[int, np.ndarray]:
    """`query_box`, asked again with a buffer twice the count where `found` was too short:
    the count and the buffer holding all of them (found or its replacement)."""
    n = query_box(qlo, qhi, q, elo, ehi, inv_cell, start, element, cell, box, above, found)
    if n > found.shape[0]:
        found = np.empty(2 * n, dtype=np.int64)
        n = query_box(qlo, qhi, q, elo, ehi, inv_cell, start, element, cell, box, above, found)
    return n, found


@nb.njit(**JIT)
def _overlapping(
    qlo: np.ndarray,
    qhi: np.ndarray,
    elo: np.ndarray,
    ehi: np.ndarray,
    inv_cell: float,
    start: np.ndarray,
    element: np.ndarray,
    cell: np.ndarray,
    box: np.ndarray,
    upper_only: bool,
    capacity: int,
) -> np.ndarray:
    """Every (query, element) overlap, (P, 2) int64, by query, then in the grid's order."""
    out = np.empty((max(capacity, 16), 2), dtype=np.int64)
    found = np.empty(64, dtype=np.int64)
    count = 0
    for q in range(qlo.shape[0]):
        above = q if upper_only else -1
        n, found = query_grown(qlo, qhi, q, elo, ehi, inv_cell, start, element, cell, box, above, found)
        if count + n > out.shape[0]:
            grown = np.empty((2 * (count + n), 2), dtype=np.int64)
            for k in range(count):  # not a slice assignment: its shape check compiles a message
                grown[k, 0] = out[k, 0]
                grown[k, 1] = out[k, 1]
            out = grown
        for j in range(n):
            out[count, 0] = q
            out[count, 1] = found[j]
            count += 1
    return out[:count]


#: cells per axis of the coarse grid `near_elements` marks the queries' boxes in
NEAR_CELLS = 16


@nb.njit(**JIT)
def _coarse(coordinate: float, low: float, scale: float, cells: int) -> int:
    """The coarse cell (0 .. cells - 1) of a finite `coordinate` (m) in a grid from `low` (m) at
    `scale` cells a metre, clamped (before the conversion: a far coordinate stays in range)."""
    return int(min(max((coordinate - low) * scale, 0.0), cells - 1.0))


@nb.njit(**JIT)
def _any_marked(
    marked: np.ndarray, lo: np.ndarray, hi: np.ndarray, e: int, low: np.ndarray, scale: np.ndarray, cells: int
) -> bool:
    """Whether box e of lo, hi (M, 3) touches a cell flagged in `marked` (cells, cells, cells) of
    the coarse grid from `low` (3,) m at `scale` (3,) cells a metre (`_coarse`)."""
    x0, x1 = _coarse(lo[e, 0], low[0], scale[0], cells), _coarse(hi[e, 0], low[0], scale[0], cells)
    y0, y1 = _coarse(lo[e, 1], low[1], scale[1], cells), _coarse(hi[e, 1], low[1], scale[1], cells)
    z0, z1 = _coarse(lo[e, 2], low[2], scale[2], cells), _coarse(hi[e, 2], low[2], scale[2], cells)
    for ix in range(x0, x1 + 1):
        for iy in range(y0, y1 + 1):
            for iz in range(z0, z1 + 1):
                if marked[ix, iy, iz]:
                    return True
    return False


@nb.njit(**JIT)
def near_elements(
    qlo: np.ndarray, qhi: np.ndarray, queries: np.ndarray, elo: np.ndarray, ehi: np.ndarray
) -> np.ndarray:
    """The elements (K,) int64, ascending, whose boxes elo, ehi (M, 3) touch a cell that a box
    of `queries` (Q,) int64 of qlo, qhi touches, in a coarse grid of `NEAR_CELLS` cells per axis
    over the queries' bounds: every element whose box overlaps one of theirs, and some near them.
    A search of a few stale vertices' pairs builds its grid of these rather than of every element
    (a grid costs about 50 ns an element, this pass a few). A query box that is not finite makes
    every element near; an element box that is not finite is near."""
    m = elo.shape[0]
    if queries.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    low = np.full(3, np.inf)
    high = np.full(3, -np.inf)
    for q in queries:
        for k in range(3):
            if not (np.isfinite(qlo[q, k]) and np.isfinite(qhi[q, k])):
                return np.arange(m, dtype=np.int64)
            low[k] = min(low[k], qlo[q, k])
            high[k] = max(high[k], qhi[q, k])
    r = NEAR_CELLS
    scale = np.zeros(3)
    for k in range(3):
        scale[k] = r / (high[k] - low[k]) if high[k] > low[k] else 0.0
    marked = np.zeros((r, r, r), dtype=np.bool_)
    first = np.empty(3, dtype=np.int64)
    last = np.empty(3, dtype=np.int64)
    for q in queries:
        for k in range(3):
            first[k] = _coarse(qlo[q, k], low[k], scale[k], r)
            last[k] = _coarse(qhi[q, k], low[k], scale[k], r)
        marked[first[0] : last[0] + 1, first[1] : last[1] + 1, first[2] : last[2] + 1] = True
    out = np.empty(m, dtype=np.int64)
    count = 0
    for e in range(m):
        finite_box = True
        outside = False
        for k in range(3):
            if not (np.isfinite(elo[e, k]) and np.isfinite(ehi[e, k])):
                finite_box = False
            elif elo[e, k] > high[k] or ehi[e, k] < low[k]:
                outside = True
        if finite_box and outside:
            continue
        if finite_box and not _any_marked(marked, elo, ehi, e, low, scale, r):
            continue  # (not finite: left to the grid, `cell_index`, and the divergence guard)
        out[count] = e
        count += 1
    return out[:count]


def grid_for(
    qlo: np.ndarray,
    qhi: np.ndarray,
    elo: np.ndarray,
    ehi: np.ndarray,
    dense_factor: float = DENSE_FACTOR,
    inv_cell: float | None = None,
    near: np.ndarray | None = None,
) -> tuple[float, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The grid of element boxes elo, ehi (M, 3) for queries qlo, qhi (Q, 3): 1 / cell (1/m) and
    `build_grid`'s bucket starts, elements, cells and dense range. The cell suits the larger
    boxes of the two, unless `inv_cell` is given (any cell finds the same pairs; sizing it reads
    every box, a tenth of a search that asks the grid for a few elements only). `near` (Q',)
    int64: only these queries will ask, and the grid holds only the elements near them
    (`near_elements`): the same pairs for them, at the cost of the elements they may meet."""
    if near is None:
        members = np.arange(elo.shape[0], dtype=np.int64)
        asked, held = (qlo, qhi), (elo, ehi)
    else:
        members = near_elements(qlo, qhi, near, elo, ehi)
        asked, held = (qlo[near], qhi[near]), (elo[members], ehi[members])
    self_search = asked[0] is held[0] and asked[1] is held[1]
    queries = asked[0].shape[0]
    if inv_cell is None:
        size = cell_size(*held)
        inv_cell = 1.0 / (size if self_search else max(size, cell_size(*asked)))
    # long boxes set apart (`LONG_CELLS`): an element past as many cells as there are queries, a query
    # past as many as there are elements; each kind's count checked first on its longest box
    element_cells = _most_cells(*held, inv_cell)  # upper bounds on the cells the boxes touch together
    query_cells = element_cells if self_search else _most_cells(*asked, inv_cell)
    long_element = max(float(LONG_CELLS), float(queries))
    long_query = max(float(LONG_CELLS), float(members.shape[0]))
    long = members[:0]
    sound = element_cells + (0.0 if self_search else query_cells) <= cell_budget(
        members.shape[0] + (0 if self_search else queries)
    )
    if element_cells > long_element * members.shape[0]:
        apart = _cell_counts(*held, inv_cell) > long_element
        if 0 < np.count_nonzero(apart) <= LONG_MOST:
            members, long = members[~apart], members[apart]
            held = (held[0][~apart], held[1][~apart])
            sound = False  # counted afresh without them
    if query_cells > long_query * queries:
        apart = _cell_counts(*asked, inv_cell) > long_query
        if np.count_nonzero(apart) <= LONG_MOST:
            asked = (asked[0][~apart], asked[1][~apart])
            sound = False
        else:
            long_query = np.inf  # too many to read every element each: the cell grows (`bounded_inv_cell`)
    if not sound:
        inv_cell = bounded_inv_cell(*asked, *held, inv_cell)
    return (inv_cell, *build_grid(elo, ehi, members, long, long_query, inv_cell, dense_factor))


def scan_grid(members: np.ndarray) -> tuple[float, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A `grid_for` grid of one dense cell holding the elements `members` (K,) int64, ascending, in
    order (1 / cell 0: every box falls in cell (0, 0, 0)), so a query reads each one's box: cheaper
    than building a grid where only a few queries ask it (`SCAN_QUERIES`). The same pairs as any
    grid among the members, each query's in element order."""
    return (
        0.0, np.array([0, members.shape[0]], dtype=np.int64), members, np.zeros((0, 3), dtype=np.int64),
        np.array([0, 0, 0, 1, 1, 1, 1], dtype=np.int64),
    )


#: queries below which a search reads every element's box (`scan_grid`) rather than building a grid:
#: a grid costs about 50 ns an element to build, a box read 1-2 ns
SCAN_QUERIES = 24


def overlapping_pairs(
    qlo: np.ndarray,
    qhi: np.ndarray,
    elo: np.ndarray,
    ehi: np.ndarray,
    *,
    upper_only: bool = False,
    dense_factor: float = DENSE_FACTOR,
) -> np.ndarray:
    """(P, 2) int64 (query, element) pairs whose boxes overlap, by query, then in the
    grid's fixed order; `upper_only` keeps element > query (a set against itself, each pair once).

    qlo, qhi (Q, 3) / elo, ehi (M, 3): box corners, metres. dense_factor: as `grid_for` (0:
    always hashed).
    """
    qlo = np.ascontiguousarray(qlo, dtype=np.float64)
    qhi = np.ascontiguousarray(qhi, dtype=np.float64)
    elo = np.ascontiguousarray(elo, dtype=np.float64)
    ehi = np.ascontiguousarray(ehi, dtype=np.float64)
    if qlo.shape[0] == 0 or elo.shape[0] == 0:
        return np.zeros((0, 2), dtype=np.int64)
    inv_cell, start, element, cell, box = grid_for(qlo, qhi, elo, ehi, dense_factor)
    return _overlapping(qlo, qhi, elo, ehi, inv_cell, start, element, cell, box, upper_only, 16 * qlo.shape[0])


@nb.njit(**JIT)
def swept_boxes(
    x0: np.ndarray, x1: np.ndarray, elements: np.ndarray, pad: float
) -> tuple[np.ndarray, np.ndarray]:
    """Boxes (M, 3) around elements (M, k) of vertex indices over both position sets x0, x1
    (V, 3), grown by pad (m) on every side: what an element sweeps moving linearly from x0 to x1."""
    m, k = elements.shape
    lo = np.empty((m, 3))
    hi = np.empty((m, 3))
    for e in range(m):
        for axis in range(3):
            low = np.inf
            high = -np.inf
            for j in range(k):
                v = elements[e, j]
                low = min(low, min(x0[v, axis], x1[v, axis]))
                high = max(high, max(x0[v, axis], x1[v, axis]))
            lo[e, axis] = low - pad
            hi[e, axis] = high + pad
    return lo, hi


@nb.njit(**JIT)
def strays(
    x: np.ndarray, base: np.ndarray, motion: np.ndarray, steps: np.ndarray, slack: float, out: np.ndarray
) -> np.ndarray:
    """The mean departure (3,) of the rows of x (V, 3) from their carried-on points
    base + steps * motion (base, motion (V, 3), steps (V,)); out (V,) bool is set where a row's
    departure is more than `slack` (m, Euclidean) from that mean (a common translation brings
    no two points closer, so only the departures from a common one count)."""
    n = x.shape[0]
    mean = np.zeros(3)
    for v in range(n):
        for axis in range(3):
            mean[axis] += x[v, axis] - base[v, axis] - steps[v] * motion[v, axis]
    if n:
        mean /= n
    limit = slack * slack
    for v in range(n):
        dx = x[v, 0] - base[v, 0] - steps[v] * motion[v, 0] - mean[0]
        dy = x[v, 1] - base[v, 1] - steps[v] * motion[v, 1] - mean[1]
        dz = x[v, 2] - base[v, 2] - steps[v] * motion[v, 2] - mean[2]
        out[v] = dx * dx + dy * dy + dz * dz > limit
    return mean
