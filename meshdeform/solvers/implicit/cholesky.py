"""Sparse Cholesky factorisation A = L L^T of the implicit solver's matrix (`factorise`).

Below `OWN_FACTOR_ROWS` rows, CHOLMOD's simplicial factor through cholespy (`CholmodFactor`):
its solves run on one thread 1.3-1.8x as fast as ours. From there on our own
(`SparseCholesky`), which runs on two threads: cholespy holds the GIL in its factorisation and
its solves, copies every right-hand side into column-major doubles and back, and keeps no
symbolic analysis between factorisations (CHOLMOD's supernodal factor through cvxopt solves
slower and is GPL-3; METIS's nested dissection through pymetis takes 0.25 s on a 256 x 256
cloth). Measurements: docs/performance.md, "A Cholesky factor of our own".

The ordering is a geometric nested dissection of the matrix's graph (`_nested_dissection`):
the rows are split at the median of the rest positions along their widest axis, the rows of
one side that touch the other form the separator, numbered after both halves, recursively
(George 1973; Heath and Raghavan's Cartesian nested dissection, 1995). No row of one half is
coupled to the other, so each half is a union of whole subtrees of the elimination tree. The
factor is the up-looking row-by-row algorithm of Davis's CSparse (`cs_chol`, "Direct Methods for
Sparse Linear Systems", 2006, ch. 4): row k of L is a sparse triangular solve against the rows
of its descendants. The two halves are factorised beside each other (`threads.beside`), the
top separator's rows after them. The solves run over supernodes (runs of columns with one
pattern, held as dense blocks): forward, each supernode's updates of the rows below it, those a
half makes to the separator's rows gathered apart and added after; backward, each supernode
reading only its ancestors' rows.
Each row's arithmetic is the same whichever thread runs it, in the same order, so the factor
and every solution are the same bytes on one thread or two.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import NamedTuple

import cholespy
import numba as nb
import numpy as np
from scipy.sparse import coo_matrix

from meshdeform.solvers.dispatch import available
from meshdeform.solvers.implicit.kernels import gather_rows, scatter_free
from meshdeform.solvers.jit import FAST, JIT
from meshdeform.solvers.threads import beside

#: matrices of at least this many rows get our own factor, smaller ones CHOLMOD's: a 96 x 96
#: cloth (9 216 rows) ran 9 % faster with CHOLMOD's, a 128 x 128 one 5 % and a 180 x 180 one 11 %
#: faster with ours (docs/performance.md); CHOLMOD's factor takes 10 % less memory
OWN_FACTOR_ROWS = 20_000
#: matrices of fewer rows are factorised and solved on one thread: below it handing work to a
#: second thread costs about what it saves (the solver's matrices reach our factor only from
#: `OWN_FACTOR_ROWS`; the tests split smaller ones through `parallel_rows`)
MIN_PARALLEL_ROWS = 5_000
#: nested dissection stops at parts of this many rows (they keep their order along the last
#: split's axis): 8 gave the least fill on a 256 x 256 cloth (2.77 M entries; 16: 2.81 M, 64: 3.10 M)
LEAF_ROWS = 8
#: relaxed supernodes (`_relaxed_supernodes`): the zeros a block may hold, as a fraction of the
#: entries of its columns (0.5: at most a third of the block), and its most columns
BLOCK_SLACK = 0.5
BLOCK_WIDEST = 32
#: a top separator of up to this many rows is factorised in two parts, each half's columns of it
#: on a thread each (`_separator_part`), then its own (`_separator_rest`), through (2, T, T) sums
#: (the 256 rows of a 256 x 256 cloth: 1 MB; this many: 135 MB); a larger one on one thread
SPLIT_SEPARATOR_ROWS = 2_900


@nb.njit(**JIT)
def _nested_dissection(graph_ptr, graph_cols, points, lists, leaf, mark, buffer, stack):  # pragma: no cover
    """Nested dissection of the graph (CSR, `graph_ptr`, `graph_cols`, no self loops) of rows at
    `points` (n, 3), in place on `lists` (3, n): on entry the rows sorted along x, y and z
    (stable); on return each list holds the elimination order (the halves of each split first,
    then its separator), the parts of at most `leaf` rows in the order along each list's axis:
    lists[0] is the order used. Each larger part is cut at the median along its widest axis, and
    the rows of the side with the fewer rows touching the other side become its separator; every
    list is partitioned stably, so each part's rows stay sorted along every axis (no sort after
    the first). mark, buffer (n,) and stack (n + 1, 2) int64 are scratch. Returns the sizes of the
    top split's two halves."""
    n = points.shape[0]
    stack[0, 0] = 0
    stack[0, 1] = n
    depth = 1
    part = 0
    first_half = n
    second_half = 0
    while depth > 0:
        depth -= 1
        lo = stack[depth, 0]
        hi = stack[depth, 1]
        m = hi - lo
        if m <= leaf:
            continue
        part += 1
        axis = 0
        width = -1.0
        for a in range(3):
            extent = points[lists[a, hi - 1], a] - points[lists[a, lo], a]
            if extent > width:
                width = extent
                axis = a
        for k in range(m):
            mark[lists[axis, lo + k]] = 4 * part + (1 if k < m // 2 else 2)
        touching_first = 0
        touching_second = 0
        for k in range(m):
            v = lists[axis, lo + k]
            own = mark[v] - 4 * part
            for p in range(graph_ptr[v], graph_ptr[v + 1]):
                if mark[graph_cols[p]] == 4 * part + 3 - own:
                    if own == 1:
                        touching_first += 1
                    else:
                        touching_second += 1
                    break
        cut = 1 if touching_first <= touching_second else 2
        for k in range(m):
            v = lists[axis, lo + k]
            if mark[v] == 4 * part + cut:
                for p in range(graph_ptr[v], graph_ptr[v + 1]):
                    if mark[graph_cols[p]] == 4 * part + 3 - cut:
                        mark[v] = 4 * part + 3
                        break
        size_first = 0
        size_second = 0
        for a in range(3):
            at = 0
            for side in range(1, 4):
                for k in range(m):
                    v = lists[a, lo + k]
                    if mark[v] == 4 * part + side:
                        buffer[at] = v
                        at += 1
                if side == 1:
                    size_first = at
                elif side == 2:
                    size_second = at - size_first
            for k in range(m):
                lists[a, lo + k] = buffer[k]
        if size_first:
            stack[depth, 0] = lo
            stack[depth, 1] = lo + size_first
            depth += 1
        if size_second:
            stack[depth, 0] = lo + size_first
            stack[depth, 1] = lo + size_first + size_second
            depth += 1
        if part == 1:
            first_half = size_first
            second_half = size_second
    return first_half, second_half


@nb.njit(**JIT)
def _row_pattern(k, row_ptr, row_cols, parent, flag, stack):  # pragma: no cover - compiled
    """The columns j < k of row k of L (CSparse's `cs_ereach`), into stack[top:n] in an order
    where each column comes before its ancestors; returns top. flag (n,) marks the visited rows
    with k (any earlier marks are < k)."""
    n = stack.shape[0]
    top = n
    flag[k] = k
    for p in range(row_ptr[k], row_ptr[k + 1]):
        i = row_cols[p]
        if i >= k:
            continue
        length = 0
        while flag[i] != k:
            stack[length] = i
            length += 1
            flag[i] = k
            i = parent[i]
        while length > 0:
            length -= 1
            top -= 1
            stack[top] = stack[length]
    return top


@nb.njit(**JIT)
def _symbolic(row_ptr, row_cols, parent, col_ptr, l_rows, flag, stack):  # pragma: no cover - compiled
    """The symbolic factorisation of the symmetric matrix whose lower triangle has rows `row_ptr`,
    `row_cols` (CSR, columns <= row), into the caller's arrays: with `l_rows` empty (0,), the
    elimination tree (parent (n,): each row's, -1 at a root; Liu's algorithm with path
    compression, CSparse's `cs_etree`, `flag` as its ancestors) and each column's entries in L
    (col_ptr (n + 1,), its cumulative sums); given l_rows (entries,) int32, the rows of each column,
    ascending, its diagonal first, as the factorisation appends them. flag, stack (n,) int64."""
    n = row_ptr.shape[0] - 1
    if l_rows.shape[0] == 0:
        for k in range(n):
            parent[k] = -1
            flag[k] = -1
        for k in range(n):
            for p in range(row_ptr[k], row_ptr[k + 1]):
                i = row_cols[p]
                while i != -1 and i < k:
                    following = flag[i]
                    flag[i] = k
                    if following == -1:
                        parent[i] = k
                    i = following
        for k in range(n + 1):
            col_ptr[k] = 0
    for k in range(n):
        flag[k] = -1
    for k in range(n):
        top = _row_pattern(k, row_ptr, row_cols, parent, flag, stack)
        if l_rows.shape[0] == 0:
            for p in range(top, n):
                col_ptr[stack[p] + 1] += 1
            col_ptr[k + 1] += 1
        else:  # col_ptr[j] counts column j's rows so far; put back below
            for p in range(top, n):
                j = stack[p]
                l_rows[col_ptr[j]] = k
                col_ptr[j] += 1
            l_rows[col_ptr[k]] = k
            col_ptr[k] += 1
    if l_rows.shape[0] == 0:
        for k in range(n):
            col_ptr[k + 1] += col_ptr[k]
    else:
        for k in range(n, 0, -1):
            col_ptr[k] = col_ptr[k - 1]
        col_ptr[0] = 0


@nb.njit(**JIT)
def _take_column(j, k, work, column_node, start, rows_ptr, pattern, vals_ptr, vals, fill):  # pragma: no cover
    """Row k's entry L_kj = work[j] / L_jj into its block position (found from fill[j], where
    column j's entries so far end, along the block's rows), and its updates of the later entries
    of row k, work[i] -= L_ij L_kj for column j's rows i between j and k (zeros included):
    one step of the up-looking row solve. Returns L_kj."""
    s = column_node[j]
    c = j - start[s]
    at = rows_ptr[s]
    column = vals_ptr[s] + c * (rows_ptr[s + 1] - at)  # column c of the block
    value = work[j] * vals[column + c]  # the diagonal holds 1 / L_jj
    work[j] = 0.0
    position = fill[j]
    while pattern[at + position] != k:
        position += 1
    for q in range(c + 1, position):
        work[pattern[at + q]] -= vals[column + q] * value
    vals[column + position] = value
    fill[j] = position + 1
    return value


@nb.njit(**JIT)
def _set_pivot(k, diagonal, column_node, start, rows_ptr, vals_ptr, vals, fill):  # pragma: no cover - compiled
    """Row k's diagonal: 1 / sqrt(diagonal) into its block. False where diagonal is not positive
    (the matrix is not positive definite there)."""
    if not diagonal > 0.0:
        return False
    s = column_node[k]
    c = k - start[s]
    vals[vals_ptr[s] + c * (rows_ptr[s + 1] - rows_ptr[s]) + c] = 1.0 / np.sqrt(diagonal)
    fill[k] = c + 1
    return True


@nb.njit(**JIT)
def _factor_rows(first, last, row_ptr, row_cols, row_vals, parent, column_node, start, rows_ptr, pattern, vals_ptr,
                 vals, fill, work, flag, stack):  # pragma: no cover - compiled
    """Rows first .. last - 1 (each after all its descendants) of L = chol(A), up-looking
    (CSparse's `cs_chol`), straight into the supernodes' blocks (`Supernodes`; zeroed before;
    `_take_column`). Returns the first row whose pivot is not positive (the matrix is not
    positive definite there), else -1. Scratch (n,) each, the thread's own: work (zeros), flag
    (-1), stack."""
    n = parent.shape[0]
    for k in range(first, last):
        top = _row_pattern(k, row_ptr, row_cols, parent, flag, stack)
        diagonal = 0.0
        for p in range(row_ptr[k], row_ptr[k + 1]):
            j = row_cols[p]
            if j == k:
                diagonal = row_vals[p]
            else:
                work[j] = row_vals[p]
        for p in range(top, n):
            value = _take_column(stack[p], k, work, column_node, start, rows_ptr, pattern, vals_ptr, vals, fill)
            diagonal -= value * value
        if not _set_pivot(k, diagonal, column_node, start, rows_ptr, vals_ptr, vals, fill):
            return k
    return -1


@nb.njit(**JIT)
def _separator_part(first, last, low, high, row_ptr, row_cols, row_vals, parent, column_node, start, rows_ptr, pattern,
                    vals_ptr, vals, fill, work, flag, stack, sums):  # pragma: no cover - compiled
    """The separator's rows first .. last (= n) - 1 in the columns low .. high - 1 of one half
    (which reach no other half's), into the blocks as `_factor_rows` does, and what those entries
    take from the rest of each row: sums (T, T) gets, for row k and separator column i < k, the
    sum over the half's columns j of -L_ij L_kj at [k - first, i - first], and the sum of L_kj^2
    at [k - first, k - first] (the two halves' sums are added in `_separator_rest`). Scratch as
    `_factor_rows`'s."""
    n = parent.shape[0]
    for k in range(first, last):
        top = _row_pattern(k, row_ptr, row_cols, parent, flag, stack)
        for p in range(row_ptr[k], row_ptr[k + 1]):
            j = row_cols[p]
            if low <= j < high:
                work[j] = row_vals[p]
        squares = 0.0
        for p in range(top, n):
            j = stack[p]
            if low <= j < high:
                value = _take_column(j, k, work, column_node, start, rows_ptr, pattern, vals_ptr, vals, fill)
                squares += value * value
        for i in range(first, k):
            sums[k - first, i - first] = work[i]
            work[i] = 0.0
        sums[k - first, k - first] = squares


@nb.njit(**JIT)
def _separator_rest(first, row_ptr, row_cols, row_vals, parent, column_node, start, rows_ptr, pattern, vals_ptr, vals,
                    fill, work, flag, stack, sums):  # pragma: no cover - compiled
    """The separator's rows first .. n - 1 in its own columns, after `_separator_part` of both
    halves (sums (2, T, T), added in that order whatever the threads). Returns the first row
    whose pivot is not positive, else -1."""
    n = parent.shape[0]
    for k in range(first, n):
        top = _row_pattern(k, row_ptr, row_cols, parent, flag, stack)
        row = k - first
        diagonal = -sums[0, row, row] - sums[1, row, row]
        for i in range(first, k):
            work[i] = sums[0, row, i - first] + sums[1, row, i - first]
        for p in range(row_ptr[k], row_ptr[k + 1]):
            j = row_cols[p]
            if j == k:
                diagonal += row_vals[p]
            elif j >= first:
                work[j] += row_vals[p]
        for p in range(top, n):
            j = stack[p]
            if j >= first:
                value = _take_column(j, k, work, column_node, start, rows_ptr, pattern, vals_ptr, vals, fill)
                diagonal -= value * value
        if not _set_pivot(k, diagonal, column_node, start, rows_ptr, vals_ptr, vals, fill):
            return k
    return -1


@nb.njit(**JIT)
def _relaxed_supernodes(col_ptr, parent, owner, slack, widest, first):  # pragma: no cover - compiled
    """The first column of each supernode, then n, into first (n + 1,); returns S + 1, how many.
    A supernode is a run of columns j, j + 1, ... each the parent of the one before (so their
    rows below the run are the last column's), of one owner (a thread's half or the separator),
    at most `widest` wide, grown while its block (triangle included) holds at most 1 + `slack`
    times the entries of its columns (the rest are zeros): Ashcraft and Grimes's relaxed
    supernodes (1989), whose wider blocks the solves go through with fewer passes over the rows
    below."""
    n = parent.shape[0]
    count = 0
    j = 0
    while j < n:
        j0 = j
        entries = col_ptr[j + 1] - col_ptr[j]
        while j + 1 < n and parent[j] == j + 1 and owner[j + 1] == owner[j0] and j + 2 - j0 <= widest:
            width = j + 2 - j0
            below = col_ptr[j + 2] - col_ptr[j + 1] - 1
            if (width + below) * width > (1.0 + slack) * (entries + col_ptr[j + 2] - col_ptr[j + 1]):
                break
            entries += col_ptr[j + 2] - col_ptr[j + 1]
            j += 1
        first[count] = j0
        count += 1
        j += 1
    first[count] = n
    return count + 1


@nb.njit(**FAST)
def _forward(first, last, start, rows_ptr, rows, vals_ptr, vals, y, solved, below):  # pragma: no cover - compiled
    """L y = b in place on y (n + 2 T, 3) for the supernodes first .. last - 1: each one's
    triangle, then its part taken from the rows below it, summed column by column into below
    (3, tallest) (contiguous runs of each column, which vectorise) and subtracted row by row.
    solved (3, widest) holds the supernode's solved columns transposed."""
    y0 = solved[0]
    y1 = solved[1]
    y2 = solved[2]
    t0 = below[0]
    t1 = below[1]
    t2 = below[2]
    for s in range(first, last):
        j0 = start[s]
        w = start[s + 1] - j0
        at = rows_ptr[s]
        h = rows_ptr[s + 1] - at
        base = vals_ptr[s]
        for c in range(w):
            s0 = y[j0 + c, 0]
            s1 = y[j0 + c, 1]
            s2 = y[j0 + c, 2]
            for cc in range(c):
                v = vals[base + cc * h + c]
                s0 -= v * y0[cc]
                s1 -= v * y1[cc]
                s2 -= v * y2[cc]
            inverse = vals[base + c * h + c]
            y0[c] = s0 * inverse
            y1[c] = s1 * inverse
            y2[c] = s2 * inverse
            y[j0 + c, 0] = y0[c]
            y[j0 + c, 1] = y1[c]
            y[j0 + c, 2] = y2[c]
        count = h - w
        for r in range(count):
            t0[r] = 0.0
            t1[r] = 0.0
            t2[r] = 0.0
        for c in range(w):
            column = base + c * h + w
            a0 = y0[c]
            a1 = y1[c]
            a2 = y2[c]
            for r in range(count):
                v = vals[column + r]
                t0[r] += v * a0
                t1[r] += v * a1
                t2[r] += v * a2
        for r in range(count):
            i = rows[at + w + r]
            y[i, 0] -= t0[r]
            y[i, 1] -= t1[r]
            y[i, 2] -= t2[r]


@nb.njit(**FAST)
def _backward(first, last, start, rows_ptr, rows, vals_ptr, vals, x, solved, below):  # pragma: no cover - compiled
    """L^T x = y in place on x (n + 2 T, 3) for the supernodes last - 1 down to first (each after
    every ancestor): each one's rows below it gathered into below (3, tallest), each column's
    sum over them (a contiguous run), then its triangle, its solved columns kept transposed in
    solved (3, widest)."""
    x0 = solved[0]
    x1 = solved[1]
    x2 = solved[2]
    e0 = below[0]
    e1 = below[1]
    e2 = below[2]
    for s in range(last - 1, first - 1, -1):
        j0 = start[s]
        w = start[s + 1] - j0
        at = rows_ptr[s]
        h = rows_ptr[s + 1] - at
        base = vals_ptr[s]
        count = h - w
        for r in range(count):
            i = rows[at + w + r]
            e0[r] = x[i, 0]
            e1[r] = x[i, 1]
            e2[r] = x[i, 2]
        for c in range(w - 1, -1, -1):
            column = base + c * h
            z0 = 0.0
            z1 = 0.0
            z2 = 0.0
            for r in range(count):
                v = vals[column + w + r]
                z0 += v * e0[r]
                z1 += v * e1[r]
                z2 += v * e2[r]
            s0 = x[j0 + c, 0] - z0
            s1 = x[j0 + c, 1] - z1
            s2 = x[j0 + c, 2] - z2
            for cc in range(c + 1, w):
                v = vals[column + cc]
                s0 -= v * x0[cc]
                s1 -= v * x1[cc]
                s2 -= v * x2[cc]
            inverse = vals[column + c]
            x0[c] = s0 * inverse
            x1[c] = s1 * inverse
            x2[c] = s2 * inverse
            x[j0 + c, 0] = x0[c]
            x[j0 + c, 1] = x1[c]
            x[j0 + c, 2] = x2[c]


@nb.njit(**FAST)
def _separator_solves(first, start, rows_ptr, rows, vals_ptr, vals, y, solved, below):  # pragma: no cover - compiled
    """Between the threads' forward and backward passes, on y (n + 2 T, 3), the T separator rows
    being rows n - T .. n - 1: each half's updates of them (rows n .. n + T - 1, then the next T:
    minus its sums, from zero) added in the same order whatever the threads; the separator's
    supernodes (first to the last) forward and backward; the solved separator rows copied to both
    halves' rows for their backward pass. solved (3, widest), below (3, tallest): scratch."""
    count = (y.shape[0] - start[start.shape[0] - 1]) // 2
    n = y.shape[0] - 2 * count
    for half in range(2):
        for k in range(count):
            i = n - count + k
            y[i, 0] += y[n + half * count + k, 0]
            y[i, 1] += y[n + half * count + k, 1]
            y[i, 2] += y[n + half * count + k, 2]
    last = start.shape[0] - 1
    _forward(first, last, start, rows_ptr, rows, vals_ptr, vals, y, solved, below)
    _backward(first, last, start, rows_ptr, rows, vals_ptr, vals, y, solved, below)
    for half in range(2):
        for k in range(count):
            i = n - count + k
            y[n + half * count + k, 0] = y[i, 0]
            y[n + half * count + k, 1] = y[i, 1]
            y[n + half * count + k, 2] = y[i, 2]


def _check_lower(
    indptr: np.ndarray, indices: np.ndarray, columns: np.ndarray, data: np.ndarray, points: np.ndarray
) -> None:
    """Raises ValueError unless (indptr, indices, data) is the lower triangle of an n x n matrix
    in CSC, each column's rows ascending, unique and starting at its diagonal, and points is
    (n, 3): the kernels index with these arrays unchecked."""
    n = indptr.shape[0] - 1
    starts = indptr[:-1]
    well_formed = (
        n >= 0 and indptr[0] == 0 and (np.diff(indptr) >= 1).all() and indptr[-1] == indices.shape[0]
        and data.shape == indices.shape and points.shape == (n, 3)
    )
    if not well_formed:
        raise ValueError("a sparse Cholesky factor needs an n x n lower triangle in CSC and n points")
    ascending = np.ones(indices.shape[0], dtype=bool)
    ascending[1:] = indices[1:] > indices[:-1]
    ascending[starts] = True
    if not ((indices[starts] == np.arange(n)).all() and ascending.all() and (indices < n).all()
            and (indices >= columns).all()):
        raise ValueError("a sparse Cholesky factor needs each column's rows ascending from its diagonal")


class Supernodes(NamedTuple):
    """L's supernodes: S runs of columns (`start` (S + 1,): the first of each, then n) that share
    one pattern of rows, held as dense h x w blocks, column-major (`vals` from `vals_ptr` (S +
    1,): the solves run down each column's contiguous rows), zeros where a column has no entry,
    1 / L_jj on the diagonal (float32 where the factor is `single`). `rows` (R,) int32, from
    `rows_ptr` (S + 1,): each block's rows in the solves' work array (n + 2 T rows: a half's rows
    in the T separator rows are its own copies, n + T k + slot); `pattern`: the same rows in L.
    `shares`: the supernodes (first, last + 1) of each thread's half and of the separator, in
    that order; `widest`, `tallest`: the most columns of a supernode and rows below them."""

    start: np.ndarray
    rows_ptr: np.ndarray
    rows: np.ndarray
    pattern: np.ndarray
    vals_ptr: np.ndarray
    vals: np.ndarray
    shares: tuple[tuple[int, int], tuple[int, int], tuple[int, int]]
    widest: int
    tallest: int


#: the blocks of a factor not yet made (or being remade)
_NO_BLOCKS = np.zeros(0)


class SparseCholesky:
    """A = L L^T of a symmetric positive definite (n, n) matrix given by its lower triangle in
    CSC (`indptr` (n + 1,), `indices`, `data`: each column's rows ascending, diagonal first), its
    rows at `points` (n, 3) (rest positions, m: the ordering's geometry), and solves of A x = b
    for (n, 3) right-hand sides (`solve`). `refactor` takes new values on the same pattern and
    keeps the ordering and the symbolic analysis.

    threads: 1 or 2 (`beside`), settable between calls; the results are the same bytes either way.
    parallel_rows: the fewest rows split into two halves (`MIN_PARALLEL_ROWS`; `compile_kernels`
    splits a small one).
    single: keep L in single precision for the solves once factorised (in double precision): the
    solves read each block once and wait on memory, so half the bytes make them 1.45x faster
    (256 x 256: 6.7 -> 4.6 ms on two threads); a solve is then the exact solve (in double
    precision) of L~ L~^T, within about 1e-7 relative of A: what a preconditioner needs, not
    an exact solve (docs/performance.md, "Single-precision factor blocks").
    """

    def __init__(
        self, indptr: np.ndarray, indices: np.ndarray, data: np.ndarray, points: np.ndarray, threads: int = 2,
        parallel_rows: int = MIN_PARALLEL_ROWS, single: bool = False,
    ) -> None:
        n = indptr.shape[0] - 1
        self.size = n
        self.single = single
        self.threads = threads
        indptr = np.asarray(indptr, dtype=np.int64)
        indices = np.asarray(indices, dtype=np.int64)
        self._indptr, self._indices = indptr, indices
        columns = np.repeat(np.arange(n, dtype=np.int64), np.diff(indptr))
        _check_lower(indptr, indices, columns, np.asarray(data), np.asarray(points))
        off = indices != columns
        a, b = indices[off], columns[off]
        graph = coo_matrix(
            (np.ones(2 * a.shape[0], dtype=np.int8), (np.concatenate([a, b]), np.concatenate([b, a]))), shape=(n, n)
        ).tocsr()
        points = np.ascontiguousarray(points, dtype=np.float64)
        lists = np.stack([np.argsort(points[:, axis], kind="stable") for axis in range(3)]).astype(np.int64)
        halves = _nested_dissection(
            graph.indptr.astype(np.int64), graph.indices.astype(np.int64), points, lists, LEAF_ROWS,
            np.zeros(n, dtype=np.int64), np.empty(n, dtype=np.int64), np.empty((n + 1, 2), dtype=np.int64),
        )
        self.order = lists[0].copy()
        rank = np.empty(n, dtype=np.int64)
        rank[self.order] = np.arange(n, dtype=np.int64)
        # the permuted matrix's lower triangle by rows; `_value_source` maps each of its entries to `data`
        pi, pj = rank[indices], rank[columns]
        entry = np.arange(indices.shape[0], dtype=np.float64)
        permuted = coo_matrix((entry + 1.0, (np.maximum(pi, pj), np.minimum(pi, pj))), shape=(n, n)).tocsr()
        permuted.sort_indices()
        self._row_ptr = permuted.indptr.astype(np.int64)
        self._row_cols = permuted.indices.astype(np.int64)
        self._value_source = (permuted.data - 1.0).astype(np.int64)
        self._parent = np.empty(n, dtype=np.int64)
        col_ptr = np.empty(n + 1, dtype=np.int64)
        flag, stack = np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64)
        no_rows = np.empty(0, dtype=np.int32)
        _symbolic(self._row_ptr, self._row_cols, self._parent, col_ptr, no_rows, flag, stack)
        #: entries of L (its lower triangle, diagonal included)
        self.entries = int(col_ptr[-1])
        # the threads' shares of rows: the top split's halves (whole subtrees each), then its separator
        first, second = (int(h) for h in halves)
        if n < parallel_rows or not (first and second):
            first, second = n, 0
        self._row_shares = ((0, first), (first, first + second), (first + second, n))
        l_rows = np.empty(self.entries, dtype=np.int32)
        _symbolic(self._row_ptr, self._row_cols, self._parent, col_ptr, l_rows, flag, stack)
        self._supernodes = self._supernode_structure(col_ptr, l_rows)
        self._column_node = np.repeat(
            np.arange(self._supernodes.start.shape[0] - 1, dtype=np.int64), np.diff(self._supernodes.start)
        )
        self._work = np.empty((n + 2 * (n - first - second), 3))  # (n + 2 T, 3): `Supernodes`
        # each thread's scratch of the solves: a supernode's solved columns and its rows below them
        self._solved = np.empty((2, 3, self._supernodes.widest))
        self._below = np.empty((2, 3, max(self._supernodes.tallest, 1)))
        self.refactor(data)

    def has_pattern(self, indptr: np.ndarray, indices: np.ndarray) -> bool:
        """Whether a matrix of this lower-triangle pattern (CSC) is the factorised one's."""
        return np.array_equal(indptr, self._indptr) and np.array_equal(indices, self._indices)

    def refactor(self, data: np.ndarray) -> None:
        """Factorise the matrix of the same pattern with values `data` (as the constructor's)."""
        data = np.asarray(data, dtype=np.float64)
        if data.shape != self._indices.shape or not np.isfinite(data).all():
            raise ValueError("the implicit solver's matrix has values of another count or non-finite ones")
        row_vals = data[self._value_source]
        nodes = self._supernodes = self._supernodes._replace(vals=_NO_BLOCKS)  # the last factor's freed first
        values = np.zeros(int(nodes.vals_ptr[-1]))  # factorised in double precision
        fill = np.arange(self.size, dtype=np.int64) - nodes.start[self._column_node]  # each diagonal's position

        matrix = (self._row_ptr, self._row_cols, row_vals, self._parent, self._column_node, nodes.start)
        blocks = (nodes.rows_ptr, nodes.pattern, nodes.vals_ptr, values, fill)

        def scratch() -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # a thread's work, flag and stack
            return np.zeros(self.size), np.full(self.size, -1, dtype=np.int64), np.empty(self.size, dtype=np.int64)

        def rows(share: int) -> int:
            return _factor_rows(*self._row_shares[share], *matrix, *blocks, *scratch())

        failed = self._in_two(functools.partial(rows, 0), functools.partial(rows, 1))
        first, last = self._row_shares[2]
        if all(k is not None and k < 0 for k in failed) and first < last:  # the separator's rows read both halves'
            if last - first > SPLIT_SEPARATOR_ROWS:
                failed.append(rows(2))
            else:  # each half's columns of them beside the other's, then their own columns
                sums = np.empty((2, last - first, last - first))
                self._in_two(
                    *(functools.partial(_separator_part, first, last, *self._row_shares[half], *matrix, *blocks,
                                        *scratch(), sums[half]) for half in (0, 1))
                )
                failed.append(_separator_rest(first, *matrix, *blocks, *scratch(), sums))
        bad = [k for k in failed if k is not None and k >= 0]
        self._supernodes = nodes._replace(vals=values.astype(np.float32) if self.single else values)
        if bad:
            raise ValueError(f"the implicit solver's matrix is not positive definite (row {int(self.order[min(bad)])})")

    def _supernode_structure(self, col_ptr: np.ndarray, l_rows: np.ndarray) -> Supernodes:
        """L's relaxed supernodes (`_relaxed_supernodes`), cut where the threads' shares change,
        from the pattern of L: its columns' rows `l_rows` from `col_ptr` (n + 1,)."""
        n = self.size
        owner = np.full(n, 2, dtype=np.int64)
        for side in (0, 1):
            owner[slice(*self._row_shares[side])] = side
        start = np.empty(n + 1, dtype=np.int64)
        start = start[: _relaxed_supernodes(col_ptr, self._parent, owner, BLOCK_SLACK, BLOCK_WIDEST, start)].copy()
        first_columns, last_columns = start[:-1], start[1:] - 1
        widths = start[1:] - first_columns
        below = np.diff(col_ptr)[last_columns] - 1  # the last column's rows under its diagonal
        heights = widths + below
        rows_ptr = np.zeros(heights.shape[0] + 1, dtype=np.int64)
        np.cumsum(heights, out=rows_ptr[1:])
        # each supernode's rows: its own columns, then the last column's rows below its diagonal
        offset = np.arange(rows_ptr[-1]) - np.repeat(rows_ptr[:-1], heights)
        node = np.repeat(np.arange(heights.shape[0]), heights)
        own = offset < widths[node]
        rows = np.where(
            own, first_columns[node] + offset,
            l_rows[np.minimum(col_ptr[last_columns[node]] + 1 + offset - widths[node], self.entries - 1)],
        ).astype(np.int32)
        vals_ptr = np.zeros(heights.shape[0] + 1, dtype=np.int64)
        np.cumsum(heights * widths, out=vals_ptr[1:])
        # a half's supernodes write their sums for the separator's rows into rows of their own
        # (n + T k + slot, k the half) and read the solved separator there in the backward pass
        low, high = self._row_shares[2]
        slot = np.full(n, -1, dtype=np.int64)
        slot[low:high] = np.arange(high - low, dtype=np.int64)
        row_owner = np.repeat(owner[first_columns], heights)
        private = (slot[rows] >= 0) & (row_owner < 2)
        node_owner = owner[first_columns]
        return Supernodes(
            start=start,
            rows_ptr=rows_ptr,
            rows=np.where(private, n + row_owner * (high - low) + slot[rows], rows).astype(np.int32),
            pattern=rows,
            vals_ptr=vals_ptr,
            vals=_NO_BLOCKS,
            shares=tuple((int(np.searchsorted(node_owner, side)), int(np.searchsorted(node_owner, side, "right")))
                         for side in (0, 1, 2)),
            widest=int(widths.max()) if widths.shape[0] else 1,
            tallest=int((heights - widths).max()) if widths.shape[0] else 1,
        )

    def _in_two(self, first: Callable[[], int | None], second: Callable[[], int | None]) -> list[int | None]:
        """[first(), second()]: beside each other on two threads where both shares hold rows."""
        (low, middle), (_, high), _ = self._row_shares
        if self.threads >= 2 and low < middle < high:
            return list(beside(first, second))
        return [first(), second()]

    def solve(self, b: np.ndarray, x: np.ndarray) -> None:
        """x (n, 3) = A^-1 b (n, 3); x and b may be the same array."""
        nodes, work, solved, below = self._supernodes, self._work, self._solved, self._below
        if nodes.vals.shape[0] != nodes.vals_ptr[-1]:  # a refactorisation that failed left no blocks
            raise ValueError("the implicit solver's matrix has no factor (its last factorisation failed)")
        structure = (nodes.start, nodes.rows_ptr, nodes.rows, nodes.vals_ptr, nodes.vals, work)
        (first, middle), (_, top), (_, last) = nodes.shares
        gather_rows(b, self.order, work)  # b permuted
        work[self.size :] = 0.0
        self._in_two(
            functools.partial(_forward, first, middle, *structure, solved[0], below[0]),
            functools.partial(_forward, middle, top, *structure, solved[1], below[1]),
        )
        if top < last:
            _separator_solves(top, *structure, solved[0], below[0])
        self._in_two(
            functools.partial(_backward, first, middle, *structure, solved[0], below[0]),
            functools.partial(_backward, middle, top, *structure, solved[1], below[1]),
        )
        scatter_free(x, self.order, work)  # back in the original order


class CholmodFactor:
    """CHOLMOD's simplicial factor through cholespy, with `SparseCholesky`'s interface: the
    lower triangle in CSC (`indptr` int32 (n + 1,), `indices` int32, `data`). Its `threads`
    attribute may be set and is unused (cholespy runs on one); `refactor` factorises anew."""

    def __init__(self, indptr: np.ndarray, indices: np.ndarray, data: np.ndarray) -> None:
        self.threads = 1
        self._indptr = np.asarray(indptr, dtype=np.int32)
        self._indices = np.asarray(indices, dtype=np.int32)
        self.refactor(data)

    def has_pattern(self, indptr: np.ndarray, indices: np.ndarray) -> bool:
        """Whether a matrix of this lower-triangle pattern (CSC) is the factorised one's."""
        return np.array_equal(indptr, self._indptr) and np.array_equal(indices, self._indices)

    def refactor(self, data: np.ndarray) -> None:
        """Factorise the matrix of the same pattern with values `data`."""
        self._factor = None  # free the old factor before building the new one
        self._factor = cholespy.CholeskySolverD(
            self._indptr.shape[0] - 1, self._indptr, self._indices, np.asarray(data, dtype=np.float64),
            cholespy.MatrixType.CSC,
        )

    def solve(self, b: np.ndarray, x: np.ndarray) -> None:
        """x (n, 3) = A^-1 b (n, 3)."""
        self._factor.solve(b, x)


def factorise(
    indptr: np.ndarray, indices: np.ndarray, data: np.ndarray, points: np.ndarray, threads: int, single: bool
) -> SparseCholesky | CholmodFactor:
    """The factor of the SPD matrix whose lower triangle is `indptr`, `indices`, `data` (CSC,
    each column's diagonal first), its rows at `points` (n, 3), factorised on `threads` (1 or 2):
    CHOLMOD's below `OWN_FACTOR_ROWS` rows, ours from there on (the module docstring), its blocks
    kept in single precision where `single` (a preconditioner's: `SparseCholesky`)."""
    if indptr.shape[0] - 1 < OWN_FACTOR_ROWS:
        return CholmodFactor(indptr, indices, data)
    return SparseCholesky(indptr, indices, data, points, threads=threads, single=single)


def compile_kernels() -> None:
    """Compiles (or loads from Numba's cache) every kernel `SparseCholesky` runs, on a 6 x 6 grid
    split in two halves and a separator (`pipeline.compile_ahead`)."""
    side = 6
    index = np.arange(side * side).reshape(side, side)
    right, down = index[:, :-1].ravel(), index[:-1, :].ravel()
    a = np.concatenate([right, down])
    b = np.concatenate([right + 1, down + side])
    rows = np.concatenate([np.arange(side * side), np.maximum(a, b)])
    cols = np.concatenate([np.arange(side * side), np.minimum(a, b)])
    vals = np.concatenate([np.full(side * side, 5.0), np.full(a.shape[0], -1.0)])
    lower = coo_matrix((vals, (rows, cols)), shape=(side * side, side * side)).tocsc()
    lower.sort_indices()
    u, v = np.meshgrid(np.arange(side, dtype=np.float64), np.arange(side, dtype=np.float64))
    points = np.stack([u.ravel(), v.ravel(), np.zeros(side * side)], axis=1)
    # single precision: the default L-BFGS's (local/global's double blocks compile on first use)
    factor = SparseCholesky(lower.indptr, lower.indices, lower.data, points, parallel_rows=0, single=True)
    factor.solve(np.ones((side * side, 3)), np.empty((side * side, 3)))


#: every kernel `SparseCholesky` runs (`kernels_cached`)
KERNELS = (_nested_dissection, _symbolic, _relaxed_supernodes, _factor_rows, _separator_part, _separator_rest, _forward,
           _backward, _separator_solves, gather_rows, scatter_free)


def kernels_cached() -> bool:
    """Whether every kernel `SparseCholesky` runs needs no compiling (`dispatch.available`)."""
    return all(available(kernel) for kernel in KERNELS)
