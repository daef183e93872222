"""A coarse space for the implicit solver: Newton steps on the displacements of a lattice.

Why: the projective-dynamics matrix that preconditions `implicit`'s L-BFGS holds every spring at
full stiffness in every direction, so where a cloth turns rather than stretches (a sheet falling
about its pinned edge, a swing) each iteration moves it only a fraction m / (b^2 k) of the way,
and a few iterations of a long step lose the rest like a strong damping (docs/performance.md, "A
coarse space for the implicit solver", has the figures). Those turning motions are smooth over the
cloth, so a handful of smooth displacement fields span them. Before the L-BFGS iterations, a few
Newton steps are taken in that span: the step's energy E(x + Z c) is minimised over c, with the
true spring Hessian (each spring's stiffness along it, and across it only as far as it is
stretched: k (1 - L / l), which is what makes turning cheap) projected onto the span, Z^T H Z, and
an Armijo line search on the full energy, so a step never raises the energy. This is the coarse
correction of two-level (multigrid and domain decomposition) methods, here on the nonlinear
energy; the fine iterations (L-BFGS with the prefactored matrix) then resolve what is local.

The span: a lattice over the rest positions of the free vertices, `nodes` nodes along the
longest side of their bounding box and as many along the others as keep its cells about cubic
(one along a side with no extent: a flat sheet has a flat lattice), fewer where that would make
more than `MAX_NODES`; each free vertex moves with the trilinear interpolation of the
displacements of its cell's corners. Nodes no free vertex
depends on are dropped. The inertia part of Z^T H Z is fixed for a step size
(`CoarseSpace.inertia_matrix`); the springs' part is assembled from the springs that are not
bending springs (soft next to the in-plane ones, a third of the springs), at the positions where
the correction starts, once a step. Everything runs serially in a fixed order (the dense solve
too: `factor_spd`, not LAPACK, whose threads may sum in another order), so runs stay
byte-identical on any thread count.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numba as nb
import numpy as np
from scipy.sparse import csr_matrix, diags

from meshdeform.solvers.jit import FAST, JIT
from meshdeform.solvers.threads import beside

#: at most this many lattice nodes (3 unknowns each; the dense solve costs their cube): a flat sheet
#: keeps its `nodes` x `nodes`, a solid's lattice gets fewer along each side (3 x 3 x 3)
MAX_NODES = 48
#: trilinear weights per vertex: the eight corners of its lattice cell (fewer are used on a flat lattice)
CORNERS = 8


@dataclass(frozen=True)
class CoarseSpace:
    """The lattice span of one model's free vertices (module docstring).

    vertex_nodes, vertex_weights: (F, 8) lattice node (0 .. count - 1, -1 for none) and trilinear
        weight of each free vertex's cell corners; the weights of a vertex sum to 1.
    count: lattice nodes kept (C); the coarse unknowns are their (C, 3) displacements (m).
    springs: (S',) indices into the solver's spring arrays of the springs assembled into Z^T H Z;
    spring_nodes: (S', 16) the nodes of z_a - z_b for each spring (ascending; -1 past the last);
    spring_coefficients: (16, S') their coefficients, row p the p-th node's of every spring (a
        pinned end contributes nothing; 0 past the last node), so that a sum over springs reads
        consecutive memory.
    group_start: (G + 1,) the springs are in groups with the same nodes; group g is springs
        group_start[g] .. group_start[g + 1] - 1.
    skip, forward, move: scratch of the dense solve, (3C,) each (`factor_spd`'s pivots left out,
        `solve_factored`'s forward substitution and result); hessian_terms (2, 6, HESSIAN_CHUNK) and
        hessian_sums (2, W (W + 1) / 2, 6): scratch of `spring_hessian`, one of each per half. Arrays
        made inside a kernel would cost every process with an empty compile cache the compiling of
        their allocators.
    second_half: the group from which `add_spring_hessian` sums the groups into a matrix of their
        own (on a second thread where asked) and adds it after the first half's; 0: one sum.
    """

    vertex_nodes: np.ndarray
    vertex_weights: np.ndarray
    count: int
    springs: np.ndarray
    spring_nodes: np.ndarray
    spring_coefficients: np.ndarray
    group_start: np.ndarray
    skip: np.ndarray
    forward: np.ndarray
    move: np.ndarray
    hessian_terms: np.ndarray
    hessian_sums: np.ndarray
    second_half: int

    def add_spring_hessian(
        self, x: np.ndarray, a: np.ndarray, b: np.ndarray, rest: np.ndarray, weight: np.ndarray,
        out: np.ndarray, threads: int = 1,
    ) -> None:
        """out (3C, 3C) += Z^T H Z of the assembled springs at positions x (V, 3) (`spring_hessian`;
        a, b, rest, weight: the solver's spring arrays): in one sum, or where
        `second_half` splits the groups, the first half into out and the second into a matrix of its
        own added after it (the halves beside each other where `threads` >= 2: the same bytes)."""

        def groups(half: int, first: int, stop: int, into: np.ndarray) -> None:
            spring_hessian(
                x, a, b, rest, weight, self.springs, self.spring_nodes, self.spring_coefficients,
                self.group_start[first : stop + 1], self.hessian_terms[half], self.hessian_sums[half], into,
            )

        last = self.group_start.shape[0] - 1
        if not self.second_half:
            groups(0, 0, last, out)
            return
        second = np.zeros_like(out)
        first_half = functools.partial(groups, 0, 0, self.second_half, out)
        second_half = functools.partial(groups, 1, self.second_half, last, second)
        if threads >= 2:
            beside(first_half, second_half)
        else:
            first_half()
            second_half()
        out += second

    def inertia_matrix(self, inertia: np.ndarray) -> np.ndarray:
        """Z^T diag(inertia) Z (3C, 3C) for the free vertices' inertia (F,) (kg / s^2): the same
        for x, y and z (a Kronecker product with the 3 x 3 identity). Sparse products, once per
        step size."""
        used = self.vertex_nodes >= 0
        rows = np.broadcast_to(np.arange(self.vertex_nodes.shape[0])[:, None], used.shape)[used]
        z = csr_matrix((self.vertex_weights[used], (rows, self.vertex_nodes[used])), shape=(used.shape[0], self.count))
        lumped = (z.T @ diags(inertia) @ z).toarray()
        return np.kron(lumped, np.eye(3))


def coarse_space(
    rest_free: np.ndarray, free: np.ndarray, a: np.ndarray, b: np.ndarray, assembled: np.ndarray, nodes: int,
    halves: bool = False,
) -> CoarseSpace | None:
    """The lattice span for free vertices at rest positions rest_free (F, 3) (free: (V,) vertex ->
    free row or -1; a, b: (S,) spring ends; assembled: (S,) bool, the springs Z^T H Z sums),
    `nodes` lattice nodes along the longest side, its Hessian summed in two halves of the springs
    where `halves`; None where there is nothing to span (no free vertex, or fewer than 2 nodes
    asked for)."""
    if nodes < 2 or rest_free.shape[0] == 0:
        return None
    low = rest_free.min(axis=0)
    extent = rest_free.max(axis=0) - low
    longest = float(extent.max())
    if not longest > 0.0:
        return None
    for along_longest in range(nodes, 1, -1):  # the most nodes along the longest side within MAX_NODES
        cell = longest / (along_longest - 1)
        dims = np.array([max(1, int(np.ceil(e / cell - 1e-9)) + 1) if e > 1e-9 * longest else 1 for e in extent])
        if int(np.prod(dims)) <= MAX_NODES:
            break
    base = np.zeros(rest_free.shape, dtype=np.int64)
    frac = np.zeros(rest_free.shape)
    for d in range(3):
        if dims[d] > 1:
            t = (rest_free[:, d] - low[d]) / cell
            base[:, d] = np.clip(np.floor(t).astype(np.int64), 0, dims[d] - 2)
            frac[:, d] = np.clip(t - base[:, d], 0.0, 1.0)
    vertex_nodes = np.full((rest_free.shape[0], CORNERS), -1, dtype=np.int64)
    vertex_weights = np.zeros((rest_free.shape[0], CORNERS))
    corner = 0
    for cx in (0, 1):
        for cy in (0, 1):
            for cz in (0, 1):
                offset = (cx, cy, cz)
                if any(offset[d] and dims[d] == 1 for d in range(3)):
                    continue
                weight = np.ones(rest_free.shape[0])
                for d in range(3):
                    if dims[d] > 1:
                        weight *= frac[:, d] if offset[d] else 1.0 - frac[:, d]
                node = ((base[:, 0] + cx) * dims[1] + (base[:, 1] + cy)) * dims[2] + (base[:, 2] + cz)
                vertex_nodes[:, corner] = np.where(weight > 0.0, node, -1)
                vertex_weights[:, corner] = np.where(weight > 0.0, weight, 0.0)
                corner += 1
    used = np.unique(vertex_nodes[vertex_nodes >= 0])
    renumber = np.full(int(np.prod(dims)), -1, dtype=np.int64)
    renumber[used] = np.arange(used.shape[0])
    vertex_nodes = np.where(vertex_nodes >= 0, renumber[np.maximum(vertex_nodes, 0)], -1)
    springs = np.flatnonzero(assembled & ((free[a] >= 0) | (free[b] >= 0))).astype(np.int64)
    spring_nodes, spring_coefficients = _spring_stencils(
        springs, a, b, free, vertex_nodes, vertex_weights, int(used.shape[0])
    )
    # springs with the same nodes (both ends in one lattice cell: most of them) side by side, so
    # that `spring_hessian` sums a group in a small block of its own and adds it to the matrix once
    order = np.lexsort(spring_nodes.T[::-1])
    springs, spring_nodes, spring_coefficients = springs[order], spring_nodes[order], spring_coefficients[order]
    new_group = np.ones(springs.shape[0], dtype=bool)
    new_group[1:] = (spring_nodes[1:] != spring_nodes[:-1]).any(axis=1)
    group_start = np.append(np.flatnonzero(new_group), springs.shape[0]).astype(np.int64)
    unknowns = 3 * int(used.shape[0])
    width = spring_nodes.shape[1]
    # the first group that starts in the second half of the springs (0: no split)
    second_half = int(np.searchsorted(group_start, springs.shape[0] // 2)) if halves else 0
    second_half = second_half if 0 < second_half < group_start.shape[0] - 1 else 0
    return CoarseSpace(
        vertex_nodes=vertex_nodes.astype(np.int32),
        vertex_weights=vertex_weights,
        count=int(used.shape[0]),
        springs=springs,
        spring_nodes=spring_nodes,
        spring_coefficients=np.ascontiguousarray(spring_coefficients.T),
        group_start=group_start,
        skip=np.zeros(unknowns, dtype=np.bool_),
        forward=np.zeros(unknowns),
        move=np.zeros(unknowns),
        hessian_terms=np.zeros((2, 6, HESSIAN_CHUNK)),
        hessian_sums=np.zeros((2, width * (width + 1) // 2, 6)),
        second_half=second_half,
    )


def _spring_stencils(
    springs: np.ndarray, a: np.ndarray, b: np.ndarray, free: np.ndarray, vertex_nodes: np.ndarray,
    vertex_weights: np.ndarray, count: int,
) -> tuple[np.ndarray, np.ndarray]:
    """(S', W) nodes (ascending, -1 past the last; W <= 16 the most of a spring) and coefficients
    of z_a - z_b per spring, each node once (count: the lattice's nodes). NumPy, not Numba: it
    runs once a model, and a compiled version cost every fresh process (a CI runner, a Dask
    worker) 0.9 s of compiling. A spring whose two ends have the same nodes (both in one lattice
    cell, most of them) takes them with the coefficients w_a - w_b at once; the others are taken
    `STENCIL_CHUNK` at a time: each spring's nodes marked and its coefficients summed in a row of
    `count` slots (so each node appears once, in ascending order: the a side's weight added
    before the b side's), then each row's marked nodes packed to the left."""
    total = springs.shape[0]
    width = 2 * CORNERS
    out_nodes = np.full((total, width), -1, dtype=np.int32)
    out_coefficients = np.zeros((total, width))
    # both ends free with the same nodes, packed to the left (most springs: both ends in one
    # lattice cell): those nodes, coefficients w_a - w_b (the bytes of the sum below)
    # (a vertex's weight is 0 at its -1 nodes); only the corner columns some vertex uses
    corners = int(np.flatnonzero((vertex_nodes >= 0).any(axis=0)).max(initial=-1)) + 1
    row_a, row_b = free[a[springs]], free[b[springs]]
    nodes_a = vertex_nodes[np.maximum(row_a, 0), :corners]
    present = nodes_a >= 0
    same = (row_a >= 0) & (row_b >= 0) & (nodes_a == vertex_nodes[np.maximum(row_b, 0), :corners]).all(axis=1)
    same &= (present[:, 1:] <= present[:, :-1]).all(axis=1)
    out_nodes[:, :corners] = nodes_a
    out_coefficients[:, :corners] = vertex_weights[row_a, :corners] - vertex_weights[row_b, :corners]
    rest = np.flatnonzero(~same)
    out_nodes[rest] = -1
    out_coefficients[rest] = 0.0
    for start in range(0, rest.shape[0], STENCIL_CHUNK):
        chunk = springs[rest[start : start + STENCIL_CHUNK]]
        rows = chunk.shape[0]
        nodes = np.full((rows, width), -1, dtype=np.int64)
        weights = np.zeros((rows, width))
        for side, ends, sign in ((0, a, 1.0), (1, b, -1.0)):
            row_of = free[ends[chunk]]
            has = row_of >= 0
            columns = slice(side * CORNERS, (side + 1) * CORNERS)
            nodes[has, columns] = vertex_nodes[row_of[has]]
            weights[has, columns] = sign * vertex_weights[row_of[has]]
        used = nodes >= 0
        slot = (np.arange(rows)[:, None] * count + nodes)[used]
        present = np.bincount(slot, minlength=rows * count).reshape(rows, count) > 0
        summed = np.bincount(slot, weights=weights[used], minlength=rows * count).reshape(rows, count)
        row, node = np.nonzero(present)  # row by row, nodes ascending
        place = np.arange(row.shape[0]) - np.searchsorted(row, row)  # the node's place in its row
        out_nodes[rest[start + row], place] = node
        out_coefficients[rest[start + row], place] = summed[row, node]
    used = max(int((out_nodes >= 0).sum(axis=1).max(initial=0)), 1)  # the most nodes of a spring: the width kept
    return out_nodes[:, :used], out_coefficients[:, :used]


#: springs whose stencils `_spring_stencils` forms at once (a block of rows x lattice nodes)
STENCIL_CHUNK = 16384


@nb.njit(**FAST)
def spring_hessian(
    x, a, b, rest, weight, springs, spring_nodes, spring_coefficients, group_start, terms, sums, out,
):  # pragma: no cover - compiled
    """out (3C, 3C) += sum over `springs` of (z_a - z_b)(z_a - z_b)^T (x) H_s at positions x (V, 3),
    H_s = k (n n^T + max(0, 1 - L / l) (I - n n^T)): a spring's Hessian with the part across it
    that a compressed spring would make negative left out (positive semi-definite), k = weight (N/m)
    the larger of its tension and compression constants whichever way it is strained (the
    prefactored matrix's weight, `ImplicitSolver.weight`): a Newton step that read a
    compressed spring's soft stiffness (1 % of the tension's) stepped far across its rest length,
    where the spring is stiff, and a strip pushed together flailed at metres a second
    (docs/performance.md, "Soft compression and the coarse Newton steps").

    A group of springs with the same nodes is taken `HESSIAN_CHUNK` springs at a time: the six
    entries of each spring's H_s (xx, yy, zz, xy, xz, yz) into a small buffer, then for each pair of
    the group's nodes p <= q the six sums over the chunk of c_p c_q H_s (coefficients from
    `spring_coefficients` (W, S'), row p the p-th node's), loops over consecutive springs that the
    compiler runs several at a time on data still in the first-level cache. The group's sums go to
    out's upper triangle, mirrored to the lower one at the end. Serial, in a fixed order."""
    width = spring_nodes.shape[1]
    for g in range(group_start.shape[0] - 1):
        first = group_start[g]
        m = 0
        while m < width and spring_nodes[first, m] >= 0:
            m += 1
        pairs = m * (m + 1) // 2
        for pair in range(pairs):
            for e in range(6):
                sums[pair, e] = 0.0
        for start in range(first, group_start[g + 1], HESSIAN_CHUNK):
            stop = min(start + HESSIAN_CHUNK, group_start[g + 1])
            for k in range(start, stop):
                s = springs[k]
                ia = a[s]
                ib = b[s]
                dx = x[ia, 0] - x[ib, 0]
                dy = x[ia, 1] - x[ib, 1]
                dz = x[ia, 2] - x[ib, 2]
                length = np.sqrt(dx * dx + dy * dy + dz * dz)
                stiffness = weight[s]
                j = k - start
                if length < 1e-12 or stiffness == 0.0:
                    for e in range(6):
                        terms[e, j] = 0.0
                    continue
                inv = 1.0 / length
                nx, ny, nz = dx * inv, dy * inv, dz * inv
                across = max(0.0, 1.0 - rest[s] * inv)
                along = stiffness * (1.0 - across)
                iso = stiffness * across
                terms[0, j] = along * nx * nx + iso
                terms[1, j] = along * ny * ny + iso
                terms[2, j] = along * nz * nz + iso
                terms[3, j] = along * nx * ny
                terms[4, j] = along * nx * nz
                terms[5, j] = along * ny * nz
            pair = 0
            for p in range(m):
                for q in range(p, m):
                    sxx = syy = szz = sxy = sxz = syz = 0.0
                    for k in range(start, stop):
                        j = k - start
                        c = spring_coefficients[p, k] * spring_coefficients[q, k]
                        sxx += c * terms[0, j]
                        syy += c * terms[1, j]
                        szz += c * terms[2, j]
                        sxy += c * terms[3, j]
                        sxz += c * terms[4, j]
                        syz += c * terms[5, j]
                    sums[pair, 0] += sxx
                    sums[pair, 1] += syy
                    sums[pair, 2] += szz
                    sums[pair, 3] += sxy
                    sums[pair, 4] += sxz
                    sums[pair, 5] += syz
                    pair += 1
        pair = 0
        for p in range(m):
            r = 3 * spring_nodes[first, p]
            for q in range(p, m):
                t = 3 * spring_nodes[first, q]
                out[r, t] += sums[pair, 0]
                out[r + 1, t + 1] += sums[pair, 1]
                out[r + 2, t + 2] += sums[pair, 2]
                out[r, t + 1] += sums[pair, 3]
                out[r, t + 2] += sums[pair, 4]
                out[r + 1, t + 2] += sums[pair, 5]
                if q > p:  # a block above the diagonal: its lower half too (t > r: nodes ascend)
                    out[r + 1, t] += sums[pair, 3]
                    out[r + 2, t] += sums[pair, 4]
                    out[r + 2, t + 1] += sums[pair, 5]
                pair += 1
    for i in range(out.shape[0]):
        for j in range(i + 1, out.shape[0]):
            out[j, i] = out[i, j]


#: springs whose Hessian entries `spring_hessian` holds at once (6 x 8 bytes each, in the first-level cache)
HESSIAN_CHUNK = 256


@nb.njit(**JIT)
def restrict(grad, vertex_nodes, vertex_weights, out):  # pragma: no cover - compiled
    """out (3C,) = Z^T grad for grad (F, 3)."""
    out[:] = 0.0
    for j in range(vertex_nodes.shape[0]):
        for p in range(CORNERS):
            node = vertex_nodes[j, p]
            if node < 0:
                continue
            w = vertex_weights[j, p]
            out[3 * node] += w * grad[j, 0]
            out[3 * node + 1] += w * grad[j, 1]
            out[3 * node + 2] += w * grad[j, 2]


@nb.njit(**JIT)
def prolong(c, vertex_nodes, vertex_weights, out):  # pragma: no cover - compiled
    """out (F, 3) = Z c for coarse displacements c (3C,)."""
    for j in range(vertex_nodes.shape[0]):
        ox = oy = oz = 0.0
        for p in range(CORNERS):
            node = vertex_nodes[j, p]
            if node < 0:
                continue
            w = vertex_weights[j, p]
            ox += w * c[3 * node]
            oy += w * c[3 * node + 1]
            oz += w * c[3 * node + 2]
        out[j, 0] = ox
        out[j, 1] = oy
        out[j, 2] = oz


@nb.njit(**JIT)
def factor_spd(matrix, skip):  # pragma: no cover - compiled
    """The Cholesky factor of a symmetric positive semi-definite matrix (n, n), in place (lower
    triangle; serial, fixed order), and into skip (n,) bool the pivots left out: a pivot below
    1e-12 of the largest diagonal entry is a direction the matrix does not see, whose row and
    column the solve passes over (`solve_factored`) instead of dividing by nearly zero."""
    n = matrix.shape[0]
    floor = 0.0
    for i in range(n):
        floor = max(floor, matrix[i, i])
    floor *= 1e-12
    for j in range(n):
        skip[j] = False
        d = matrix[j, j]
        for k in range(j):
            d -= matrix[j, k] * matrix[j, k]
        if not d > floor:
            skip[j] = True
            for i in range(j, n):
                matrix[i, j] = 0.0
            continue
        d = np.sqrt(d)
        matrix[j, j] = d
        for i in range(j + 1, n):
            v = matrix[i, j]
            for k in range(j):
                v -= matrix[i, k] * matrix[j, k]
            matrix[i, j] = v / d


@nb.njit(**JIT)
def solve_factored(lower, skip, rhs, y, x):  # pragma: no cover - compiled
    """x (n,) with L L^T x = rhs (n,) for the factor of `factor_spd` (zero where a pivot was left
    out); y (n,): scratch for L y = rhs."""
    n = rhs.shape[0]
    for i in range(n):
        y[i] = 0.0
        if skip[i]:
            continue
        v = rhs[i]
        for k in range(i):
            v -= lower[i, k] * y[k]
        y[i] = v / lower[i, i]
    for i in range(n - 1, -1, -1):
        x[i] = 0.0
        if skip[i]:
            continue
        v = y[i]
        for k in range(i + 1, n):
            v -= lower[k, i] * x[k]
        x[i] = v / lower[i, i]


@nb.njit(**JIT)
def newton_move(grad, vertex_nodes, vertex_weights, lower, skip, gradient, forward, move):  # pragma: no cover
    """A coarse Newton step: gradient (3C,) = Z^T grad for grad (F, 3), the coarse move (3C,)
    solving (Z^T H Z) c = -gradient with the factor `lower`, `skip` of `factor_spd` (forward
    (3C,): the solve's scratch); gradient is left negated. Returns the slope of the fine step Z c,
    grad . Z c = (Z^T grad) . c (negative downhill), without forming it (`prolong` does, for a
    step that is taken)."""
    restrict(grad, vertex_nodes, vertex_weights, gradient)
    for i in range(gradient.shape[0]):  # in place (an array expression compiles far more code)
        gradient[i] = -gradient[i]
    solve_factored(lower, skip, gradient, forward, move)
    slope = 0.0
    for i in range(move.shape[0]):
        slope -= gradient[i] * move[i]
    return slope
