"""Solvers behind one interface; importing this package registers the built-in ones."""

from meshdeform.solvers import verlet  # noqa: F401
from meshdeform.solvers.base import SOLVERS, Control, Solver, SolverOptions, make_solver

__all__ = ["SOLVERS", "Control", "Solver", "SolverOptions", "make_solver"]
