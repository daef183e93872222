"""The `xpbd` solver: compliant distance constraints in small steps (solver.py), its Numba kernels (kernels.py)."""

from meshdeform.solvers.xpbd.solver import XPBDSolver

__all__ = ["XPBDSolver"]
