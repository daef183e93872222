"""Solvers behind one interface (`base.Solver`), one folder each, listed in `registry.SOLVERS`.

| name       | what                                                                   |
|------------|------------------------------------------------------------------------|
| `anchor`   | vertices spring back to rest (stress-ball deformer), semi-implicit Euler |
| `verlet`   | Verlet integration, springs relaxed as distance constraints (Jakobsen)  |
| `xpbd`     | compliant distance constraints, small steps (Macklin et al. 2016/2019)  |
| `springs`  | Hooke springs, semi-implicit Euler, stable substeps, Provot strain limit |
| `implicit` | BDF2 steps minimised by L-BFGS on a prefactored projective-dynamics matrix |
"""

from meshdeform.solvers.base import Control, Solver, SolverOptions
from meshdeform.solvers.options import (
    AnchorOptions,
    ImplicitOptions,
    SpringsOptions,
    VerletOptions,
    XPBDOptions,
)
from meshdeform.solvers.registry import SOLVERS, make_solver, solver_class, solver_options

__all__ = [
    "SOLVERS",
    "AnchorOptions",
    "Control",
    "ImplicitOptions",
    "Solver",
    "SolverOptions",
    "SpringsOptions",
    "VerletOptions",
    "XPBDOptions",
    "make_solver",
    "solver_class",
    "solver_options",
]
