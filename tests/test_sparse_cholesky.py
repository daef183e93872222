"""The implicit solver's sparse Cholesky factor (`meshdeform.solvers.implicit.cholesky`) against
SciPy's sparse LU solve (SuperLU: another algorithm, another code), on matrices large enough for
the two threads' shares and on the small and odd ones."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.sparse import coo_matrix, csc_matrix, tril
from scipy.sparse.linalg import spsolve

from meshdeform.solvers.implicit import cholesky
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


def test_a_single_precision_factor_solves_within_its_rounding_on_any_thread_count() -> None:
    """`single`: L kept in float32 for the solves (the L-BFGS preconditioner's): the solution of
    a matrix within about 1e-7 relative of A, the same bytes on one thread and two, after a
    refactorisation too."""
    points, edges = grid(90)
    rng = np.random.default_rng(4)
    matrix = spring_matrix(edges, points.shape[0], rng)
    rhs = rng.standard_normal((points.shape[0], 3))
    expected = np.stack([spsolve(matrix, rhs[:, k]) for k in range(3)], axis=1)
    solutions = []
    for threads in (1, 2):
        factor = SparseCholesky(*lower(matrix), points, threads=threads, single=True)
        factor.refactor(lower(matrix)[2])
        solutions.append(np.empty_like(rhs))
        factor.solve(rhs, solutions[-1])
    assert solutions[0].tobytes() == solutions[1].tobytes()
    error = np.abs(solutions[0] - expected).max() / np.abs(expected).max()
    assert 1e-12 < error < 1e-5  # single precision's rounding, not double's
    residual = np.abs(matrix @ solutions[0] - rhs).max() / np.abs(rhs).max()
    assert residual < 1e-5


def test_one_thread_and_two_give_the_same_bytes() -> None:
    points, edges = grid(80)
    rng = np.random.default_rng(2)
    matrix = spring_matrix(edges, points.shape[0], rng)
    rhs = rng.standard_normal((points.shape[0], 3))
    one, two = solve_both(matrix, points, rhs, 1), solve_both(matrix, points, rhs, 2)
    assert one.tobytes() == two.tobytes()


def test_a_separator_too_large_to_split_is_factorised_on_one_thread(monkeypatch) -> None:
    """Past `SPLIT_SEPARATOR_ROWS` the top separator's rows are factorised whole after both
    halves (no (2, T, T) sums): the same solution as SuperLU's, the same bytes on one thread or two,
    and within rounding of the split separator's."""
    points, edges = grid(80)
    rng = np.random.default_rng(3)
    matrix = spring_matrix(edges, points.shape[0], rng)
    rhs = rng.standard_normal((points.shape[0], 3))
    split = solve_both(matrix, points, rhs, 2)
    monkeypatch.setattr(cholesky, "SPLIT_SEPARATOR_ROWS", 0)
    one, two = solve_both(matrix, points, rhs, 1), solve_both(matrix, points, rhs, 2)
    assert one.tobytes() == two.tobytes()
    expected = np.stack([spsolve(matrix, rhs[:, k]) for k in range(3)], axis=1)
    np.testing.assert_allclose(two, expected, rtol=1e-8, atol=1e-10 * np.abs(expected).max())
    np.testing.assert_allclose(two, split, rtol=1e-10, atol=1e-12 * np.abs(split).max())


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


@pytest.mark.parametrize("n", [0, 1, 2, 7])
def test_small_and_diagonal_matrices(n: int) -> None:
    """Split however small (`parallel_rows=0`): halves or a separator may be empty."""
    rng = np.random.default_rng(n)
    diagonal = csc_matrix(np.diag(rng.uniform(1.0, 3.0, n)), shape=(n, n))
    rhs = rng.standard_normal((n, 3))
    factor = SparseCholesky(*lower(diagonal), rng.standard_normal((n, 3)), parallel_rows=0)
    got = np.empty_like(rhs)
    factor.solve(rhs, got)
    np.testing.assert_allclose(got, rhs / diagonal.diagonal()[:, None], rtol=1e-14)


def odd_graphs() -> dict[str, tuple[np.ndarray, int]]:
    """Edges (E, 2) and vertex counts of graphs unlike a sheet."""
    star = np.stack([np.zeros(30, dtype=np.int64), np.arange(1, 31)], axis=1)
    complete = np.array([(i, j) for i in range(12) for j in range(i + 1, 12)])
    path = np.stack([np.arange(40), np.arange(1, 41)], axis=1)
    pieces = np.concatenate([path[:10], path[20:30]])  # two paths and isolated vertices
    return {"star": (star, 31), "complete": (complete, 12), "path": (path, 41), "pieces": (pieces, 41)}


@pytest.mark.parametrize("name", sorted(odd_graphs()))
def test_odd_graphs_split_however_small_solve_alike_on_one_thread_and_two(name: str) -> None:
    edges, n = odd_graphs()[name]
    rng = np.random.default_rng(7)
    matrix = spring_matrix(edges, n, rng)
    points = rng.standard_normal((n, 3))
    points[: n // 3] = points[0]  # a third of the rows at one point: ties in every axis
    rhs = rng.standard_normal((n, 3))
    solutions = []
    for threads in (1, 2):
        factor = SparseCholesky(*lower(matrix), points, threads=threads, parallel_rows=0)
        solutions.append(np.empty_like(rhs))
        factor.solve(rhs, solutions[-1])
    assert solutions[0].tobytes() == solutions[1].tobytes()
    np.testing.assert_allclose(matrix @ solutions[0], rhs, atol=1e-10 * np.abs(rhs).max())


def test_malformed_input_is_refused_before_any_kernel_reads_it() -> None:
    """The kernels index with these arrays unchecked (Numba): a wrong shape, an upper-triangle
    or repeated entry, or a point count other than the rows' is refused."""
    points, edges = grid(4)
    indptr, indices, data = lower(spring_matrix(edges, points.shape[0], np.random.default_rng(8)))
    SparseCholesky(indptr, indices, data, points)  # well formed
    upper = indices.copy()
    upper[indptr[1] - 1] = 0  # a row above its column's diagonal
    repeated = indices.copy()
    repeated[indptr[0] + 2] = repeated[indptr[0] + 1]
    cases = [
        (indptr, indices, data, points[:-1]),
        (indptr, indices, data[:-1], points),
        (indptr, upper, data, points),
        (indptr, repeated, data, points),
    ]
    for case in cases:
        with pytest.raises(ValueError):
            SparseCholesky(*case)
    factor = SparseCholesky(indptr, indices, data, points)
    with pytest.raises(ValueError):
        factor.refactor(np.where(np.arange(data.shape[0]) == 3, np.nan, data))


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
