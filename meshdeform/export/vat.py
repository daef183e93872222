"""Vertex animation textures (VAT): the bake as two 16-bit PNG textures a game engine's vertex shader plays.

The way engines play back baked cloth (SideFX Labs VAT, Unity VFX Toolbox, Unreal's vertex
animation tools): every frame's vertex positions (and normals) are texels of a texture, and the
mesh carries a second UV set pointing each vertex at its texel. Written into `vat/`:

- `positions.png`: 16-bit RGB; texel (x, y) with x = v % width, y = f * rows_per_frame + v // width
  holds vertex v of frame f, quantised per axis over the bounds of the whole bake:
  position = bounds_min + value / 65535 * (bounds_max - bounds_min). Texture frame f is the f-th
  frame written, scene frame `scene_frames[f]`: frame 0 is the rest pose (scene frame
  `start_frame`, `frames` counting it) unless `[output] frames` starts later. Row 0 is the top row of the PNG (image row
  order). Texels past the last vertex of a frame's last row are 0.
- `normals.png`: 16-bit RGB, the same layout, unit area-weighted vertex normals of each deformed
  frame (`meshdeform.geometry.vertex_normals`) as value = (n * 0.5 + 0.5) * 65535, rounded
  (a vertex on no polygon has the zero normal, stored as 32768).
- `mesh.obj`: the rest-pose mesh (input vertex order, polygons, groups) whose one UV set (`vt`,
  one per vertex) is the VAT UV of frame 0: the centre of the vertex's texel in the engines' UV
  convention (origin bottom-left), u = (x + 0.5) / width, v = 1 - (y + 0.5) / height. A shader
  reads frame f at (u, v - f * rows_per_frame / height). OBJ holds a single UV set, so the mesh is
  written for the animation and the material UVs stay in the input mesh (same vertices, same
  polygons); the UVs are also `uv2` in `vat.json`.
- `mesh.glb`: the same mesh as binary glTF 2.0 (fan-triangulated), the one format here with a second
  UV set: TEXCOORD_0 the input's UVs, TEXCOORD_1 the VAT UVs, in glTF's top-left UV convention
  (v_gltf = 1 - v; importers flip it back), its vertices laid out as `scene.glb`'s: the input's in
  their order, then a copy per further UV of a seam vertex, each with the vertex's VAT UV, listed in
  `meshes[0].extras.seamSource` (`glb_bytes`).
- `vat.json`: everything a decoder needs (`frames`, `vertices`, `width`, `height`,
  `rows_per_frame`, `bounds_min`, `bounds_max`, the texture and mesh file names, `fps`,
  `start_frame`, the encodings and conventions in words, `uv2`).

The coordinates are Y up whatever `up_axis` says, as the mesh.glb's must be and engines import
meshes: the input's from a Y-up input, turned from a Z-up one (`ExportContext.to_y_up`); the
textures, mesh.obj and mesh.glb agree. An axis on which
nothing moves or extends (a flat sheet's z at rest) would have a zero range: its bounds are
widened by `ZERO_RANGE_PAD` each side and `vat.json`'s `bounds_widened` names it. Positions and
normals are spooled to anonymous temporary files as the frames come (float64 / float32) and
encoded at close, when the bounds over every frame are known; the PNGs are written by the small
encoder below (stored filter 0 rows, zlib level 6), streamed frame by frame, so memory stays one
frame's texels whatever the bake's length. The texture is `width` wide with `width` the vertex
count up to `MAX_WIDTH`; engines limit texture sizes (often 8192 or 16384), which bounds
frames * rows_per_frame.
"""

from __future__ import annotations

import json
import struct
import tempfile
import zlib
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import IO, ClassVar

import numpy as np

from meshdeform.atomic import atomic_open
from meshdeform.export.base import BaseExporter, ExportContext, FrameData
from meshdeform.export.gltf import fan_triangles, gltf_vertices
from meshdeform.geometry import vertex_normals
from meshdeform.mesh import Mesh

FOLDER = "vat"
POSITION_TEXTURE = "positions.png"
NORMAL_TEXTURE = "normals.png"
MESH_FILE = "mesh.obj"
GLB_FILE = "mesh.glb"
DESCRIPTION = "vat.json"
#: widest texture written (texels); more vertices wrap onto further rows of the same frame
MAX_WIDTH = 8192
#: metres added each side of an axis whose range over the whole bake is zero
ZERO_RANGE_PAD = 1e-6
#: the largest 16-bit value
FULL = 65535


def texture_layout(vertices: int, frames: int) -> tuple[int, int, int]:
    """(width, rows_per_frame, height) of the textures for `vertices` vertices and `frames` frames."""
    width = max(1, min(int(vertices), MAX_WIDTH))
    rows = max(1, -(-int(vertices) // width))
    return width, rows, rows * int(frames)


def vat_uvs(vertices: int, width: int, height: int) -> np.ndarray:
    """(V, 2) texel-centre UVs of frame 0 in the engines' convention (origin bottom-left)."""
    v = np.arange(vertices)
    return np.column_stack([(v % width + 0.5) / width, 1.0 - (v // width + 0.5) / height])


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


class _Png16Writer:
    """A 16-bit RGB PNG written row block by row block: IHDR, one IDAT per block, IEND."""

    def __init__(self, handle: IO[bytes], width: int, height: int) -> None:
        self.handle = handle
        self.width = width
        handle.write(b"\x89PNG\r\n\x1a\n")
        handle.write(_chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 16, 2, 0, 0, 0)))
        self._zip = zlib.compressobj(6)

    def rows(self, texels: np.ndarray) -> None:
        """Append rows of texels (rows, width, 3) uint16."""
        rows = texels.shape[0]
        raw = np.zeros((rows, 1 + 6 * self.width), dtype=np.uint8)  # filter byte 0 (none) per row
        raw[:, 1:] = np.ascontiguousarray(texels, dtype=">u2").view(np.uint8).reshape(rows, -1)
        data = self._zip.compress(raw.tobytes())
        if data:
            self.handle.write(_chunk(b"IDAT", data))

    def finish(self) -> None:
        self.handle.write(_chunk(b"IDAT", self._zip.flush()))
        self.handle.write(_chunk(b"IEND", b""))


def glb_bytes(mesh: Mesh, vat_uv: np.ndarray) -> bytes:
    """A binary glTF 2.0 of the rest-pose mesh, fan-triangulated, with TEXCOORD_0 the input's UVs (when it has
    them) and TEXCOORD_1 the VAT UVs, both in glTF's convention (origin top-left: v_gltf = 1 - v).

    The vertex layout is `scene.glb`'s (`gltf.gltf_vertices`): glTF vertices 0..V-1 are the input vertices in
    their order; glTF has one UV per vertex, so a vertex with several input UVs (a seam) is copied, the copies
    follow as vertices V.. with the vertex's VAT UV, and `meshes[0].extras.seamSource` lists the input vertex
    of each (glTF vertex V + j is input vertex seamSource[j])."""
    source, corner_vertex, uv = gltf_vertices(mesh)
    indices = corner_vertex[fan_triangles(mesh).ravel()]
    position = np.asarray(mesh.positions, dtype=np.float32)[source]
    flip = np.array([0.0, 1.0])
    columns = {"POSITION": position, "TEXCOORD_1": (flip - vat_uv[source] * [-1.0, 1.0]).astype(np.float32)}
    if uv is not None:
        columns["TEXCOORD_0"] = (flip - uv * [-1.0, 1.0]).astype(np.float32)
    blob, views, accessors, attributes = b"", [], [], {}
    for name, data in [*columns.items(), ("indices", indices.astype(np.uint32))]:
        raw = np.ascontiguousarray(data).astype(data.dtype.newbyteorder("<")).tobytes()
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(raw)})
        views[-1]["target"] = 34963 if name == "indices" else 34962
        accessor = {
            "bufferView": len(views) - 1,
            "componentType": 5125 if name == "indices" else 5126,
            "count": int(data.shape[0]),
            "type": {1: "SCALAR", 2: "VEC2", 3: "VEC3"}[1 if data.ndim == 1 else data.shape[1]],
        }
        if name == "POSITION":
            accessor["min"] = [float(x) for x in data.min(axis=0)] if data.size else [0.0] * 3
            accessor["max"] = [float(x) for x in data.max(axis=0)] if data.size else [0.0] * 3
        accessors.append(accessor)
        if name != "indices":
            attributes[name] = len(accessors) - 1
        blob += raw + b"\0" * (-len(raw) % 4)
    primitive = {"attributes": attributes, "indices": len(accessors) - 1, "mode": 4}
    glb_mesh: dict[str, object] = {"primitives": [primitive]}
    if source.size > mesh.vertex_count:
        glb_mesh["extras"] = {"seamSource": source[mesh.vertex_count :].tolist()}
    document = {
        "asset": {"version": "2.0", "generator": "meshdeform vat"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": "vat_mesh"}],
        "meshes": [glb_mesh],
        "buffers": [{"byteLength": len(blob)}],
        "bufferViews": views,
        "accessors": accessors,
    }
    text = json.dumps(document, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    total = 12 + 8 + len(text) + 8 + len(blob)
    header = struct.pack("<4sII", b"glTF", 2, total)
    return header + struct.pack("<I4s", len(text), b"JSON") + text + struct.pack("<I4s", len(blob), b"BIN\0") + blob


class VatExporter(BaseExporter):
    """Spools positions and normals per frame; encodes the textures, mesh and `vat.json` at close."""

    name: ClassVar[str] = "vat"
    summary: ClassVar[str] = "vertex animation textures (16-bit PNG) for game engines"
    supports_topology_change: ClassVar[bool] = False
    topology_message: ClassVar[str] = "vertex animation textures need a fixed vertex count"

    @classmethod
    def estimated_bytes(cls, mesh: Mesh, frames: int) -> int | None:
        """Two textures stored at most uncompressed (6 bytes a texel, a filter byte a row, zlib's own),
        the mesh as OBJ text and as glTF (at most one glTF vertex of 28 bytes and 4 bytes of indices a
        triangle corner: 3 (corners - 2 * polygons)), and `vat.json`'s UVs (about 48 characters a vertex)."""
        from meshdeform.export.obj import obj_frame_bytes

        width, _, height = texture_layout(mesh.vertex_count, frames)
        raw = height * (1 + 6 * width)
        texture = raw + raw // 1000 + 12 * frames + 1024  # deflate's stored blocks, an IDAT chunk a frame
        triangle_corners = 3 * max(int(mesh.face_indices.shape[0]) - 2 * mesh.face_count, 0)
        glb = 32 * triangle_corners + 4096
        return int(2 * texture + obj_frame_bytes(mesh) + glb + 48 * mesh.vertex_count * 2 + 4096)

    def _open(self, ctx: ExportContext) -> None:
        self._folder = self._make_dir(ctx.out_dir / FOLDER)
        self._positions: IO[bytes] = tempfile.TemporaryFile(dir=ctx.out_dir, prefix=".vat.", suffix=".spool")  # noqa: SIM115
        self._normals: IO[bytes] = tempfile.TemporaryFile(dir=ctx.out_dir, prefix=".vat.", suffix=".spool")  # noqa: SIM115
        self._scene_frames: list[int] = []
        self._low = np.full(3, np.inf)
        self._high = np.full(3, -np.inf)

    def _write(self, ctx: ExportContext, frame: FrameData, mesh: Mesh, positions: np.ndarray) -> None:
        pos = np.ascontiguousarray(ctx.to_y_up(np.asarray(positions, dtype=np.float64)))
        if pos.shape[0]:
            self._low = np.minimum(self._low, pos.min(axis=0))
            self._high = np.maximum(self._high, pos.max(axis=0))
        self._positions.write(pos.tobytes())
        self._scene_frames.append(ctx.scene_frame(frame.index))
        self._normals.write(np.ascontiguousarray(vertex_normals(mesh, pos), dtype=np.float32).tobytes())

    def _close(self, ctx: ExportContext) -> list[Path]:
        n, vertices = self.frames_written, ctx.mesh.vertex_count
        width, rows, height = texture_layout(vertices, n)
        low, high = self._bounds(vertices)
        positions = self._view(self._positions, np.float64, n, vertices)
        normals = self._view(self._normals, np.float32, n, vertices)
        span = high - low
        finished = [
            self._texture(POSITION_TEXTURE, positions, lambda p: (p - low) / span, width, rows, height),
            self._texture(NORMAL_TEXTURE, normals, lambda q: q.astype(np.float64) * 0.5 + 0.5, width, rows, height),
        ]
        del positions, normals
        uvs = vat_uvs(vertices, width, height)
        normals = None if ctx.mesh.normals is None else ctx.to_y_up(np.asarray(ctx.mesh.normals))
        y_up = replace(ctx.mesh, positions=ctx.to_y_up(np.asarray(ctx.mesh.positions)), normals=normals)
        finished.append(self._mesh_file(y_up, uvs))
        target = self._folder / GLB_FILE
        with atomic_open(target, "wb") as out:
            out.write(glb_bytes(y_up, uvs))
        self._written.append(target)
        finished.append(target)
        finished.append(self._description(ctx, n, width, rows, height, low, high, uvs))
        self._close_spools()
        return finished

    # -- pieces --------------------------------------------------------------------------------
    def _bounds(self, vertices: int) -> tuple[np.ndarray, np.ndarray]:
        """Per-axis bounds over every frame, an axis of zero range widened (`self._widened` names them)."""
        low, high = (self._low.copy(), self._high.copy()) if vertices else (np.zeros(3), np.zeros(3))
        flat = ~(high - low > 0)
        low[flat] -= ZERO_RANGE_PAD
        high[flat] += ZERO_RANGE_PAD
        self._widened = [axis for axis, f in zip("xyz", flat, strict=True) if f]
        return low, high

    @staticmethod
    def _view(handle: IO[bytes], dtype: type, frames: int, vertices: int) -> np.ndarray:
        handle.flush()
        if frames * vertices == 0:
            return np.zeros((frames, vertices, 3), dtype=dtype)
        return np.memmap(handle, dtype=dtype, mode="r", shape=(frames, vertices, 3))

    def _texture(
        self,
        file_name: str,
        frames: np.ndarray,
        unit: Callable[[np.ndarray], np.ndarray],
        width: int,
        rows: int,
        height: int,
    ) -> Path:
        """Write one texture: `unit` maps a frame's (V, 3) values onto [0, 1] per component."""
        target = self._folder / file_name
        vertices = frames.shape[1]
        block = np.zeros((rows * width, 3), dtype=np.uint16)
        with atomic_open(target, "wb") as out:
            png = _Png16Writer(out, width, height)
            for values in frames:
                block[:vertices] = np.rint(np.clip(unit(np.asarray(values)), 0.0, 1.0) * FULL).astype(np.uint16)
                png.rows(block.reshape(rows, width, 3))
            png.finish()
        self._written.append(target)
        return target

    def _mesh_file(self, mesh: Mesh, uvs: np.ndarray) -> Path:
        from meshdeform.io import save

        target = self._folder / MESH_FILE
        corners = np.asarray(mesh.face_indices, dtype=np.int64)
        save(target, replace(mesh, uvs=uvs, face_uv_indices=corners, normals=None, face_normal_indices=None))
        self._written.append(target)
        return target

    def _description(
        self,
        ctx: ExportContext,
        frames: int,
        width: int,
        rows: int,
        height: int,
        low: np.ndarray,
        high: np.ndarray,
        uvs: np.ndarray,
    ) -> Path:
        """Write `vat.json`: the layout (frames, vertices, texture size), the bounds, file names, encodings."""
        description = {
            "format": "meshdeform vertex animation textures",
            "frames": int(frames),
            "vertices": int(ctx.mesh.vertex_count),
            "width": int(width),
            "height": int(height),
            "rows_per_frame": int(rows),
            "fps": float(ctx.fps),
            "start_frame": int(ctx.start_frame),
            "first_scene_frame": self._scene_frames[0],
            "scene_frames": self._scene_frames,
            "frame_zero": (
                "texture frame f is scene frame scene_frames[f] (first_scene_frame + f); frame 0 is the rest pose "
                "when first_scene_frame is start_frame, as it is unless [output] frames starts later"
            ),
            "bounds_min": [float(x) for x in low],
            "bounds_max": [float(x) for x in high],
            "bounds_widened": self._widened,
            "bounds_note": f"an axis of zero range over the bake is widened by {ZERO_RANGE_PAD} each side",
            "position_texture": POSITION_TEXTURE,
            "normal_texture": NORMAL_TEXTURE,
            "mesh": MESH_FILE,
            "mesh_gltf": GLB_FILE,
            "bit_depth": 16,
            "channels": "RGB = xyz",
            "coordinates": "Y up, right-handed (as glTF): the input's, turned from a Z-up input",
            "texel": "vertex v of frame f is texel x = v % width, y = f * rows_per_frame + v // width",
            "row_order": "row 0 is the top row of the PNG (image row order)",
            "position_encoding": "position = bounds_min + value / 65535 * (bounds_max - bounds_min)",
            "normal_encoding": "value = round((n * 0.5 + 0.5) * 65535); n = value / 65535 * 2 - 1, unit area-weighted",
            "uv_convention": (
                "uv2 and mesh.obj's vt: texel centres of frame 0 with the UV origin bottom-left (Unity, Unreal, "
                "OBJ): u = (x + 0.5) / width, v = 1 - (y + 0.5) / height; frame f is at v - f * rows_per_frame / "
                "height (an engine that flips V on import, as Unreal does, then has its origin top-left)"
            ),
            "uv2": np.round(uvs, 9).tolist(),
        }
        target = self._folder / DESCRIPTION
        with atomic_open(target, "w", encoding="utf-8") as out:
            json.dump(description, out, indent=1)
            out.write("\n")
        self._written.append(target)
        return target

    def _close_spools(self) -> None:
        for handle in (getattr(self, "_positions", None), getattr(self, "_normals", None)):
            if handle is not None:
                handle.close()

    def _abort(self) -> None:
        self._close_spools()
