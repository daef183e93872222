"""The `implicit` solver: projective dynamics with BDF2 (solver.py), its Numba kernels (kernels.py)."""

from meshdeform.solvers.implicit.solver import ImplicitSolver

__all__ = ["ImplicitSolver"]
