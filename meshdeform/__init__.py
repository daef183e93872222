"""meshdeform: mass-spring deformation of polygon meshes, as a library.

    mesh = meshdeform.load("flag.obj")
    model = meshdeform.SpringModel.from_mesh(mesh, meshdeform.Material(), pinned_input=mask)
    for frame in meshdeform.simulate(model, meshdeform.Scene(), meshdeform.Settings(solver="xpbd")):
        frame.positions   # (V, 3) in the input's vertex order

Names are imported lazily so that `import meshdeform` stays cheap for command-line help.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "load": "meshdeform.io",
    "save": "meshdeform.io",
    "Mesh": "meshdeform.mesh",
    "grid_mesh": "meshdeform.mesh",
    "Material": "meshdeform.material",
    "KindMaterial": "meshdeform.material",
    "SpringModel": "meshdeform.model",
    "State": "meshdeform.model",
    "Scene": "meshdeform.scene",
    "Settings": "meshdeform.simulate",
    "Frame": "meshdeform.simulate",
    "simulate": "meshdeform.simulate",
    "SolverOptions": "meshdeform.solvers.options",
    "make_solver": "meshdeform.solvers.registry",
    "build_springs": "meshdeform.topology",
    "Tearer": "meshdeform.tearing",
    "TearRegion": "meshdeform.tearing",
    "TearSettings": "meshdeform.tearing",
    "Cut": "meshdeform.tearing",
    "MeshdeformError": "meshdeform.errors",
    "MeshLoadError": "meshdeform.errors",
    "RecipeError": "meshdeform.errors",
    "SimulationDiverged": "meshdeform.errors",
    "ExportError": "meshdeform.errors",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'meshdeform' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return __all__
