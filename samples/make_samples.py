"""Make the bundled sample meshes: small, deterministic, written as plain text (the body's cache
as little-endian binary).

    python samples/make_samples.py [OUT_DIR [BODY_DIR]]
        (defaults: samples/meshes, samples/recipes/body)

flag.obj      32 x 20 quad grid in the XY plane (2 x 1.25 units, Y up), with UVs and two groups
curtain.obj   40 x 30 quad grid in the XY plane (3 x 2.2 units), with UVs
sheet.obj     24 x 24 grid in the XZ plane at height 1, triangulated (tests triangle shear springs)
icosphere.ply subdivided icosahedron, radius 0.5, with a `weight` vertex property (1 at the top)
rope.obj      a 40-vertex polyline (`l` element) hanging along X at height 1
cape.obj      20 x 28 quad grid (0.6 x 0.9 m) curved around the back (z < 0) of the body below, its
              top row along the shoulders (y = 1.35) 1.5 cm off the torso, its hem flaring to 8 cm off

Into BODY_DIR (beside the recipes, as a recipe's cache paths stay inside the recipe's folder; not
in OUT_DIR, whose meshes are all baked as assets):

body.obj      a capsule figure, Y up, feet at y = 0, facing +z: a torso capsule (radius 0.17 m,
              axis x = z = 0 from y = 0 to 1.52) and a separate head sphere (radius 0.09 m, centre
              y = 1.64), one closed mesh of two parts, 1.73 m tall
body.pc2      its animation, BODY_FRAMES samples (one a frame at 24 fps, start frame 1): `body_pose`,
              a rigid motion: it walks along +z, speeding up to 1 m/s over the first 0.5 s, bobs
              2 cm twice a second, and turns 90 degrees to its left (towards +x) and back over 3 s;
              sample 0 is the rest mesh

The files are written by this script alone, so tests can check that they are reproducible.
"""

from __future__ import annotations

import struct
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


#: the body's dimensions (m): torso capsule radius and the top of its axis, head sphere
TORSO_RADIUS = 0.17
TORSO_TOP = 1.52
HEAD_RADIUS = 0.09
HEAD_CENTRE = 1.64
#: samples in body.pc2: 72 frames at 24 fps (3 s) and a few spare
BODY_FRAMES = 76
BODY_FPS = 24.0
#: the cape's top row height (m, where the torso is still a cylinder) and its gap to the torso
SHOULDERS = 1.35
CAPE_GAP = 0.015


def body_mesh() -> trimesh.Trimesh:
    """The body at rest: torso capsule and head sphere as one mesh (vertices rounded to 1 nm)."""
    torso = trimesh.creation.capsule(height=TORSO_TOP - 2 * TORSO_RADIUS, radius=TORSO_RADIUS, count=[24, 24])
    torso.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0]))  # axis along y
    torso.apply_translation([0.0, TORSO_TOP / 2, 0.0])
    head = trimesh.creation.icosphere(subdivisions=2, radius=HEAD_RADIUS)
    head.apply_translation([0.0, HEAD_CENTRE, 0.0])
    vertices = np.round(np.concatenate([torso.vertices, head.vertices]), 9)
    faces = np.concatenate([torso.faces, head.faces + len(torso.vertices)])
    return trimesh.Trimesh(vertices, faces, process=False)


def body_pose(frame: int) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (3, 3) and translation (3,) (m) taking the rest body to its pose at cache sample
    `frame` (from 0, at t = frame / 24 s): rotated about its own vertical axis, then moved."""
    t = frame / BODY_FPS
    yaw = 0.5 * np.pi * np.sin(np.pi * min(t, 3.0) / 3.0) ** 2
    c, s = np.cos(yaw), np.sin(yaw)
    rotation = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    forward = t * t if t < 0.5 else t - 0.25  # speed t / 0.5 m/s up to 1 m/s, then steady
    bob = 0.01 * (1.0 - np.cos(4.0 * np.pi * t))
    return rotation, np.array([0.0, bob, forward])


def body_obj() -> str:
    body = body_mesh()
    return obj_text(np.asarray(body.vertices), np.asarray(body.faces), header="capsule figure (rest of body.pc2)")


def body_pc2() -> bytes:
    """PC2: header (magic, version 1, points, start frame 1, one sample a frame, samples), then
    every sample's points as float32, little-endian."""
    rest = np.asarray(body_mesh().vertices)
    samples = np.array([rest @ r.T + t for r, t in (body_pose(f) for f in range(BODY_FRAMES))])
    header = struct.pack("<12siiffi", b"POINTCACHE2\0", 1, rest.shape[0], 1.0, 1.0, BODY_FRAMES)
    return header + samples.astype("<f4").tobytes()


def cape() -> str:
    nx, ny, width, length = 20, 28, 0.6, 0.9
    xyz, uv, quads = grid(nx, ny, width, length)
    # columns around the back: the top row on a half circle 1.5 cm off the torso (0.6 m of arc),
    # lower rows farther out (up to 8 cm at the hem), so that only the top touches the body
    drop = length - xyz[:, 1]
    radius = TORSO_RADIUS + CAPE_GAP + 0.065 * drop / length
    angle = (xyz[:, 0] / width - 0.5) * width / (TORSO_RADIUS + CAPE_GAP)
    curved = np.stack([radius * np.sin(angle), SHOULDERS - drop, -radius * np.cos(angle)], axis=1)
    return obj_text(np.round(curved, 9), quads, uv, header="cape")


SAMPLES = {
    "flag.obj": flag,
    "curtain.obj": curtain,
    "sheet.obj": sheet,
    "rope.obj": rope,
    "icosphere.ply": icosphere_ply,
    "cape.obj": cape,
}
#: written into BODY_DIR: text (str) or binary (bytes)
BODY_FILES = {"body.obj": body_obj, "body.pc2": body_pc2}


def make_samples(out_dir: Path, body_dir: Path | None = None) -> list[Path]:
    """Write every sample mesh into out_dir and the body's files into body_dir (default: the
    recipes' `body` folder beside out_dir); returns the paths written."""
    body_dir = body_dir if body_dir is not None else out_dir.parent / "recipes" / "body"
    written = []
    for folder, files in ((out_dir, SAMPLES), (body_dir, BODY_FILES)):
        folder.mkdir(parents=True, exist_ok=True)
        for name, make in files.items():
            path = folder / name
            content = make()
            if isinstance(content, bytes):
                path.write_bytes(content)
            else:
                path.write_text(content, encoding="utf-8", newline="\n")
            written.append(path)
    return written


if __name__ == "__main__":
    here = Path(__file__).resolve().parent
    target = Path(sys.argv[1]) if len(sys.argv) > 1 else here / "meshes"
    body_target = Path(sys.argv[2]) if len(sys.argv) > 2 else here / "recipes" / "body"
    for p in make_samples(target, body_target):
        print(p)
