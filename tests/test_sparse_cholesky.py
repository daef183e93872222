"""The implicit solver's sparse Cholesky factor (`meshdeform.solvers.implicit.cholesky`) against
SciPy's sparse LU solve (SuperLU: another algorithm, another code), on matrices large enough for
the two threads' shares and on the small and odd ones."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.sparse import coo_matrix, csc_matrix, tril
from scipy.sparse.linalg import spsolve

from meshdeform.solvers.implicit.cholesky import MIN_PARALLEL_ROWS, SparseCholesky


def spring_matrix(edges: np.ndarray, n: int, rng: np.random.Generator) -> csc_matrix:
    """A mass-spring system matrix: positive diagonal masses plus w (e_a - e_b)(e_a - e_b)^T for
    each edge (a, b) with a random weight w > 0 (n, n, symmetric positive definite)."""
    weights = rng.uniform(0.5, 2.0, edges.shape[0])
    a, b = edges[:, 0], edges[:, 1]
    rows = np.concatenate([np.arange(n), a, b, a, b])
    cols = np.concatenate([np.arange(n), a, b, b, a])
    vals = np.concatenate([rng.uniform(0.01, 0.1, n), weights, weights, -weights, -weights])
    return coo_matrix((vals, (rows, cols)), shape=(n, n)).tocsc()


def lower(matrix: csc_matrix) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The lower triangle as CSC arrays, each column's rows ascending (its diagonal first)."""
    low = tril(matrix).tocsc()
    low.sort_indices()
    return low.indptr, low.indices, low.data


def grid(side: int) -> tuple[np.ndarray, np.ndarray]:
    """A side x side sheet's points (n, 3) and its structural and shear springs (E, 2)."""
    index = np.arange(side * side).reshape(side, side)
    pairs = [
        (index[:, :-1], index[:, 1:]), (index[:-1, :], index[1:, :]),
        (index[:-1, :-1], index[1:, 1:]), (index[:-1, 1:], index[1:, :-1]),
    ]
    edges = np.concatenate([np.stack([p.ravel(), q.ravel()], axis=1) for p, q in pairs])
    u, v = np.meshgrid(np.linspace(0, 1, side), np.linspace(0, 1, side))
    return np.stack([u.ravel(), np.zeros(side * side), v.ravel()], axis=1), edges


def solve_both(matrix: csc_matrix, points: np.ndarray, rhs: np.ndarray, threads: int) -> np.ndarray:
    factor = SparseCholesky(*lower(matrix), points, threads=threads)
    out = np.empty_like(rhs)
    factor.solve(rhs, out)
    return out


@pytest.mark.parametrize("threads", [1, 2])
def test_a_large_sheet_solves_like_superlu(threads: int) -> None:
    """90 x 90 (8 100 rows): the two halves of the top split are factorised and solved apart."""
    points, edges = grid(90)
    assert points.shape[0] >= MIN_PARALLEL_ROWS
    rng = np.random.default_rng(1)
    matrix = spring_matrix(edges, points.shape[0], rng)
    rhs = rng.standard_normal((points.shape[0], 3))
    expected = np.stack([spsolve(matrix, rhs[:, k]) for k in range(3)], axis=1)
    got = solve_both(matrix, points, rhs, threads)
    np.testing.assert_allclose(got, expected, rtol=1e-8, atol=1e-10 * np.abs(expected).max())


def test_one_thread_and_two_give_the_same_bytes() -> None:
    points, edges = grid(80)
    rng = np.random.default_rng(2)
    matrix = spring_matrix(edges, points.shape[0], rng)
    rhs = rng.standard_normal((points.shape[0], 3))
    one, two = solve_both(matrix, points, rhs, 1), solve_both(matrix, points, rhs, 2)
    assert one.tobytes() == two.tobytes()


def test_a_closed_surface_and_a_refactorisation() -> None:
    """An icosphere's edges (a closed surface: the cuts go through it in 3D), then new values on
    the same pattern through `refactor`; the right-hand side may be the output array."""
    sphere = trimesh.creation.icosphere(subdivisions=5)  # 10 242 vertices
    points, edges = np.asarray(sphere.vertices), np.asarray(sphere.edges_unique)
    rng = np.random.default_rng(3)
    first = spring_matrix(edges, points.shape[0], rng)
    factor = SparseCholesky(*lower(first), points)
    second = spring_matrix(edges, points.shape[0], rng)
    indptr, indices, data = lower(second)
    assert factor.has_pattern(indptr, indices)
    factor.refactor(data)
    rhs = rng.standard_normal((points.shape[0], 3))
    expected = np.stack([spsolve(second, rhs[:, k]) for k in range(3)], axis=1)
    factor.solve(rhs, rhs)
    np.testing.assert_allclose(rhs, expected, rtol=1e-8, atol=1e-10 * np.abs(expected).max())


@pytest.mark.parametrize("n", [1, 2, 7])
def test_small_and_diagonal_matrices(n: int) -> None:
    rng = np.random.default_rng(n)
    diagonal = csc_matrix(np.diag(rng.uniform(1.0, 3.0, n)))
    rhs = rng.standard_normal((n, 3))
    got = solve_both(diagonal, rng.standard_normal((n, 3)), rhs, 2)
    np.testing.assert_allclose(got, rhs / diagonal.diagonal()[:, None], rtol=1e-14)


def test_two_disconnected_pieces() -> None:
    """Two sheets side by side with no spring between them: the halves may have no separator."""
    points, edges = grid(60)
    other = points + np.array([2.0, 0.0, 0.0])
    points = np.concatenate([points, other])
    edges = np.concatenate([edges, edges + other.shape[0]])
    rng = np.random.default_rng(4)
    matrix = spring_matrix(edges, points.shape[0], rng)
    rhs = rng.standard_normal((points.shape[0], 3))
    expected = np.stack([spsolve(matrix, rhs[:, k]) for k in range(3)], axis=1)
    np.testing.assert_allclose(solve_both(matrix, points, rhs, 2), expected, rtol=1e-8,
                               atol=1e-10 * np.abs(expected).max())


def test_a_matrix_that_is_not_positive_definite_is_refused() -> None:
    points, edges = grid(6)
    matrix = spring_matrix(edges, points.shape[0], np.random.default_rng(5)).tolil()
    matrix[10, 10] = -1.0
    with pytest.raises(ValueError, match="not positive definite"):
        SparseCholesky(*lower(matrix.tocsc()), points)
