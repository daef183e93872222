"""An independent decoder of the `vat/` folder: only `vat.json`'s contract and VTK's PNG reader (libpng).

Nothing of meshdeform.export.vat is used: the texel layout and the encodings are the ones the issue
states (x = v % width, y = f * rows_per_frame + v // width, row 0 the top row of the image;
position = bounds_min + value / 65535 * (bounds_max - bounds_min); n = value / 65535 * 2 - 1).
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np


def png_header(path: Path) -> tuple[int, int, int, int]:
    """(width, height, bit depth, colour type) from the PNG's IHDR bytes (its published layout)."""
    data = path.read_bytes()[:33]
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR"
    width, height, depth, colour = struct.unpack(">IIBB", data[16:26])
    return width, height, depth, colour


def read_png16(path: Path) -> np.ndarray:
    """The texels (height, width, channels) uint16 of a 16-bit PNG, row 0 the top row of the image."""
    import vtk
    from vtk.util.numpy_support import vtk_to_numpy

    reader = vtk.vtkPNGReader()
    reader.SetFileName(str(path))
    reader.Update()
    image = reader.GetOutput()
    width, height, _ = image.GetDimensions()
    scalars = image.GetPointData().GetScalars()
    assert scalars.GetDataType() == vtk.VTK_UNSIGNED_SHORT, "not read as 16-bit"
    texels = vtk_to_numpy(scalars).reshape(height, width, -1)
    return texels[::-1]  # VTK's image origin is the bottom-left texel


def decode(folder: Path) -> tuple[dict, list[np.ndarray], list[np.ndarray]]:
    """(vat.json, positions of every frame (V, 3), normals of every frame (V, 3)) of a `vat/` folder."""
    info = json.loads((folder / "vat.json").read_text(encoding="utf-8"))
    width, rows, vertices = info["width"], info["rows_per_frame"], info["vertices"]
    low, high = np.asarray(info["bounds_min"]), np.asarray(info["bounds_max"])
    positions = read_png16(folder / info["position_texture"]).astype(np.float64)
    normals = read_png16(folder / info["normal_texture"]).astype(np.float64)
    v = np.arange(vertices)
    frames_p, frames_n = [], []
    for f in range(info["frames"]):
        x, y = v % width, f * rows + v // width
        frames_p.append(low + positions[y, x, :3] / 65535 * (high - low))
        frames_n.append(normals[y, x, :3] / 65535 * 2 - 1)
    return info, frames_p, frames_n
