"""The implicit solver's preconditioner on the motions that keep its held contacts
(`meshdeform.solvers.implicit.held`) against the constrained minimum solved densely."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from meshdeform.solvers.implicit import cholesky
from meshdeform.solvers.implicit.held import HeldContacts


def grid_matrix(n: int, seed: int) -> tuple[np.ndarray, cholesky.CholmodFactor]:
    """A projective-dynamics-like SPD matrix on an n x n grid (random positive spring weights,
    a small mass term) and its factor: dense (N, N) and factored."""
    rng = np.random.default_rng(seed)
    index = np.arange(n * n).reshape(n, n)
    edges = np.concatenate([
        np.stack([index[:, :-1].ravel(), index[:, 1:].ravel()], axis=1),
        np.stack([index[:-1, :].ravel(), index[1:, :].ravel()], axis=1),
        np.stack([index[:-1, :-1].ravel(), index[1:, 1:].ravel()], axis=1),
    ])
    weights = rng.uniform(50.0, 500.0, edges.shape[0])
    dense = np.diag(rng.uniform(0.5, 2.0, n * n))
    for (i, j), w in zip(edges, weights, strict=True):
        dense[i, i] += w
        dense[j, j] += w
        dense[i, j] -= w
        dense[j, i] -= w
    lower = sp.csc_matrix(np.tril(dense))
    lower.sort_indices()
    factor = cholesky.CholmodFactor(lower.indptr.astype(np.int32), lower.indices.astype(np.int32), lower.data)
    return dense, factor


def constrained_solve(dense: np.ndarray, g: np.ndarray, constraints: list[tuple[int, np.ndarray]]) -> np.ndarray:
    """argmin 1/2 z.(A (x) I3) z - g.z subject to n . z_r = 0 for each (r, n): the KKT system of
    the 3N unknowns and the multipliers, solved densely."""
    n = dense.shape[0]
    big = np.kron(dense, np.eye(3))
    c = np.zeros((len(constraints), 3 * n))
    for k, (row, normal) in enumerate(constraints):
        c[k, 3 * row : 3 * row + 3] = normal
    kkt = np.block([[big, c.T], [c, np.zeros((c.shape[0], c.shape[0]))]])
    solution = np.linalg.solve(kkt, np.concatenate([g.ravel(), np.zeros(c.shape[0])]))
    return solution[: 3 * n].reshape(n, 3)


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def test_the_held_solve_is_the_constrained_minimum_and_keeps_every_held_contact() -> None:
    """Rows held along tilted normals and rows held along every axis (one in both lists): the
    corrected solve is the KKT system's answer, moves no held row along its constraint, and the
    columns kept from the first call give the same answer again."""
    dense, factor = grid_matrix(7, seed=1)
    rng = np.random.default_rng(2)
    g = rng.normal(size=(49, 3))
    rows = np.array([3, 17, 30, 48])
    normals = np.array([unit(rng.normal(size=3)) for _ in rows])
    fixed = np.array([17, 24])
    direction = np.zeros((49, 3))
    factor.solve(g, direction)
    unconstrained = direction.copy()
    held = HeldContacts(49)
    held.project(factor, direction, rows, normals, fixed)
    constraints = [(r, n) for r, n in zip(rows, normals, strict=True) if r not in fixed]
    constraints += [(r, axis) for r in fixed for axis in np.eye(3)]
    expected = constrained_solve(dense, g, constraints)
    assert np.abs(direction - expected).max() < 1e-9 * np.abs(expected).max()
    for row, normal in constraints:
        assert abs(direction[row] @ normal) < 1e-12 * np.abs(unconstrained).max()
    # the free rows beside the held ones moved: the correction is not a filter of those rows alone
    assert np.abs(direction - unconstrained)[[4, 16, 18]].max() > 1e-3 * np.abs(unconstrained).max()
    again = unconstrained.copy()
    held.project(factor, again, rows, normals, fixed)
    assert np.array_equal(again, direction)


def test_more_held_rows_than_its_capacity_keeps_those_pushed_hardest_against_their_contacts() -> None:
    """With room for two constraints, of three rows held along +y the two that the plain solve moves the most
    against it are kept exactly, and the answer is the constrained minimum with those two alone."""
    dense, factor = grid_matrix(5, seed=3)
    g = np.zeros((25, 3))
    g[[0, 12, 24], 1] = [1.0, 3.0, 2.0]  # row 12 pushed hardest, then 24, then 0
    direction = np.zeros((25, 3))
    factor.solve(g, direction)
    held = HeldContacts(25)
    held.capacity = 2
    up = np.array([0.0, 1.0, 0.0])
    held.project(factor, direction, np.array([0, 12, 24]), np.tile(up, (3, 1)), np.zeros(0, dtype=np.int64))
    expected = constrained_solve(dense, g, [(12, up), (24, up)])
    assert np.abs(direction - expected).max() < 1e-9 * np.abs(expected).max()


def test_a_call_computes_columns_for_at_most_its_new_rows_the_ones_pushed_hardest_first() -> None:
    """With room for one new row a call (a large cloth's bound on its column solves), of three
    rows held along +y the first call keeps the one the plain solve moves the most against it;
    the next call keeps it and adds the one of the others it moves the most: each answer the
    constrained minimum with those rows alone."""
    dense, factor = grid_matrix(5, seed=3)
    g = np.zeros((25, 3))
    g[[0, 12, 24], 1] = 3.0
    g[24, 0] = 1.0
    plain = np.zeros((25, 3))
    factor.solve(g, plain)
    held = HeldContacts(25)
    held.new_rows = 1
    rows, normals = np.array([0, 12, 24]), np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    against = np.abs(np.einsum("ij,ij->i", plain[rows], normals))
    assert against[1] > 1.5 * against[2] > 1.5 * against[0]  # 12 moved the most against its normal, then 24
    for kept in ([(12, normals[1])], [(12, normals[1]), (24, normals[2])]):
        direction = plain.copy()
        held.project(factor, direction, rows, normals, np.zeros(0, dtype=np.int64))
        expected = constrained_solve(dense, g, kept)
        assert np.abs(direction - expected).max() < 1e-9 * np.abs(expected).max()
