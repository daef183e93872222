"""The `verlet` solver: Verlet integration, springs relaxed as constraints (solver.py); its kernels (kernels.py)."""

from meshdeform.solvers.verlet.solver import VerletSolver

__all__ = ["VerletSolver"]
