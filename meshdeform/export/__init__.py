"""Mesh-sequence exporters, one module per format, behind one registry.

| name | files in the result folder | topology change (tearing) |
|---|---|---|
| obj  | `frames/frame_0001.obj` ...                | follows it |
| ply  | `frames/frame_0001.ply` ...                | follows it |
| pc2  | `cache.pc2`                                | refused: point caches need a fixed vertex count |
| mdd  | `cache.mdd`                                | refused: point caches need a fixed vertex count |
| usd  | `scene.usdc` (ascii: `.usda`; layers="split": + `rest.usdc`, `animation.usdc`) | topology time samples |
| vtk  | `vtk/frame_0001.vtp` ... + `scene.pvd`     | follows it |
| xdmf | `scene.xdmf` (inline XML data)             | refused: one fixed mesh |
| npz  | `positions.npz`                            | refused: one fixed vertex count |
| gltf | `scene.glb` (morph targets)                | refused: morph targets need a fixed topology |
| vat  | `vat/positions.png`, `normals.png`, `mesh.obj`, `mesh.glb`, `vat.json` | refused: one fixed vertex count |

Every exporter is streaming: `open(ctx)` once, `write(frame)` per frame, `close()` to finalise
(or `abort()` to remove everything written), and files appear under their final names only
when complete. `ExportSession` drives several at once.
"""

from meshdeform.export.base import (
    UP_AXES,
    BaseExporter,
    ExportContext,
    Exporter,
    FrameData,
    frame_file_name,
    quarter_turns,
    turn_about_x,
)
from meshdeform.export.registry import EXPORTERS, ExportSession, make_exporter

__all__ = [
    "EXPORTERS",
    "UP_AXES",
    "BaseExporter",
    "ExportContext",
    "ExportSession",
    "Exporter",
    "FrameData",
    "frame_file_name",
    "make_exporter",
    "quarter_turns",
    "turn_about_x",
]
