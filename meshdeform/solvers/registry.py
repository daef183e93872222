"""The solver registry: every solver by its name, one line each.

Adding a solver is a folder `meshdeform/solvers/<name>/` (solver.py: the class; kernels.py: its
Numba kernels) plus its line below (and the import above it); nothing else lists solvers.
"""

from __future__ import annotations

from meshdeform.errors import MeshdeformError
from meshdeform.solvers.anchor.solver import AnchorSolver
from meshdeform.solvers.base import Solver
from meshdeform.solvers.implicit.solver import ImplicitSolver
from meshdeform.solvers.options import SolverOptions
from meshdeform.solvers.springs.solver import SpringsSolver
from meshdeform.solvers.verlet.solver import VerletSolver
from meshdeform.solvers.xpbd.solver import XPBDSolver

#: the solver a run uses when none is named (`Settings`, a recipe's `[simulation] solver`): implicit,
#: whose global solve keeps a production-resolution cloth at its material's stretch, smooth, where
#: the position solvers' few sweeps leave it stretched and rough, at the same speed where nothing
#: touches the cloth (docs/performance.md, "A coarse space for the implicit solver")
DEFAULT_SOLVER = "implicit"
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


def solver_options(cls: type[Solver], options: SolverOptions | None) -> SolverOptions:
    """`options` checked for solver `cls`, or its defaults (`cls.options_class()`) when None.

    Options of another class (another solver's) raise MeshdeformError: no solver ignores options
    meant for another.
    """
    if options is None:
        return cls.options_class()
    if type(options) is not cls.options_class:
        raise MeshdeformError(
            f"solver {cls.name!r} takes {cls.options_class.__name__}, not {type(options).__name__}"
        )
    return options


def make_solver(name: str, options: SolverOptions | None = None) -> Solver:
    """A solver instance by registry name, with `options` (its `options_class`) or its defaults.

    Unknown names raise MeshdeformError listing the known ones; options of another solver's class
    raise MeshdeformError too.
    """
    cls = solver_class(name)
    return cls(solver_options(cls, options))
