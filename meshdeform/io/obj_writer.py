"""The OBJ writer: frames of one mesh as OBJ files, vertex order, polygons, UVs, normals and groups
of the input kept (the reader is `meshdeform.io.obj`)."""

from __future__ import annotations

import os

import numpy as np

from meshdeform.atomic import atomic_open
from meshdeform.errors import ExportError
from meshdeform.geometry import normal_layout, surface_normals
from meshdeform.mesh import Mesh

__all__ = ["ObjWriter", "require_finite", "write_obj"]

PathLike = str | os.PathLike[str]


def require_finite(values: np.ndarray, what: str, path: PathLike | None = None) -> None:
    """ExportError naming the first row of `values` (rows first) that holds a NaN or infinity:
    the writers never put a non-finite number into a file."""
    values = np.asarray(values)
    if values.dtype.kind != "f" or values.size == 0:
        return
    bad = ~np.isfinite(values.reshape(values.shape[0], -1)).all(axis=1)
    if bad.any():
        row = int(np.flatnonzero(bad)[0])
        where = f"{path}: " if path is not None else ""
        shown = values[row].tolist()
        raise ExportError(f"{where}{what}, row {row}: not finite ({shown}); nothing non-finite is written")


def _format_rows(prefix: str, values: np.ndarray, fmt: str = "%r") -> str:
    """`prefix v0 v1 ...` lines for a 2-D float array, `%r` = shortest exact round trip."""
    values = np.asarray(values, dtype=np.float64)
    if values.shape[0] == 0:
        return ""
    row = prefix + (" " + fmt) * values.shape[1] + "\n"
    return (row * values.shape[0]) % tuple(values.ravel().tolist())


class ObjWriter:
    """Writes frames of one mesh as OBJ files; the static text is built once in __init__.

    Per frame only the `v` lines (and the `vn` lines, recomputed by `surface_normals` when the
    input had normals) are formatted. Vertex order and count, UVs, the `v/vt/vn` index pattern (with
    the `vn` numbering of `normal_layout`: per vertex, split at the input's hard edges),
    statements (`g`, `o`, `usemtl`, `s`, `mtllib`) and `l` lines are those of the input.
    """

    def __init__(self, mesh: Mesh) -> None:
        self.mesh = mesh
        self._colors = mesh.vertex_properties.get("color")
        if self._colors is not None:
            colors = np.asarray(self._colors, dtype=np.float64)
            if colors.ndim != 2 or colors.shape[0] != mesh.vertex_count or colors.shape[1] < 3:
                colors = None
            else:
                colors = colors[:, :3]
                if np.issubdtype(np.asarray(self._colors).dtype, np.integer):
                    colors = colors / 255.0
            self._colors = colors
        if self._colors is not None:
            require_finite(self._colors, "vertex colours")
        self._has_normals = mesh.normals is not None and mesh.face_normal_indices is not None
        layout = normal_layout(mesh)
        self._corner_normal = None if layout is None else layout.corner_normal
        self._has_uvs = mesh.uvs is not None and mesh.face_uv_indices is not None
        if self._has_uvs:
            require_finite(mesh.uvs, "texture coordinates")
        head = [f"# written by meshdeform: {mesh.vertex_count} vertices, {mesh.face_count} polygons\n"]
        statements = list(mesh.statements)
        head.extend(text + "\n" for count, text in statements if count <= 0)
        # the static parts, encoded once
        self._head = "".join(head).encode("utf-8")
        self._uv_text = (_format_rows("vt", mesh.uvs) if self._has_uvs else "").encode("utf-8")
        tail = self._faces_text([(c, t) for c, t in statements if c > 0]) + self._lines_text()
        self._tail = tail.encode("utf-8")

    def _faces_text(self, statements: list[tuple[int, str]]) -> str:
        mesh = self.mesh
        n_faces = mesh.face_count
        columns = [mesh.face_indices + 1]
        if self._has_uvs and self._has_normals:
            corner = "%d/%d/%d"
            columns += [mesh.face_uv_indices + 1, self._corner_normal + 1]
        elif self._has_uvs:
            corner = "%d/%d"
            columns.append(mesh.face_uv_indices + 1)
        elif self._has_normals:
            corner = "%d//%d"
            columns.append(self._corner_normal + 1)
        else:
            corner = "%d"
        values = np.stack([np.asarray(c, dtype=np.int64) for c in columns], axis=1).ravel().tolist()
        face_sizes = mesh.face_sizes
        uniform = n_faces > 0 and bool(np.all(face_sizes == face_sizes[0]))
        sizes = [] if uniform else face_sizes.tolist()
        by_size = {k: "f" + (" " + corner) * k + "\n" for k in np.flatnonzero(np.bincount(face_sizes)).tolist()}

        def formats(a: int, b: int) -> list[str]:
            """The format strings of faces a..b-1."""
            if uniform:
                return [by_size[int(face_sizes[0])] * (b - a)]
            return list(map(by_size.__getitem__, sizes[a:b]))

        # statements go between faces, at the face count recorded when they were read
        pieces: list[str] = []
        done = 0
        for count, statement in sorted(statements, key=lambda st: st[0]):
            if count >= n_faces:
                break
            pieces += formats(done, count)
            pieces.append(statement.replace("%", "%%") + "\n")
            done = count
        pieces += formats(done, n_faces)
        text = "".join(pieces) % tuple(values)
        trailing = [t for c, t in statements if c >= n_faces]
        return text + "".join(t + "\n" for t in trailing)

    def _lines_text(self) -> str:
        mesh = self.mesh
        if mesh.line_count == 0:
            return ""
        out = []
        flat = (np.asarray(mesh.line_indices, dtype=np.int64) + 1).tolist()
        offs = mesh.line_offsets.tolist()
        for k in range(mesh.line_count):
            out.append("l " + " ".join(map(str, flat[offs[k] : offs[k + 1]])) + "\n")
        return "".join(out)

    def _frame_parts(self, positions: np.ndarray | None, path: PathLike | None = None) -> list[bytes]:
        mesh = self.mesh
        pos = mesh.positions if positions is None else np.asarray(positions, dtype=np.float64)
        if pos.shape != mesh.positions.shape:
            raise ExportError(f"positions have shape {pos.shape}, the mesh needs {mesh.positions.shape}")
        require_finite(pos, "vertex positions", path)
        if self._colors is not None:
            v_text = _format_rows("v", np.hstack([pos, self._colors]))
        else:
            v_text = _format_rows("v", pos)
        vn_text = ""
        if self._has_normals:
            normals = surface_normals(mesh, pos)
            require_finite(normals, "normals", path)
            vn_text = _format_rows("vn", normals, "%.7g")
        return [self._head, v_text.encode("ascii"), self._uv_text, vn_text.encode("ascii"), self._tail]

    def text(self, positions: np.ndarray | None = None) -> str:
        """The OBJ text of one frame."""
        return b"".join(self._frame_parts(positions)).decode("utf-8")

    def write(self, path: PathLike, positions: np.ndarray | None = None) -> None:
        """Write one frame to `path` atomically (ExportError, and no file, if anything is not finite)."""
        parts = self._frame_parts(positions, path)
        with atomic_open(path, "wb") as handle:
            for part in parts:
                handle.write(part)


def write_obj(path: PathLike, mesh: Mesh, positions: np.ndarray | None = None) -> None:
    """Write `mesh` (with other `positions` if given) as an OBJ file, atomically."""
    ObjWriter(mesh).write(path, positions)
