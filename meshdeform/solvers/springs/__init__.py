"""The `springs` solver: explicit Hooke springs (solver.py, with the explicit base `anchor` shares); kernels.py."""

from meshdeform.solvers.springs.solver import ExplicitSolver, SpringsSolver

__all__ = ["ExplicitSolver", "SpringsSolver"]
