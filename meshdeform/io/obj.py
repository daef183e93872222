"""Wavefront OBJ reading and writing: polygons, UV seams, authored normals and groups kept.

Reading works on the bytes with NumPy: lines are sorted by keyword from their first bytes, the
lines of each keyword are cut out in one go, and their numbers parsed in one C call (all `v`
lines at once; all faces at once when every corner has the same `v/vt/vn` pattern, which is
checked per corner). Only unusual lines (statements, leading whitespace) go through Python. A
slow line-by-line path takes over when the fast one does not apply; it is also what names the line
of an error. Broken input raises `MeshLoadError` with one line `"<path>: line <n>: <what>"` (or `byte <n>`
for a file that is not text, whose bytes are never quoted); repairable oddities (degenerate
polygons, dangling or non-finite normals, UV references, colours on only some vertex lines,
`mtllib` names outside the mesh's folder, which are not copied) are repaired and reported in
`Mesh.warnings`. Numbers are C decimal numbers (`1_000` is refused), NaN and infinity are refused
for positions, colours and UVs, and a file whose every face is malformed is refused.

Writing precomputes everything that does not change between frames (faces, `vt`, statements),
so a frame costs only the formatting of `v` (and recomputed `vn`) lines.
"""

from __future__ import annotations

import codecs
import os
import re
import warnings
from collections.abc import Iterable
from pathlib import Path
from typing import NamedTuple

import numpy as np

from meshdeform.errors import MeshLoadError
from meshdeform.geometry import PolygonCleanup, clean_polygons
from meshdeform.io.files import special_file_kind
from meshdeform.mesh import MAX_COORDINATE, Mesh

__all__ = [
    "MaterialLibrary",
    "c_float",
    "material_libraries",
    "parse_numbers",
    "read_mesh_bytes",
    "read_obj",
]

PathLike = str | os.PathLike[str]

# statements replayed by the writer (grouping and material state between faces)
_KEPT_STATEMENTS = frozenset({"g", "o", "s", "usemtl", "mtllib"})
# valid OBJ statements we do not use (free-form geometry, display attributes, points)
_IGNORED_STATEMENTS = frozenset(
    {
        "p", "vp", "cstype", "deg", "bmat", "step", "curv", "curv2", "surf", "parm", "trim", "hole",
        "scrv", "sp", "end", "con", "mg", "bevel", "c_interp", "d_interp", "lod", "usemap", "maplib",
        "shadow_obj", "trace_obj", "ctech", "stech", "call", "csh",
    }
)  # fmt: skip
_KIND = {"v": 1, "vt": 2, "vn": 3, "f": 4}
_MSVC_NONFINITE = re.compile(r"^[-+]?\d*\.?\d*#(IND|INF|QNAN|SNAN)\w*$", re.IGNORECASE)
# OBJ numbers are C (strtod) decimal numbers: Python's float() and int() also take '1_000',
# Unicode digits and surrounding spaces, which no OBJ writer produces and no other reader accepts.
# strtod's nan / inf spellings are numbers too (refused later as non-finite, with the line).
_C_FLOAT = re.compile(
    r"[+-]?(?:(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|inf(?:inity)?|nan(?:\([0-9A-Za-z_]*\))?)",
    re.IGNORECASE,
)
_C_INT = re.compile(r"[+-]?[0-9]+")
_CONTROL_BYTES = bytes([*range(0x00, 0x09), *range(0x0E, 0x1A), *range(0x1B, 0x20)])
_NOT_CONTROL = bytes(sorted(set(range(256)) - set(_CONTROL_BYTES)))
_MISSING = np.iinfo(np.int64).min  # a corner without a vt / vn reference
_HUGE = 2**62  # indices are clamped to +-_HUGE: far out of range, and no int64 overflow
# a comment starts with '#' at the start of a token; MSVC's "1.#IND" is a (non-finite) number
_COMMENT = re.compile(r"(?:^|\s)#.*")
# put in place of the keyword of each line, so one bulk parse also gives the line lengths; NaN
# parses fastest, and data that holds NaN itself fails the count check and takes the slow path
_SENTINEL = b" nan "
# bytes.translate tables: whitespace -> 1 (else 0); 'f' and '/' -> space (else unchanged)
_IS_SPACE = bytes(1 if c in b" \t\n" else 0 for c in range(256))
_FACE_DIGITS = bytes.maketrans(b"f/", b"  ")


# --------------------------------------------------------------------------- shared helpers


def read_mesh_bytes(path: PathLike) -> bytes:
    """The bytes of a mesh file, or a one-line MeshLoadError naming the file."""
    p = Path(path)
    if (kind := special_file_kind(p)) is not None:
        raise MeshLoadError(f"{path}: is {kind}, not a mesh file")
    try:
        return p.read_bytes()
    except FileNotFoundError:
        raise MeshLoadError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise MeshLoadError(f"{path}: is a directory, not a mesh file") from None
    except PermissionError:
        raise MeshLoadError(f"{path}: permission denied") from None
    except OSError as exc:
        raise MeshLoadError(f"{path}: cannot read: {exc.strerror or exc}") from None


def parse_numbers(data: bytes, count: int) -> np.ndarray | None:
    """`count` whitespace-separated C decimal numbers parsed in one C call (float64), or None if
    any token is not one or the count differs (shared by the OBJ and ascii PLY readers)."""
    if count == 0:
        return np.zeros(0)
    values = _parse_all(data, np.float64)
    return values if values is not None and values.shape[0] == count else None


def c_float(token: str) -> float | None:
    """A token as a C decimal number (NaN / infinity included), or None if it is not one."""
    if _C_FLOAT.fullmatch(token):
        return float(token.split("(")[0])
    if _MSVC_NONFINITE.match(token):  # MSVC's printf of NaN / infinity
        return float("nan")
    return None


def _c_int(token: str) -> int:
    """A token as a C decimal integer clamped to +-_HUGE; ValueError if it is not one."""
    if not _C_INT.fullmatch(token):
        raise ValueError(token)
    return max(-_HUGE, min(_HUGE, int(token)))


def _line_of_value(counts: np.ndarray, index: int) -> int:
    """The line (0-based, among lines holding `counts` values each) of flat value `index`."""
    return int(np.searchsorted(np.cumsum(counts), index, side="right"))


def _short(text: str, limit: int = 40) -> str:
    """A snippet of a line for an error message."""
    text = text.strip()
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _parse_all(data: bytes, dtype: type) -> np.ndarray | None:
    """Parse whitespace-separated numbers in C (NumPy), or None if any token is not a number.

    Callers check the count (NumPy reads whitespace-only text as one 0).
    """
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            return np.fromstring(data, dtype=dtype, sep=" ")
        except (ValueError, DeprecationWarning):
            return None


def _utf8(data: bytes, path: PathLike, notes: list[str]) -> bytes:
    """The file as UTF-8 bytes without BOM: BOM-marked UTF-8 / UTF-16 / UTF-32, UTF-16 without
    BOM (every other byte zero), else UTF-8, else Latin-1 (with a note). Bytes that are neither
    (control bytes other than tab, line ends and DOS's end-of-file mark) are refused with their
    offset, without quoting them: the file is not text at all."""
    for bom, encoding in (
        (codecs.BOM_UTF32_LE, "utf-32-le"),
        (codecs.BOM_UTF32_BE, "utf-32-be"),
        (codecs.BOM_UTF8, "utf-8"),
        (codecs.BOM_UTF16_LE, "utf-16-le"),
        (codecs.BOM_UTF16_BE, "utf-16-be"),
    ):
        if data.startswith(bom):
            body = data[len(bom) :]
            try:
                text = body.decode(encoding)
            except UnicodeDecodeError as exc:
                line = body[: exc.start].decode(encoding, "replace").count("\n") + 1
                raise MeshLoadError(f"{path}: line {line}: invalid {encoding.upper()} text") from None
            return body if encoding == "utf-8" else text.encode("utf-8")
    head = data[:4096]
    if len(head) >= 4 and head.count(0) * 2 >= len(head) - 1:
        for encoding, zeros in (("utf-16-le", head[1::2]), ("utf-16-be", head[0::2])):
            if not zeros.strip(b"\x00"):
                try:
                    return data.decode(encoding).encode("utf-8")
                except UnicodeDecodeError:
                    break
    controls = data.translate(None, _NOT_CONTROL)
    if controls:  # a PNG, ZIP, binary STL ... renamed: say so, never quote it
        raise MeshLoadError(f"{path}: byte {data.find(controls[:1])}: not a text OBJ file (binary data)")
    if data.isascii():
        return data
    try:
        data.decode("utf-8")
        return data
    except UnicodeDecodeError:
        notes.append("the file is not valid UTF-8; it was read as Latin-1")
        return data.decode("latin-1").encode("utf-8")


class MaterialLibrary(NamedTuple):
    """An `mtllib` file safe to copy beside the frames: `name` (the file name the statement
    gives, to copy it under) and `path` (the file, every symbolic link resolved)."""

    name: str
    path: Path


_DRIVE = re.compile(r"[A-Za-z]:")


def material_libraries(source: PathLike | None, statements: Iterable[tuple[int, str]]) -> tuple[
    list[MaterialLibrary], list[str]
]:  # fmt: skip
    """The `mtllib` files of an OBJ read from `source` that may be copied, and those refused.

    Only names inside the OBJ's folder count: an absolute name (`/x.mtl`, `C:\\x.mtl`), one
    with a `..` part, or one that resolves (through symbolic links) outside the folder is refused,
    so copying a mesh's materials never reads a file elsewhere; so is a name that does not end in
    `.mtl` or has a hidden part (`.ssh/key`): only material libraries are copied. Libraries that do not exist are
    simply absent (neither list). Texture paths inside an .mtl are not looked at. Returns
    (copyable libraries, refused names each with the reason, as "'name' (reason)").
    """
    if source is None:
        return [], []
    folder = Path(source).parent
    root = folder.resolve()
    found: list[MaterialLibrary] = []
    refused: list[str] = []
    for _, text in statements:
        words = text.split()
        if not words or words[0] != "mtllib":
            continue
        for name in words[1:]:
            parts = re.split(r"[\\/]", name)
            if name.startswith(("/", "\\")) or _DRIVE.match(name) or Path(name).is_absolute():
                refused.append(f"'{name}' (an absolute path)")
                continue
            if ".." in parts:
                refused.append(f"'{name}' (it climbs out of the mesh's folder)")
                continue
            hidden = any(part.startswith(".") for part in parts if part not in ("", "."))
            if hidden or not name.lower().endswith(".mtl"):
                refused.append(f"'{name}' (not a .mtl file, or in a hidden folder)")
                continue
            try:
                real = (folder / name).resolve()
            except (OSError, RuntimeError):  # a link loop
                refused.append(f"'{name}' (its links cannot be resolved)")
                continue
            if not real.is_relative_to(root):
                refused.append(f"'{name}' (a link to outside the mesh's folder)")
            elif real.is_file() and all(lib.name != Path(name).name for lib in found):
                found.append(MaterialLibrary(Path(name).name, real))
    return found, refused


class _Lines:
    """The lines of one keyword: their bytes joined (each ending in a newline) for bulk parsing,
    their 1-based line numbers, and their text on demand (slow paths and messages)."""

    def __init__(self, data: bytes, numbers: np.ndarray) -> None:
        self.data = data
        self.numbers = numbers
        self._text: list[str] | None = None

    def __len__(self) -> int:
        return int(self.numbers.shape[0])

    def text(self) -> list[str]:
        if self._text is None:
            self._text = self.data.decode("utf-8", "replace").split("\n")[: len(self)]
        return self._text


# --------------------------------------------------------------------------- reader


class _Reader:
    """State of one OBJ read; `read()` returns the Mesh."""

    def __init__(self, path: PathLike) -> None:
        self.path = path
        self.warnings: list[str] = []

    def fail(self, line: int | None, what: str) -> MeshLoadError:
        where = f"line {line}: " if line is not None else ""
        return MeshLoadError(f"{self.path}: {where}{what}")

    def read(self) -> Mesh:
        data = read_mesh_bytes(self.path)
        if not data or data.isspace():
            raise self.fail(None, "empty file" if not data else "the file holds only whitespace")
        text = _utf8(data, self.path, self.warnings)
        buf = text.rstrip(b"\x1a")  # DOS end-of-file mark
        controls = b"" if text is data else buf.translate(None, _NOT_CONTROL)  # raw bytes: checked by _utf8
        if controls:
            line = buf.count(b"\n", 0, buf.find(controls[:1])) + 1
            raise self.fail(line, "not a text OBJ file (binary data)")
        if b"\r" in buf:
            buf = buf.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
        if b"\\" in buf:
            buf = self._join_continuations(buf)
        if not buf.endswith(b"\n"):
            buf += b"\n"
        return self._build(buf)

    def _check_material_libraries(self, statements: list[tuple[int, str]]) -> None:
        """Warn (in Mesh.warnings, so in the report) about `mtllib` names the exporters will not copy."""
        if not any(text.startswith("mtllib") for _, text in statements):
            return
        _, refused = material_libraries(self.path, statements)
        if refused:
            self.warnings.append(
                f"material libraries outside the mesh's folder are not copied with the frames: {', '.join(refused)}"
            )

    @staticmethod
    def _join_continuations(buf: bytes) -> bytes:
        """Join lines ending in a backslash with the next; the joined text stays at the first
        line and the others become empty, so line numbers stay true."""
        lines = buf.split(b"\n")
        i = 0
        n = len(lines)
        while i < n:
            start = i
            while lines[start].rstrip().endswith(b"\\") and i + 1 < n:
                lines[start] = lines[start].rstrip()[:-1] + b" " + lines[i + 1]
                lines[i + 1] = b""
                i += 1
            if lines[start].rstrip().endswith(b"\\"):
                lines[start] = lines[start].rstrip()[:-1]
            i += 1
        return b"\n".join(lines)

    # ---- pass 1: sort lines by keyword
    def _build(self, buf: bytes) -> Mesh:
        arr = np.frombuffer(buf, dtype=np.uint8)
        ends = np.flatnonzero(arr == 10)
        n_lines = ends.shape[0]
        starts = np.zeros(n_lines, dtype=np.int64)
        starts[1:] = ends[:-1] + 1
        last = arr.shape[0] - 1
        c0 = arr[starts]
        c1 = arr[np.minimum(starts + 1, last)]
        c2 = arr[np.minimum(starts + 2, last)]
        ws1 = (c1 == 32) | (c1 == 9)
        ws2 = (c2 == 32) | (c2 == 9)
        kinds = np.zeros(n_lines, dtype=np.uint8)  # 1 v, 2 vt, 3 vn, 4 f, 5 l
        is_v = c0 == 118
        kinds[is_v & ws1] = 1
        kinds[is_v & (c1 == 116) & ws2] = 2
        kinds[is_v & (c1 == 110) & ws2] = 3
        kinds[(c0 == 102) & ws1] = 4
        other = np.flatnonzero((kinds == 0) & (c0 != 10) & (c0 != 35))

        # the rest (statements, lines with leading whitespace, odd keywords) line by line
        l_items: list[tuple[int, str]] = []
        statements: list[tuple[int, str]] = []
        group_runs: list[tuple[int, tuple[str, ...]]] = []
        group_names: dict[str, None] = {}
        current_g: tuple[str, ...] = ()
        current_o: tuple[str, ...] = ()
        ignored: dict[str, int] = {}
        first_ignored = 0
        unknown = 0
        first_unknown: tuple[int, str] | None = None
        for i, a, b in zip(other.tolist(), starts[other].tolist(), ends[other].tolist(), strict=True):
            stripped = buf[a:b].decode("utf-8", "replace").strip()
            if not stripped or stripped[0] == "#":
                continue
            if "#" in stripped:
                stripped = _COMMENT.sub("", stripped).rstrip()
                if not stripped:
                    continue
            parts = stripped.split()
            key = parts[0]
            if key in _KIND:
                kinds[i] = _KIND[key]
            elif key == "l":
                kinds[i] = 5
                l_items.append((i, " ".join(parts[1:])))
            elif key in _KEPT_STATEMENTS:
                statements.append((i, stripped))
                if key == "g" or key == "o":
                    rest = " ".join(parts[1:])
                    names = tuple(parts[1:]) if key == "g" else ((rest,) if rest else ())
                    if key == "g":
                        current_g = names
                    else:
                        current_o = names
                    for name in names:
                        group_names.setdefault(name)
                    group_runs.append((i, tuple(dict.fromkeys(current_g + current_o))))
            elif key in _IGNORED_STATEMENTS:
                ignored[key] = ignored.get(key, 0) + 1
                first_ignored = first_ignored or i + 1
            else:
                unknown += 1
                if first_unknown is None:
                    first_unknown = (i + 1, stripped)

        counts = np.bincount(kinds, minlength=6)
        self._check_material_libraries(statements)
        if not counts[1] and not counts[4] and not counts[5]:
            if first_unknown is not None:
                raise self.fail(
                    first_unknown[0],
                    "not an OBJ file: no vertex, face or line statement, and this line is not an OBJ statement",
                )
            raise self.fail(None, "no vertices, faces or lines: nothing to load")
        if ignored:
            listed = ", ".join(f"{k} ({n})" for k, n in ignored.items())
            self.warnings.append(
                f"ignored {sum(ignored.values())} unsupported OBJ statements: {listed} (first at line {first_ignored})"
            )
        if first_unknown is not None:
            self.warnings.append(
                f"ignored {unknown} lines with unknown statements (first at line {first_unknown[0]}: "
                f"'{_short(first_unknown[1])}')"
            )

        # the bytes of each keyword's lines, cut out as runs of consecutive lines of one kind
        change = np.flatnonzero(kinds[1:] != kinds[:-1]) + 1
        run_first = np.concatenate([[0], change])
        run_last = np.concatenate([change - 1, [n_lines - 1]])
        run_kind = kinds[run_first]
        byte_kind = None if run_first.shape[0] < 4096 else np.repeat(kinds, ends - starts + 1)

        def cut(k: int) -> _Lines:
            numbers = np.flatnonzero(kinds == k) + 1
            if not numbers.shape[0]:
                return _Lines(b"", numbers)
            if byte_kind is not None:
                return _Lines(arr[byte_kind == k].tobytes(), numbers)
            sel = run_kind == k
            spans = zip(starts[run_first[sel]].tolist(), (ends[run_last[sel]] + 1).tolist(), strict=True)
            return _Lines(b"".join(buf[a:b] for a, b in spans), numbers)

        positions, colors = self._parse_vertices(cut(1))
        uvs = self._parse_uvs(cut(2)) if counts[2] else None
        normals = self._parse_normals(cut(3)) if counts[3] else None
        f_lines = cut(4)

        # how many v / vt / vn / f come before each line, for relative indices and statements
        face_rows = f_lines.numbers - 1
        cum = {k: np.cumsum(kinds == k, dtype=np.int64) for k in (1, 2, 3, 4)}
        before = {k: cum[k][face_rows] for k in (1, 2, 3)}
        sizes, v_raw, vt_raw, vn_raw = self._parse_faces(f_lines)
        if counts[3] and normals is None:  # dropped as non-finite (with a warning): so are the references
            vn_raw = None
        n_faces = sizes.shape[0]
        offsets = np.zeros(n_faces + 1, dtype=np.int64)
        np.cumsum(sizes, out=offsets[1:])
        corner_face = np.repeat(np.arange(n_faces, dtype=np.int64), sizes)
        face_lines = f_lines.numbers

        n_v = positions.shape[0]
        face_indices = self._resolve_vertices(v_raw, before[1][corner_face], n_v, face_lines[corner_face], "face")
        face_uv = self._resolve_optional(
            vt_raw, before[2], corner_face, face_lines, 0 if uvs is None else len(uvs), "UV"
        )
        face_nrm = self._resolve_optional(
            vn_raw, before[3], corner_face, face_lines, 0 if normals is None else len(normals), "normal"
        )
        line_indices, line_offsets = self._parse_lines(l_items, cum[1], n_v)

        cleanup = clean_polygons(face_indices, offsets)
        if n_faces and not cleanup.face_keep.any() and line_offsets.shape[0] == 1:
            raise self.fail(
                int(face_lines[0]),
                f"no usable face: all {n_faces} faces have fewer than 3 distinct vertices (nothing but points left)",
            )
        if not cleanup.face_keep.all() or cleanup.repaired.any():
            self._report_cleanup(cleanup, face_lines)
            keep_c = cleanup.corner_keep
            face_indices = face_indices[keep_c]
            face_uv = None if face_uv is None else face_uv[keep_c]
            face_nrm = None if face_nrm is None else face_nrm[keep_c]
            new_sizes = np.bincount(corner_face[keep_c], minlength=n_faces)[cleanup.face_keep]
            offsets = np.zeros(new_sizes.shape[0] + 1, dtype=np.int64)
            np.cumsum(new_sizes, out=offsets[1:])
        kept_before = np.zeros(n_faces + 1, dtype=np.int64)
        np.cumsum(cleanup.face_keep, out=kept_before[1:])

        face_count_at = cum[4]
        runs = [(int(face_count_at[i]), members) for i, members in group_runs]
        groups = self._groups(group_names, runs, n_faces, cleanup.face_keep, kept_before)
        statements_out = tuple((int(kept_before[face_count_at[i]]), text) for i, text in statements)

        if offsets.shape[0] == 1 and line_offsets.shape[0] == 1:
            self.warnings.append("the file has no polygons or lines, only vertices")
        vertex_properties: dict[str, np.ndarray] = {}
        if colors is not None:
            vertex_properties["color"] = colors
        return Mesh(
            positions=positions,
            face_indices=face_indices,
            face_offsets=offsets,
            uvs=uvs if face_uv is not None else None,
            face_uv_indices=face_uv,
            normals=normals if face_nrm is not None else None,
            face_normal_indices=face_nrm,
            line_indices=line_indices,
            line_offsets=line_offsets,
            statements=statements_out,
            groups=groups,
            vertex_properties=vertex_properties,
            source=Path(self.path),
            warnings=tuple(self.warnings),
        )

    # ---- numbers
    def _rows(self, lines: _Lines, prefix: bytes, what: str) -> tuple[np.ndarray, np.ndarray]:
        """All numbers of the lines of one keyword, flat, and how many each line has.

        Fast path: the keyword of each line is replaced by a sentinel number and everything is
        parsed in one C call; the sentinels give the count per line. Slow path (comments,
        MSVC `1.#IND`, errors): line by line, naming the line of an unparsable number.
        """
        if not len(lines):
            return np.zeros(0), np.zeros(0, dtype=np.int64)
        if b"#" not in lines.data:
            values = _parse_all(lines.data.replace(prefix, _SENTINEL), np.float64)
            if values is not None:
                marks = np.flatnonzero(np.isnan(values))
                if marks.shape[0] == len(lines) and marks[0] == 0:
                    counts = np.diff(np.append(marks, values.shape[0])) - 1
                    keep = np.ones(values.shape[0], dtype=bool)
                    keep[marks] = False
                    return values[keep], counts
        flat: list[float] = []
        counts = np.zeros(len(lines), dtype=np.int64)
        for j, line in enumerate(lines.text()):
            tokens = _COMMENT.sub("", line).split()[1:]
            counts[j] = len(tokens)
            for token in tokens:
                value = c_float(token)
                if value is None:
                    raise self.fail(
                        int(lines.numbers[j]), f"cannot parse '{_short(token, 24)}' as a number ({what})"
                    )
                flat.append(value)
        return np.array(flat, dtype=np.float64), counts

    def _parse_vertices(self, lines: _Lines) -> tuple[np.ndarray, np.ndarray | None]:
        """Positions (V, 3) and, when every vertex line has one, colours (V, 3).

        A vertex line holds `x y z`, `x y z w` (w ignored), `x y z r g b` or `x y z r g b a`
        (a ignored); any other count is refused rather than guessed. Colours on only some lines
        are dropped with a warning (no made-up colour for the others). Every value must be
        finite, colours included.
        """
        values, counts = self._rows(lines, b"v", "vertex coordinate")
        if not len(lines):
            return np.zeros((0, 3)), None
        numbers = lines.numbers
        bad = np.flatnonzero(counts < 3)
        if bad.size:
            j = int(bad[0])
            raise self.fail(int(numbers[j]), f"a vertex needs 3 coordinates, this one has {int(counts[j])}")
        odd = np.flatnonzero((counts == 5) | (counts > 7))
        if odd.size:
            j = int(odd[0])
            raise self.fail(
                int(numbers[j]),
                f"a vertex line holds 3, 4 (x y z w), 6 or 7 (x y z r g b [a]) numbers, this one has {int(counts[j])}",
            )
        uniform = bool(np.all(counts == counts[0]))
        starts = np.zeros(counts.shape[0], dtype=np.int64)
        if not uniform:
            np.cumsum(counts[:-1], out=starts[1:])
        table = values.reshape(-1, int(counts[0]))[:, :3] if uniform else values[starts[:, None] + np.arange(3)]
        bad = ~np.isfinite(values)
        if bad.any():
            first = int(np.flatnonzero(bad)[0])
            j = _line_of_value(counts, first)
            column = first - int(np.sum(counts[:j]))
            what = "position" if column < 3 else ("colour" if column < 6 and counts[j] >= 6 else "value")
            raise self.fail(int(numbers[j]), f"non-finite vertex {what} '{_short(lines.text()[j])}'")
        huge = np.abs(table).max(axis=1, initial=0.0) > MAX_COORDINATE
        if huge.any():
            j = int(np.flatnonzero(huge)[0])
            raise self.fail(
                int(numbers[j]),
                f"vertex position '{_short(lines.text()[j])}' is beyond the limit of {MAX_COORDINATE:g} "
                "for a coordinate",
            )
        colors = None
        has_color = counts >= 6
        if has_color.all():
            rgb = values.reshape(-1, int(counts[0]))[:, 3:6] if uniform else values[starts[:, None] + 3 + np.arange(3)]
            colors = np.ascontiguousarray(rgb, dtype=np.float64)
        elif has_color.any():
            j = int(np.flatnonzero(~has_color)[0])
            self.warnings.append(
                f"dropped all vertex colours: {int((~has_color).sum())} of {counts.shape[0]} vertex lines have no "
                f"colour (first at line {int(numbers[j])})"
            )
        return np.ascontiguousarray(table, dtype=np.float64), colors

    def _parse_uvs(self, lines: _Lines) -> np.ndarray:
        values, counts = self._rows(lines, b"vt", "texture coordinate")
        bad = np.flatnonzero(counts < 1)
        if bad.size:
            raise self.fail(int(lines.numbers[int(bad[0])]), "a texture coordinate (vt) needs at least 1 value")
        self._refuse_nonfinite(lines, values, counts, "texture coordinate")
        for width in (2, 3):
            if np.all(counts == width):
                return values.reshape(-1, width)
        width = 3 if np.any(counts >= 3) else 2
        out = np.zeros((counts.shape[0], width))
        starts = np.zeros(counts.shape[0], dtype=np.int64)
        np.cumsum(counts[:-1], out=starts[1:])
        for k in range(width):
            has = counts > k
            out[has, k] = values[starts[has] + k]
        return out

    def _parse_normals(self, lines: _Lines) -> np.ndarray | None:
        """The `vn` normals (N, 3), or None (with a warning) when one is not finite: the writers
        recompute normals from the positions, so they are dropped as dangling ones are."""
        values, counts = self._rows(lines, b"vn", "normal")
        bad = np.flatnonzero(counts != 3)
        if bad.size:
            j = int(bad[0])
            raise self.fail(int(lines.numbers[j]), f"a normal (vn) needs 3 values, this one has {int(counts[j])}")
        bad = ~np.isfinite(values.reshape(-1, 3)).all(axis=1)
        if bad.any():
            self.warnings.append(
                f"dropped all normals: {int(bad.sum())} of {len(lines)} are not finite (first at line "
                f"{int(lines.numbers[int(np.flatnonzero(bad)[0])])})"
            )
            return None
        return values.reshape(-1, 3)

    def _refuse_nonfinite(self, lines: _Lines, values: np.ndarray, counts: np.ndarray, what: str) -> None:
        """MeshLoadError naming the first line of `lines` that holds a NaN or infinity."""
        bad = ~np.isfinite(values)
        if bad.any():
            j = _line_of_value(counts, int(np.flatnonzero(bad)[0]))
            raise self.fail(int(lines.numbers[j]), f"non-finite {what} '{_short(lines.text()[j])}'")

    # ---- faces
    def _parse_faces(self, lines: _Lines) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
        """Per-face corner counts and the raw (1-based or negative) v / vt / vn indices per
        corner; vt / vn are None when no corner has them, `_MISSING` where a corner lacks one."""
        if not len(lines):
            empty = np.zeros(0, dtype=np.int64)
            return empty, empty, None, None
        fast = self._faces_fast(lines)
        if fast is not None:
            return fast
        return self._faces_slow(lines)

    @staticmethod
    def _faces_fast(lines: _Lines) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None] | None:
        """All faces in one parse, when every corner has the pattern of the first corner.

        Tokens are found on the bytes with NumPy; each corner's slash count (and `//`) is
        checked against the first corner's, and the number count against corners x slots, so
        an empty slot or a stray token sends the file to the slow path.
        """
        if b"#" in lines.data:  # trailing comments
            return None
        fb = np.frombuffer(lines.data, dtype=np.uint8)
        space = np.frombuffer(lines.data.translate(_IS_SPACE), dtype=np.bool_)
        start = ~space
        start[1:] &= space[:-1]
        tok = np.flatnonzero(start)
        kw = fb[tok] == 102  # the 'f' keyword
        n_lines = len(lines)
        if int(kw.sum()) != n_lines or not np.all(space[np.minimum(tok[kw] + 1, fb.shape[0] - 1)]):
            return None
        corner_tok = ~kw
        n_corners = int(corner_tok.sum())
        sizes = np.bincount((np.cumsum(kw) - 1)[corner_tok], minlength=n_lines)
        if n_corners == 0:
            empty = np.zeros(0, dtype=np.int64)
            return sizes, empty, None, None
        slash = np.flatnonzero(fb == 47)
        per_tok = np.bincount(np.searchsorted(tok, slash, side="right") - 1, minlength=tok.shape[0])[corner_tok]
        slashes = int(per_tok[0])
        if slashes > 2 or not np.all(per_tok == slashes):
            return None
        pairs = slash[:-1][np.diff(slash) == 1]  # '//'
        double = False
        if slashes == 2 and pairs.shape[0]:
            per_pair = np.bincount(np.searchsorted(tok, pairs, side="right") - 1, minlength=tok.shape[0])[corner_tok]
            double = bool(per_pair[0])
            if not np.all(per_pair == int(double)):
                return None
        elif pairs.shape[0]:
            return None
        slots = 1 if slashes == 0 else (2 if slashes == 1 or double else 3)
        values = _parse_all(lines.data.translate(_FACE_DIGITS), np.int64)
        if values is None or values.shape[0] != slots * n_corners:
            return None
        table = np.clip(values, -_HUGE, _HUGE).reshape(n_corners, slots)
        vt = table[:, 1] if slots == 3 or (slots == 2 and not double) else None
        vn = table[:, -1] if slashes == 2 else None
        return sizes, table[:, 0], vt, vn

    def _faces_slow(self, lines: _Lines) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
        sizes = np.zeros(len(lines), dtype=np.int64)
        v: list[int] = []
        vt: list[int] = []
        vn: list[int] = []
        missing = int(_MISSING)
        for j, line in enumerate(lines.text()):
            tokens = _COMMENT.sub("", line).split()[1:]
            sizes[j] = len(tokens)
            for token in tokens:
                parts = token.split("/")
                if len(parts) > 3 or not parts[0]:
                    raise self.fail(int(lines.numbers[j]), f"malformed face corner '{_short(token, 24)}'")
                try:
                    v.append(_c_int(parts[0]))
                    vt.append(_c_int(parts[1]) if len(parts) > 1 and parts[1] else missing)
                    vn.append(_c_int(parts[2]) if len(parts) > 2 and parts[2] else missing)
                except ValueError:
                    raise self.fail(
                        int(lines.numbers[j]),
                        f"cannot parse face corner '{_short(token, 24)}' (expected v, v/vt, v//vn or v/vt/vn)",
                    ) from None
        vt_arr = np.array(vt, dtype=np.int64)
        vn_arr = np.array(vn, dtype=np.int64)
        return (
            sizes,
            np.array(v, dtype=np.int64),
            None if np.all(vt_arr == missing) else vt_arr,
            None if np.all(vn_arr == missing) else vn_arr,
        )

    def _resolve_vertices(
        self, raw: np.ndarray, before: np.ndarray, count: int, lines: np.ndarray, element: str
    ) -> np.ndarray:
        """1-based / negative vertex references to 0-based; index 0 or out of range is an error."""
        idx = np.where(raw > 0, raw - 1, before + raw)
        bad = (raw == 0) | (idx < 0) | (idx >= count)
        if np.any(bad):
            j = int(np.flatnonzero(bad)[0])
            r = int(raw[j])
            shown = str(r) if abs(r) < _HUGE else "beyond 64 bits"
            if r == 0:
                raise self.fail(int(lines[j]), f"{element} index 0 (OBJ indices start at 1)")
            if r < 0:
                raise self.fail(
                    int(lines[j]),
                    f"{element} index {shown} out of range (relative index, {int(before[j])} vertices defined "
                    "before it)",
                )
            raise self.fail(int(lines[j]), f"{element} index {shown} out of range ({count} vertices)")
        return idx

    def _resolve_optional(
        self,
        raw: np.ndarray | None,
        before_face: np.ndarray,
        corner_face: np.ndarray,
        face_lines: np.ndarray,
        count: int,
        what: str,
    ) -> np.ndarray | None:
        """vt / vn references; if any corner lacks one or points nowhere, all of them are dropped
        (with a warning) and the mesh loads without UVs / normals."""
        if raw is None:
            return None
        missing = raw == _MISSING
        before = before_face[corner_face]
        idx = np.where(raw > 0, raw - 1, before + raw)
        bad = ~missing & ((raw == 0) | (idx < 0) | (idx >= count))
        total = raw.shape[0]
        plural = "UVs" if what == "UV" else "normals"
        if np.any(bad):
            j = int(np.flatnonzero(bad)[0])
            self.warnings.append(
                f"dropped all {what} references: {int(bad.sum())} of {total} face corners refer to {plural} that do "
                f"not exist (first at line {int(face_lines[corner_face[j]])}: index {int(raw[j])}, {count} defined)"
            )
            return None
        if np.any(missing):
            j = int(np.flatnonzero(missing)[0])
            self.warnings.append(
                f"dropped all {what} references: {int(missing.sum())} of {total} face corners have no {what} "
                f"index (first at line {int(face_lines[corner_face[j]])})"
            )
            return None
        return idx

    def _parse_lines(
        self, items: list[tuple[int, str]], v_before: np.ndarray, n_v: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """`l` polylines (few, so line by line); v/vt corners keep only the vertex."""
        if not items:
            return np.zeros(0, dtype=np.int64), np.zeros(1, dtype=np.int64)
        polylines: list[np.ndarray] = []
        dropped = 0
        first_dropped = 0
        for i, text in items:
            try:
                raw = np.array([_c_int(t.split("/")[0]) for t in text.split()], dtype=np.int64)
            except ValueError:
                raise self.fail(i + 1, f"cannot parse line element 'l {_short(text)}'") from None
            before = np.full(raw.shape, v_before[i])
            idx = self._resolve_vertices(raw, before, n_v, np.full(raw.shape, i + 1), "line element")
            if idx.shape[0] < 2:
                dropped += 1
                first_dropped = first_dropped or i + 1
                continue
            polylines.append(idx)
        if dropped:
            self.warnings.append(
                f"dropped {dropped} line elements with fewer than 2 vertices (first at line {first_dropped})"
            )
        sizes = np.array([p.shape[0] for p in polylines], dtype=np.int64)
        offsets = np.zeros(sizes.shape[0] + 1, dtype=np.int64)
        np.cumsum(sizes, out=offsets[1:])
        flat = np.concatenate(polylines) if polylines else np.zeros(0, dtype=np.int64)
        return flat, offsets

    def _report_cleanup(self, cleanup: PolygonCleanup, face_lines: np.ndarray) -> None:
        def first_line(mask: np.ndarray) -> int:
            return int(face_lines[int(np.flatnonzero(mask)[0])])

        if cleanup.too_small.any():
            n = int(cleanup.too_small.sum())
            self.warnings.append(
                f"dropped {n} face{'s' if n > 1 else ''} with fewer than 3 vertices (first at line "
                f"{first_line(cleanup.too_small)})"
            )
        if cleanup.degenerate.any():
            n = int(cleanup.degenerate.sum())
            self.warnings.append(
                f"dropped {n} degenerate polygon{'s' if n > 1 else ''} with fewer than 3 distinct vertices "
                f"(first at line {first_line(cleanup.degenerate)})"
            )
        if cleanup.repaired.any():
            n = int(cleanup.repaired.sum())
            self.warnings.append(
                f"removed repeated consecutive vertices from {n} polygon{'s' if n > 1 else ''} (first at line "
                f"{first_line(cleanup.repaired)})"
            )

    @staticmethod
    def _groups(
        names: dict[str, None],
        runs: list[tuple[int, tuple[str, ...]]],
        n_faces: int,
        face_keep: np.ndarray,
        kept_before: np.ndarray,
    ) -> dict[str, np.ndarray]:
        """Group / object name -> indices of its faces (after dropped faces are taken out)."""
        ranges: dict[str, list[np.ndarray]] = {name: [] for name in names}
        for k, (start, members) in enumerate(runs):
            end = runs[k + 1][0] if k + 1 < len(runs) else n_faces
            if end > start:
                for name in members:
                    ranges[name].append(np.arange(start, end, dtype=np.int64))
        groups: dict[str, np.ndarray] = {}
        for name, parts in ranges.items():
            faces = np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)
            faces = faces[face_keep[faces]]
            groups[name] = kept_before[faces]
        return groups


def read_obj(path: PathLike) -> Mesh:
    """Read an OBJ file into a Mesh (polygons and vertex order kept); MeshLoadError if broken."""
    return _Reader(path).read()
