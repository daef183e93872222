"""Make the bundled sample meshes: small, deterministic, written as plain text.

    python samples/make_samples.py [OUT_DIR]      (default: samples/meshes)

flag.obj      32 x 20 quad grid in the XY plane (2 x 1.25 units, Y up), with UVs and two groups
curtain.obj   40 x 30 quad grid in the XY plane (3 x 2.2 units), with UVs
sheet.obj     24 x 24 grid in the XZ plane at height 1, triangulated (tests triangle shear springs)
icosphere.ply subdivided icosahedron, radius 0.5, with a `weight` vertex property (1 at the top)
rope.obj      a 40-vertex polyline (`l` element) hanging along X at height 1

The files are written by this script alone, so tests can check that they are reproducible.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import trimesh


def _fmt(values: np.ndarray) -> list[str]:
    return [" ".join(repr(float(x)) for x in row) for row in np.atleast_2d(values)]


def grid(nx: int, ny: int, width: float, height: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices (row-major from the bottom-left), UVs and quads (counter-clockwise seen from +Z)."""
    u, v = np.meshgrid(np.linspace(0.0, 1.0, nx), np.linspace(0.0, 1.0, ny))
    uv = np.stack([u.ravel(), v.ravel()], axis=1)
    idx = np.arange(nx * ny).reshape(ny, nx)
    quads = np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]], axis=-1).reshape(-1, 4)
    xyz = np.zeros((nx * ny, 3))
    xyz[:, 0] = np.round(uv[:, 0] * width, 9)
    xyz[:, 1] = np.round(uv[:, 1] * height, 9)
    return xyz, np.round(uv, 9), quads


def obj_text(
    positions: np.ndarray,
    faces: np.ndarray | None = None,
    uvs: np.ndarray | None = None,
    groups: list[tuple[str, np.ndarray]] | None = None,
    lines: np.ndarray | None = None,
    header: str = "",
) -> str:
    out = [f"# {header}", "# made by samples/make_samples.py"]
    out += [f"v {row}" for row in _fmt(positions)]
    if uvs is not None:
        out += [f"vt {row}" for row in _fmt(uvs)]

    def face_line(face: np.ndarray) -> str:
        if uvs is None:
            return "f " + " ".join(str(i + 1) for i in face)
        return "f " + " ".join(f"{i + 1}/{i + 1}" for i in face)

    if faces is not None:
        if groups:
            for name, members in groups:
                out.append(f"g {name}")
                out += [face_line(faces[k]) for k in members]
        else:
            out += [face_line(face) for face in faces]
    if lines is not None:
        out.append("l " + " ".join(str(i + 1) for i in lines))
    return "\n".join(out) + "\n"


def flag() -> str:
    xyz, uv, quads = grid(32, 20, 2.0, 1.25)
    # a hoist stripe (first two columns of quads, where the pole goes) and the fly
    column = np.arange(quads.shape[0]) % 31
    return obj_text(
        xyz, quads, uv, [("hoist", np.flatnonzero(column < 2)), ("fly", np.flatnonzero(column >= 2))], header="flag"
    )


def curtain() -> str:
    xyz, uv, quads = grid(40, 30, 3.0, 2.2)
    return obj_text(xyz, quads, uv, header="curtain")


def sheet() -> str:
    xyz, uv, quads = grid(24, 24, 1.5, 1.5)
    # lay it flat at height 1: (x, y) -> (x - 0.75, 1, y - 0.75)
    flat = np.stack([xyz[:, 0] - 0.75, np.ones(len(xyz)), xyz[:, 1] - 0.75], axis=1)
    tris = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    return obj_text(np.round(flat, 9), tris, uv, header="triangulated sheet")


def rope() -> str:
    n = 40
    xyz = np.zeros((n, 3))
    xyz[:, 0] = np.round(np.linspace(0.0, 2.0, n), 9)
    xyz[:, 1] = 1.0
    return obj_text(xyz, lines=np.arange(n), header="rope")


def icosphere_ply() -> str:
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    v = np.round(np.asarray(sphere.vertices), 9)
    f = np.asarray(sphere.faces)
    weight = np.round(np.clip((v[:, 1] - 0.3) / 0.2, 0.0, 1.0), 6)
    head = [
        "ply",
        "format ascii 1.0",
        "comment made by samples/make_samples.py",
        f"element vertex {len(v)}",
        "property float x",
        "property float y",
        "property float z",
        "property float weight",
        f"element face {len(f)}",
        "property list uchar int vertex_indices",
        "end_header",
    ]
    rows = [f"{a!r} {b!r} {c!r} {w!r}" for (a, b, c), w in zip(v.tolist(), weight.tolist(), strict=True)]
    faces = [f"3 {a} {b} {c}" for a, b, c in f.tolist()]
    return "\n".join(head + rows + faces) + "\n"


SAMPLES = {
    "flag.obj": flag,
    "curtain.obj": curtain,
    "sheet.obj": sheet,
    "rope.obj": rope,
    "icosphere.ply": icosphere_ply,
}


def make_samples(out_dir: Path) -> list[Path]:
    """Write every sample mesh into out_dir; returns the paths written."""
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for name, make in SAMPLES.items():
        path = out_dir / name
        path.write_text(make(), encoding="utf-8", newline="\n")
        written.append(path)
    return written


if __name__ == "__main__":
    target = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parent / "meshes"
    for p in make_samples(target):
        print(p)
