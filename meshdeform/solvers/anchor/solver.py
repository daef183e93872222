"""The stress-ball deformer (Catlike Coding's "Mesh Deformation"): vertices spring back to rest.

Each vertex is pulled toward its anchor by an acceleration -K s (x - anchor), K =
`options.anchor_stiffness` (the original's "spring force", 1/s^2) and s = `options.uniform_scale`
(the original multiplies the displacement by the object's uniform scale), with the original's
damping `options.anchor_damping` (velocities relative to the anchors decay as exp(-c t); c = 5/s
as in the original makes the default stress ball nearly critically damped, a hanging cloth
rests within about 3 s), air damping `options.damping` and semi-implicit Euler (v += a dt,
x += v dt). Impacts come from outside as
accelerations (or a velocity kick dv as dv / dt over one substep) in `Control`.

Anchors (`options.anchor_frame`): "world" (default) uses the rest positions, as the original,
so a struck ball springs back to its rest shape and place; "centroid" moves them with the
centre of mass, so anchors hold the shape and not the place: the body keeps its momentum (falls
freely under gravity, drifts after an impact) while its shape springs back; "auto" is "world"
when any vertex is pinned (pins hold the place) and "centroid" otherwise. Under gravity in the
world frame a free body hangs below its rest place by g / (anchor_stiffness * uniform_scale).
With `options.neighbour_springs` the mesh's springs act as well (exactly as in the
`springs` solver, with its stability splitting and optional strain limit), so that pinned
vertices hold the rest of the mesh too.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from meshdeform.errors import MeshdeformError
from meshdeform.model import SpringModel
from meshdeform.solvers.options import ANCHOR_FRAMES, AnchorOptions
from meshdeform.solvers.springs.solver import ExplicitSolver


class AnchorSolver(ExplicitSolver):
    """Vertices spring back to their rest positions (optionally plus neighbour springs)."""

    name: ClassVar[str] = "anchor"
    summary: ClassVar[str] = "vertices spring back to their rest shape (stress-ball deformer), semi-implicit Euler"
    hint: ClassVar[str] = "lower anchor_stiffness or spring stiffness, or keep stable_substeps on"
    options_class: ClassVar[type[AnchorOptions]] = AnchorOptions
    default_substeps: ClassVar[int] = 8

    def __init__(self, options: AnchorOptions) -> None:
        if options.anchor_frame not in ANCHOR_FRAMES:
            raise MeshdeformError(
                f"unknown anchor_frame {options.anchor_frame!r}; choose one of: {', '.join(ANCHOR_FRAMES)}"
            )
        super().__init__(options)
        self.use_springs = bool(options.neighbour_springs)
        self.anchor_damping = max(float(options.anchor_damping), 0.0)

    def _anchor(self, model: SpringModel) -> tuple[float, np.ndarray, bool, np.ndarray]:
        k = max(float(self.options.anchor_stiffness), 0.0) * float(self.options.uniform_scale)
        frame = self.options.anchor_frame
        follow = frame == "centroid" or (frame == "auto" and not bool(np.any(model.pinned)))
        rest = np.ascontiguousarray(model.rest_positions, dtype=np.float64)
        mass = np.asarray(model.mass, dtype=np.float64)
        total = float(mass.sum())
        center = (mass @ rest) / total if total > 0 else np.zeros(3)
        return k, rest, follow, np.ascontiguousarray(center, dtype=np.float64)
