"""Tearing and scripted cuts that really open the mesh: vertices split, faces separate, pieces fall.

The model of a tear (the one Obi Cloth and most real-time tearing use, here on polygons):

- A *tearable* spring whose stretch ratio (current / rest length; optionally averaged over the
  last `average` substeps so one-substep spikes do not tear) exceeds its break threshold fails.
  A failing shear or bending spring is simply removed. A failing structural spring (a mesh
  edge u-v) tears the cloth open at one of its ends: that vertex is split by the plane through
  it perpendicular to the spring, so the polygons around it on the far side of the plane get a
  copy of the vertex of their own. The crack runs along mesh edges, never through a polygon,
  and may run on through its tips in the same update.
- A scripted cut (`Cut`) at a time splits, in one go, every vertex near a plane or a swept
  polyline whose polygons lie on both sides of it, optionally only the vertices of a selection.

The package, one concern a module:

- `settings`: `TearRegion`, `TearSettings` (where and when springs break, the update budget).
- `detect`: the compiled per-substep stretch test and the per-model state of the tested springs.
- `crack`: which end of a failing spring splits, by which plane, and how far the crack runs on.
- `cuts`: `Cut` and which vertices a cut splits.
- `corners`: the fixed polygon corner topology and local queries on it.
- `surgery`: `split_vertices` (corners regrouped into copies) and the rebuilt `SpringModel`.
- `output`: the grown output layout (input vertices first, copies appended) and its `Mesh`.
- `tearer`: `Tearer`, what `meshdeform.simulate` calls after each substep, and `TearEvent`.
"""

from meshdeform.tearing.cuts import Cut
from meshdeform.tearing.settings import (
    DEFAULT_BURST,
    DEFAULT_INTERVAL,
    DEFAULT_LOOKAHEAD,
    DEFAULT_TIP,
    TearRegion,
    TearSettings,
    kind_thresholds,
)
from meshdeform.tearing.surgery import mesh_pieces, split_vertices
from meshdeform.tearing.tearer import Tearer, TearEvent

__all__ = [
    "DEFAULT_BURST",
    "DEFAULT_INTERVAL",
    "DEFAULT_LOOKAHEAD",
    "DEFAULT_TIP",
    "Cut",
    "TearEvent",
    "TearRegion",
    "TearSettings",
    "Tearer",
    "kind_thresholds",
    "mesh_pieces",
    "split_vertices",
]
