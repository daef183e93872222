"""Stanford PLY reading and writing with our own header parser and NumPy.

Why not trimesh or meshio: trimesh rejects files whose `face` element comes before `vertex`
(allowed by the format), meshio fails on list properties it does not know. Here:

- ascii, binary_little_endian and binary_big_endian, every PLY type name (`char`/`int8` ...
  `double`/`float64`), elements in any order, CR / LF / CRLF header lines;
- binary elements of scalars are one `np.frombuffer`; list elements take a vectorised path when
  every row has the same list lengths (checked), else a walk over the rows that records offsets
  followed by vectorised gathers;
- `vertex_indices` / `vertex_index` become polygons, `nx ny nz` normals, `u v` / `s t` /
  `texture_u texture_v` UVs (or, without those, a face list `texcoord` of u v per corner, as
  MeshLab writes UVs with seams), `red green blue [alpha]` a `color` array (each also kept under
  its own name); other vertex / face scalars go to `vertex_properties` / `face_properties` with
  their types; other list properties and other elements are skipped.

Reads are exact or refused: an ascii row must hold exactly the values its properties declare
(one row per line, blank lines skipped, nothing after the last declared row), a binary body
must be exactly as long as the header's counts and types say (one trailing line end is
tolerated, as some writers add it), numbers follow C syntax, and NaN / infinite values of kept
properties are refused (non-finite normals are dropped with a warning: the writers recompute
them). Errors are one line: `"<path>: element '<name>' row <r>: <what>"`, `"<path>: line <n>: <what>"`
(header, rows beyond the declared ones) or `"<path>: byte <n>: <what>"` (binary).
"""

from __future__ import annotations

import os
import re
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from meshdeform.errors import MeshLoadError
from meshdeform.geometry import clean_polygons
from meshdeform.io.obj import c_float, parse_numbers, read_mesh_bytes
from meshdeform.mesh import MAX_COORDINATE, Mesh

__all__ = ["PLY_TYPES", "read_ply"]

PathLike = str | os.PathLike[str]

PLY_TYPES: dict[str, str] = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}
PLY_FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}
_END_HEADER = re.compile(rb"(?:^|[\r\n])end_header[ \t]*(\r\n|\n|\r|\Z)")
_HEADER_JUNK = re.compile(rb"[\x00-\x08\x0e-\x1f]")
# bytes.translate tables: the bytes an ascii body may hold (deleted, leaving the others);
# whitespace -> 1, else 0
_TEXT_BYTES = bytes([9, 10, 13, *range(32, 127)])
_IS_SPACE = bytes(1 if c in b" \t\n" else 0 for c in range(256))
_UV_NAMES = (("u", "v"), ("s", "t"), ("texture_u", "texture_v"), ("texture_s", "texture_t"))
_INDEX_NAMES = ("vertex_indices", "vertex_index")
FACE_RESERVED = ("vertex_indices", "vertex_index", "texcoord")
_CORNER_UV_NAMES = ("texcoord", "texcoords")  # face lists of u v per corner (MeshLab, OpenMesh)


@dataclass
class _Property:
    name: str
    code: str  # NumPy type code without byte order, e.g. "f4"
    count_code: str | None = None  # set for list properties

    @property
    def is_list(self) -> bool:
        return self.count_code is not None


@dataclass
class _Element:
    name: str
    count: int
    line: int
    props: list[_Property] = field(default_factory=list)

    @property
    def has_lists(self) -> bool:
        return any(p.is_list for p in self.props)


class _Reader:
    """State of one PLY read; `read()` returns the Mesh."""

    def __init__(self, path: PathLike) -> None:
        self.path = path
        self.warnings: list[str] = []

    def fail(self, where: str | None, what: str) -> MeshLoadError:
        return MeshLoadError(f"{self.path}: {where + ': ' if where else ''}{what}")

    # ---- header
    def _header(self, data: bytes) -> tuple[str, list[_Element], int]:
        if not data:
            raise self.fail(None, "empty file")
        if not data.startswith(b"ply"):
            raise self.fail(None, "not a PLY file (it does not start with 'ply')")
        match = _END_HEADER.search(data)
        if match is None:
            junk = _HEADER_JUNK.search(data)
            if junk is not None:
                line = data.count(b"\n", 0, junk.start()) + 1
                raise self.fail(
                    None, f"no end_header: the header is truncated or corrupted (binary data on line {line})"
                )
            raise self.fail(None, "no end_header line: the header is truncated")
        header = data[: match.start()]
        junk = _HEADER_JUNK.search(header)
        if junk is not None:
            line = len(re.split(rb"\r\n|\r|\n", data[: junk.start()]))
            raise self.fail(f"line {line}", "binary data in the PLY header")
        body_start = match.end()
        lines = header.decode("latin-1").splitlines()
        fmt: str | None = None
        elements: list[_Element] = []
        names: set[str] = set()
        for n, raw in enumerate(lines, 1):
            parts = raw.split()
            if n == 1:
                if parts != ["ply"]:
                    raise self.fail("line 1", "not a PLY file (the first line is not 'ply')")
                continue
            if not parts:
                continue
            key = parts[0]
            where = f"line {n}"
            if key in ("comment", "obj_info"):
                continue
            if key == "format":
                if len(parts) < 2 or parts[1] not in PLY_FORMATS:
                    shown = parts[1] if len(parts) > 1 else "(none)"
                    raise self.fail(
                        where, f"unknown PLY format '{shown}' (ascii, binary_little_endian or binary_big_endian)"
                    )
                if fmt is not None:
                    raise self.fail(where, "a second 'format' line")
                fmt = parts[1]
                if len(parts) > 2 and parts[2] not in ("1.0", "1"):
                    self.warnings.append(f"PLY version {parts[2]} is not 1.0; read as 1.0")
            elif key == "element":
                if len(parts) != 3:
                    raise self.fail(where, "an element line needs a name and a count: 'element <name> <count>'")
                if not re.fullmatch(r"[+-]?[0-9]+", parts[2]):  # int() would also take '1_000'
                    raise self.fail(where, f"element count '{parts[2][:24]}' is not a whole number")
                count = int(parts[2])
                if count < 0:
                    raise self.fail(where, f"negative element count {count}")
                if parts[1] in names:
                    raise self.fail(where, f"a second '{parts[1]}' element (the header declares it twice)")
                names.add(parts[1])
                elements.append(_Element(parts[1], count, n))
            elif key == "property":
                if not elements:
                    raise self.fail(where, "a property before any element")
                elements[-1].props.append(self._property(parts, where, elements[-1]))
            else:
                raise self.fail(where, f"unexpected header line '{raw.strip()[:40]}'")
        if fmt is None:
            raise self.fail(None, "the header has no 'format' line")
        return fmt, elements, body_start

    def _property(self, parts: list[str], where: str, element: _Element) -> _Property:
        if len(parts) >= 2 and parts[1] == "list":
            if len(parts) != 5:
                raise self.fail(where, "a list property needs 'property list <count type> <item type> <name>'")
            for t in parts[2:4]:
                if t not in PLY_TYPES:
                    raise self.fail(where, f"unknown property type '{t}'")
            if PLY_TYPES[parts[2]][0] == "f":
                raise self.fail(where, f"a list count type must be an integer type, not '{parts[2]}'")
            prop = _Property(parts[4], PLY_TYPES[parts[3]], PLY_TYPES[parts[2]])
        else:
            if len(parts) != 3:
                raise self.fail(where, "a property needs 'property <type> <name>'")
            if parts[1] not in PLY_TYPES:
                raise self.fail(where, f"unknown property type '{parts[1]}'")
            prop = _Property(parts[2], PLY_TYPES[parts[1]])
        if any(p.name == prop.name for p in element.props):
            raise self.fail(where, f"property '{prop.name}' appears twice in element '{element.name}'")
        return prop

    # ---- binary body
    def _binary(self, data: bytes, offset: int, element: _Element, order: str) -> tuple[dict, int]:
        """Read one element: {name: array} for scalars, {name: (counts, flat items)} for lists."""
        where = f"element '{element.name}'"
        props = element.props
        count = element.count
        left = len(data) - offset
        if not props:
            return {}, offset
        if not element.has_lists:
            dt = np.dtype([(f"f{i}", order + p.code) for i, p in enumerate(props)])
            need = dt.itemsize * count
            if need > left:
                raise self.fail(
                    f"{where} row {left // dt.itemsize}",
                    f"the file ends early: {count} rows of {dt.itemsize} bytes need {need} bytes, {left} are left "
                    "(truncated file?)",
                )
            rows = np.frombuffer(data, dt, count, offset)
            return {p.name: rows[f"f{i}"] for i, p in enumerate(props)}, offset + need
        min_row = sum(np.dtype(p.count_code or p.code).itemsize for p in props)
        if min_row * count > left:
            raise self.fail(
                where, f"the file ends early: {count} rows need at least {min_row * count} bytes, {left} left"
            )
        if count == 0:
            return {p.name: (np.zeros(0, np.int64), np.zeros(0, p.code)) if p.is_list else np.zeros(0, p.code)
                    for p in props}, offset  # fmt: skip
        fast = self._binary_uniform(data, offset, element, order)
        if fast is not None:
            return fast
        return self._binary_walk(data, offset, element, order)

    def _peek_counts(self, data: bytes, offset: int, element: _Element, order: str) -> list[int] | None:
        counts = []
        pos = offset
        for p in element.props:
            if p.is_list:
                size = np.dtype(p.count_code).itemsize
                if pos + size > len(data):
                    return None
                c = int(np.frombuffer(data, order + p.count_code, 1, pos)[0])
                if c < 0:
                    return None
                counts.append(c)
                pos += size + c * np.dtype(p.code).itemsize
            else:
                pos += np.dtype(p.code).itemsize
        return counts

    def _binary_uniform(self, data: bytes, offset: int, element: _Element, order: str) -> tuple[dict, int] | None:
        """Vectorised path: every row has the list lengths of the first row (checked)."""
        counts = self._peek_counts(data, offset, element, order)
        if counts is None:
            return None
        it = iter(counts)
        row_size = sum(
            np.dtype(p.count_code).itemsize + next(it) * np.dtype(p.code).itemsize
            if p.is_list
            else np.dtype(p.code).itemsize
            for p in element.props
        )
        if row_size * element.count > len(data) - offset:
            return None
        fields = []
        it = iter(counts)
        for i, p in enumerate(element.props):
            if p.is_list:
                fields.append((f"n{i}", order + p.count_code))
                fields.append((f"f{i}", order + p.code, (next(it),)))
            else:
                fields.append((f"f{i}", order + p.code))
        dt = np.dtype(fields)
        need = dt.itemsize * element.count
        if need > len(data) - offset:
            return None
        rows = np.frombuffer(data, dt, element.count, offset)
        it = iter(counts)
        out: dict = {}
        for i, p in enumerate(element.props):
            if p.is_list:
                c = next(it)
                if not np.all(rows[f"n{i}"] == c):
                    return None
                out[p.name] = (np.full(element.count, c, dtype=np.int64), rows[f"f{i}"].reshape(-1))
            else:
                out[p.name] = rows[f"f{i}"]
        return out, offset + need

    def _binary_walk(self, data: bytes, offset: int, element: _Element, order: str) -> tuple[dict, int]:
        """Rows of varying list lengths: one pass records where every value is, then gathers."""
        n = len(data)
        plan = []
        for i, p in enumerate(element.props):
            if p.is_list:
                cdt = np.dtype(p.count_code)
                unpack = struct.Struct(order + cdt.char).unpack_from
                plan.append((i, True, cdt.itemsize, unpack, np.dtype(p.code).itemsize))
            else:
                plan.append((i, False, np.dtype(p.code).itemsize, None, 0))
        starts: dict[int, list[int]] = {i: [] for i in range(len(element.props))}
        lengths: dict[int, list[int]] = {i: [] for i, p in enumerate(element.props) if p.is_list}
        pos = offset
        for r in range(element.count):
            for i, is_list, size, unpack, item in plan:
                if is_list:
                    if pos + size > n:
                        raise self.fail(f"element '{element.name}' row {r}", "the file ends early (truncated file?)")
                    c = unpack(data, pos)[0]
                    if c < 0:
                        raise self.fail(f"element '{element.name}' row {r}", f"negative list length {c}")
                    starts[i].append(pos + size)
                    lengths[i].append(c)
                    pos += size + c * item
                else:
                    starts[i].append(pos)
                    pos += size
            if pos > n:
                raise self.fail(f"element '{element.name}' row {r}", "the file ends early (truncated file?)")
        raw = np.frombuffer(data, np.uint8)
        out: dict = {}
        for i, p in enumerate(element.props):
            dt = np.dtype(order + p.code)
            begin = np.array(starts[i], dtype=np.int64)
            if p.is_list:
                lens = np.array(lengths[i], dtype=np.int64)
                total = int(lens.sum())
                first = np.zeros(lens.shape[0], dtype=np.int64)
                np.cumsum(lens[:-1], out=first[1:])
                local = np.arange(total, dtype=np.int64) - np.repeat(first, lens)
                item_pos = np.repeat(begin, lens) + local * dt.itemsize
                values = raw[item_pos[:, None] + np.arange(dt.itemsize)].reshape(-1).view(dt)
                out[p.name] = (lens, values)
            else:
                out[p.name] = raw[begin[:, None] + np.arange(dt.itemsize)].reshape(-1).view(dt)
        return out, pos

    # ---- ascii body
    def _ascii_body(self, data: bytes, body: int, elements: list[_Element]) -> dict[str, dict]:
        """Every element of an ascii body, each row on its own line, read exactly or refused.

        One row per non-blank line: the values of a row must be exactly what its properties
        declare (a list's length, then that many values), and no line may follow the last
        declared row, so a wrong count in the header or a stray value on a line is an error
        naming the element and row instead of a read shifted by a value. Numbers are parsed in
        one C call (C decimal syntax: no '1_000'); tokens per line are counted with NumPy.
        """
        text = data[body:]
        controls = text.translate(None, _TEXT_BYTES)
        if controls:
            at = body + text.find(controls[:1])
            raise self.fail(f"byte {at}", "binary data in an ascii PLY body (the header says 'format ascii')")
        if b"\r" in text:
            text = text.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
        first_line = len(re.split(rb"\r\n|\r|\n", data[:body]))  # the file's line number of the body's first line
        raw = np.frombuffer(text, dtype=np.uint8)
        space = np.frombuffer(text.translate(_IS_SPACE), dtype=np.bool_)
        starts = ~space
        starts[1:] &= space[:-1]
        token_at = np.flatnonzero(starts)
        line_start = np.concatenate([[0], np.flatnonzero(raw == 10) + 1])
        first_token = np.append(np.searchsorted(token_at, line_start), token_at.shape[0])
        per_line = np.diff(first_token)  # tokens on each line of the body
        filled = np.flatnonzero(per_line)
        row_lines = filled + first_line  # file line number of every row
        row_width = per_line[filled]
        row_start = np.zeros(row_width.shape[0] + 1, dtype=np.int64)
        np.cumsum(row_width, out=row_start[1:])
        values = parse_numbers(text, int(token_at.shape[0]))
        if values is None:  # find the culprit token (NumPy and `c_float` agree on the syntax)
            tokens = text.split()
            numbers = [c_float(t.decode("ascii")) for t in tokens]
            bad = next((k for k, v in enumerate(numbers) if v is None), None)
            if bad is None:
                values = np.array(numbers, dtype=np.float64)
        if values is None:
            row = int(np.searchsorted(row_start, bad, side="right") - 1)
            element, r = self._element_row(elements, row)
            raise self.fail(
                f"element '{element}' row {r}",
                f"cannot parse '{tokens[bad][:24].decode('latin-1')}' as a number (line {int(row_lines[row])})",
            )
        parsed: dict[str, dict] = {}
        row = 0
        n_rows = row_width.shape[0]
        for element in elements:
            if row + element.count > n_rows:
                raise self.fail(
                    f"element '{element.name}' row {n_rows - row}", "the file ends early (truncated file?)"
                )
            rows = slice(row, row + element.count)
            parsed[element.name] = self._ascii_element(
                element, values, row_start[rows], row_width[rows], row_lines[rows]
            )
            row += element.count
        if row < n_rows:
            last = elements[-1] if elements else None
            declared = f"'{last.name}' has {last.count} rows" if last else "no elements"
            raise self.fail(
                f"line {int(row_lines[row])}",
                f"more rows than the header declares (the last element {declared}; {n_rows - row} rows follow)",
            )
        return parsed

    def _element_row(self, elements: list[_Element], row: int) -> tuple[str, int]:
        """The element and its row number of the `row`-th row of an ascii body."""
        for element in elements:
            if row < element.count:
                return element.name, row
            row -= element.count
        return (elements[-1].name if elements else "none"), (elements[-1].count if elements else 0) + row

    def _ascii_element(
        self, element: _Element, values: np.ndarray, start: np.ndarray, width: np.ndarray, lines: np.ndarray
    ) -> dict:
        """One element from the values of its rows: row k holds values[start[k] : start[k] + width[k]].

        Property by property for all rows at once: a scalar takes one value, a list its length
        and that many values; then every row must have been used up exactly.
        """
        count = element.count
        out: dict = {}
        used = np.zeros(count, dtype=np.int64)  # values taken so far in each row
        for p in element.props:
            short = np.flatnonzero(used >= width)
            if short.shape[0]:
                self._row_width_error(element, int(short[0]), width, lines, used)
            at = start + used
            if not p.is_list:
                out[p.name] = self._typed(values[at], p, element)
                used += 1
                continue
            lengths = values[at]
            good = np.isfinite(lengths) & (lengths >= 0) & (lengths == np.floor(lengths))
            if not good.all():
                r = int(np.flatnonzero(~good)[0])
                raise self.fail(
                    f"element '{element.name}' row {r}",
                    f"list length {float(lengths[r])!r} of '{p.name}' is not a whole number >= 0 "
                    f"(line {int(lines[r])})",
                )
            lens = lengths.astype(np.int64)
            over = np.flatnonzero(used + 1 + lens > width)
            if over.shape[0]:
                r = int(over[0])
                raise self.fail(
                    f"element '{element.name}' row {r}",
                    f"the list '{p.name}' declares {int(lens[r])} values, line {int(lines[r])} holds only "
                    f"{int(width[r] - used[r] - 1)} after it",
                )
            first = np.zeros(count, dtype=np.int64)
            np.cumsum(lens[:-1], out=first[1:])
            local = np.arange(int(lens.sum()), dtype=np.int64) - np.repeat(first, lens)
            out[p.name] = (lens, values[np.repeat(at + 1, lens) + local])
            used += 1 + lens
        extra = np.flatnonzero(used != width)
        if extra.shape[0]:
            self._row_width_error(element, int(extra[0]), width, lines, used)
        if not element.props:
            return {}
        return out

    def _row_width_error(
        self, element: _Element, r: int, width: np.ndarray, lines: np.ndarray, used: np.ndarray
    ) -> None:
        declared = " ".join(("list " if p.is_list else "") + p.name for p in element.props)
        if used[r] < width[r]:
            what = f"{int(width[r] - used[r])} values more than its properties ({declared}) take"
        else:
            what = f"{int(width[r])} values, too few for its properties ({declared})"
        raise self.fail(f"element '{element.name}' row {r}", f"line {int(lines[r])} holds {what}")

    def _typed(self, values: np.ndarray, prop: _Property, element: _Element) -> np.ndarray:
        """ASCII values (parsed as float64) in the property's declared type, checked."""
        dt = np.dtype(prop.code)
        if dt.kind == "f":
            return values.astype(dt)
        info = np.iinfo(dt)
        bad = ~np.isfinite(values) | (values != np.round(values)) | (values < info.min) | (values > info.max)
        if np.any(bad):
            r = int(np.flatnonzero(bad)[0])
            raise self.fail(
                f"element '{element.name}' row {r}",
                f"{prop.name} = {float(values[r])!r} is not a valid {dt.name} value",
            )
        return values.astype(dt)

    # ---- assemble
    def read(self) -> Mesh:
        data = read_mesh_bytes(self.path)
        fmt, elements, body = self._header(data)
        order = PLY_FORMATS[fmt]
        parsed: dict[str, dict] = {}
        if order is None:
            parsed = self._ascii_body(data, body, elements)
        else:
            pos = body
            for element in elements:
                parsed[element.name], pos = self._binary(data, pos, element, order)
            left = data[pos:]
            if left and left not in (b"\n", b"\r\n", b"\r"):  # one line end after the body is tolerated
                last = "the header"
                if elements:
                    last = f"the last element ('{elements[-1].name}', {elements[-1].count} rows)"
                raise self.fail(
                    f"byte {pos}",
                    f"{len(left)} bytes after {last}: the header's counts or types do not match the body",
                )
        with np.errstate(invalid="ignore", over="ignore"):  # NaN bit patterns: reported, not warned
            return self._mesh(elements, parsed)

    def _mesh(self, elements: list[_Element], parsed: dict[str, dict]) -> Mesh:
        by_name = {e.name: e for e in elements}
        if "vertex" not in by_name:
            raise self.fail(None, "no 'vertex' element")
        vertex = by_name["vertex"]
        vdata = parsed["vertex"]
        names = [p.name for p in vertex.props]
        missing = [c for c in "xyz" if c not in names or by_name["vertex"].props[names.index(c)].is_list]
        if missing:
            raise self.fail("element 'vertex'", f"no scalar property {', '.join(missing)}")
        n_v = vertex.count
        if n_v == 0 and ("face" not in by_name or by_name["face"].count == 0):
            raise self.fail(None, "no vertices and no faces: nothing to load")
        positions = np.stack([np.asarray(vdata[c], dtype=np.float64) for c in "xyz"], axis=1)
        finite = np.isfinite(positions).all(axis=1)
        if not finite.all():
            r = int(np.flatnonzero(~finite)[0])
            raise self.fail(f"element 'vertex' row {r}", f"non-finite position {positions[r].tolist()}")
        huge = np.abs(positions).max(axis=1, initial=0.0) > MAX_COORDINATE
        if huge.any():
            r = int(np.flatnonzero(huge)[0])
            raise self.fail(
                f"element 'vertex' row {r}",
                f"position {positions[r].tolist()} is beyond the limit of {MAX_COORDINATE:g} for a coordinate",
            )

        used = {"x", "y", "z"}
        normals = None
        if all(c in vdata and not isinstance(vdata[c], tuple) for c in ("nx", "ny", "nz")):
            normals = np.stack([np.asarray(vdata[c], dtype=np.float64) for c in ("nx", "ny", "nz")], axis=1)
            used |= {"nx", "ny", "nz"}
            bad = ~np.isfinite(normals).all(axis=1)
            if bad.any():  # writers recompute normals from the positions: drop them, as OBJ does
                self.warnings.append(
                    f"dropped the normals: {int(bad.sum())} of {n_v} are not finite (first: vertex row "
                    f"{int(np.flatnonzero(bad)[0])})"
                )
                normals = None
        uvs = None
        for a, b in _UV_NAMES:
            if a in vdata and b in vdata and not isinstance(vdata[a], tuple) and not isinstance(vdata[b], tuple):
                uvs = np.stack([np.asarray(vdata[a], dtype=np.float64), np.asarray(vdata[b], dtype=np.float64)], 1)
                used |= {a, b}
                break
        vertex_properties: dict[str, np.ndarray] = {}
        for p in vertex.props:
            if p.name in used or p.is_list:
                continue
            vertex_properties[p.name] = np.ascontiguousarray(vdata[p.name]).astype(np.dtype(p.code), copy=False)
        self._refuse_nonfinite("vertex", vertex_properties)
        if uvs is not None:
            self._refuse_nonfinite("vertex", {"texture coordinate": uvs})
        if all(c in vertex_properties for c in ("red", "green", "blue")):
            channels = ["red", "green", "blue"] + (["alpha"] if "alpha" in vertex_properties else [])
            vertex_properties["color"] = np.stack([vertex_properties[c] for c in channels], axis=1)

        face_indices = np.zeros(0, dtype=np.int64)
        offsets = np.zeros(1, dtype=np.int64)
        face_properties: dict[str, np.ndarray] = {}
        corner_uvs = None
        if "face" in by_name:
            face = by_name["face"]
            fdata = parsed["face"]
            index_prop = next((p for p in face.props if p.name in _INDEX_NAMES and p.is_list), None)
            if index_prop is None:
                if face.count:
                    raise self.fail("element 'face'", "no 'vertex_indices' list property")
            else:
                lens, flat = fdata[index_prop.name]
                offsets = np.zeros(lens.shape[0] + 1, dtype=np.int64)
                np.cumsum(lens, out=offsets[1:])
                values = np.asarray(flat, dtype=np.float64)  # exact for every PLY integer type
                bad = ~((values >= 0) & (values < n_v) & (values == np.floor(values)))  # also catches NaN
                if np.any(bad):
                    c = int(np.flatnonzero(bad)[0])
                    r = int(np.searchsorted(offsets, c, side="right") - 1)
                    value = float(values[c])
                    shown = int(value) if value.is_integer() else value
                    raise self.fail(f"element 'face' row {r}", f"vertex index {shown} out of range ({n_v} vertices)")
                face_indices = values.astype(np.int64)
            for p in face.props:
                if not p.is_list:
                    face_properties[p.name] = np.ascontiguousarray(fdata[p.name]).astype(np.dtype(p.code), copy=False)
                elif p.name in _CORNER_UV_NAMES and uvs is None and corner_uvs is None and index_prop is not None:
                    lens, flat = fdata[p.name]
                    if np.array_equal(lens, 2 * np.diff(offsets)):  # MeshLab: u v per corner
                        corner_uvs = np.asarray(flat, dtype=np.float64).reshape(-1, 2)
            self._refuse_nonfinite("face", face_properties)
            if corner_uvs is not None:
                corner_row = np.repeat(np.arange(face.count), np.diff(offsets))
                self._refuse_nonfinite("face", {"texcoord": corner_uvs}, corner_row)
        elif vertex.count:
            self.warnings.append("the file has no 'face' element, only vertices")
        skipped = [e for e in elements if e.name not in ("vertex", "face")]
        if skipped:
            listed = ", ".join(f"'{e.name}' ({e.count} rows)" for e in skipped)
            self.warnings.append(f"ignored elements {listed}")

        cleanup = clean_polygons(face_indices, offsets)
        if offsets.shape[0] > 1 and not cleanup.face_keep.any():
            raise self.fail(
                "element 'face'",
                f"no usable face: all {offsets.shape[0] - 1} faces have fewer than 3 distinct vertices",
            )
        if not cleanup.face_keep.all() or cleanup.repaired.any():
            n_faces = offsets.shape[0] - 1
            self._report_cleanup(cleanup)
            corner_face = np.repeat(np.arange(n_faces, dtype=np.int64), np.diff(offsets))
            face_indices = face_indices[cleanup.corner_keep]
            corner_uvs = None if corner_uvs is None else corner_uvs[cleanup.corner_keep]
            sizes = np.bincount(corner_face[cleanup.corner_keep], minlength=n_faces)[cleanup.face_keep]
            offsets = np.zeros(sizes.shape[0] + 1, dtype=np.int64)
            np.cumsum(sizes, out=offsets[1:])
            face_properties = {k: v[cleanup.face_keep] for k, v in face_properties.items()}

        face_uv_indices = None if uvs is None else face_indices.copy()
        if corner_uvs is not None:
            uvs, face_uv_indices = corner_uvs, np.arange(corner_uvs.shape[0], dtype=np.int64)
        return Mesh(
            positions=positions,
            face_indices=face_indices,
            face_offsets=offsets,
            uvs=uvs,
            face_uv_indices=face_uv_indices,
            normals=normals,
            face_normal_indices=None if normals is None else face_indices.copy(),
            vertex_properties=vertex_properties,
            face_properties=face_properties,
            source=Path(self.path),
            warnings=tuple(self.warnings),
        )

    def _refuse_nonfinite(self, element: str, arrays: dict[str, np.ndarray], row_of: np.ndarray | None = None) -> None:
        """MeshLoadError naming the row of the first NaN or infinity in float `arrays` (rows first;
        `row_of` maps array rows to element rows when they differ, as for per-corner values)."""
        for name, values in arrays.items():
            if values.dtype.kind != "f":
                continue
            bad = ~np.isfinite(values.reshape(values.shape[0], -1)).all(axis=1)
            if bad.any():
                r = int(np.flatnonzero(bad)[0])
                r = r if row_of is None else int(row_of[r])
                raise self.fail(f"element '{element}' row {r}", f"non-finite {name} value")

    def _report_cleanup(self, cleanup) -> None:
        for mask, what in (
            (cleanup.too_small, "faces with fewer than 3 vertices"),
            (cleanup.degenerate, "degenerate faces with fewer than 3 distinct vertices"),
        ):
            if mask.any():
                self.warnings.append(
                    f"dropped {int(mask.sum())} {what} (first: face row {int(np.flatnonzero(mask)[0])})"
                )
        if cleanup.repaired.any():
            self.warnings.append(
                f"removed repeated consecutive vertices from {int(cleanup.repaired.sum())} faces "
                f"(first: face row {int(np.flatnonzero(cleanup.repaired)[0])})"
            )


def read_ply(path: PathLike) -> Mesh:
    """Read a PLY file (ascii or binary, any element order) into a Mesh; MeshLoadError if broken."""
    return _Reader(path).read()
