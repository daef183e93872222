"""The solver registry: every solver by its name, one line each.

Adding a solver is a folder `meshdeform/solvers/<name>/` (solver.py: the class; kernels.py: its
Numba kernels) plus its line below (and the import above it); nothing else lists solvers.
"""

from __future__ import annotations

from meshdeform.errors import MeshdeformError
from meshdeform.solvers.anchor.solver import AnchorSolver
from meshdeform.solvers.base import Solver, SolverOptions
from meshdeform.solvers.implicit.solver import ImplicitSolver
from meshdeform.solvers.springs.solver import SpringsSolver
from meshdeform.solvers.verlet.solver import VerletSolver
from meshdeform.solvers.xpbd.solver import XPBDSolver

#: solver name (`Solver.name`) -> class
SOLVERS: dict[str, type[Solver]] = {
    cls.name: cls
    for cls in (
        AnchorSolver,
        VerletSolver,
        XPBDSolver,
        SpringsSolver,
        ImplicitSolver,
    )
}


def solver_class(name: str) -> type[Solver]:
    """The registered solver class; unknown names raise MeshdeformError listing the known ones."""
    try:
        return SOLVERS[name]
    except KeyError:
        raise MeshdeformError(f"unknown solver {name!r}; choose one of: {', '.join(sorted(SOLVERS))}") from None


def make_solver(name: str, options: SolverOptions | None = None) -> Solver:
    """A solver instance by registry name; unknown names raise MeshdeformError listing the known ones."""
    return solver_class(name)(options or SolverOptions())
