"""glTF 2.0 export: `scene.glb`, the input mesh with the animation as morph targets.

One mesh with one triangle primitive (polygons fan-triangulated, corner 0 to every later edge), its
POSITION the rest pose (frame index 0), one morph target per later frame (POSITION deltas from the
rest pose, and NORMAL deltas of the area-weighted vertex normals), and an animation whose `weights`
channel is one-hot: key k at time k / fps (seconds; time 0 is the rest pose, scene frame
`start_frame`) has weight 1 on the target of frame k and 0 elsewhere, LINEAR, so between two keys
only two targets are active. The mesh's default weights are all zero (the rest pose).

Layout: glTF vertices 0..V-1 are the input vertices in their order. Where the UVs are per corner
(seams) a vertex with several UVs is copied, and the copies follow as vertices V.., the input vertex
of each listed in `meshes[0].extras.seamSource` (glTF vertex V + j is input vertex seamSource[j]).
TEXCOORD_0 is (u, 1 - v): glTF's origin is the top left. Input normals are not written (they would
not follow the cloth): the normals are computed from each frame's positions. The face groups are
listed in `meshes[0].extras.groups` (name -> input face indices) rather than split into primitives:
one primitive keeps the vertex order importers read (Blender rebuilds its mesh per primitive).

Coordinates are Y up whatever `up_axis`, as glTF's specification requires: the input's unchanged
from a Y-up input, turned from a Z-up one (`simulation.up = "z"`: (x, y, z) -> (x, z, -y),
`ExportContext.to_y_up`); every importer converts to its own world (Blender: (x, y, z) -> (x, -z, y)).
The GLB is written at close from spools of float32 deltas (memory stays flat), through a temporary
name. A topology change (tearing) is refused: morph targets need a fixed vertex count. Written with NumPy, `json` and
`struct`, no dependency (docs/recipes.md, "glTF").
"""

from __future__ import annotations

import json
import struct
import tempfile
from pathlib import Path
from typing import IO, Any, ClassVar

import numpy as np

from meshdeform.atomic import atomic_open
from meshdeform.export.base import BaseExporter, ExportContext, FrameData
from meshdeform.geometry import vertex_normals
from meshdeform.mesh import Mesh

FILE_NAME = "scene.glb"
_FLOAT, _UINT = 5126, 5125
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_CHUNK = 1 << 22  # bytes copied from a spool at a time


def fan_triangles(mesh: Mesh) -> np.ndarray:
    """(T, 3) int64 corner indices (into `face_indices`) of the fan triangulation of every polygon of
    3 or more corners: (c0, c_i, c_i+1), polygon after polygon."""
    sizes = mesh.face_sizes
    counts = np.maximum(sizes - 2, 0)
    first = np.repeat(mesh.face_offsets[:-1], counts)
    starts = np.cumsum(counts) - counts
    local = np.arange(int(counts.sum()), dtype=np.int64) - np.repeat(starts, counts) + 1
    return np.stack([first, first + local, first + local + 1], axis=1)


def gltf_vertices(mesh: Mesh) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The glTF vertex layout: (source (W,) input vertex of each glTF vertex, the first V being
    0..V-1; corner_vertex (C,) glTF vertex of each corner; uv (W, 2) or None)."""
    v = mesh.vertex_count
    corners = np.asarray(mesh.face_indices, dtype=np.int64)
    if mesh.uvs is None:
        return np.arange(v, dtype=np.int64), corners, None
    uvs = np.asarray(mesh.uvs, dtype=np.float64)[:, :2]
    uv_index = corners if mesh.face_uv_indices is None else np.asarray(mesh.face_uv_indices, dtype=np.int64)
    chosen = np.zeros(v, dtype=np.int64)
    order = np.argsort(corners, kind="stable")[::-1]  # the last write wins: each vertex's first corner
    chosen[corners[order]] = uv_index[order]
    if mesh.face_uv_indices is None and uvs.shape[0] == v:
        chosen = np.arange(v, dtype=np.int64)
    split = uv_index != chosen[corners]
    keys = np.stack([corners[split], uv_index[split]], axis=1)
    unique, inverse = np.unique(keys, axis=0, return_inverse=True)
    source = np.concatenate([np.arange(v, dtype=np.int64), unique[:, 0]])
    corner_vertex = corners.copy()
    corner_vertex[split] = v + inverse.reshape(-1)
    uv = np.concatenate([uvs[chosen], uvs[unique[:, 1]]]) if uvs.shape[0] else np.zeros((source.size, 2))
    return source, corner_vertex, uv


def _unit_normals(mesh: Mesh, positions: np.ndarray, source: np.ndarray) -> np.ndarray:
    """Area-weighted unit normals of the glTF vertices (W, 3); +Y where a vertex has none (glTF
    normals must be unit vectors)."""
    n = vertex_normals(mesh, positions)[source]
    n[np.linalg.norm(n, axis=1) < 0.5] = (0.0, 1.0, 0.0)
    return n


class GltfExporter(BaseExporter):
    """Spools per-frame float32 position and normal deltas; writes `scene.glb` at close."""

    name: ClassVar[str] = "gltf"
    summary: ClassVar[str] = "glTF 2.0 scene.glb, the animation as morph targets"
    supports_topology_change: ClassVar[bool] = False
    topology_message: ClassVar[str] = "glTF morph targets need a fixed topology"

    @classmethod
    def estimated_bytes(cls, mesh: Mesh, frames: int) -> int | None:
        """Two float32 vec3 per vertex per frame (position and normal), uv and indices once, the weight
        keys (frames squared floats), at most 600 bytes of JSON per frame and 9 per listed seam copy or
        group face; the vertex count with the seam copies."""
        w = int(gltf_vertices(mesh)[0].size)
        triangles = int(np.maximum(mesh.face_sizes - 2, 0).sum())
        listed = (w - mesh.vertex_count) + sum(int(np.size(f)) for f in mesh.groups.values())  # JSON int lists
        return int(8192 + 24 * w * frames + 8 * w + 12 * triangles + 4 * frames * frames + 600 * frames + 9 * listed)

    def _open(self, ctx: ExportContext) -> None:
        self._source, self._corner_vertex, self._uv = gltf_vertices(ctx.mesh)
        self._spools: list[IO[bytes]] = [
            tempfile.TemporaryFile(dir=ctx.out_dir, prefix=f".gltf-{kind}.", suffix=".spool")  # noqa: SIM115
            for kind in ("position", "normal")
        ]
        self._rest: tuple[np.ndarray, np.ndarray] | None = None
        self._bounds: list[tuple[list[float], list[float]]] = []

    def _write(self, ctx: ExportContext, frame: FrameData, mesh: Mesh, positions: np.ndarray) -> None:
        points = ctx.to_y_up(np.asarray(positions, dtype=np.float64))  # glTF is Y up
        normals = _unit_normals(mesh, points, self._source)
        points = points[self._source]
        if self._rest is None:
            self._rest = (points.astype(np.float32), normals.astype(np.float32))
            return
        rest_points, rest_normals = self._rest
        delta = (points - rest_points).astype(np.float32)
        self._spools[0].write(delta.tobytes())
        self._spools[1].write((normals - rest_normals).astype(np.float32).tobytes())
        self._bounds.append(_min_max(delta))

    def _close(self, ctx: ExportContext) -> list[Path]:
        assert self._rest is not None
        rest_points, rest_normals = self._rest
        w = int(self._source.size)
        targets = len(self._bounds)
        triangles = self._corner_vertex[fan_triangles(ctx.mesh)].astype(np.uint32)
        blobs: list[bytes] = [triangles.tobytes(), rest_points.tobytes(), rest_normals.tobytes()]
        if self._uv is not None:
            uv = self._uv.astype(np.float32)
            uv[:, 1] = 1.0 - uv[:, 1]
            blobs.append(uv.tobytes())
        times = (np.arange(targets + 1, dtype=np.float64) / ctx.fps).astype(np.float32)
        keys = np.zeros((targets + 1, targets), dtype=np.float32)
        keys[np.arange(1, targets + 1), np.arange(targets)] = 1.0
        if targets:
            blobs += [times.tobytes(), keys.tobytes()]
        views: list[dict[str, Any]] = []
        offset = 0
        for i, blob in enumerate(blobs):
            view: dict[str, Any] = {"buffer": 0, "byteOffset": offset, "byteLength": len(blob)}
            if i == 0:
                view["target"] = _ELEMENT_ARRAY_BUFFER
            elif i < (4 if self._uv is not None else 3):
                view["target"] = _ARRAY_BUFFER
            views.append(view)
            offset += _pad4(len(blob))
        spool_bytes = 12 * w * targets
        if targets:
            for _ in self._spools:
                views.append(
                    {
                        "buffer": 0,
                        "byteOffset": offset,
                        "byteLength": spool_bytes,
                        "byteStride": 12,
                        "target": _ARRAY_BUFFER,
                    }
                )
                offset += spool_bytes
        accessors: list[dict[str, Any]] = [
            {"bufferView": 0, "componentType": _UINT, "count": int(triangles.size), "type": "SCALAR"},
            {"bufferView": 1, "componentType": _FLOAT, "count": w, "type": "VEC3", **_bounds_of(rest_points)},
            {"bufferView": 2, "componentType": _FLOAT, "count": w, "type": "VEC3"},
        ]
        attributes = {"POSITION": 1, "NORMAL": 2}
        if self._uv is not None:
            attributes["TEXCOORD_0"] = len(accessors)
            accessors.append({"bufferView": 3, "componentType": _FLOAT, "count": w, "type": "VEC2"})
        primitive: dict[str, Any] = {"attributes": attributes, "indices": 0, "mode": 4}
        mesh_json: dict[str, Any] = {
            "name": ctx.mesh.source.stem if ctx.mesh.source else "cloth",
            "primitives": [primitive],
        }
        extras: dict[str, Any] = {"fps": float(ctx.fps), "startFrame": int(ctx.start_frame)}
        if w > ctx.mesh.vertex_count:
            extras["seamSource"] = self._source[ctx.mesh.vertex_count :].tolist()
        if ctx.mesh.groups:
            extras["groups"] = {name: np.asarray(f).tolist() for name, f in ctx.mesh.groups.items()}
        mesh_json["extras"] = extras
        gltf: dict[str, Any] = {
            "asset": {"version": "2.0", "generator": "meshdeform"},
            "scene": 0,
            "scenes": [{"nodes": [0]}],
            "nodes": [{"mesh": 0, "name": mesh_json["name"]}],
            "meshes": [mesh_json],
        }
        if targets:
            time_view = len(blobs) - 2
            position_view, normal_view = len(blobs), len(blobs) + 1
            time_accessor = len(accessors)
            accessors.append(
                {"bufferView": time_view, "componentType": _FLOAT, "count": targets + 1, "type": "SCALAR",
                 "min": [float(times[0])], "max": [float(times[-1])]}
            )  # fmt: skip
            accessors.append(
                {"bufferView": time_view + 1, "componentType": _FLOAT, "count": keys.size, "type": "SCALAR"}
            )
            primitive["targets"] = []
            for k, (low, high) in enumerate(self._bounds):
                primitive["targets"].append({"POSITION": len(accessors), "NORMAL": len(accessors) + 1})
                accessors.append(
                    {"bufferView": position_view, "byteOffset": 12 * w * k, "componentType": _FLOAT, "count": w,
                     "type": "VEC3", "min": low, "max": high}
                )  # fmt: skip
                accessors.append(
                    {"bufferView": normal_view, "byteOffset": 12 * w * k, "componentType": _FLOAT, "count": w,
                     "type": "VEC3"}
                )  # fmt: skip
            mesh_json["weights"] = [0.0] * targets
            mesh_json["extras"]["targetNames"] = [f"frame_{ctx.scene_frame(k + 1)}" for k in range(targets)]
            gltf["animations"] = [
                {
                    "name": "simulation",
                    "samplers": [{"input": time_accessor, "output": time_accessor + 1, "interpolation": "LINEAR"}],
                    "channels": [{"sampler": 0, "target": {"node": 0, "path": "weights"}}],
                }
            ]
        gltf["accessors"] = accessors
        gltf["bufferViews"] = views
        gltf["buffers"] = [{"byteLength": offset}]
        text = json.dumps(gltf, separators=(",", ":")).encode()
        text += b" " * (_pad4(len(text)) - len(text))
        total = 12 + 8 + len(text) + 8 + offset
        target = ctx.out_dir / FILE_NAME
        with atomic_open(target, "wb") as out:
            out.write(struct.pack("<4sII", b"glTF", 2, total))
            out.write(struct.pack("<I4s", len(text), b"JSON") + text)
            out.write(struct.pack("<I4s", offset, b"BIN\0"))
            for blob in blobs:
                out.write(blob + b"\0" * (_pad4(len(blob)) - len(blob)))
            if targets:
                for spool in self._spools:
                    spool.flush()
                    spool.seek(0)
                    while chunk := spool.read(_CHUNK):
                        out.write(chunk)
        self._close_spools()
        return [target]

    def _close_spools(self) -> None:
        for spool in self._spools:
            spool.close()

    def _abort(self) -> None:
        self._close_spools()


def _pad4(n: int) -> int:
    return (n + 3) // 4 * 4


def _min_max(values: np.ndarray) -> tuple[list[float], list[float]]:
    """Per-component minimum and maximum of a float32 (W, 3) array, as JSON floats (exact: a float32
    is a float64 exactly, and repr round-trips)."""
    if values.shape[0] == 0:
        return [0.0] * 3, [0.0] * 3
    return [float(x) for x in values.min(axis=0)], [float(x) for x in values.max(axis=0)]


def _bounds_of(values: np.ndarray) -> dict[str, list[float]]:
    low, high = _min_max(values)
    return {"min": low, "max": high}
