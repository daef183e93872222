"""Robustness corpus and runner for issue #13 "Safe on anyone's files".

A deterministic generator of hostile inputs for the `meshdeform` command line (mutated meshes and
recipes, odd encodings, path tricks, every way of mistyping `-o`) and a runner that executes each
case through the real CLI in a fresh subprocess with a time and memory limit, then checks what a
user may expect of a tool fed anyone's files:

- it ends in under `TIME_LIMIT` seconds with exit code 0 or 2 (2: bad input or usage);
- at most one non-empty line on stderr and no Python traceback anywhere;
- nothing outside the run's own output folder changed (every file of the case folder is hashed
  before and after the run), and a failed run leaves no output folder and no `.partial-` folder;
- a successful run's text outputs hold no `nan` / `inf` and no copy of a file from outside.

Cases are plain data (`Case`): files to write into a fresh folder, the CLI arguments and what is
expected of the output folder. `generate(count, seed)` gives the same cases for the same seed
(each case is drawn from its own `random.Random(f"{seed}:{index}")`, so the first N cases of a
larger run are the N cases of a smaller one). `run_case` runs one; `benchmarks/robustness.py`
runs hundreds and prints a table, `tests/test_robustness.py` runs a fixed sample in CI.

The corpus is made at run time from `samples/`, small generated grids and, when present, the
shared real/broken meshes (read in place, never copied into the repository).
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import random
import re
import resource
import shutil
import signal
import stat
import struct
import subprocess
import sys
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SAMPLES = REPO / "samples"

#: seconds a case may take, start-up of the Python process included
TIME_LIMIT = 10.0
#: seconds a timed-out case has after SIGTERM to clean up before SIGKILL
TERM_GRACE = 3.0
#: address-space limit of every case's process (bytes): numba/LLVM start fine under it
MEMORY_LIMIT = 6 * 1024**3
#: what the console script `meshdeform` runs (pyproject: meshdeform = "pipeline.cli:app")
BOOT = "import sys; sys.argv[0] = 'meshdeform'; from pipeline.cli import app; sys.exit(app())"
#: exit codes a case may end with: 0 ok, 2 bad input or usage
ALLOWED_EXIT = (0, 2)
#: cheap test for non-finite numbers written into a text output
_NON_FINITE = re.compile(rb"(?i)(?<![a-z])(nan|inf|infinity)(?![a-z])")

# ----------------------------------------------------------------------------------------------
# Cases


@dataclass
class Case:
    """One CLI run over a folder of files.

    `files` (relative path -> bytes), `links` (relative path -> symlink target) and `fifos`
    (relative paths of named pipes) are created under a fresh case folder; the command runs in
    `cwd` (relative to it). `{root}` in `argv` is replaced by the case folder's absolute path.
    `out` is the `-o` value as typed (None: the command writes nothing); `out_replaceable` says the
    folder is an earlier meshdeform output, whose content a successful run may replace.
    `forbidden` lists files outside the case whose content must never be copied into the output.
    """

    name: str
    category: str
    description: str
    argv: list[str]
    files: dict[str, bytes] = field(default_factory=dict)
    links: dict[str, str] = field(default_factory=dict)
    fifos: list[str] = field(default_factory=list)
    cwd: str = "work"
    out: str | None = None
    out_replaceable: bool = False
    forbidden: list[str] = field(default_factory=list)

    def shown_argv(self, root: Path | None = None) -> str:
        """The command line as a user would type it (for reproducers)."""
        import shlex

        args = [a.replace("{root}", str(root)) if root else a for a in self.argv]
        return "meshdeform " + " ".join(shlex.quote(a) for a in args)


# ----------------------------------------------------------------------------------------------
# Seed material: meshes and recipes


def _shared_meshes() -> Path | None:
    """The shared real/broken meshes folder when present (see tests/shared_meshes.py)."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    try:
        from shared_meshes import find_shared_meshes
    finally:
        sys.path.pop(0)
    return find_shared_meshes()


#: shared meshes larger than this are not used (each case must stay fast on a correct tool)
SHARED_MAX_BYTES = 80_000


@cache
def seed_meshes() -> tuple[tuple[str, bytes], ...]:
    """(file name, bytes) of every valid mesh the mutations start from."""
    found: list[tuple[str, bytes]] = []
    for path in sorted((SAMPLES / "meshes").iterdir()):
        if path.suffix in (".obj", ".ply"):
            found.append((path.name, path.read_bytes()))
    rng = random.Random(1)
    for n in (3, 8, 17):
        found.append((f"grid{n}.obj", obj_grid(n, n, uvs=n != 3, normals=n == 8, groups=n == 17)))
        for fmt in ("ascii", "binary_little_endian", "binary_big_endian"):
            found.append((f"grid{n}_{fmt}.ply", ply_grid(n, n, fmt, rng)))
    shared = _shared_meshes()
    if shared is not None:
        for path in sorted((shared / "real").iterdir()):
            if path.suffix in (".obj", ".ply") and path.stat().st_size <= SHARED_MAX_BYTES:
                found.append((path.name, path.read_bytes()))
    return tuple(found)


@cache
def broken_meshes() -> tuple[tuple[str, bytes], ...]:
    """(file name, bytes) of the shared broken meshes (empty when the folder is absent)."""
    shared = _shared_meshes()
    if shared is None:
        return ()
    return tuple(
        (p.name, p.read_bytes())
        for p in sorted((shared / "broken").iterdir())
        if p.suffix in (".obj", ".ply") and p.stat().st_size <= SHARED_MAX_BYTES
    )


#: sample recipe -> the sample mesh it is written for
RECIPE_MESH = {
    "blackhole": "sheet.obj",
    "cape": "cape.obj",
    "curtain": "curtain.obj",
    "drop": "sheet.obj",
    "flag": "flag.obj",
    "rope": "rope.obj",
    "showcase": "sheet.obj",
    "stressball": "icosphere.ply",
    "tear": "curtain.obj",
}


#: sample mesh -> the files beside the sample recipes that its recipe reads (the body collider)
RECIPE_FILES = {"cape.obj": ("body/body.obj", "body/body.pc2")}


def recipe_files(mesh_name: str, folder: str = "work") -> dict[str, bytes]:
    """{folder/relative path: bytes} of the files the sample recipe for mesh_name reads."""
    return {f"{folder}/{rel}": (SAMPLES / "recipes" / rel).read_bytes() for rel in RECIPE_FILES.get(mesh_name, ())}


def shorten_recipe(text: str, frames: int = 2) -> str:
    """A sample recipe made cheap: `frames` frames, at most 8 substeps, no previews."""
    text = re.sub(r"(?m)^frames\s*=\s*\d+", f"frames = {frames}", text)
    text = re.sub(r"(?m)^substeps\s*=\s*(\d+)", lambda m: f"substeps = {min(int(m.group(1)), 8)}", text)
    return re.sub(r"(?m)^preview\s*=.*$", "", text)


@cache
def seed_recipes() -> tuple[tuple[str, str, str], ...]:
    """(recipe name, shortened recipe text, mesh file name) for every sample recipe."""
    return tuple(
        (path.stem, shorten_recipe(path.read_text()), RECIPE_MESH.get(path.stem, "sheet.obj"))
        for path in sorted((SAMPLES / "recipes").glob("*.toml"))
    )


def sample_mesh(name: str) -> bytes:
    """Bytes of one of samples/meshes."""
    return (SAMPLES / "meshes" / name).read_bytes()


#: every solver, in the order random recipes draw from (this module runs any checkout's CLI without
#: importing its engine: tests/test_robustness.py checks these against the solver registry)
SOLVERS = ("xpbd", "verlet", "anchor", "springs", "implicit")
#: the output formats random recipes draw from: registered formats, usd and xdmf left out
RECIPE_FORMATS = ("obj", "ply", "pc2", "mdd", "npz", "vtk")


def minimal_recipe(rng: random.Random, frames: int = 2) -> str:
    """A short valid recipe with a random solver and random output formats."""
    solver = rng.choice(SOLVERS)
    formats = rng.sample(RECIPE_FORMATS, rng.randint(1, 3))
    listed = ", ".join(f'"{f}"' for f in formats)
    return f'[simulation]\nsolver = "{solver}"\nframes = {frames}\nsubsteps = 4\n\n[output]\nformats = [{listed}]\n'


# ----------------------------------------------------------------------------------------------
# Small generated meshes


def _grid(nx: int, ny: int) -> tuple[list[tuple[float, float, float]], list[tuple[int, int, int, int]]]:
    points = [(x / (nx - 1), 1.0, y / (ny - 1)) for y in range(ny) for x in range(nx)]
    quads = [
        (y * nx + x, y * nx + x + 1, (y + 1) * nx + x + 1, (y + 1) * nx + x)
        for y in range(ny - 1)
        for x in range(nx - 1)
    ]
    return points, quads


def obj_grid(nx: int, ny: int, *, uvs: bool = False, normals: bool = False, groups: bool = False) -> bytes:
    """An nx x ny quad grid in the XZ plane at height 1 as OBJ text (1-based indices)."""
    points, quads = _grid(nx, ny)
    lines = ["# generated grid", *(f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in points)]
    if uvs:
        lines += [f"vt {x:.6f} {z:.6f}" for x, _, z in points]
    if normals:
        lines.append("vn 0 1 0")
    for i, quad in enumerate(quads):
        if groups and i in (0, len(quads) // 2):
            lines.append(f"g part{i}")
        corners = []
        for v in quad:
            k = v + 1
            corners.append(f"{k}/{k}/1" if uvs and normals else f"{k}/{k}" if uvs else f"{k}//1" if normals else f"{k}")
        lines.append("f " + " ".join(corners))
    return ("\n".join(lines) + "\n").encode()


def ply_grid(nx: int, ny: int, fmt: str, rng: random.Random) -> bytes:
    """An nx x ny quad grid as PLY (ascii or binary), with random extra properties.

    Float or double positions, optionally normals, uchar colours and `s t` UVs; the face list's
    count/index types are drawn too, so the readers meet every common layout.
    """
    points, quads = _grid(nx, ny)
    pos_type = rng.choice(["float", "double"])
    props: list[tuple[str, str]] = [(a, pos_type) for a in "xyz"]
    with_normals, with_colour, with_uv = rng.random() < 0.5, rng.random() < 0.5, rng.random() < 0.5
    if with_normals:
        props += [("nx", "float"), ("ny", "float"), ("nz", "float")]
    if with_colour:
        props += [("red", "uchar"), ("green", "uchar"), ("blue", "uchar")]
    if with_uv:
        props += [("s", "float"), ("t", "float")]
    count_type, index_type = rng.choice([("uchar", "int"), ("uchar", "uint"), ("int", "int"), ("ushort", "int")])
    header = ["ply", f"format {fmt} 1.0", f"element vertex {len(points)}"]
    header += [f"property {t} {n}" for n, t in props]
    header += [f"element face {len(quads)}", f"property list {count_type} {index_type} vertex_indices", "end_header"]
    rows = []
    for i, (x, y, z) in enumerate(points):
        row: list[float] = [x, y, z]
        if with_normals:
            row += [0.0, 1.0, 0.0]
        if with_colour:
            row += [i % 256, (3 * i) % 256, 200]
        if with_uv:
            row += [x, z]
        rows.append(row)
    head = ("\n".join(header) + "\n").encode()
    if fmt == "ascii":
        body = "".join(" ".join(f"{v:g}" for v in row) + "\n" for row in rows)
        body += "".join("4 " + " ".join(map(str, q)) + "\n" for q in quads)
        return head + body.encode()
    order = "<" if fmt == "binary_little_endian" else ">"
    codes = {"float": "f", "double": "d", "uchar": "B", "int": "i", "uint": "I", "ushort": "H"}
    vertex_format = order + "".join(codes[t] for _, t in props)
    out = bytearray(head)
    for row in rows:
        out += struct.pack(vertex_format, *row)
    for q in quads:
        out += struct.pack(order + codes[count_type] + codes[index_type] * 4, 4, *q)
    return bytes(out)


def big_polygon_obj(corners: int = 20_000) -> bytes:
    """One polygon of `corners` corners on a circle (the readers' and triangulators' worst case)."""
    import math

    lines = [
        f"v {math.cos(2 * math.pi * i / corners):.6f} 1 {math.sin(2 * math.pi * i / corners):.6f}"
        for i in range(corners)
    ]
    lines.append("f " + " ".join(str(i + 1) for i in range(corners)))
    return ("\n".join(lines) + "\n").encode()


# ----------------------------------------------------------------------------------------------
# Mutations (bytes -> bytes, seeded)

#: replacements for a number in a mesh or recipe
WEIRD_NUMBERS = (
    "1e308", "-1e308", "1e309", "-1e309", str(10**30), "-" + str(10**30), str(2**63), str(2**64), "nan", "NaN",
    "-nan", "inf", "-inf", "Infinity", "1_000", "0x10", "0b11", "1e-400", "-0", "9" * 400, "1.5.5", "+-1", "", "e",
    "١٢", "1,5", "null", "-1", "0", "4294967295", "2147483648", "1e",
)  # fmt: skip
_NUMBER = re.compile(rb"[-+]?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?")


def byte_flips(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """Set 1-8 random bytes to random values."""
    if not data:
        return b"\xff", "one byte 0xff"
    out = bytearray(data)
    k = rng.randint(1, 8)
    for _ in range(k):
        out[rng.randrange(len(out))] = rng.randrange(256)
    return bytes(out), f"{k} random bytes changed"


def truncate(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """Cut the file at a random offset."""
    at = rng.randrange(len(data)) if data else 0
    return data[:at], f"truncated at byte {at} of {len(data)}"


def edit_lines(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """Delete, duplicate or swap random lines."""
    lines = data.split(b"\n")
    if len(lines) < 3:
        return data + data, "file doubled"
    op = rng.choice(["delete", "duplicate", "swap"])
    for _ in range(rng.randint(1, 4)):
        i, j = rng.randrange(len(lines)), rng.randrange(len(lines))
        if op == "delete" and len(lines) > 2:
            del lines[i]
        elif op == "duplicate":
            lines.insert(i, lines[j])
        else:
            lines[i], lines[j] = lines[j], lines[i]
    return b"\n".join(lines), f"lines {op}d"


def weird_numbers(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """Replace 1-3 numbers of the text by huge, negative, non-finite or malformed ones."""
    matches = list(_NUMBER.finditer(data))
    if not matches:
        return data, "no number to replace"
    chosen = sorted(rng.sample(matches, min(len(matches), rng.randint(1, 3))), key=lambda m: m.start(), reverse=True)
    out, used = data, []
    for m in chosen:
        value = rng.choice(WEIRD_NUMBERS)
        used.append(value[:20])
        out = out[: m.start()] + value.encode() + out[m.end() :]
    return out, "numbers replaced by " + ", ".join(repr(u) for u in used)


def bad_face_indices(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """OBJ: a face corner out of range, zero, negative beyond the count, or malformed."""
    lines = data.split(b"\n")
    faces = [i for i, line in enumerate(lines) if line.startswith(b"f ")]
    vertices = sum(1 for line in lines if line.startswith(b"v "))
    if not faces:
        lines.append(b"f 1 2 3")
        faces = [len(lines) - 1]
    value = rng.choice(
        [str(vertices + 1), "0", str(-(vertices + 5)), str(10**30), "-" + str(10**30), str(2**31), "1/2/3/4", "//1",
         "1//", "a", "1.5", "nan", "-0", str(2**63)]
    )  # fmt: skip
    i = rng.choice(faces)
    words = lines[i].split()
    words[rng.randrange(1, len(words))] = value.encode()
    lines[i] = b" ".join(words)
    return b"\n".join(lines), f"face line {i + 1} corner set to {value[:24]!r} ({vertices} vertices)"


def ply_header_counts(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """PLY: an element count changed, a property added or removed, or the format line changed."""
    end = data.find(b"end_header")
    if end < 0:
        return truncate(data, rng)
    head, body = data[:end], data[end:]
    lines = head.split(b"\n")
    elements = [i for i, line in enumerate(lines) if line.startswith(b"element ")]
    op = rng.choice(["count", "count", "add_property", "drop_property", "format"])
    if op == "count" and elements:
        i = rng.choice(elements)
        words = lines[i].split()
        n = int(words[2]) if words[2].isdigit() else 0
        value = rng.choice([n + 1, n - 1, n + 1000, 0, -1, 10**12, 2**32, 2**31 - 1, "x", 10**30])
        words[2] = str(value).encode()
        lines[i] = b" ".join(words)
        desc = f"header '{lines[i].decode(errors='replace')}' (was {n})"
    elif op == "add_property" and elements:
        i = rng.choice(elements)
        lines.insert(i + 1, rng.choice([b"property float extra", b"property list uchar int extra", b"property int"]))
        desc = f"property added after line {i + 1}: rows one value short"
    elif op == "drop_property":
        props = [i for i, line in enumerate(lines) if line.startswith(b"property ")]
        if not props:
            return truncate(data, rng)
        i = rng.choice(props)
        desc = f"property '{lines[i].decode(errors='replace')}' removed: rows one value long"
        del lines[i]
    else:
        fmts = [i for i, line in enumerate(lines) if line.startswith(b"format ")]
        if not fmts:
            return truncate(data, rng)
        value = rng.choice([b"ascii", b"binary_little_endian", b"binary_big_endian", b"binary", b"ascii 2.0"])
        lines[fmts[0]] = b"format " + value + b" 1.0"
        desc = f"format line set to {value.decode()}"
    return b"\n".join(lines) + body, desc


def ply_body(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """PLY: the body after the header cut short, extended, or one row given an extra value."""
    end = data.find(b"end_header")
    if end < 0:
        return truncate(data, rng)
    start = data.find(b"\n", end) + 1
    body = data[start:]
    op = rng.choice(["short", "long", "extra_value", "list_count"])
    if op == "short" and body:
        cut = rng.randrange(len(body))
        return data[: start + cut], f"body cut to {cut} of {len(body)} bytes"
    if op == "long":
        extra = bytes(rng.randrange(256) for _ in range(rng.randint(1, 64)))
        return data + extra, f"{len(extra)} bytes appended to the body"
    if op == "extra_value" and b"ascii" in data[:end]:
        rows = body.split(b"\n")
        i = rng.randrange(len(rows))
        rows[i] += b" 7 8"
        return data[:start] + b"\n".join(rows), f"body row {i} given two extra values"
    # a list count byte set to its maximum (binary) or a face row's count raised (ascii)
    if b"ascii" in data[:end]:
        rows = body.split(b"\n")
        faces = [i for i, r in enumerate(rows) if r.startswith((b"3 ", b"4 "))]
        if faces:
            i = rng.choice(faces)
            rows[i] = b"255" + rows[i][1:]
            return data[:start] + b"\n".join(rows), f"face row {i} claims 255 corners"
    out = bytearray(data)
    if len(body) > 8:
        out[start + rng.randrange(len(body))] = 0xFF
    return bytes(out), "one body byte set to 0xff"


def encoding(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """Odd encodings: UTF-16 with BOM, UTF-8 BOM, latin-1 bytes, NUL bytes, CRLF, CR only."""
    op = rng.choice(["utf16", "utf8bom", "latin1", "nul", "crlf", "cr", "utf32"])
    text = data.decode("latin-1")
    if op == "utf16":
        return text.encode("utf-16"), "UTF-16 with BOM"
    if op == "utf32":
        return text.encode("utf-32"), "UTF-32 with BOM"
    if op == "utf8bom":
        return b"\xef\xbb\xbf" + data, "UTF-8 BOM"
    if op == "latin1":
        return data.replace(b"\n", b"\n# caf\xe9 \xff\xfe\n", 3) + b"g gr\xfcn\n", "latin-1 bytes in comments/group"
    if op == "nul":
        at = rng.randrange(len(data)) if data else 0
        return data[:at] + b"\x00" * rng.randint(1, 16) + data[at:], f"NUL bytes at {at}"
    if op == "crlf":
        return data.replace(b"\n", b"\r\n"), "CRLF line ends"
    return data.replace(b"\n", b"\r"), "CR-only line ends"


MESH_MUTATIONS: dict[str, Callable[[bytes, random.Random], tuple[bytes, str]]] = {
    "byte_flips": byte_flips,
    "truncate": truncate,
    "edit_lines": edit_lines,
    "weird_numbers": weird_numbers,
}

#: first bytes of files that are not meshes, given a mesh suffix
FOREIGN_HEADERS = {
    "png": b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR" + bytes(64),
    "zip": b"PK\x03\x04\x14\x00\x00\x00\x08\x00" + bytes(64),
    "gzip": b"\x1f\x8b\x08\x00" + bytes(64),
    "elf": b"\x7fELF\x02\x01\x01" + bytes(64),
    "pdf": b"%PDF-1.4\n%\xe2\xe3\xcf\xd3\n",
}


# ----------------------------------------------------------------------------------------------
# Case makers, one per category


def _command(
    rng: random.Random, mesh: str, recipe: str = "recipe.toml", simulate_weight: float = 0.5
) -> tuple[list[str], str | None]:
    """A random command over `mesh`: inspect, inspect --json, check --mesh, or simulate into `out`."""
    roll = rng.random()
    if roll < simulate_weight:
        quiet = ["-q"] if rng.random() < 0.7 else []
        return ["simulate", mesh, "-r", recipe, "-o", "out", *quiet], "out"
    if roll < simulate_weight + (1 - simulate_weight) / 3:
        return ["check", recipe, "--mesh", mesh], None
    return (["inspect", mesh, "--json"] if rng.random() < 0.5 else ["inspect", mesh]), None


def _mesh_case(rng: random.Random, category: str, name: str, data: bytes, what: str, source: str) -> Case:
    argv, out = _command(rng, name)
    return Case(
        name="",
        category=category,
        description=f"{source}: {what}",
        argv=argv,
        files={f"work/{name}": data, "work/recipe.toml": minimal_recipe(rng).encode()},
        out=out,
    )


def _pick_seed(rng: random.Random, suffix: str | None = None) -> tuple[str, bytes]:
    meshes = [m for m in seed_meshes() if suffix is None or m[0].endswith(suffix)]
    return rng.choice(meshes)


def make_mesh_bytes(rng: random.Random, turn: int) -> Case:
    """Byte flips, truncations and line edits of any seed mesh."""
    name, data = _pick_seed(rng)
    mutation = rng.choice(["byte_flips", "truncate", "edit_lines"])
    mutated, what = MESH_MUTATIONS[mutation](data, rng)
    return _mesh_case(rng, "mesh-bytes", name, mutated, what, name)


def make_mesh_numbers(rng: random.Random, turn: int) -> Case:
    """Numbers of an ascii mesh replaced by huge, negative, non-finite or malformed ones."""
    meshes = [m for m in seed_meshes() if m[0].endswith(".obj") or b"format ascii" in m[1][:200]]
    name, data = rng.choice(meshes)
    mutated, what = weird_numbers(data, rng)
    return _mesh_case(rng, "mesh-numbers", name, mutated, what, name)


def make_obj_faces(rng: random.Random, turn: int) -> Case:
    """OBJ face indices out of range, zero, negative beyond the count; a 20,000-corner polygon."""
    if rng.random() < 0.15:
        data = big_polygon_obj(rng.choice([20_000, 5_000]))
        return _mesh_case(rng, "obj-faces", "polygon.obj", data, "one polygon with 20,000 corners", "generated")
    name, data = _pick_seed(rng, ".obj")
    mutated, what = bad_face_indices(data, rng)
    return _mesh_case(rng, "obj-faces", name, mutated, what, name)


def make_ply_header(rng: random.Random, turn: int) -> Case:
    """PLY header counts that do not match the body, properties added/removed, format changed."""
    name, data = _pick_seed(rng, ".ply")
    mutated, what = ply_header_counts(data, rng)
    return _mesh_case(rng, "ply-header", name, mutated, what, name)


def make_ply_body(rng: random.Random, turn: int) -> Case:
    """PLY bodies short, long, with extra values or a list count of 255."""
    name, data = _pick_seed(rng, ".ply")
    mutated, what = ply_body(data, rng)
    return _mesh_case(rng, "ply-body", name, mutated, what, name)


def make_encoding(rng: random.Random, turn: int) -> Case:
    """Odd encodings of a valid mesh, or a non-mesh file (PNG, zip, ...) named .obj/.ply."""
    name, data = _pick_seed(rng)
    if rng.random() < 0.3:
        kind = rng.choice(sorted(FOREIGN_HEADERS))
        return _mesh_case(rng, "encoding", name, FOREIGN_HEADERS[kind], f"a {kind} file renamed {name}", "foreign")
    mutated, what = encoding(data, rng)
    return _mesh_case(rng, "encoding", name, mutated, what, name)


def make_shared(rng: random.Random, turn: int) -> Case:
    """The shared broken meshes as they are, and real/broken ones lightly mutated."""
    broken = list(broken_meshes())
    if broken and rng.random() < 0.5:
        name, data = rng.choice(broken)
        return _mesh_case(rng, "shared", name, data, "as it is", f"shared/broken/{name}")
    pool = broken + [m for m in seed_meshes() if not m[0].startswith(("grid",)) and m[0] not in RECIPE_MESH.values()]
    name, data = rng.choice(pool or list(seed_meshes()))
    mutation = rng.choice(sorted(MESH_MUTATIONS))
    mutated, what = MESH_MUTATIONS[mutation](data, rng)
    return _mesh_case(rng, "shared", name, mutated, what, f"shared/{name}")


#: recipe value replacements (the whole right-hand side of a `key = value` line)
WEIRD_VALUES = (
    "nan", "-nan", "inf", "-inf", "1e308", "-1e308", "1e-320", str(10**30), "-" + str(10**30), str(2**63), "-1", "0",
    '"obj"', '"nan"', "true", "[]", "[1, 2]", "{}", '"../../etc/passwd"', "1_000", "0x10", "1979-05-27T07:32:00Z",
    '"\\u0000"', "[nan, nan, nan]", "[1e308, 1e308, 1e308]", "[inf, 0, 0]", '""', '"1.0"', "[[1, 2, 3]]",
    "{ a = 1 }", "-0.0", "1e-308",
)  # fmt: skip
_ASSIGNMENT = re.compile(r"^(\s*[A-Za-z_][\w.\"]*\s*=\s*)(.+)$")


def _recipe_lines(text: str) -> list[int]:
    return [
        i for i, line in enumerate(text.split("\n")) if _ASSIGNMENT.match(line) and not line.lstrip().startswith("#")
    ]


def mutate_recipe(text: str, rng: random.Random) -> tuple[str, str]:
    """One random recipe mutation: a value replaced, a number made weird, an unknown key, a type changed."""
    lines = text.split("\n")
    assigned = _recipe_lines(text)
    op = rng.choice(["value", "value", "number", "unknown_key", "type", "duplicate_table", "delete_line"])
    if op in ("value", "type") and assigned:
        i = rng.choice(assigned)
        m = _ASSIGNMENT.match(lines[i])
        assert m is not None
        value = (
            rng.choice(WEIRD_VALUES) if op == "value" else '"' + m.group(2).split("#")[0].strip().replace('"', "") + '"'
        )
        lines[i] = m.group(1) + value
        return "\n".join(lines), f"line {i + 1} set to '{lines[i].strip()[:80]}'"
    if op == "number" and assigned:
        i = rng.choice(assigned)
        mutated, what = weird_numbers(lines[i].encode(), rng)
        lines[i] = mutated.decode("utf-8", "replace")
        return "\n".join(lines), f"line {i + 1}: {what}"
    if op == "unknown_key":
        headers = [i for i, line in enumerate(lines) if line.startswith("[")] or [0]
        i = rng.choice(headers)
        key = rng.choice(["frmes = 3", "bogus = 1", "solver.x = 1", "substep = 2", '"" = 1', "[bogus]\nx = 1"])
        lines.insert(i + 1, key)
        return "\n".join(lines), f"unknown key '{key}' after line {i + 1}"
    if op == "duplicate_table":
        headers = [line for line in lines if line.startswith("[") and not line.startswith("[[")]
        if headers:
            header = rng.choice(headers)
            return text + f"\n{header}\n", f"table {header} repeated"
    if assigned:
        i = rng.choice(assigned)
        desc = f"line {i + 1} '{lines[i].strip()[:60]}' deleted"
        del lines[i]
        return "\n".join(lines), desc
    return text + "\n]]]\n", "garbage appended"


def _recipe_case(
    rng: random.Random, category: str, recipe: str, mesh_name: str, what: str, *, raw: bytes | None = None
) -> Case:
    """A recipe case: check, check --mesh, or simulate (the recipe's own frame count)."""
    roll = rng.random()
    if roll < 0.25:
        argv, out = ["check", "recipe.toml"], None
    elif roll < 0.5:
        argv, out = ["check", "recipe.toml", "--mesh", mesh_name], None
    else:
        argv, out = ["simulate", mesh_name, "-r", "recipe.toml", "-o", "out", "-q"], "out"
        if category != "recipe-limits":  # a mutation that drops `frames` must not make a default 120-frame run
            argv += ["--frames", "2"]
    return Case(
        name="",
        category=category,
        description=what,
        argv=argv,
        files={
            "work/recipe.toml": raw if raw is not None else recipe.encode(),
            f"work/{mesh_name}": sample_mesh(mesh_name),
            **recipe_files(mesh_name),
        },
        out=out,
    )


def make_recipe_values(rng: random.Random, turn: int) -> Case:
    """Sample recipes (cut to 2 frames) with a value, number, key or type mutated."""
    name, text, mesh_name = rng.choice(seed_recipes())
    mutated, what = mutate_recipe(text, rng)
    return _recipe_case(rng, "recipe-values", mutated, mesh_name, f"{name}.toml: {what}")


def make_recipe_bytes(rng: random.Random, turn: int) -> Case:
    """Sample recipes byte-flipped, truncated, re-encoded or with NUL bytes."""
    name, text, mesh_name = rng.choice(seed_recipes())
    op = rng.choice(["byte_flips", "truncate", "encoding", "edit_lines"])
    func = {"byte_flips": byte_flips, "truncate": truncate, "encoding": encoding, "edit_lines": edit_lines}[op]
    raw, what = func(text.encode(), rng)
    return _recipe_case(rng, "recipe-bytes", "", mesh_name, f"{name}.toml: {what}", raw=raw)


#: (key, value, table) settings that ask for absurd amounts of work or memory
LIMIT_SETTINGS = (
    ("frames", str(10**9), "simulation"), ("frames", str(2**63), "simulation"), ("frames", str(10**30), "simulation"),
    ("substeps", str(10**6), "simulation"), ("substeps", str(10**9), "simulation"),
    ("iterations", str(10**6), "simulation"), ("iterations", str(10**9), "simulation"),
    ("fps", "1e-300", "simulation"), ("fps", "1e308", "simulation"), ("fps", "nan", "simulation"),
    ("seed", str(10**30), "simulation"), ("seed", "-1", "simulation"), ("start_frame", str(10**30), "simulation"),
    ("tear_burst", str(10**9), "simulation"), ("tear_interval", "1e-300", "simulation"),
    ("damping", "nan", "simulation"), ("gravity", "[1e308, 1e308, 1e308]", "simulation"),
    ("gravity", "[nan, 0, 0]", "simulation"), ("partitions", str(10**9), "simulation"),
    ("stretch_modulus", "1e308", "material"), ("density", "1e-320", "material"), ("vertex_mass", "1e308", "material"),
    ("density", "inf", "material"),
)  # fmt: skip


def make_recipe_limits(rng: random.Random, turn: int) -> Case:
    """A small valid recipe with one setting asking for 10**9 frames, 10**6 substeps, 1e308 ..."""
    key, value, table = rng.choice(LIMIT_SETTINGS)
    if rng.random() < 0.15:
        count = rng.choice([20_000, 100_000])
        body = "".join(
            f"[[impacts]]\ntime = {i * 1e-3}\npoint = [0, 1, 0]\nradius = 0.1\nstrength = 1\n" for i in range(count)
        )
        recipe = "[simulation]\nframes = 2\nsubsteps = 2\n\n" + body
        return _recipe_case(rng, "recipe-limits", recipe, "sheet.obj", f"{count} [[impacts]] tables")
    recipe = '[simulation]\nframes = 2\nsubsteps = 4\n\n[material]\ndensity = 0.2\n\n[output]\nformats = ["obj"]\n'
    pattern = re.compile(rf"(?m)^{key} = .*$")
    line = f"{key} = {value}"
    if pattern.search(recipe):
        recipe = pattern.sub(line, recipe)
    else:
        recipe = recipe.replace(f"[{table}]\n", f"[{table}]\n{line}\n")
    return _recipe_case(rng, "recipe-limits", recipe, rng.choice(["sheet.obj", "rope.obj"]), f"{table}.{line}")


def make_cli_options(rng: random.Random, turn: int) -> Case:
    """`simulate` with hostile option values (0, 10**9, nan, inf, malformed vectors and pins)."""
    options = [
        ["--frames", "0"], ["--frames", "-1"], ["--frames", str(10**9)], ["--frames", str(10**30)], ["--frames", "nan"],
        ["--fps", "nan"], ["--fps", "inf"], ["--fps", "1e-300"], ["--fps", "-24"], ["--substeps", str(10**7)],
        ["--iterations", str(10**7)], ["--damping", "nan"], ["--damping", "inf"], ["--damping", "1e308"],
        ["--gravity", "nan,0,0"], ["--gravity", "1e308,1e308,1e308"], ["--gravity", "1,2"], ["--gravity", ",,,"],
        ["--gravity", "inf,-inf,0"], ["--pin", "indices:" + str(10**30)], ["--pin", "indices:-1"],
        ["--pin", "indices:"],
        ["--pin", "box:nan,0,0,1,1,1"], ["--pin", "box:1,1,1"], ["--pin", "sphere:1"], ["--pin", "indices:1e3"],
        ["--format", "xyz"], ["--format", ""], ["--format", "OBJ"], ["--format", "../obj"], ["--solver", "nope"],
        ["--solver", ""], ["--frames"], ["--bogus-option"], ["-o"], ["--recipe"],
    ]  # fmt: skip
    chosen = rng.choice(options)
    mesh = rng.choice(["rope.obj", "sheet.obj", "icosphere.ply"])
    extra = [] if "--frames" in chosen else ["--frames", "2"]
    argv = ["simulate", mesh, "-o", "out", "-q", "--substeps", "2", *extra, *chosen]
    if chosen in (["-o"], ["--recipe"], ["--frames"]):
        argv = ["simulate", mesh, "--frames", "2", *chosen]
    return Case(
        name="",
        category="cli-options",
        description="simulate " + " ".join(chosen),
        argv=argv,
        files={f"work/{mesh}": sample_mesh(mesh)},
        out="out",
    )


def make_paths(rng: random.Random, turn: int) -> Case:
    """Path tricks: mesh/recipe arguments that are folders, devices, pipes, loops; collider paths;
    `mtllib` naming /etc/passwd; file names with spaces, newlines, odd suffixes."""
    recipe = minimal_recipe(rng)
    files = {"work/recipe.toml": recipe.encode(), "work/rope.obj": sample_mesh("rope.obj")}
    links: dict[str, str] = {}
    fifos: list[str] = []
    forbidden: list[str] = []
    kind = rng.choice(
        ["mesh_arg", "mesh_arg", "recipe_arg", "collider", "collider", "mtllib", "mtllib", "name", "name"]
    )
    if kind == "mesh_arg":
        target = rng.choice(["missing.obj", "folder.obj", "/dev/null", "/dev/zero", "pipe.obj", "loop.obj",
                             "dangling.obj", "/", "", ".", "rope.obj/", "/etc/passwd", "/proc/self/mem"])  # fmt: skip
        files["work/folder.obj/keep.txt"] = b"user file\n"
        links["work/loop.obj"] = "loop.obj"
        links["work/dangling.obj"] = "nowhere/mesh.obj"
        if target == "pipe.obj":
            fifos.append("work/pipe.obj")
        argv, out = _command(rng, target)
        what = f"mesh argument {target!r}"
    elif kind == "recipe_arg":
        target = rng.choice(
            ["missing.toml", "folder", "/dev/zero", "/dev/null", "rope.obj", "pipe.toml", "/etc/passwd", ""]
        )
        files["work/folder/keep.txt"] = b"user file\n"
        if target == "pipe.toml":
            fifos.append("work/pipe.toml")
        argv = ["simulate", "rope.obj", "-r", target, "-o", "out", "-q"] if rng.random() < 0.5 else ["check", target]
        out = "out" if argv[0] == "simulate" else None
        what = f"recipe argument {target!r}"
    elif kind == "collider":
        target = rng.choice(
            ["../../etc/passwd", "/etc/passwd", "/dev/zero", "", ".", "missing.obj", "meshes", "recipe.toml",
             "a\\u0000b.obj", "/proc/self/environ", "~/mesh.obj", "loop.obj"]
        )  # fmt: skip
        files["work/meshes/keep.txt"] = b"user file\n"
        links["work/loop.obj"] = "loop.obj"
        text = recipe + f'\n[[colliders]]\nmesh = "{target}"\n'
        files["work/recipe.toml"] = text.encode()
        argv, out = (["check", "recipe.toml", "--mesh", "rope.obj"], None) if rng.random() < 0.4 else (
            ["simulate", "rope.obj", "-r", "recipe.toml", "-o", "out", "-q"], "out")  # fmt: skip
        what = f"collider mesh path {target!r}"
    elif kind == "mtllib":
        target = rng.choice(
            ["../../etc/passwd", "/etc/passwd", "/dev/zero", "../../../../../../etc/shadow", "/proc/self/environ",
             "pipe.mtl", "folder"]
        )  # fmt: skip
        if target == "pipe.mtl":
            fifos.append("work/pipe.mtl")
        files["work/folder/keep.txt"] = b"user file\n"
        files["work/rope.obj"] = f"mtllib {target}\nusemtl red\n".encode() + sample_mesh("rope.obj")
        files["work/recipe.toml"] = b'[simulation]\nframes = 2\nsubsteps = 4\n\n[output]\nformats = ["obj"]\n'
        argv, out = ["simulate", "rope.obj", "-r", "recipe.toml", "-o", "out", "-q"], "out"
        forbidden = ["/etc/passwd", "/etc/shadow"]
        what = f"OBJ with 'mtllib {target}'"
    else:
        target = rng.choice(["my mesh.obj", "my\nmesh.obj", "mesh.OBJ", "mesh.Ply", "mesh.stl", "mesh", "mesh.obj.txt",
                             "-mesh.obj", "ÿ.obj", "mesh\x7f.obj", ".obj", "mesh.obj "])  # fmt: skip
        source = "icosphere.ply" if target.lower().endswith(".ply") else "rope.obj"
        files[f"work/{target}"] = sample_mesh(source)
        argv, out = _command(rng, target)
        what = f"mesh file named {target!r}"
    return Case(name="", category="paths", description=what, argv=argv, files=files, links=links, fifos=fifos,
                out=out, forbidden=forbidden)  # fmt: skip


#: a user's folder tree the -o cases run in (cwd = home/project)
USER_FILES = {
    "home/notes.txt": b"my notes\n",
    "home/photo.jpg": b"\xff\xd8\xff\xe0 not really a photo",
    "home/docs/letter.txt": b"Dear ...\n",
    "home/project/README.md": b"# my project\n",
    "home/project/meshes/keep.txt": b"do not delete\n",
    "home/project/recipes/keep.txt": b"do not delete either\n",
    "home/project/prev/report.json": b'{"tool": "meshdeform"}\n',
    "home/project/prev/frames/frame_1.obj": b"v 0 0 0\n",
}
USER_LINKS = {
    "home/project/link_home": "..",
    "home/project/link_meshes": "meshes",
    "home/project/link_file": "README.md",
}

#: every way of mistyping -o we could think of (relative to home/project)
OUT_MISTYPES = (
    ".", "./", ".//", "..", "../", "meshes", "meshes/", "./meshes/../", "recipes", "recipes/", "meshes/cloth.obj",
    "README.md", "", "{root}/home", "{root}/home/project", "{root}/home/project/", "{root}", "link_home", "link_home/",
    "link_meshes", "link_file", "meshes/..", "../project", "out/..", "{root}/home/project/meshes", "/", "~", "prev",
    "prev/frames", "../docs",
)  # fmt: skip


def make_output_folder(rng: random.Random, turn: int) -> Case:
    """`-o` mistyped to a folder (or file) full of user files; the run itself is valid or fails.

    The mistypes are taken in turn (every one is tried with a valid recipe first), the recipe of
    later rounds is valid three times in four."""
    out = OUT_MISTYPES[turn % len(OUT_MISTYPES)]
    files = dict(USER_FILES)
    files["home/project/meshes/cloth.obj"] = obj_grid(6, 6, uvs=True)
    good = turn < len(OUT_MISTYPES) or rng.random() < 0.75
    files["home/project/recipes/short.toml"] = (minimal_recipe(rng) if good else "[simulation]\nframes = 0\n").encode()
    if out == "/":  # never let a broken tool loose on the machine's root: only a failing recipe there
        files["home/project/recipes/short.toml"] = b"[simulation]\nframes = 0\n"
        good = False
    argv = ["simulate", "meshes/cloth.obj", "-r", "recipes/short.toml", "-o", out, "-q"]
    if rng.random() < 0.3:
        argv = ["simulate", "meshes/cloth.obj", "-r", "recipes/short.toml", "--out", out]
    return Case(
        name="",
        category="output-folder",
        description=f"-o {out!r} in a folder of user files ({'valid' if good else 'failing'} recipe)",
        argv=argv,
        files=files,
        links=dict(USER_LINKS),
        cwd="home/project",
        out=out,
        out_replaceable=out == "prev",
    )


#: category -> (maker(rng, turn: how many cases of the category came before), weight)
CATEGORIES: dict[str, tuple[Callable[[random.Random, int], Case], int]] = {
    "mesh-bytes": (make_mesh_bytes, 3),
    "mesh-numbers": (make_mesh_numbers, 3),
    "obj-faces": (make_obj_faces, 2),
    "ply-header": (make_ply_header, 2),
    "ply-body": (make_ply_body, 2),
    "encoding": (make_encoding, 2),
    "shared": (make_shared, 2),
    "recipe-values": (make_recipe_values, 3),
    "recipe-bytes": (make_recipe_bytes, 1),
    "recipe-limits": (make_recipe_limits, 2),
    "cli-options": (make_cli_options, 2),
    "paths": (make_paths, 3),
    "output-folder": (make_output_folder, 3),
}


def generate(
    count: int, seed: int = 13, *, weighted: bool = True, categories: Iterable[str] | None = None
) -> list[Case]:
    """`count` cases; case i is drawn from `random.Random(f"{seed}:{i}")` in a category taken in turn
    from the category list (repeated by weight when `weighted`)."""
    names = list(categories) if categories is not None else list(CATEGORIES)
    rounds = max(CATEGORIES[n][1] for n in names) if weighted else 1
    # round-robin over the weights, so that any prefix of the cases spans the categories
    order = [n for r in range(rounds) for n in names if (CATEGORIES[n][1] if weighted else 1) > r]
    cases = []
    turns: dict[str, int] = dict.fromkeys(names, 0)
    for i in range(count):
        category = order[i % len(order)]
        rng = random.Random(f"{seed}:{i}:{category}")
        case = CATEGORIES[category][0](rng, turns[category])
        turns[category] += 1
        case.name = f"{i:04d}-{category}"
        cases.append(case)
    return cases


# ----------------------------------------------------------------------------------------------
# Running a case


@dataclass
class Outcome:
    """What one case did and which checks it failed (`reasons` empty: passed)."""

    case: Case
    exit_code: int | None
    seconds: float
    stdout: str
    stderr: str
    reasons: list[str]
    root: Path | None = None
    retried: bool = False

    @property
    def passed(self) -> bool:
        return not self.reasons


def materialise(case: Case, root: Path) -> None:
    """Create the case's files, symlinks and pipes under `root` (an empty folder)."""
    for rel, data in case.files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
    for rel, target in case.links.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.symlink_to(target)
    for rel in case.fifos:
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        os.mkfifo(path)
    (root / case.cwd).mkdir(parents=True, exist_ok=True)


def snapshot(root: Path) -> dict[str, str]:
    """Relative path -> sha256 (files), 'link:target', 'dir', 'fifo' or 'other' for everything under root.

    Symlinks are not followed and pipes are not opened (reading one would block)."""
    found: dict[str, str] = {}
    for folder, dirs, names in os.walk(root):
        for name in dirs + names:
            path = Path(folder) / name
            rel = str(path.relative_to(root))
            mode = os.lstat(path).st_mode
            if stat.S_ISLNK(mode):
                found[rel] = "link:" + os.readlink(path)
            elif stat.S_ISDIR(mode):
                found[rel] = "dir"
            elif stat.S_ISREG(mode):
                found[rel] = hashlib.sha256(path.read_bytes()).hexdigest()
            elif stat.S_ISFIFO(mode):
                found[rel] = "fifo"
            else:
                found[rel] = "other"
    return found


def _limit_resources() -> None:  # runs in the child before exec
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))


def _cache_state(cache_dir: str) -> int:
    """Number of files in the Numba cache folder (grows when a run compiled kernels)."""
    return sum(len(names) for _, _, names in os.walk(cache_dir))


def default_cache_dir() -> str:
    """The Numba cache all cases share: $NUMBA_CACHE_DIR, else the tool's own default (pipeline/cli.py)."""
    return os.environ.get("NUMBA_CACHE_DIR") or os.path.join(os.path.expanduser("~"), ".cache", "meshdeform", "numba")


def case_env(checkout: Path, cache_dir: str) -> dict[str, str]:
    """The environment of every case: the checkout first on the path, one shared Numba cache."""
    env = dict(os.environ)
    env["PYTHONPATH"] = str(checkout)
    env["NUMBA_CACHE_DIR"] = cache_dir
    env["PYTHONDONTWRITEBYTECODE"] = "1"
    env["COLUMNS"] = "120"
    env.pop("PYTHONWARNINGS", None)
    return env


def run_cli(
    argv: list[str], cwd: Path, env: dict[str, str], python: str, timeout: float
) -> tuple[int | None, float, str, str]:
    """Run `meshdeform argv` in `cwd`; (exit code or None on timeout, seconds, stdout, stderr)."""
    started = time.perf_counter()
    with subprocess.Popen(
        [python, "-c", BOOT, *argv],
        cwd=cwd,
        env=env,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        start_new_session=True,
        preexec_fn=_limit_resources,
    ) as proc:
        try:
            out, err = proc.communicate(timeout=timeout)
            code: int | None = proc.returncode
        except subprocess.TimeoutExpired:
            # as a user's `kill` or a batch system would: SIGTERM (the tool may clean up), then SIGKILL
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGTERM)
            try:
                out, err = proc.communicate(timeout=TERM_GRACE)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGKILL)
                out, err = proc.communicate()
            code = None
    return code, time.perf_counter() - started, out.decode("utf-8", "replace"), err.decode("utf-8", "replace")


def non_finite_text(name: str, data: bytes) -> bool:
    """Whether a text output holds a non-finite number: OBJ data lines, an ascii PLY body, JSON values.

    Names (groups, materials, comments, the PLY header, JSON strings) are not looked at, so a group
    called "info" or a warning that mentions nan is not taken for a number."""
    if name.endswith(".json"):
        import json

        found = []
        with contextlib.suppress(ValueError):
            json.loads(data, parse_constant=found.append)
        return bool(found)
    if name.endswith(".obj"):
        lines = [line for line in data.split(b"\n") if line.startswith((b"v ", b"vt ", b"vn "))]
        return any(_NON_FINITE.search(line) for line in lines)
    if name.endswith(".ply") and data.startswith(b"ply") and b"format ascii" in data[:200]:
        end = data.find(b"end_header")
        return end >= 0 and _NON_FINITE.search(data[end + 10 :]) is not None
    return False


def _under(path: str, folder: str) -> bool:
    return path == folder or path.startswith(folder.rstrip("/") + "/")


def judge(case: Case, root: Path, before: dict[str, str], after: dict[str, str], out_rel: str | None,
          out_existed: bool, code: int | None, seconds: float, stdout: str, stderr: str) -> list[str]:  # fmt: skip
    """The checks of one finished case; each failed one as a short reason."""
    reasons: list[str] = []
    if code is None:
        reasons.append(f"timeout: still running after {TIME_LIMIT:g} s (SIGTERM, then SIGKILL after {TERM_GRACE:g} s)")
    elif code not in ALLOWED_EXIT:
        reasons.append(f"exit code {code}" + (" (killed by a signal)" if code < 0 else ""))
    if code is not None and seconds >= TIME_LIMIT:
        reasons.append(f"slow: {seconds:.1f} s")
    lines = [line for line in stderr.splitlines() if line.strip()]
    if len(lines) > 1:
        reasons.append(f"{len(lines)} lines on stderr")
    if "Traceback" in stderr or "Traceback" in stdout:
        reasons.append("traceback")

    def inside_out(path: str) -> bool:
        return out_rel == "" or (out_rel is not None and _under(path, out_rel))

    for path, digest in before.items():
        if case.out_replaceable and out_rel and _under(path, out_rel) and path != out_rel:
            continue
        now = after.get(path)
        if now is None:
            reasons.append(f"removed: {path}")
        elif now != digest:
            reasons.append(f"changed: {path}")
    new = sorted(set(after) - set(before))
    partial = [p for p in new if ".partial-" in p or ".old-" in p]
    if partial:
        reasons.append(f"staging folder left: {partial[0]}")
    if code != 0:
        stray = [p for p in new if p not in partial]
        if stray:
            reasons.append(
                f"output left after failure: {stray[0]}" + (f" (+{len(stray) - 1})" if len(stray) > 1 else "")
            )
    else:
        outside = [p for p in new if p not in partial and not inside_out(p)]
        if outside:
            reasons.append(f"written outside the output: {outside[0]}")
        for p in new:
            if p in partial or after[p] in ("dir", "fifo", "other") or after[p].startswith("link:"):
                continue
            if non_finite_text(p, (root / p).read_bytes()):
                reasons.append(f"non-finite number in {p}")
                break
        for source in case.forbidden:
            with contextlib.suppress(OSError):
                secret = hashlib.sha256(Path(source).read_bytes()).hexdigest()
                copied = [p for p in new if after[p] == secret]
                if copied:
                    reasons.append(f"{source} copied into the output as {copied[0]}")
        if (
            case.argv
            and case.argv[0] == "simulate"
            and out_rel is not None
            and not any(p.endswith("report.json") for p in new)
            and not out_existed
        ):
            reasons.append("exit 0 but no report.json written")
    return reasons


def _relative_out(case: Case, root: Path) -> str | None:
    """The `-o` folder relative to the case root (symlinks resolved), '' when it is the root
    itself, None when it is outside the case or the command writes nothing."""
    if case.out is None:
        return None
    typed = case.out.replace("{root}", str(root))
    resolved = Path(os.path.realpath(root / case.cwd / typed))
    try:
        rel = resolved.relative_to(root.resolve())
    except ValueError:
        return None
    return "" if str(rel) == "." else str(rel)


def run_case(case: Case, workdir: Path, *, checkout: Path = REPO, python: str = sys.executable,
             cache_dir: str | None = None, keep: Path | None = None) -> Outcome:  # fmt: skip
    """Run one case in a fresh folder under `workdir`; keep a pristine copy under `keep` when it fails."""
    cache_dir = cache_dir or default_cache_dir()
    env = case_env(checkout, cache_dir)
    retried = False
    for attempt in range(2):
        box = workdir / case.name  # private to the case: what `-o {root}/..` would touch is checked too
        root = box / "case"
        if box.exists():
            shutil.rmtree(box)
        root.mkdir(parents=True)
        materialise(case, root)
        before = snapshot(root)
        out_rel = _relative_out(case, root)
        out_existed = (out_rel is not None and out_rel in before) or out_rel == ""
        argv = [a.replace("{root}", str(root)) for a in case.argv]
        cached = _cache_state(cache_dir) if os.path.isdir(cache_dir) else 0
        code, seconds, stdout, stderr = run_cli(argv, root / case.cwd, env, python, TIME_LIMIT)
        # a timeout while Numba compiled kernels (a cold cache) is not the case's fault: run it again warm
        if code is None and attempt == 0 and os.path.isdir(cache_dir) and _cache_state(cache_dir) != cached:
            retried = True
            continue
        break
    after = snapshot(root)
    reasons = judge(case, root, before, after, out_rel, out_existed, code, seconds, stdout, stderr)
    beside = sorted(p.name for p in box.iterdir() if p.name != "case") if box.is_dir() else ["(the case folder itself)"]
    if beside:
        reasons.append(f"written beside the case folder: {beside[0]}")
    kept = None
    if reasons and keep is not None:
        kept = keep / case.name
        if kept.exists():
            shutil.rmtree(kept)
        kept.mkdir(parents=True)
        materialise(case, kept)
        (kept / "ARGV.txt").write_text(f"cd {kept / case.cwd}\n{case.shown_argv(kept)}\n")
    shutil.rmtree(box, ignore_errors=True)
    return Outcome(case, code, seconds, stdout, stderr, reasons, root=kept, retried=retried)


def warm_up(
    workdir: Path, *, checkout: Path = REPO, python: str = sys.executable, cache_dir: str | None = None
) -> float:
    """Compile the kernels the cases use into the shared Numba cache (untimed); seconds spent.

    One frame of every sample recipe on its mesh and of every solver on a grid; skipped when a
    stamp in the cache says this checkout's engine sources were warmed already."""
    cache_dir = cache_dir or default_cache_dir()
    digest = hashlib.sha256(str(checkout.resolve()).encode())
    for path in sorted((checkout / "meshdeform").rglob("*.py")):
        digest.update(path.read_bytes())
    stamp = Path(cache_dir) / f"robustness-warm-{digest.hexdigest()[:16]}"
    if stamp.exists():
        return 0.0
    started = time.perf_counter()
    env = case_env(checkout, cache_dir)
    root = workdir / "warm-up"
    root.mkdir(parents=True, exist_ok=True)
    runs: list[list[str]] = []
    for name, text, mesh in seed_recipes():
        (root / mesh).write_bytes(sample_mesh(mesh))
        for rel, data in recipe_files(mesh, str(root)).items():
            Path(rel).parent.mkdir(parents=True, exist_ok=True)
            Path(rel).write_bytes(data)
        (root / f"{name}.toml").write_text(shorten_recipe(text, frames=1))
        runs.append(["simulate", mesh, "-r", f"{name}.toml", "-o", f"out-{name}", "-q"])
    (root / "grid.obj").write_bytes(obj_grid(8, 8))
    for solver in SOLVERS:
        runs.append(["simulate", "grid.obj", "--solver", solver, "--frames", "1", "-o", f"out-{solver}", "-q"])
    for argv in runs:
        run_cli(argv, root, env, python, 900.0)
    shutil.rmtree(root, ignore_errors=True)
    Path(cache_dir).mkdir(parents=True, exist_ok=True)
    stamp.write_text("warm\n")
    return time.perf_counter() - started


def run_cases(cases: list[Case], workdir: Path, *, jobs: int = 2, checkout: Path = REPO, python: str = sys.executable,
              keep: Path | None = None, on_done: Callable[[Outcome], None] | None = None) -> list[Outcome]:  # fmt: skip
    """Run cases `jobs` at a time; outcomes in the order of `cases`."""
    from concurrent.futures import ThreadPoolExecutor

    cache_dir = default_cache_dir()

    def one(case: Case) -> Outcome:
        outcome = run_case(case, workdir, checkout=checkout, python=python, cache_dir=cache_dir, keep=keep)
        if on_done is not None:
            on_done(outcome)
        return outcome

    with ThreadPoolExecutor(max_workers=max(1, jobs)) as pool:
        return list(pool.map(one, cases))
