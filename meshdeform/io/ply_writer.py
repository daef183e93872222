"""The PLY writer: frames of one mesh as binary (or ASCII) PLY files, vertex order, polygons,
properties, UVs and normals of the input kept (the reader is `meshdeform.io.ply`)."""

from __future__ import annotations

import itertools
import os

import numpy as np

from meshdeform.atomic import atomic_open
from meshdeform.errors import ExportError
from meshdeform.geometry import normal_layout, surface_normals, vertex_normals
from meshdeform.io.obj_writer import require_finite
from meshdeform.io.ply import FACE_RESERVED, PLY_FORMATS, PLY_TYPES
from meshdeform.mesh import Mesh

__all__ = ["PlyWriter", "write_ply"]

PathLike = str | os.PathLike[str]


_PLY_NAME = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int", "u4": "uint", "f4": "float",
             "f8": "double"}  # fmt: skip


def _ply_code(dtype: np.dtype, values: np.ndarray) -> str:
    """The PLY-representable type code closest to `dtype` (int64 -> int when it fits)."""
    dtype = np.dtype(dtype)
    code = f"{dtype.kind}{dtype.itemsize}"
    if code in _PLY_NAME:
        return code
    if dtype.kind == "b":
        return "u1"
    if dtype.kind in "iu":
        if values.size == 0 or (values.min() >= -(2**31) and values.max() < 2**31):
            return "i4"
        if values.min() >= 0 and values.max() < 2**32:
            return "u4"
        return "f8"
    if dtype.kind == "f":
        return "f4" if dtype.itemsize < 4 else "f8"
    raise ExportError(f"cannot write a {dtype} property to PLY")


def _scatter_bytes(buf: np.ndarray, dest: np.ndarray, values: np.ndarray) -> None:
    """buf[dest[k] : dest[k] + row_bytes] = bytes of row k (vectorised)."""
    if dest.shape[0] == 0:
        return
    raw = np.ascontiguousarray(values).view(np.uint8).reshape(dest.shape[0], -1)
    buf[dest[:, None] + np.arange(raw.shape[1])] = raw


class PlyWriter:
    """Writes frames of one mesh as PLY files: binary little-endian by default.

    Kept from the input: vertex order, polygons (uchar count + int indices), extra vertex and face
    properties with their types where PLY has them, UVs (per vertex as `s t`, or per corner as a
    MeshLab-style face `texcoord` list when the UVs have seams). Normals (`nx ny nz`) are
    recomputed every frame when the input had normals. The faces and static columns are packed
    once; a frame only fills the position (and normal) columns.
    """

    def __init__(self, mesh: Mesh, encoding: str = "binary_little_endian", position_type: str = "float") -> None:
        if encoding not in PLY_FORMATS:
            raise ExportError(f"unknown PLY encoding {encoding!r}; use one of {', '.join(PLY_FORMATS)}")
        if position_type not in ("float", "double"):
            raise ExportError(f"position_type must be 'float' or 'double', not {position_type!r}")
        self.mesh = mesh
        self.encoding = encoding
        self._order = PLY_FORMATS[encoding] or "<"
        n_v = mesh.vertex_count
        pcode = PLY_TYPES[position_type]
        columns: list[tuple[str, str, np.ndarray | None]] = [(c, pcode, None) for c in "xyz"]

        self._normals = None
        if mesh.normals is not None and mesh.face_normal_indices is not None:
            per_vertex = mesh.normals.shape[0] == n_v and np.array_equal(mesh.face_normal_indices, mesh.face_indices)
            self._normals = "corner" if per_vertex else "vertex"
            # a corner of every vertex (0 for unused ones, whose input normal is kept)
            corners = np.asarray(mesh.face_indices, dtype=np.int64)
            self._used = np.zeros(n_v, dtype=bool)
            self._used[corners] = True
            self._first_corner = np.zeros(n_v, dtype=np.int64)
            self._first_corner[corners[::-1]] = np.arange(corners.shape[0] - 1, -1, -1)
            columns += [(c, "f4", None) for c in ("nx", "ny", "nz")]
        uv_corner = None
        if mesh.uvs is not None and mesh.face_uv_indices is not None:
            uvs = np.asarray(mesh.uvs, dtype=np.float64)[:, :2]
            if uvs.shape[0] == n_v and np.array_equal(mesh.face_uv_indices, mesh.face_indices):
                columns += [("s", "f4", uvs[:, 0]), ("t", "f4", uvs[:, 1])]
            else:
                uv_corner = uvs[mesh.face_uv_indices]
        columns += self._property_columns(mesh.vertex_properties, n_v, "vertex", {c[0] for c in columns})
        self._vertex_columns = columns

        self._vdtype = np.dtype([(f"c{i}", self._order + code) for i, (_, code, _) in enumerate(columns)])
        self._static = np.zeros(n_v, dtype=self._vdtype)
        for i, (name, _, values) in enumerate(columns):
            if values is not None:
                self._static[f"c{i}"] = values
                require_finite(self._static[f"c{i}"], f"vertex property '{name}'")  # as written (float32 too)

        face_columns = self._property_columns(mesh.face_properties, mesh.face_count, "face", set(FACE_RESERVED))
        sizes = mesh.face_sizes
        count_code = "u1" if sizes.size == 0 or sizes.max() <= 255 else "i4"
        uv_count_code = "u1" if sizes.size == 0 or 2 * sizes.max() <= 255 else "i4"
        lines = ["ply", f"format {encoding} 1.0", "comment written by meshdeform", f"element vertex {n_v}"]
        lines += [f"property {_PLY_NAME[code]} {name}" for name, code, _ in columns]
        lines += [f"element face {mesh.face_count}", f"property list {_PLY_NAME[count_code]} int vertex_indices"]
        if uv_corner is not None:
            require_finite(uv_corner.astype(np.float32), "texture coordinates (per corner)")
            lines.append(f"property list {_PLY_NAME[uv_count_code]} float texcoord")
        for name, code, values in face_columns:
            require_finite(np.asarray(values).astype(code), f"face property '{name}'")
        lines += [f"property {_PLY_NAME[code]} {name}" for name, code, _ in face_columns]
        lines.append("end_header")
        self._header = ("\n".join(lines) + "\n").encode("latin-1", "replace")  # names as read (Latin-1)
        if encoding == "ascii":
            self._faces = self._faces_ascii(count_code, uv_corner, face_columns)
        else:
            self._faces = self._faces_binary(count_code, uv_count_code, uv_corner, face_columns)

    @staticmethod
    def _property_columns(
        props: dict[str, np.ndarray], n: int, what: str, taken: set[str]
    ) -> list[tuple[str, str, np.ndarray]]:
        """Scalar columns for extra properties: (V,) arrays as they are, (V, k) as name_0..;
        `color` only when it is not already there as red / green / blue. Names already written
        (x, y, z, normals, UVs) are not written twice."""
        out: list[tuple[str, str, np.ndarray]] = []
        channels = ("red", "green", "blue", "alpha")
        for name, values in props.items():
            values = np.asarray(values)
            if values.shape[:1] != (n,):
                raise ExportError(f"{what} property '{name}' has shape {values.shape}, expected ({n}, ...)")
            if name == "color" and values.ndim == 2:
                if all(c in props for c in channels[:3]):
                    continue
                if values.dtype.kind == "f":  # OBJ colours are 0..1
                    require_finite(values, "vertex colours")
                    values = np.round(np.clip(values, 0.0, 1.0) * 255).astype(np.uint8)
                for k in range(min(values.shape[1], 4)):
                    out.append((channels[k], _ply_code(values.dtype, values[:, k]), values[:, k]))
                continue
            if values.ndim == 1:
                out.append((name, _ply_code(values.dtype, values), values))
            else:
                flat = values.reshape(n, -1)
                for k in range(flat.shape[1]):
                    out.append((f"{name}_{k}", _ply_code(values.dtype, flat[:, k]), flat[:, k]))
        unique: list[tuple[str, str, np.ndarray]] = []
        for column in out:
            if column[0] not in taken and " " not in column[0] and column[0]:
                taken.add(column[0])
                unique.append(column)
        return unique

    def _faces_binary(self, count_code: str, uv_count_code: str, uv_corner, face_columns) -> bytes:
        mesh = self.mesh
        order = self._order
        sizes = mesh.face_sizes.astype(np.int64)
        n_faces = sizes.shape[0]
        cdt = np.dtype(order + count_code)
        per_face = cdt.itemsize
        per_corner = 4
        if uv_corner is not None:
            per_face += np.dtype(uv_count_code).itemsize
            per_corner += 8
        fdt = np.dtype([(f"c{i}", order + code) for i, (_, code, _) in enumerate(face_columns)])
        per_face += fdt.itemsize
        record = per_face + per_corner * sizes
        start = np.zeros(n_faces, dtype=np.int64)
        np.cumsum(record[:-1], out=start[1:])
        buf = np.zeros(int(record.sum()), dtype=np.uint8)
        corner_face = mesh.corner_face
        corner_local = np.arange(mesh.face_indices.shape[0], dtype=np.int64) - mesh.face_offsets[corner_face]
        cursor = start.copy()
        _scatter_bytes(buf, cursor, sizes.astype(cdt))
        cursor += cdt.itemsize
        idx = np.asarray(mesh.face_indices).astype(order + "i4")
        _scatter_bytes(buf, cursor[corner_face] + corner_local * 4, idx)
        cursor += 4 * sizes
        if uv_corner is not None:
            udt = np.dtype(order + uv_count_code)
            _scatter_bytes(buf, cursor, (2 * sizes).astype(udt))
            cursor += udt.itemsize
            _scatter_bytes(buf, cursor[corner_face] + corner_local * 8, uv_corner.astype(order + "f4"))
            cursor += 8 * sizes
        if face_columns:
            rows = np.zeros(n_faces, dtype=fdt)
            for i, (_, _, values) in enumerate(face_columns):
                rows[f"c{i}"] = values
            _scatter_bytes(buf, cursor, rows)
        return buf.tobytes()

    def _faces_ascii(self, count_code: str, uv_corner, face_columns) -> bytes:
        mesh = self.mesh
        sizes = mesh.face_sizes.tolist()
        flat = mesh.face_indices.tolist()
        offs = mesh.face_offsets.tolist()
        uv = None if uv_corner is None else uv_corner.astype(np.float32).tolist()
        extra = [[_ascii_value(v, code) for v in values.tolist()] for _, code, values in face_columns]
        out = []
        for f, k in enumerate(sizes):
            parts = [str(k), *map(str, flat[offs[f] : offs[f + 1]])]
            if uv is not None:
                parts.append(str(2 * k))
                parts += [f"{c:.9g}" for pair in uv[offs[f] : offs[f + 1]] for c in pair]
            parts += [col[f] for col in extra]
            out.append(" ".join(parts))
        return ("\n".join(out) + ("\n" if out else "")).encode("ascii")

    def _vertex_rows(self, positions: np.ndarray, path: PathLike | None) -> np.ndarray:
        """The vertex records of one frame; ExportError if a position or normal is not finite as
        written (a float64 beyond float32's range would be infinite in a `float` column)."""
        rows = self._static.copy()
        with np.errstate(over="ignore"):  # beyond float32: infinite, refused just below
            for i in range(3):
                rows[f"c{i}"] = positions[:, i]
        require_finite(np.stack([rows[f"c{i}"] for i in range(3)], axis=1), "vertex positions", path)
        if self._normals is not None:
            if self._normals == "corner":
                # one input normal per vertex: each vertex's corners share one group of the layout
                # (unused vertices keep their input normal)
                layout = normal_layout(self.mesh)
                normals = np.array(self.mesh.normals, dtype=np.float64)
                normals /= np.maximum(np.linalg.norm(normals, axis=1), 1e-300)[:, None]
                corner = self._first_corner[self._used]
                normals[self._used] = surface_normals(self.mesh, positions)[layout.corner_normal[corner]]
            else:
                normals = vertex_normals(self.mesh, positions)
            for i in range(3):
                rows[f"c{3 + i}"] = normals[:, i]
            require_finite(normals, "normals", path)
        return rows

    def data(self, positions: np.ndarray | None = None, path: PathLike | None = None) -> bytes:
        """The bytes of the PLY file of one frame (`path` only names the file in errors)."""
        mesh = self.mesh
        pos = mesh.positions if positions is None else np.asarray(positions, dtype=np.float64)
        if pos.shape != mesh.positions.shape:
            raise ExportError(f"positions have shape {pos.shape}, the mesh needs {mesh.positions.shape}")
        rows = self._vertex_rows(pos, path)
        if self.encoding != "ascii":
            return self._header + rows.tobytes() + self._faces
        columns = [rows[f"c{i}"] for i in range(len(self._vertex_columns))]
        codes = [code for _, code, _ in self._vertex_columns]
        fmt = " ".join("%r" if c == "f8" else "%.9g" if c == "f4" else "%d" for c in codes) + "\n"
        values = tuple(itertools.chain.from_iterable(zip(*(c.tolist() for c in columns), strict=True)))
        text = (fmt * pos.shape[0]) % values if pos.shape[0] else ""
        return self._header + text.encode("ascii") + self._faces

    def write(self, path: PathLike, positions: np.ndarray | None = None) -> None:
        """Write one frame to `path` atomically (ExportError, and no file, if anything is not finite)."""
        payload = self.data(positions, path)
        with atomic_open(path, "wb") as handle:
            handle.write(payload)


def _ascii_value(value: float | int, code: str) -> str:
    if code == "f8":
        return repr(float(value))
    if code == "f4":
        return f"{value:.9g}"
    return str(int(value))


def write_ply(
    path: PathLike,
    mesh: Mesh,
    positions: np.ndarray | None = None,
    encoding: str = "binary_little_endian",
    position_type: str = "float",
) -> None:
    """Write `mesh` (with other `positions` if given) as a PLY file, atomically."""
    PlyWriter(mesh, encoding=encoding, position_type=position_type).write(path, positions)
