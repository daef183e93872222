"""Mesh input and output: `load` and `save` pick the format from the file suffix.

OBJ and PLY are read into a `Mesh` with polygons and vertex order kept; broken files raise
`MeshLoadError` with one line naming the file (and the line or element row) and what is wrong.
For writing many frames of one mesh, use `ObjWriter` / `PlyWriter` (static parts built once).
Point caches of deforming colliders are read by `meshdeform.io.caches` (not imported here: it takes
the PC2 and MDD layouts from `meshdeform.export`, which imports this package).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from meshdeform.errors import ExportError, MeshLoadError
from meshdeform.io.obj import read_obj
from meshdeform.io.obj_writer import ObjWriter, write_obj
from meshdeform.io.ply import read_ply
from meshdeform.io.ply_writer import PlyWriter, write_ply
from meshdeform.mesh import Mesh

__all__ = [
    "MESH_SUFFIXES",
    "ObjWriter",
    "PlyWriter",
    "load",
    "read_obj",
    "read_ply",
    "save",
    "write_obj",
    "write_ply",
    "writer_for",
]

MESH_SUFFIXES = (".obj", ".ply")


def _suffix(path: str | os.PathLike[str]) -> str:
    return Path(path).suffix.lower()


def load(path: str | os.PathLike[str]) -> Mesh:
    """Read an OBJ or PLY file (suffix, any case) into a Mesh; MeshLoadError if it cannot be read."""
    p = Path(path)
    suffix = _suffix(p)
    if p.is_dir():
        raise MeshLoadError(f"{path}: is a directory, not a mesh file")
    if suffix not in MESH_SUFFIXES:
        shown = f"'{p.suffix}'" if p.suffix else "no extension"
        raise MeshLoadError(f"{path}: unknown mesh file extension ({shown}); expected .obj or .ply")
    if not p.exists():
        raise MeshLoadError(f"{path}: no such file")
    return read_obj(p) if suffix == ".obj" else read_ply(p)


def writer_for(path: str | os.PathLike[str], mesh: Mesh) -> ObjWriter | PlyWriter:
    """The frame writer matching the suffix of `path` (for writing many frames of one mesh)."""
    suffix = _suffix(path)
    if suffix == ".obj":
        return ObjWriter(mesh)
    if suffix == ".ply":
        return PlyWriter(mesh)
    raise ExportError(f"{path}: unknown mesh file extension '{Path(path).suffix}'; expected .obj or .ply")


def save(path: str | os.PathLike[str], mesh: Mesh, positions: np.ndarray | None = None) -> None:
    """Write `mesh` (with other `positions` if given) as OBJ or PLY by suffix, atomically."""
    writer_for(path, mesh).write(path, positions)
