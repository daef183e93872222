"""The implicit solver's prefactored global matrix: the sparse Cholesky factor against dense solves."""

from __future__ import annotations

import math

import numpy as np
import pytest
from factories import TOP_CORNERS, Pin, grid_cloth

from meshdeform.model import SpringModel, State
from meshdeform.solvers import Control, make_solver
from meshdeform.solvers.implicit import ImplicitSolver, cholesky
from meshdeform.solvers.options import ImplicitOptions
from meshdeform.topology import SpringKind

CORNERS = ("bottom-left", "bottom-right", *TOP_CORNERS)


def dense_matrix(solver: ImplicitSolver, dt: float, model: SpringModel, kinds: tuple[SpringKind, ...]) -> np.ndarray:
    """q M / b^2 + sum_s w_s (e_a - e_b)(e_a - e_b)^T over the free vertices and the model's
    springs of the given kinds, built entry by entry (b = 2 dt / 3; q = 1 + b c
    takes the air damping's drag c = -ln(1 - damping) into the step)."""
    assert solver.a.shape[0] == model.springs.shape[0]  # every spring has a weight: none dropped
    nf = solver.free_vertices.shape[0]
    beta = 2.0 * dt / 3.0
    q = 1.0 - beta * math.log(1.0 - solver.options.damping)
    matrix = np.diag(q * solver.free_mass / beta**2)
    chosen = np.isin(model.kinds, kinds)
    fa, fb = solver.free[model.springs[chosen, 0]], solver.free[model.springs[chosen, 1]]
    for i, j, w in zip(fa, fb, solver.weight[chosen], strict=True):
        if i >= 0:
            matrix[i, i] += w
        if j >= 0:
            matrix[j, j] += w
        if i >= 0 and j >= 0:
            matrix[i, j] -= w
            matrix[j, i] -= w
    assert matrix.shape == (nf, nf)
    return matrix


def factor_solve(solver: ImplicitSolver, rhs: np.ndarray) -> np.ndarray:
    assert solver.factor is not None
    out = np.empty_like(rhs)
    solver.factor.solve(np.ascontiguousarray(rhs), out)
    return out


#: the kinds of spring each `preconditioner` puts into the L-BFGS matrix
MATRIX_SPRINGS = {
    "in_plane": (SpringKind.STRUCTURAL, SpringKind.SHEAR),
    "all": (SpringKind.STRUCTURAL, SpringKind.SHEAR, SpringKind.BENDING),
}


@pytest.mark.parametrize("preconditioner", sorted(MATRIX_SPRINGS))
@pytest.mark.parametrize(("n", "pins", "pinned"), [(7, TOP_CORNERS, 2), (9, (*CORNERS, 40), 5), (5, (), 0)])
def test_factor_matches_a_dense_solve(n: int, pins: tuple[Pin, ...], pinned: int, preconditioner: str) -> None:
    """Hanging from two corners, held at four corners and the centre (vertex 40), free; the
    matrix of the in-plane springs (the default) or of every spring."""
    model = grid_cloth(n, pins=pins).model
    solver = make_solver("implicit", ImplicitOptions(preconditioner=preconditioner))
    assert isinstance(solver, ImplicitSolver)
    dt = 1.0 / 24.0
    solver._prepare(model)
    solver._factorise(dt)
    assert solver.free_vertices.shape[0] == n * n - pinned
    rhs = np.random.default_rng(n).standard_normal((solver.free_vertices.shape[0], 3)) * 10.0
    expected = np.linalg.solve(dense_matrix(solver, dt, model, MATRIX_SPRINGS[preconditioner]), rhs)
    np.testing.assert_allclose(factor_solve(solver, rhs), expected, rtol=1e-9, atol=1e-12 * np.abs(expected).max())


def test_local_global_iterations_factorise_every_spring() -> None:
    """Their fixed point is the step's minimum only with the exact matrix, whatever the preconditioner says."""
    model = grid_cloth(6, pins=TOP_CORNERS).model
    solver = make_solver("implicit", ImplicitOptions(method="local_global", preconditioner="in_plane"))
    assert isinstance(solver, ImplicitSolver)
    solver._prepare(model)
    solver._factorise(1.0 / 24.0)
    rhs = np.random.default_rng(2).standard_normal((solver.free_vertices.shape[0], 3))
    expected = np.linalg.solve(dense_matrix(solver, 1.0 / 24.0, model, MATRIX_SPRINGS["all"]), rhs)
    np.testing.assert_allclose(factor_solve(solver, rhs), expected, rtol=1e-9, atol=1e-12 * np.abs(expected).max())


def test_a_new_time_step_refactorises() -> None:
    model = grid_cloth(6, pins=TOP_CORNERS).model
    solver = make_solver("implicit")
    assert isinstance(solver, ImplicitSolver)
    state = State.at_rest(model)
    control = Control(np.tile([0.0, -9.81, 0.0], (model.vertex_count, 1)))
    solver.step(model, state, 1.0 / 24.0, control)
    solver.step(model, state, 1.0 / 96.0, control)
    rhs = np.random.default_rng(1).standard_normal((solver.free_vertices.shape[0], 3))
    expected = np.linalg.solve(dense_matrix(solver, 1.0 / 96.0, model, MATRIX_SPRINGS["in_plane"]), rhs)
    np.testing.assert_allclose(factor_solve(solver, rhs), expected, rtol=1e-9, atol=1e-12 * np.abs(expected).max())
    assert np.isfinite(state.positions).all()


def test_all_vertices_pinned_steps_without_a_factor() -> None:
    model = grid_cloth(3, pins=range(9)).model
    solver = make_solver("implicit")
    assert isinstance(solver, ImplicitSolver)
    state = State.at_rest(model)
    before = state.positions.copy()
    solver.step(model, state, 1.0 / 24.0, Control(np.tile([0.0, -9.81, 0.0], (9, 1))))
    assert solver.factor is None
    np.testing.assert_array_equal(state.positions, before)


def test_a_step_length_switched_back_to_reuses_its_factor_until_the_anchors_change(monkeypatch) -> None:
    """A run alternating two step lengths (contact and slow steps) factorises each length once and
    then reuses it; a renewal of the anchored rows in between refactorises the length kept aside
    when it is switched back to. Checked against a solver that assembles and factorises at every
    switch: the same positions bit for bit, in fewer factorisations."""
    model = grid_cloth(8, pins=TOP_CORNERS).model
    control = Control(np.tile([0.0, -9.81, 0.0], (model.vertex_count, 1)))
    lengths = [1.0 / 48.0, 1.0 / 96.0] * 4
    factorisations = []
    original = cholesky.CholmodFactor.refactor

    def counted(self, data: np.ndarray) -> None:
        factorisations[-1] += 1
        original(self, data)

    monkeypatch.setattr(cholesky.CholmodFactor, "refactor", counted)
    finals = []
    for keep_aside in (True, False):
        factorisations.append(0)
        solver = make_solver("implicit")
        assert isinstance(solver, ImplicitSolver)
        state = State.at_rest(model)
        for step, dt in enumerate(lengths):
            if not keep_aside:
                solver._other_length = None  # the length before is forgotten: assembled anew
            if step == 4:  # the anchored set renewed (as `_step` does on a contact's rows)
                assert solver.anchors is not None and solver.anchors.update(np.arange(40))
                solver._factor()
            solver.step(model, state, dt, control)
        finals.append(state.positions.copy())
    np.testing.assert_array_equal(finals[0], finals[1])
    # kept aside: each length once, then at the renewal the current one and, switched back, the other
    assert factorisations == [4, len(lengths) + 1]
