"""The `anchor` solver (stress ball, solver.py); it runs the explicit step of `springs` (springs/kernels.py)."""

from meshdeform.solvers.anchor.solver import AnchorSolver

__all__ = ["AnchorSolver"]
