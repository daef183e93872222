"""What the tests build: cloth grids (the sheet, its pins, its spring model, an OBJ file of it, a
slit in it), the turn of a slope and a command-line app holding one command.

Every grid is `meshdeform.mesh.grid_mesh`: nx x ny vertices, vertex (i, j) at index `j * nx + i`,
i along x and j along y (plane "xy", a hanging sheet with Y up) or along z (plane "xz", a
horizontal sheet), spread evenly over `size` metres from the origin, quads (i, j), (i+1, j),
(i+1, j+1), (i, j+1), with per-vertex UVs (i / (nx - 1), j / (ny - 1)).

Pins are named by the grid's own sides, so that they mean the same vertices in either plane:

    left    i = 0           right   i = nx - 1
    bottom  j = 0           top     j = ny - 1
    top-left, top-right, bottom-left, bottom-right: the four corners

(in "xy" the top row is the one at y = size[1]; in "xz" it is the row at z = size[1]). A pin may
also be a vertex index. `TOP_CORNERS` is the usual hanging cloth: pinned at its two top corners.

The functions are plain (import them: `from factories import grid_cloth`), so that module-level
helpers and parametrised tests can call them with any size; tests/conftest.py says where they are.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Literal, NamedTuple

import numpy as np
import typer

from meshdeform.io import write_obj
from meshdeform.material import KindMaterial, Material
from meshdeform.mesh import Mesh, grid_mesh
from meshdeform.model import SpringModel

Plane = Literal["xy", "xz"]
#: a side or corner of the grid (see the module docstring) or a vertex index
Pin = str | int

TOP_CORNERS: tuple[str, str] = ("top-left", "top-right")
#: a knit (1000 N/m, the default material until 2026-12-05; the default is a woven 10 000 N/m):
#: scenes built around a cloth that stretches, crumples into itself or drapes within a few frames
KNIT = Material(stretch_modulus=1000.0, bending=KindMaterial(stiffness=0.05))

_SIDES = {
    "left": lambda i, j, nx, ny: i == 0,
    "right": lambda i, j, nx, ny: i == nx - 1,
    "bottom": lambda i, j, nx, ny: j == 0,
    "top": lambda i, j, nx, ny: j == ny - 1,
}


def grid_sheet(
    nx: int,
    ny: int | None = None,
    *,
    size: float | tuple[float, float] = 1.0,
    plane: Plane = "xy",
    triangles: bool | Literal["alternate"] = False,
    uvs: bool = True,
    centred: bool = False,
    offset: Sequence[float] | None = None,
) -> Mesh:
    """A grid of nx x ny vertices (ny defaults to nx) over `size` metres (one number: a square).

    triangles: each quad split along its (i, j)-(i+1, j+1) diagonal; the triangles (0, 1, 2) of
        every quad come first, then the triangles (0, 2, 3), quad order kept in each half;
        "alternate": the quads of odd i + j split along the other diagonal instead, into (0, 1, 3)
        and (1, 2, 3) (a checkerboard of diagonals, as many modellers triangulate).
    uvs: False drops the UVs (a mesh of positions and polygons only).
    centred: the sheet centred on the origin in its plane (from -size / 2 to size / 2).
    offset: (3,) metres added to every position (the sheet moved, e.g. lifted above a ground).
    """
    ny = nx if ny is None else ny
    width, height = (size, size) if isinstance(size, int | float) else size
    mesh = grid_mesh(nx, ny, size=(float(width), float(height)), plane=plane)
    if triangles:
        quads = mesh.face_indices.reshape(-1, 4)
        first, second = quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]
        if triangles == "alternate":
            i, j = np.meshgrid(np.arange(nx - 1), np.arange(ny - 1))
            odd = ((i + j).ravel() % 2 == 1)[:, None]
            first, second = np.where(odd, quads[:, [0, 1, 3]], first), np.where(odd, quads[:, [1, 2, 3]], second)
        flat = np.concatenate([first, second]).ravel()
        offsets = np.arange(0, flat.size + 1, 3, dtype=np.int64)
        mesh = Mesh(
            positions=mesh.positions,
            face_indices=flat,
            face_offsets=offsets,
            uvs=mesh.uvs,
            face_uv_indices=flat.copy(),
        )
    if not uvs:
        mesh = Mesh(positions=mesh.positions, face_indices=mesh.face_indices, face_offsets=mesh.face_offsets)
    if centred or offset is not None:
        shift = np.zeros(3) if offset is None else np.array(offset, dtype=np.float64)
        if centred:
            shift[[0, 1 if plane == "xy" else 2]] -= [width / 2, height / 2]
        mesh = mesh.with_positions(mesh.positions + shift)
    return mesh


def slope_turn(degrees: float) -> np.ndarray:
    """(3, 3) rotation by `degrees` about Z (Y up): it turns a horizontal sheet onto the plane
    through the origin tilted that much, whose unit normal is its column 1 ([-sin, cos, 0]) and
    whose downhill direction is minus its column 0 ([-cos, -sin, 0]). Apply as `points @ turn.T`."""
    angle = np.radians(degrees)
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def grid_pins(nx: int, ny: int, pins: Iterable[Pin]) -> np.ndarray:
    """(nx * ny,) bool mask of the pinned vertices: the union of the named sides and corners
    (module docstring) and the vertex indices in `pins`."""
    i, j = np.meshgrid(np.arange(nx), np.arange(ny))
    i, j = i.ravel(), j.ravel()
    mask = np.zeros(nx * ny, dtype=bool)
    for pin in pins:
        if isinstance(pin, int | np.integer):
            mask[int(pin)] = True
            continue
        sides = pin.split("-")
        if not sides or any(side not in _SIDES for side in sides):
            raise ValueError(f"unknown pin {pin!r}: a vertex index or one of {', '.join(_SIDES)} or a corner")
        mask |= np.logical_and.reduce([_SIDES[side](i, j, nx, ny) for side in sides])
    return mask


class Cloth(NamedTuple):
    """A grid sheet and its spring model: `mesh` (V input vertices), `model`, `pinned` (V,) bool."""

    mesh: Mesh
    model: SpringModel
    pinned: np.ndarray


def grid_cloth(
    nx: int,
    ny: int | None = None,
    *,
    pins: Iterable[Pin] = (),
    material: Material | None = None,
    **sheet: object,
) -> Cloth:
    """`grid_sheet(nx, ny, **sheet)` built into a `SpringModel` (default material) pinned at `pins`.

    `grid_cloth(8, pins=TOP_CORNERS).model` is the usual 1 m cloth hanging from two corners.
    """
    ny = nx if ny is None else ny
    mesh = grid_sheet(nx, ny, **sheet)  # type: ignore[arg-type]
    pinned = grid_pins(nx, ny, pins)
    return Cloth(mesh, SpringModel.from_mesh(mesh, material, pinned_input=pinned), pinned)


class PunchedPlate(NamedTuple):
    """A 0.6 m box plate, 1 cm thick (`lo`, `hi`, m), still until 0.05 s and then rising 3 m at a
    speed through a 1 m sheet (25 x 25, triangles) lying flat 0.5 m above it, no gravity,
    self-collision on, friction 0.5, thickness 5 mm; frames until 2 after it stops at `arrive` (s)."""

    mesh: Mesh
    recipe: str
    arrive: float
    lo: np.ndarray
    hi: np.ndarray

    def rise(self, time: float) -> float:
        """How far (m) the plate has risen at `time` (s)."""
        return 3.0 * min(max(time - 0.05, 0.0) / (self.arrive - 0.05), 1.0)


def punched_plate(solver: str, speed: float) -> PunchedPlate:
    """The plate scene rising at `speed` (m/s) under `solver` (its recipe text; `PunchedPlate`)."""
    arrive = 0.05 + 3.0 / speed
    recipe = (
        f'[simulation]\nsolver = "{solver}"\nfps = 24\nframes = {round(24 * arrive) + 2}\ngravity = [0, 0, 0]\n\n'
        "[self_collision]\n\n[[colliders]]\nbox = { min = [-0.3, 0.0, -0.3], max = [0.3, 0.01, 0.3] }\n"
        "friction = 0.5\nthickness = 0.005\n"
        "animate = [{ time = 0.0, translate = [0, 0, 0] }, { time = 0.05, translate = [0, 0, 0] }, "
        f"{{ time = {arrive!r}, translate = [0, 3.0, 0] }}]\n"
    )
    mesh = grid_sheet(25, 25, size=1.0, plane="xz", triangles=True, centred=True, offset=(0.0, 0.5, 0.0))
    return PunchedPlate(mesh, recipe, arrive, np.array([-0.3, 0.0, -0.3]), np.array([0.3, 0.01, 0.3]))


def twisted_strip(solver: str, degrees: float, seconds: float = 2.0) -> tuple[Mesh, str]:
    """A 0.4 x 1 m strip of 20 x 20 vertices upright in XY (diagonals alternating), its top row
    pinned still and its bottom row pinned to a turn of `degrees` about the vertical axis while
    rising 0.3 m over `seconds`, no gravity, self-collision at its defaults, 24 fps until the turn
    ends, under `solver`: the mesh and its recipe text."""
    mesh = grid_sheet(20, 20, size=(0.4, 1.0), plane="xy", triangles="alternate", offset=(-0.2, 0.0, 0.0))
    recipe = (
        f'[simulation]\nsolver = "{solver}"\nfps = 24\nframes = {round(24 * seconds)}\ngravity = [0, 0, 0]\n\n'
        "[self_collision]\n\n[[pins]]\nselect = { box = { min = [-1, 0.99, -1], max = [1, 2, 1] } }\n\n"
        "[[pins]]\nselect = { box = { min = [-1, -1, -1], max = [1, 0.01, 1] } }\npivot = [0, 0, 0]\n"
        "animate = [{ time = 0.0, rotate = [0, 0, 0], translate = [0, 0, 0] }, "
        f"{{ time = {seconds!r}, rotate = [0, {degrees!r}, 0], translate = [0, 0.3, 0] }}]\n"
    )
    return mesh, recipe


def pulled_banner(solver: str, frames: int = 18, extra: str = "") -> tuple[Mesh, str]:
    """A 1 m x 0.5 m sheet (20 x 10 vertices, XY plane) gripped along its two short edges, the
    grips pulled 0.15 m apart each from 0.1 s to 0.6 s: the cloth as a whole stretched 1.3x
    along x. The mesh and a recipe of `solver` at its defaults (xpbd, verlet: tethers 1.0), 24
    fps, with `extra` (TOML) appended."""
    mesh = grid_mesh(20, 10, size=(1.0, 0.5), plane="xy")
    grips = ""
    for side, shift in ((0.0, -0.15), (1.0, 0.15)):
        grips += (
            "[[pins]]\nrelative = true\n"
            f"select = {{ box = {{ min = [{side - 0.01}, 0, 0], max = [{side + 0.01}, 1, 1] }} }}\n"
            f"animate = [ {{ time = 0.0, translate = [0, 0, 0] }}, {{ time = 0.1, translate = [0, 0, 0] }},\n"
            f"            {{ time = 0.6, translate = [{shift}, 0, 0] }} ]\n\n"
        )
    return mesh, f'[simulation]\nsolver = "{solver}"\nfps = 24\nframes = {frames}\n\n' + grips + extra


def bumpy_ground(n: int = 17, size: float = 1.6) -> tuple[np.ndarray, np.ndarray]:
    """An open n x n grid of height 0.2 + 0.15 sin(6 x) cos(5 z) (m) over size x size (m), centred on
    the Y axis: vertices (n^2, 3) and triangles (a, b, c), (a, c, d) per cell (2 (n - 1)^2, 3)."""
    u = np.linspace(-size / 2, size / 2, n)
    x, z = np.meshgrid(u, u)
    y = 0.2 + 0.15 * np.sin(6 * x) * np.cos(5 * z)
    vertices = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    index = np.arange(n * n).reshape(n, n)
    a, b, c, d = index[:-1, :-1].ravel(), index[:-1, 1:].ravel(), index[1:, 1:].ravel(), index[1:, :-1].ravel()
    return vertices, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def height_over_grid(vertices: np.ndarray, n: int, size: float, points: np.ndarray) -> np.ndarray:
    """The height (m) of `bumpy_ground`'s grid of n x n vertices over size x size (m) under each point
    (N, 3) (its x, z), interpolated in the grid's triangle (a, b, c) or (a, c, d) under it: (N,)."""
    spacing = size / (n - 1)
    u = (points[:, 0] + size / 2) / spacing
    w = (points[:, 2] + size / 2) / spacing
    i = np.clip(np.floor(u).astype(int), 0, n - 2)
    j = np.clip(np.floor(w).astype(int), 0, n - 2)
    fu, fw = u - i, w - j
    y = vertices[:, 1].reshape(n, n)
    ya, yb, yc, yd = y[j, i], y[j, i + 1], y[j + 1, i + 1], y[j + 1, i]
    upper = fu >= fw  # triangle (a, b, c): below the diagonal a-c in (u, w)
    return np.where(upper, ya + fu * (yb - ya) + fw * (yc - yb), ya + fw * (yd - ya) + fu * (yc - yd))


def write_grid(path: Path, nx: int, ny: int | None = None, **sheet: object) -> Path:
    """`grid_sheet(nx, ny, **sheet)` written to the OBJ file `path` (its folder made); returns `path`."""
    path.parent.mkdir(parents=True, exist_ok=True)
    write_obj(path, grid_sheet(nx, ny, **sheet))  # type: ignore[arg-type]
    return path


def slit_grid(
    mesh: Mesh,
    nx: int,
    column: int,
    quad_rows: int,
    *,
    open_tip: bool = False,
    shift: Sequence[float] | None = None,
) -> tuple[Mesh, np.ndarray]:
    """The grid `mesh` (nx vertices a row, quads) cut open along vertex column `column` through its
    lowest `quad_rows` rows of quads, as tearing leaves it: the quads right of the cut take copies
    of the column's vertices, appended after the V input vertices in row order.

    The copies are of the vertices of rows 0 .. quad_rows - 1, so the vertex at the cut's tip
    (row quad_rows) stays shared; open_tip copies it too. shift: (3,) metres added to the copies.
    Returns the torn mesh (positions and polygons, no UVs) and the copied vertices (K,) int64.
    """
    vertex_count = mesh.vertex_count
    copies = np.arange(quad_rows + 1 if open_tip else quad_rows, dtype=np.int64) * nx + column
    lookup = np.arange(vertex_count, dtype=np.int64)
    lookup[copies] = vertex_count + np.arange(copies.size)
    faces = mesh.face_indices.reshape(-1, 4).copy()
    quad = np.arange(faces.shape[0])
    right = (quad % (nx - 1) >= column) & (quad // (nx - 1) < quad_rows)
    faces[right] = lookup[faces[right]]
    moved = mesh.positions[copies] if shift is None else mesh.positions[copies] + np.asarray(shift, dtype=np.float64)
    torn = Mesh(
        positions=np.vstack([mesh.positions, moved]), face_indices=faces.ravel(), face_offsets=mesh.face_offsets
    )
    return torn, copies


def command_app(register: Callable[[typer.Typer], None]) -> typer.Typer:
    """A Typer app holding only the command(s) `register(app)` adds (a `pipeline.commands` module's
    `register`); its callback keeps a single command a named subcommand, as in the real app."""
    app = typer.Typer()

    @app.callback()
    def main() -> None:
        """Test app."""

    register(app)
    return app
