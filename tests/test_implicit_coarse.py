"""The implicit solver's coarse space (`meshdeform.solvers.implicit.coarse`): its lattice, its matrix
against finite differences of the step's gradient, and its dense solve against NumPy's."""

from __future__ import annotations

import numpy as np
from factories import TOP_CORNERS, grid_cloth

from meshdeform.material import KindMaterial, Material
from meshdeform.solvers.implicit import coarse
from meshdeform.solvers.implicit.solver import ImplicitSolver
from meshdeform.solvers.options import ImplicitOptions


def _prepared(n: int = 10, nodes: int = 4) -> tuple[ImplicitSolver, np.ndarray]:
    """A prepared implicit solver on an n x n cloth without bending springs (which the coarse
    matrix leaves out), and the rest positions (V, 3)."""
    model = grid_cloth(n, pins=TOP_CORNERS, material=Material(bending=KindMaterial(enabled=False))).model
    solver = ImplicitSolver(ImplicitOptions(coarse=nodes))
    solver._prepare(model)
    solver._factorise(1.0 / 96.0)
    return solver, np.asarray(model.rest_positions, dtype=np.float64)


def test_the_lattice_interpolates_every_free_vertex() -> None:
    """Each free vertex's weights are a partition of unity, and the lattice reproduces every linear
    field of the rest positions exactly (trilinear interpolation), so it can carry a turn."""
    solver, rest = _prepared()
    space = solver.coarse_space
    assert space is not None
    assert np.allclose(np.where(space.vertex_nodes >= 0, space.vertex_weights, 0.0).sum(axis=1), 1.0)
    free_rest = rest[solver.free_vertices]
    # the nodes' rest positions by least squares from the vertices, then interpolated back
    z = np.zeros((free_rest.shape[0], space.count))
    for corner in range(coarse.CORNERS):
        used = space.vertex_nodes[:, corner] >= 0
        z[np.flatnonzero(used), space.vertex_nodes[used, corner]] += space.vertex_weights[used, corner]
    field = free_rest @ np.array([[0.3, -1.0, 0.2], [2.0, 0.5, -0.7], [0.0, 0.0, 0.0]]) + 0.25
    node_values, *_ = np.linalg.lstsq(z, field, rcond=None)
    assert np.abs(z @ node_values - field).max() < 1e-9


def test_the_coarse_matrix_is_the_step_hessian_seen_through_the_lattice() -> None:
    """Z^T H Z against central differences of the step energy's gradient (`step_energy`, another
    kernel) along each lattice field, on a sheet stretched everywhere (where no part of a spring's
    Hessian is left out)."""
    solver, rest = _prepared()
    space = solver.coarse_space
    rng = np.random.default_rng(3)
    x = rest * 1.08 + rng.normal(0.0, 0.001, rest.shape)
    y = x + rng.normal(0.0, 0.01, rest.shape)
    assert (np.linalg.norm(x[solver.a] - x[solver.b], axis=1) > solver.rest).all()  # every spring stretched
    matrix = solver.coarse_inertia.copy()
    space.add_spring_hessian(x, solver.a, solver.b, solver.rest, solver.weight, matrix)
    assert np.allclose(matrix, matrix.T)
    fv = solver.free_vertices
    eps = 1e-6
    numeric = np.zeros_like(matrix)
    field = np.zeros((fv.shape[0], 3))
    gradient = np.zeros((fv.shape[0], 3))
    restricted = np.zeros(3 * space.count)
    for column in range(3 * space.count):
        unit = np.zeros(3 * space.count)
        unit[column] = 1.0
        coarse.prolong(unit, space.vertex_nodes, space.vertex_weights, field)
        sides = []
        for sign in (1.0, -1.0):
            moved = x.copy()
            moved[fv] += sign * eps * field
            solver._energy(moved, y, gradient)
            coarse.restrict(gradient, space.vertex_nodes, space.vertex_weights, restricted)
            sides.append(restricted.copy())
        numeric[:, column] = (sides[0] - sides[1]) / (2.0 * eps)
    scale = np.abs(matrix).max()
    assert np.abs(numeric - matrix).max() < 1e-5 * scale


def _solve(matrix: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    lower = matrix.copy()
    skip = np.zeros(rhs.shape[0], dtype=np.bool_)
    coarse.factor_spd(lower, skip)
    forward, solution = np.zeros(rhs.shape[0]), np.zeros(rhs.shape[0])
    coarse.solve_factored(lower, skip, rhs, forward, solution)
    return solution


def test_the_dense_solve_matches_numpy_and_leaves_unseen_directions_alone() -> None:
    rng = np.random.default_rng(5)
    a = rng.normal(size=(12, 12))
    spd = a @ a.T + 12 * np.eye(12)
    rhs = rng.normal(size=12)
    assert np.allclose(_solve(spd, rhs), np.linalg.solve(spd, rhs))
    # a direction the matrix does not see (a zero row and column) gets no component
    singular = spd.copy()
    singular[4, :] = 0.0
    singular[:, 4] = 0.0
    solution = _solve(singular, rhs)
    assert solution[4] == 0.0
    keep = np.arange(12) != 4
    assert np.allclose(solution[keep], np.linalg.solve(singular[np.ix_(keep, keep)], rhs[keep]))


def test_a_lattice_no_spring_reaches_builds_and_steps() -> None:
    """Free vertices no spring touches (every spring between pinned vertices): the coarse space
    has no stencil to group, and its Hessian of no spring adds nothing."""
    rest = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.5]])
    free = np.array([-1, -1, 0, 1])  # vertices 0, 1 pinned
    a, b = np.array([0]), np.array([1])
    space = coarse.coarse_space(rest[2:], free, a, b, np.array([True]), 4)
    assert space is not None and space.springs.shape[0] == 0
    matrix = np.eye(3 * space.count)
    space.add_spring_hessian(rest, a, b, np.ones(1), np.ones(1), matrix)
    assert np.array_equal(matrix, np.eye(3 * space.count))
