"""Compiled contact of a cloth's vertices, edges and triangles with one collider shape (Numba).

The cloth is a list of primitives, rows (i0, i1, i2) of vertex indices: a triangle, an edge
(a, b, b) or a vertex (a, a, a). Every query works in the collider's rest frame ("local"):
positions (V, 3) at the start (x0) and at the end (x1) of the substep, the path between them
linear. A shape is a `ShapeArrays`: a plane, a sphere, a capsule, an axis-aligned box (exact
closest points by `box_distance`) or a triangle mesh (`Surface`, with its BVH).

`closest_simple` (planes, spheres, capsules), `closest_box` and `closest_mesh` give, for one primitive in one
configuration, the signed clearance d (negative: inside a solid, or on the far side of an open
sheet from the side it keeps), the contact point on the cloth as weights (w0, w1, w2) on its
vertices, the surface point q and the outward unit normal n, with d = n . (p - q) for the
cloth point p = sum w_k x_k. The contact asks for d >= h (h: the collider's thickness in local
units).

`contact` runs one substep for one shape (compiled once per query: `contact_kernel(kind, company)`):
- `_advance` is conservative advancement (Mirtich 1996; Zhang et al., "Continuous collision
  detection for articulated models using Taylor models and temporal culling", 2007): along the
  path a point of the primitive moves at most L = max_k |x1_k - x0_k| (its vertices move
  linearly), so after the clearance d at path parameter s it cannot come nearer than h - gap
  before s + (d - h + gap) / L. Stepping by that never passes through anything, whatever the
  speed and however thin the shape; the first configuration found within h is the time of
  impact, and its (w, n, q) a plane the end position must stay in front of;
- `_solve` enforces those planes and the closest-point contacts at the end positions by
  Gauss-Seidel position corrections weighted by the contact weights and inverse masses
  (position-based dynamics: lambda = depth / sum_k w_k^2 m_k^-1, dx_k = lambda w_k m_k^-1 n);
- static friction holds the vertex contacts within its cone where they were along the surface
  (`hold_still`; for the solvers that do not hold contacts themselves);
- a fail-safe puts back at their start the vertices of any contact the corrections could not
  free, or primitive the hold brought within the floor (the start was clear, so the end is).
`respond` then removes the approaching normal velocity of every contact point (relative to the
surface) and applies Coulomb friction, spread over the vertices the same way. Everything runs
serially in the primitives' order: the same input gives the same bytes.
"""

from __future__ import annotations

import types
from collections.abc import Callable
from typing import NamedTuple

import numba
import numpy as np

from meshdeform.contact.box_distance import primitive_box_closest
from meshdeform.contact.bvh import closest_to_point, closest_to_triangle, new_stack
from meshdeform.contact.primitives import point_triangle_weights
from meshdeform.contact.surface import FEATURE_EPS, Surface, pseudo_normal
from meshdeform.contact.triangle_distance import segment_triangle_closest
from meshdeform.solvers.jit import JIT, opaque

PLANE = 0
SPHERE = 1
CAPSULE = 2
MESH = 3
BOX = 4

#: a Gauss-Seidel sweep that moves no contact by more than this fraction of h ends the solve
SETTLED = 1e-4
#: distances below this count as touching: the direction from surface to cloth is not used
TOUCH = 1e-12


class ShapeArrays(NamedTuple):
    """A shape as the kernels read it, in its rest frame, as the leading arguments of every
    kernel here (`contact(*shape, ...)`; one by one, since Numba passes a tuple of arrays to a
    compiled call at a cost far above a sphere's query).

    kind: PLANE, SPHERE, CAPSULE, BOX or MESH. params (5, 3): the plane's point and unit normal
    (or the sphere's centre), the capsule's fallback normal (row 1: a unit vector across the
    axis, for a cloth point on the axis), the capsule's ends or the box's lo and hi corners
    (rows 2, 3), the radius (row 4, column 0). closed .. tri_bounds: a mesh (`Surface` and its
    `TriangleBVH`; a box's 12 triangles, whose vertices are its corners in
    `box_distance`'s order; a one-triangle placeholder for the other kinds): closed, vertices,
    triangles, normals, then the BVH's bounds, nodes, order and tri_bounds.
    """

    kind: int
    params: np.ndarray
    closed: bool
    vertices: np.ndarray
    triangles: np.ndarray
    normals: np.ndarray
    bounds: np.ndarray
    nodes: np.ndarray
    order: np.ndarray
    tri_bounds: np.ndarray


def shape_arrays(kind: int, params: np.ndarray, surface: Surface) -> ShapeArrays:
    """The kernels' view of a shape: its kind, params (5, 3) and surface (meshes)."""
    bvh = surface.bvh
    return ShapeArrays(
        kind, np.ascontiguousarray(params, dtype=np.float64), bool(surface.closed), surface.vertices,
        surface.triangles, surface.normals, bvh.bounds, bvh.nodes, bvh.order, bvh.tri_bounds,
    )  # fmt: skip


@numba.njit(**JIT)
def _merge(i0: int, i1: int, i2: int, w0: float, w1: float, w2: float) -> tuple[float, float, float]:
    """Weights of repeated vertices (an edge (a, b, b), a vertex (a, a, a)) summed on the first
    row that holds the vertex, so each vertex appears once in the corrections."""
    if i1 == i0:
        w0 += w1
        w1 = 0.0
    if i2 == i0:
        w0 += w2
        w2 = 0.0
    elif i2 == i1:
        w1 += w2
        w2 = 0.0
    return w0, w1, w2


@numba.njit(**JIT)
def _triangle_normal(tri: np.ndarray) -> tuple[float, float, float, bool]:
    ux, uy, uz = tri[1, 0] - tri[0, 0], tri[1, 1] - tri[0, 1], tri[1, 2] - tri[0, 2]
    vx, vy, vz = tri[2, 0] - tri[0, 0], tri[2, 1] - tri[0, 1], tri[2, 2] - tri[0, 2]
    nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    length = np.sqrt(nx * nx + ny * ny + nz * nz)
    if length > 0.0:
        return nx / length, ny / length, nz / length, True
    return 0.0, 1.0, 0.0, False


@numba.njit(**JIT)
def closest_plane(
    params: np.ndarray, tri: np.ndarray, i0: int, i1: int, i2: int
) -> tuple[float, float, float, float, float, float, float, float, float, float, float]:
    """`closest_simple`'s answer for a plane (params rows 0 and 1: a point and the unit normal):
    a half-space's distance is linear over the primitive, least at a corner. Every query below
    answers planes with it, so a plane runs in whichever compiled pipeline its scene already
    needs (`contact_kernel`)."""
    nx, ny, nz = params[1, 0], params[1, 1], params[1, 2]
    best = np.inf
    corner = 0
    for k in range(3):
        dk = (tri[k, 0] - params[0, 0]) * nx + (tri[k, 1] - params[0, 1]) * ny + (tri[k, 2] - params[0, 2]) * nz
        if dk < best:
            best, corner = dk, k
    w0 = 1.0 if corner == 0 else 0.0
    w1 = 1.0 if corner == 1 else 0.0
    w2 = 1.0 if corner == 2 else 0.0
    w0, w1, w2 = _merge(i0, i1, i2, w0, w1, w2)
    qx = tri[corner, 0] - best * nx
    qy = tri[corner, 1] - best * ny
    qz = tri[corner, 2] - best * nz
    return best, w0, w1, w2, qx, qy, qz, nx, ny, nz, 0.0


@numba.njit(**JIT)
def closest_simple(
    kind: int,
    params: np.ndarray,
    closed: bool,
    vertices: np.ndarray,
    triangles: np.ndarray,
    normals: np.ndarray,
    bounds: np.ndarray,
    nodes: np.ndarray,
    order: np.ndarray,
    tri_bounds: np.ndarray,
    tri: np.ndarray,
    i0: int,
    i1: int,
    i2: int,
    hint: float,
    limit: float,
    stack: np.ndarray,
) -> tuple[float, float, float, float, float, float, float, float, float, float, float]:
    """(d, w0, w1, w2, qx, qy, qz, nx, ny, nz, side) of the primitive whose current corners are
    the rows of tri (3, 3) (vertex indices i0, i1, i2 tell edges and vertices apart), for a
    plane, a sphere or a capsule (`closest_mesh`: meshes; both take the same arguments, the
    leading ones a `ShapeArrays`).

    limit: clearance beyond which the caller needs no exact answer; a mesh then returns
    d = limit and a zero normal. hint: for an open sheet, the side (+1 / -1 along the face
    normals) the primitive keeps, 0 when unknown; side: the side used (0 for other shapes).
    stack: a BVH traversal stack (`bvh.new_stack()`)."""
    if kind == PLANE:
        return closest_plane(params, tri, i0, i1, i2)
    if kind in (SPHERE, CAPSULE):
        r0, r1, r2, r3 = opaque(0), opaque(1), opaque(2), opaque(3)  # rows: one compile of the callees
        if kind == SPHERE:
            ax, ay, az = params[0, 0], params[0, 1], params[0, 2]
            w0, w1, w2 = point_triangle_weights(ax, ay, az, tri, r0, r1, r2)
        else:
            _, u, w0, w1, w2 = segment_triangle_closest(params, r2, r3, tri, r0, r1, r2)
            ax = params[2, 0] + u * (params[3, 0] - params[2, 0])
            ay = params[2, 1] + u * (params[3, 1] - params[2, 1])
            az = params[2, 2] + u * (params[3, 2] - params[2, 2])
        px = w0 * tri[0, 0] + w1 * tri[1, 0] + w2 * tri[2, 0]
        py = w0 * tri[0, 1] + w1 * tri[1, 1] + w2 * tri[2, 1]
        pz = w0 * tri[0, 2] + w1 * tri[1, 2] + w2 * tri[2, 2]
        vx, vy, vz = px - ax, py - ay, pz - az
        length = np.sqrt(vx * vx + vy * vy + vz * vz)
        if length > TOUCH:
            nx, ny, nz = vx / length, vy / length, vz / length
        else:  # the centre (axis) lies on the primitive: out along its normal, else the fallback
            nx, ny, nz, ok = _triangle_normal(tri)
            if not ok:
                if kind == SPHERE:
                    nx, ny, nz = 0.0, 1.0, 0.0
                else:
                    nx, ny, nz = params[1, 0], params[1, 1], params[1, 2]
        r = params[4, 0]
        w0, w1, w2 = _merge(i0, i1, i2, w0, w1, w2)
        return length - r, w0, w1, w2, ax + r * nx, ay + r * ny, az + r * nz, nx, ny, nz, 0.0
    return np.inf, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0


@numba.njit(**JIT)
def closest_mesh(
    kind: int,
    params: np.ndarray,
    closed: bool,
    vertices: np.ndarray,
    triangles: np.ndarray,
    normals: np.ndarray,
    bounds: np.ndarray,
    nodes: np.ndarray,
    order: np.ndarray,
    tri_bounds: np.ndarray,
    tri: np.ndarray,
    i0: int,
    i1: int,
    i2: int,
    hint: float,
    limit: float,
    stack: np.ndarray,
) -> tuple[float, float, float, float, float, float, float, float, float, float, float]:
    """`closest_simple` for a triangle mesh: the exact closest points by the BVH, the sign (a
    closed mesh) or the side kept (an open sheet) by the pseudo-normal there; planes too
    (`closest_plane`)."""
    if kind == PLANE:
        return closest_plane(params, tri, i0, i1, i2)
    vertex = i0 == i1 and i1 == i2
    verts = vertices
    tris = triangles
    face = normals[:, 0]
    limit2 = limit * limit if limit < np.inf else np.inf
    if vertex:
        d2, t, m0, m1, m2 = closest_to_point(
            bounds, nodes, order, tri_bounds, verts, tris, tri[0, 0], tri[0, 1], tri[0, 2], limit2, stack
        )
        w0, w1, w2 = 1.0, 0.0, 0.0
    else:
        r0, r1, r2 = opaque(0), opaque(1), opaque(2)  # rows: one compile of the callees (`opaque`)
        d2, t, w0, w1, w2, m0, m1, m2 = closest_to_triangle(
            bounds, nodes, order, tri_bounds, verts, tris, face, tri, r0, r1, r2, limit2, stack
        )
    if t < 0:
        return limit, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, hint
    px = w0 * tri[0, 0] + w1 * tri[1, 0] + w2 * tri[2, 0]
    py = w0 * tri[0, 1] + w1 * tri[1, 1] + w2 * tri[2, 1]
    pz = w0 * tri[0, 2] + w1 * tri[1, 2] + w2 * tri[2, 2]
    a, b, c = tris[t, 0], tris[t, 1], tris[t, 2]
    qx = m0 * verts[a, 0] + m1 * verts[b, 0] + m2 * verts[c, 0]
    qy = m0 * verts[a, 1] + m1 * verts[b, 1] + m2 * verts[c, 1]
    qz = m0 * verts[a, 2] + m1 * verts[b, 2] + m2 * verts[c, 2]
    gx, gy, gz = pseudo_normal(normals, t, m0, m1, m2)
    glen = np.sqrt(gx * gx + gy * gy + gz * gz)
    if glen > 0.0:
        gx, gy, gz = gx / glen, gy / glen, gz / glen
    else:
        gx, gy, gz = 0.0, 1.0, 0.0
    vx, vy, vz = px - qx, py - qy, pz - qz
    du = np.sqrt(d2)
    along = vx * gx + vy * gy + vz * gz
    w0, w1, w2 = _merge(i0, i1, i2, w0, w1, w2)
    if closed:
        if du <= TOUCH:
            return 0.0, w0, w1, w2, qx, qy, qz, gx, gy, gz, 0.0
        sign = -1.0 if along < 0.0 else 1.0
        return sign * du, w0, w1, w2, qx, qy, qz, sign * vx / du, sign * vy / du, sign * vz / du, 0.0
    here = 0.0
    if du > TOUCH:
        here = 1.0 if along > 0.0 else (-1.0 if along < 0.0 else 0.0)
    side = hint if hint != 0.0 else (here if here != 0.0 else 1.0)
    interior = m0 > FEATURE_EPS and m1 > FEATURE_EPS and m2 > FEATURE_EPS
    if vertex and here != 0.0 and here != side and interior:  # crossed the sheet: back to its side
        fx, fy, fz = normals[t, 0, 0], normals[t, 0, 1], normals[t, 0, 2]
        return -du, w0, w1, w2, qx, qy, qz, side * fx, side * fy, side * fz, side
    if du > TOUCH:
        return du, w0, w1, w2, qx, qy, qz, vx / du, vy / du, vz / du, side
    return 0.0, w0, w1, w2, qx, qy, qz, side * gx, side * gy, side * gz, side


@numba.njit(**JIT)
def closest_box(
    kind: int,
    params: np.ndarray,
    closed: bool,
    vertices: np.ndarray,
    triangles: np.ndarray,
    normals: np.ndarray,
    bounds: np.ndarray,
    nodes: np.ndarray,
    order: np.ndarray,
    tri_bounds: np.ndarray,
    tri: np.ndarray,
    i0: int,
    i1: int,
    i2: int,
    hint: float,
    limit: float,
    stack: np.ndarray,
) -> tuple[float, float, float, float, float, float, float, float, float, float, float]:
    """`closest_simple` for an axis-aligned box (`box_distance.primitive_box_closest`; its
    corners are `vertices`, its bounds params rows 2 and 3): exact closest points in a few dozen
    operations where the box as a 12-triangle mesh took a BVH walk of triangle pairs); planes
    too (`closest_plane`)."""
    if kind == PLANE:
        return closest_plane(params, tri, i0, i1, i2)
    corners = 1 if (i0 == i1 and i1 == i2) else (2 if i1 == i2 else 3)
    d, w0, w1, w2, qx, qy, qz, nx, ny, nz = primitive_box_closest(tri, corners, vertices, params[2], params[3])
    w0, w1, w2 = _merge(i0, i1, i2, w0, w1, w2)
    return d, w0, w1, w2, qx, qy, qz, nx, ny, nz, 0.0


#: the query the pipeline below (`_advance`, `_solve`, `_evaluate`, `contact`: plain Python
#: functions) calls; `_family` compiles the pipeline once with each query in its place
closest = closest_simple


@numba.njit(**JIT)
def _fill(tri: np.ndarray, x0: np.ndarray, x1: np.ndarray, i0: int, i1: int, i2: int, s: float) -> None:
    for k in range(3):
        tri[0, k] = x0[i0, k] + s * (x1[i0, k] - x0[i0, k])
        tri[1, k] = x0[i1, k] + s * (x1[i1, k] - x0[i1, k])
        tri[2, k] = x0[i2, k] + s * (x1[i2, k] - x0[i2, k])


@numba.njit(**JIT)
def candidates(
    x0: np.ndarray,
    x1: np.ndarray,
    prims: np.ndarray,
    movable: np.ndarray,
    kind: int,
    params: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    margin: float,
) -> np.ndarray:  # pragma: no cover - compiled
    """Ids of the primitives with a movable vertex whose swept box comes within `margin` of
    the shape: of its bounds lo, hi (3,), and for a sphere of the sphere itself; for a plane
    whose start or end vertices come within `margin` of the plane.

    First each vertex's outcode (Cohen and Sutherland's): for a plane, bit 0 where neither end
    comes within `margin`; else bits 2k and 2k + 1 where its swept interval on axis k lies wholly
    below lo - margin or above hi + margin. A primitive's swept box misses the bounds exactly where
    all its corners share a bit (the box's interval is the union of theirs), so a primitive costs
    an AND of three codes instead of its corners' eighteen extremes; the sphere's distance test
    reads the box of the primitives that pass."""
    n = x0.shape[0]
    code = np.zeros(n, dtype=np.int64)
    for i in range(n):
        if kind == PLANE:
            far = True
            for x in (x0, x1):
                d = (
                    (x[i, 0] - params[0, 0]) * params[1, 0]
                    + (x[i, 1] - params[0, 1]) * params[1, 1]
                    + (x[i, 2] - params[0, 2]) * params[1, 2]
                )
                if d < margin:
                    far = False
            code[i] = 1 if far else 0
            continue
        for k in range(3):
            if max(x0[i, k], x1[i, k]) < lo[k] - margin:
                code[i] |= 1 << (2 * k)
            if min(x0[i, k], x1[i, k]) > hi[k] + margin:
                code[i] |= 2 << (2 * k)
    keep = np.zeros(prims.shape[0], dtype=np.bool_)
    for p in range(prims.shape[0]):
        i0, i1, i2 = prims[p, 0], prims[p, 1], prims[p, 2]
        if not (movable[i0] or movable[i1] or movable[i2]) or code[i0] & code[i1] & code[i2]:
            continue
        if kind == SPHERE:  # squared distance from its centre to the swept box
            gap2 = 0.0
            for k in range(3):
                pmin = min(x0[i0, k], x0[i1, k], x0[i2, k], x1[i0, k], x1[i1, k], x1[i2, k])
                pmax = max(x0[i0, k], x0[i1, k], x0[i2, k], x1[i0, k], x1[i1, k], x1[i2, k])
                g = max(pmin - params[0, k], 0.0, params[0, k] - pmax)
                gap2 += g * g
            reach = params[4, 0] + margin
            keep[p] = gap2 <= reach * reach
        else:
            keep[p] = True
    return np.flatnonzero(keep)


def _advance(
    kind: int,
    params: np.ndarray,
    closed: bool,
    vertices: np.ndarray,
    triangles: np.ndarray,
    normals: np.ndarray,
    bounds: np.ndarray,
    nodes: np.ndarray,
    order: np.ndarray,
    tri_bounds: np.ndarray,
    x0: np.ndarray,
    x1: np.ndarray,
    i0: int,
    i1: int,
    i2: int,
    hint: float,
    h: float,
    gap: float,
    max_steps: int,
    tri: np.ndarray,
    stack: np.ndarray,
) -> tuple[bool, float, float, float, float, float, float, float, float, float, float, float, float]:
    """Conservative advancement of one primitive from x0 to x1: (hit, s, d0, w0, w1, w2, qx, qy,
    qz, nx, ny, nz, side0) with s the path parameter of the first configuration within h, d0
    the clearance at the start and side0 the open sheet's side the primitive keeps: the one its
    start lies on, or where the start touches the sheet the one it kept before (hint). A path still advancing after
    max_steps steps (grazing the shell) counts as hit where it stands: its plane only binds
    if the end position is behind it."""
    vertex = i0 == i1 and i1 == i2
    exact_start = vertex and kind == MESH and closed
    travel = 0.0
    for r in range(3):
        i = i0 if r == 0 else (i1 if r == 1 else i2)
        dx, dy, dz = x1[i, 0] - x0[i, 0], x1[i, 1] - x0[i, 1], x1[i, 2] - x0[i, 2]
        travel = max(travel, dx * dx + dy * dy + dz * dz)
    travel = np.sqrt(travel)
    s = 0.0
    steps = 0
    _fill(tri, x0, x1, i0, i1, i2, 0.0)
    # a vertex deep inside a solid mesh is farther from the surface than any limit
    limit = np.inf if exact_start else h + gap + travel
    # an open sheet's side: where the start lies, unless it touches the sheet (then the one kept)
    d, w0, w1, w2, qx, qy, qz, nx, ny, nz, side = closest(
        kind,
        params,
        closed,
        vertices,
        triangles,
        normals,
        bounds,
        nodes,
        order,
        tri_bounds,
        tri,
        i0,
        i1,
        i2,
        0.0,
        limit,
        stack,
    )
    d0 = d
    side0 = side if (d > h or hint == 0.0) else hint
    if side0 != side:
        d, w0, w1, w2, qx, qy, qz, nx, ny, nz, side = closest(
            kind,
            params,
            closed,
            vertices,
            triangles,
            normals,
            bounds,
            nodes,
            order,
            tri_bounds,
            tri,
            i0,
            i1,
            i2,
            side0,
            limit,
            stack,
        )
        d0 = d
    while True:
        if d <= h or steps >= max_steps:
            return True, s, d0, w0, w1, w2, qx, qy, qz, nx, ny, nz, side0
        if s >= 1.0 or d - (1.0 - s) * travel > h:
            return False, 1.0, d0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, side0
        steps += 1
        s = min(1.0, s + (d - h + gap) / travel)
        _fill(tri, x0, x1, i0, i1, i2, s)
        limit = h + gap + (1.0 - s) * travel
        d, w0, w1, w2, qx, qy, qz, nx, ny, nz, _ = closest(
            kind, params, closed, vertices, triangles, normals, bounds, nodes, order, tri_bounds,
            tri, i0, i1, i2, side0, limit, stack,
        )  # fmt: skip


@numba.njit(**JIT)
def _correct(
    x: np.ndarray,
    inv_mass: np.ndarray,
    i0: int,
    i1: int,
    i2: int,
    w0: float,
    w1: float,
    w2: float,
    nx: float,
    ny: float,
    nz: float,
    depth: float,
    moved: np.ndarray,
) -> float:
    """Move the contact point sum w_k x_k by depth along n (inverse-mass weighted); returns the
    distance it moved (0 when its vertices are all pinned)."""
    denom = w0 * w0 * inv_mass[i0] + w1 * w1 * inv_mass[i1] + w2 * w2 * inv_mass[i2]
    if not denom > 1e-300:
        return 0.0
    lam = depth / denom
    for i, wk in ((i0, w0), (i1, w1), (i2, w2)):
        f = lam * wk * inv_mass[i]
        if f != 0.0:
            x[i, 0] += f * nx
            x[i, 1] += f * ny
            x[i, 2] += f * nz
            moved[i] = True
    return depth


def _solve(
    kind: int,
    params: np.ndarray,
    closed: bool,
    vertices: np.ndarray,
    triangles: np.ndarray,
    normals: np.ndarray,
    bounds: np.ndarray,
    nodes: np.ndarray,
    order: np.ndarray,
    tri_bounds: np.ndarray,
    x: np.ndarray,
    inv_mass: np.ndarray,
    prims: np.ndarray,
    cand: np.ndarray,
    slots: np.ndarray,
    plane: np.ndarray,
    hint: np.ndarray,
    h: float,
    gap: float,
    plane_sweeps: int,
    joint_sweeps: int,
    push: np.ndarray,
    moved: np.ndarray,
    end: np.ndarray,
    d_end: np.ndarray,
    tri: np.ndarray,
    stack: np.ndarray,
) -> bool:
    """Gauss-Seidel over the contacts `slots` (of cand), in order: `plane_sweeps` sweeps
    over their time-of-impact planes (plane[k] = w (3), q (3), n (3): n . (sum w x - q) >= h),
    then up to `joint_sweeps` over the planes and the closest-point contacts at the current
    positions, stopping after a sweep that moved nothing (by more than `SETTLED` h). x (V, 3)
    updated in place; push (slots) accumulates how far each contact point moved; end, d_end
    (slots) take each contact's last closest point (w, q, n) and clearance. Returns True when
    those are the final positions' (the last sweep moved nothing)."""
    settled = SETTLED * h + 1e-12
    for sweep_index in range(plane_sweeps + joint_sweeps):
        still = True
        for k in slots:
            p = cand[k]
            i0, i1, i2 = prims[p, 0], prims[p, 1], prims[p, 2]
            along = 0.0
            for j in range(3):
                pj = plane[k, 0] * x[i0, j] + plane[k, 1] * x[i1, j] + plane[k, 2] * x[i2, j]
                along += (pj - plane[k, 3 + j]) * plane[k, 6 + j]
            if along < h:
                push[k] += _correct(
                    x, inv_mass, i0, i1, i2, plane[k, 0], plane[k, 1], plane[k, 2],
                    plane[k, 6], plane[k, 7], plane[k, 8], h - along, moved,
                )  # fmt: skip
                still = still and h - along <= settled
            if sweep_index >= plane_sweeps:
                d = _evaluate(
                    kind, params, closed, vertices, triangles, normals, bounds, nodes, order, tri_bounds,
                    x, prims, p, hint[p], h + gap, end, k, tri, stack,
                )  # fmt: skip
                d_end[k] = d
                if d < h:
                    push[k] += _correct(
                        x, inv_mass, i0, i1, i2, end[k, 0], end[k, 1], end[k, 2], end[k, 6], end[k, 7], end[k, 8],
                        h - d, moved,
                    )  # fmt: skip
                    still = still and h - d <= settled
        if still and sweep_index >= plane_sweeps:
            return True
    return False


def _evaluate(
    kind: int,
    params: np.ndarray,
    closed: bool,
    vertices: np.ndarray,
    triangles: np.ndarray,
    normals: np.ndarray,
    bounds: np.ndarray,
    nodes: np.ndarray,
    order: np.ndarray,
    tri_bounds: np.ndarray,
    x: np.ndarray,
    prims: np.ndarray,
    p: int,
    hint: float,
    limit: float,
    out: np.ndarray,
    row: int,
    tri: np.ndarray,
    stack: np.ndarray,
) -> float:  # fmt: skip
    """Clearance of primitive p at x; its w (3), q (3), n (3) go to out[row]."""
    i0, i1, i2 = prims[p, 0], prims[p, 1], prims[p, 2]
    _fill(tri, x, x, i0, i1, i2, 0.0)
    d, w0, w1, w2, qx, qy, qz, nx, ny, nz, _ = closest(
        kind,
        params,
        closed,
        vertices,
        triangles,
        normals,
        bounds,
        nodes,
        order,
        tri_bounds,
        tri,
        i0,
        i1,
        i2,
        hint,
        limit,
        stack,
    )
    out[row, 0], out[row, 1], out[row, 2] = w0, w1, w2
    out[row, 3], out[row, 4], out[row, 5] = qx, qy, qz
    out[row, 6], out[row, 7], out[row, 8] = nx, ny, nz
    return d


@numba.njit(**JIT)
def hold_still(
    x0: np.ndarray,
    x1: np.ndarray,
    prims: np.ndarray,
    cand: np.ndarray,
    contacts: np.ndarray,
    plane: np.ndarray,
    end: np.ndarray,
    d_end: np.ndarray,
    push: np.ndarray,
    touch: float,
    friction: float,
    inv_mass: np.ndarray,
    held: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """Static friction in positions, in the shape's rest frame (the surface still), inside
    `contact` before its fail-safe: each vertex contact among `contacts` (rows of cand, plane and
    end (C, 9), d_end and push (C,); a primitive whose three corners are one vertex) that acts
    (`acting_contacts`: touching at the end within `touch`, its final normal, or pushed, its
    time-of-impact plane's) and whose way along the surface over the substep, from x0 to x1
    (V, 3), is within `friction` times its push out of the shape (m) is put back where it started
    along the surface (x1 in place; held (V,) gets how far, m). The velocity friction (`respond`) removes
    a sticking contact's velocity but not the way it slid within the substep, so a cloth lying
    still on a slope crept down by 1/2 g sin(slope) dt^2 a substep; beyond the cone the contact
    slides, and `respond` slows it. Edge and face contacts keep the velocity friction alone."""
    for k in contacts:
        touches = d_end[k] <= touch
        if not (touches or push[k] > 0.0):
            continue
        p = cand[k]
        i = prims[p, 0]
        if prims[p, 1] != i or prims[p, 2] != i or not inv_mass[i] > 0.0:
            continue
        row = end if touches else plane
        nx, ny, nz = row[k, 6], row[k, 7], row[k, 8]
        dx = x1[i, 0] - x0[i, 0]
        dy = x1[i, 1] - x0[i, 1]
        dz = x1[i, 2] - x0[i, 2]
        along = dx * nx + dy * ny + dz * nz
        tx, ty, tz = dx - along * nx, dy - along * ny, dz - along * nz
        if tx * tx + ty * ty + tz * tz <= (friction * max(push[k], 0.0)) ** 2:
            x1[i, 0] -= tx
            x1[i, 1] -= ty
            x1[i, 2] -= tz
            held[i] = np.sqrt(tx * tx + ty * ty + tz * tz)


def contact(
    kind: int,
    params: np.ndarray,
    closed: bool,
    vertices: np.ndarray,
    triangles: np.ndarray,
    normals: np.ndarray,
    bounds: np.ndarray,
    nodes: np.ndarray,
    order: np.ndarray,
    tri_bounds: np.ndarray,
    x0: np.ndarray,
    x1: np.ndarray,
    prims: np.ndarray,
    movable: np.ndarray,
    inv_mass: np.ndarray,
    hint: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    h: float,
    gap: float,
    floor: float,
    max_steps: int,
    plane_sweeps: int,
    joint_sweeps: int,
    rounds: int,
    friction: float,
    touch: float,
):  # pragma: no cover - compiled
    """One substep of contact with one shape, in its rest frame: x0, x1 (V, 3) the start and
    end positions (x1 corrected in place), prims (P, 3), movable and inv_mass (V,), hint (P,)
    the open-sheet sides (updated: see `_advance`; 0 away from the shape), h the thickness, gap the advancement's
    tolerance, floor the clearance below which the fail-safe puts vertices back; friction: the
    static friction that holds vertex contacts where they were along the surface (`hold_still`;
    0: none), touch the clearance within which a contact touches at the end (`acting_contacts`).

    1. candidates (swept boxes near the shape), each swept by `_advance`;
    2. the hits resolved by `_solve`; up to `rounds` times, candidates that the corrections
       moved are swept again from x0 and new hits added and solved; then static friction's hold
       (`hold_still`);
    3. the fail-safe: every contact, every candidate with a vertex the hold moved (a vertex held
       where it was along a moving box's top could drive a triangle beside it into the box's
       edge) and every primitive with a vertex put back, still nearer than floor, has its movable
       vertices put back at x0, until none is (the start was clear);
    4. the contacts evaluated at their final positions.

    Returns (ids (C,) primitive ids, plane (C, 9) the time-of-impact w, q, n, end (C, 9) the
    final w, q, n, d_end (C,), push (C,), moved (V,), reverted (V,), counts (4,): swept (hits
    along a path clear at its start), crossed (of those, ends inside, past or nearest the far
    side of the shape), extra rounds, vertices put back)."""
    n = x0.shape[0]
    tri = np.empty((3, 3))
    stack = new_stack()
    cand = candidates(x0, x1, prims, movable, kind, params, lo, hi, h + gap)
    c_count = cand.shape[0]
    hit = np.zeros(c_count, dtype=np.bool_)
    plane = np.zeros((c_count, 9))
    end = np.zeros((c_count, 9))
    d_end = np.full(c_count, np.inf)
    push = np.zeros(c_count)
    slots = np.empty(c_count, dtype=np.int64)
    moved = np.zeros(n, dtype=np.bool_)
    reverted = np.zeros(n, dtype=np.bool_)
    counts = np.zeros(4, dtype=np.int64)
    m = 0
    for k in range(c_count):
        p = cand[k]
        i0, i1, i2 = prims[p, 0], prims[p, 1], prims[p, 2]
        found, s, d0, w0, w1, w2, qx, qy, qz, nx, ny, nz, side = _advance(
            kind,
            params,
            closed,
            vertices,
            triangles,
            normals,
            bounds,
            nodes,
            order,
            tri_bounds,
            x0,
            x1,
            i0,
            i1,
            i2,
            hint[p],
            h,
            gap,
            max_steps,
            tri,
            stack,
        )
        hint[p] = side
        if not found:
            continue
        hit[k] = True
        slots[m] = k
        m += 1
        plane[k, 0], plane[k, 1], plane[k, 2] = w0, w1, w2
        plane[k, 3], plane[k, 4], plane[k, 5] = qx, qy, qz
        plane[k, 6], plane[k, 7], plane[k, 8] = nx, ny, nz
        if d0 > h and s < 1.0:
            counts[0] += 1
            de = _evaluate(
                kind,
                params,
                closed,
                vertices,
                triangles,
                normals,
                bounds,
                nodes,
                order,
                tri_bounds,
                x1,
                prims,
                p,
                side,
                np.inf,
                end,
                k,
                tri,
                stack,
            )
            behind = end[k, 6] * nx + end[k, 7] * ny + end[k, 8] * nz < 0.0
            if de < 0.0 or de > h or behind:
                counts[1] += 1
    current = _solve(
        kind,
        params,
        closed,
        vertices,
        triangles,
        normals,
        bounds,
        nodes,
        order,
        tri_bounds,
        x1,
        inv_mass,
        prims,
        cand,
        slots[:m],
        plane,
        hint,
        h,
        gap,
        plane_sweeps,
        joint_sweeps,
        push,
        moved,
        end,
        d_end,
        tri,
        stack,
    )
    for _ in range(rounds):  # primitives the corrections moved into contact
        added = m
        for k in range(c_count):
            p = cand[k]
            if hit[k] or not (moved[prims[p, 0]] or moved[prims[p, 1]] or moved[prims[p, 2]]):
                continue
            i0, i1, i2 = prims[p, 0], prims[p, 1], prims[p, 2]
            found, s, d0, w0, w1, w2, qx, qy, qz, nx, ny, nz, side = _advance(
                kind,
                params,
                closed,
                vertices,
                triangles,
                normals,
                bounds,
                nodes,
                order,
                tri_bounds,
                x0,
                x1,
                i0,
                i1,
                i2,
                hint[p],
                h,
                gap,
                max_steps,
                tri,
                stack,
            )
            if found:
                hit[k] = True
                slots[added] = k
                added += 1
                plane[k, 0], plane[k, 1], plane[k, 2] = w0, w1, w2
                plane[k, 3], plane[k, 4], plane[k, 5] = qx, qy, qz
                plane[k, 6], plane[k, 7], plane[k, 8] = nx, ny, nz
        if added == m:
            break
        m = added
        counts[2] += 1
        current = _solve(
            kind,
            params,
            closed,
            vertices,
            triangles,
            normals,
            bounds,
            nodes,
            order,
            tri_bounds,
            x1,
            inv_mass,
            prims,
            cand,
            slots[:m],
            plane,
            hint,
            h,
            gap,
            plane_sweeps,
            joint_sweeps,
            push,
            moved,
            end,
            d_end,
            tri,
            stack,
        )
    contacts = slots[:m]
    for k in contacts if not current else contacts[:0]:
        d_end[k] = _evaluate(
            kind,
            params,
            closed,
            vertices,
            triangles,
            normals,
            bounds,
            nodes,
            order,
            tri_bounds,
            x1,
            prims,
            cand[k],
            hint[cand[k]],
            h + gap,
            end,
            k,
            tri,
            stack,
        )
    held = np.zeros(n)  # how far static friction's hold moved each vertex (m)
    if friction > 0.0:
        hold_still(x0, x1, prims, cand, contacts, plane, end, d_end, push, touch, friction, inv_mass, held)
        for i in range(n):
            moved[i] = moved[i] or held[i] > 0.0
    # the fail-safe; a primitive is looked at again once one of its vertices has been put back
    changed = True
    first = True
    while changed:
        changed = False
        for k in range(c_count):
            p = cand[k]
            i0, i1, i2 = prims[p, 0], prims[p, 1], prims[p, 2]
            touched = reverted[i0] or reverted[i1] or reverted[i2]
            shift = max(held[i0], max(held[i1], held[i2]))  # a clearance changes by at most this
            if not (touched or (first and (hit[k] or shift > 0.0))):
                continue
            free = False
            for i in (i0, i1, i2):
                if movable[i] and not reverted[i]:
                    free = True
            if not free:
                continue
            d = (
                d_end[k]
                if (first and not touched and (shift == 0.0 or (hit[k] and d_end[k] - shift >= floor)))
                else _evaluate(
                    kind,
                    params,
                    closed,
                    vertices,
                    triangles,
                    normals,
                    bounds,
                    nodes,
                    order,
                    tri_bounds,
                    x1,
                    prims,
                    p,
                    hint[p],
                    h + gap,
                    end,
                    k,
                    tri,
                    stack,
                )
            )
            if hit[k]:
                d_end[k] = d
            if d < floor:
                for i in (i0, i1, i2):
                    if movable[i] and not reverted[i]:
                        x1[i, 0], x1[i, 1], x1[i, 2] = x0[i, 0], x0[i, 1], x0[i, 2]
                        reverted[i] = True
                        moved[i] = True
                        counts[3] += 1
                changed = True
        first = False
    if counts[3] > 0:  # contacts whose vertices went back: their final contact again
        for k in contacts:
            p = cand[k]
            if reverted[prims[p, 0]] or reverted[prims[p, 1]] or reverted[prims[p, 2]]:
                d_end[k] = _evaluate(
                    kind,
                    params,
                    closed,
                    vertices,
                    triangles,
                    normals,
                    bounds,
                    nodes,
                    order,
                    tri_bounds,
                    x1,
                    prims,
                    p,
                    hint[p],
                    h + gap,
                    end,
                    k,
                    tri,
                    stack,
                )
    near = np.zeros(prims.shape[0], dtype=np.bool_)
    near[cand] = True
    for p in range(prims.shape[0]):  # a sheet's side is only kept near it
        if not near[p]:
            hint[p] = 0.0
    return cand[contacts], plane[contacts], end[contacts], d_end[contacts], push[contacts], moved, reverted, counts


def near(
    kind: int,
    params: np.ndarray,
    closed: bool,
    vertices: np.ndarray,
    triangles: np.ndarray,
    normals: np.ndarray,
    bounds: np.ndarray,
    nodes: np.ndarray,
    order: np.ndarray,
    tri_bounds: np.ndarray,
    x: np.ndarray,
    prims: np.ndarray,
    movable: np.ndarray,
    hint: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    reach: float,
):  # pragma: no cover - compiled
    """The primitives (P, 3) of the cloth at x (V, 3; local) with a movable vertex (movable (V,))
    whose clearance from the shape is below `reach` (local units), with hint (P,) the open-sheet
    sides as `contact` keeps them: their ids (N,), closest points (N, 9: w, q, n as `contact`'s
    rows) and clearances (N,), in primitive order. The planes a solver keeps its contacts on
    between two collider passes (`Collider.planes`)."""
    cand = candidates(x, x, prims, movable, kind, params, lo, hi, reach)
    rows = np.zeros((cand.shape[0], 9))
    clearance = np.empty(cand.shape[0])
    tri = np.empty((3, 3))
    stack = new_stack()
    found = 0
    for k in range(cand.shape[0]):
        p = cand[k]
        d = _evaluate(
            kind, params, closed, vertices, triangles, normals, bounds, nodes, order, tri_bounds,
            x, prims, p, hint[p], reach, rows, found, tri, stack,
        )  # fmt: skip
        if d < reach:
            cand[found] = p
            clearance[found] = d
            found += 1
    return cand[:found], rows[:found], clearance[:found]


@numba.njit(**JIT)
def fastest_speed(velocities: np.ndarray, inv_mass: np.ndarray) -> float:  # pragma: no cover - compiled
    """The largest speed (m/s) among the movable vertices (inv_mass > 0) of velocities (V, 3); 0 without any."""
    top = 0.0
    for i in range(velocities.shape[0]):
        if inv_mass[i] > 0.0:
            s = velocities[i, 0] * velocities[i, 0] + velocities[i, 1] * velocities[i, 1]
            s += velocities[i, 2] * velocities[i, 2]
            top = max(top, s)
    return np.sqrt(top)


@numba.njit(**JIT)
def plane_rows(
    ids: np.ndarray,
    weights: np.ndarray,
    prims: np.ndarray,
    positions: np.ndarray,
    velocities: np.ndarray,
    normals: np.ndarray,
    surface: np.ndarray,
    surface_velocity: np.ndarray,
    thickness: float,
    band: float,
    slack: float,
    dt: float,
    far: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """The contact planes of `near`'s primitives ids (N,) with their weights (N, 3), in the world
    (`Collider.planes`): each point p = sum_j w_j positions[prims[id, j]] gets the plane of normal
    normals[k] through surface[k] moved out by `thickness` (m), or through p itself where p lies
    more than `slack` (m) nearer; with `far`, only the points within `band` (m) of their plane or
    closing on it (at the surface's velocity less the point's, velocities (V, 3) m/s, over dt s)
    by more than the band and as far as they close. Returns the kept rows' vertices (M, 3),
    weights (M, 3), normals (M, 3), offsets (M,) and surface velocities (M, 3), in row order."""
    n = ids.shape[0]
    vertices = np.empty((n, 3), dtype=np.int64)
    kept_weights = np.empty((n, 3))
    kept_normals = np.empty((n, 3))
    offsets = np.empty(n)
    kept_velocity = np.empty((n, 3))
    m = 0
    for k in range(n):
        p = ids[k]
        i0, i1, i2 = prims[p, 0], prims[p, 1], prims[p, 2]
        w0, w1, w2 = weights[k, 0], weights[k, 1], weights[k, 2]
        nx, ny, nz = normals[k, 0], normals[k, 1], normals[k, 2]
        px = w0 * positions[i0, 0] + w1 * positions[i1, 0] + w2 * positions[i2, 0]
        py = w0 * positions[i0, 1] + w1 * positions[i1, 1] + w2 * positions[i2, 1]
        pz = w0 * positions[i0, 2] + w1 * positions[i1, 2] + w2 * positions[i2, 2]
        offset = nx * surface[k, 0] + ny * surface[k, 1] + nz * surface[k, 2] + thickness
        now = nx * px + ny * py + nz * pz
        ux, uy, uz = surface_velocity[k, 0], surface_velocity[k, 1], surface_velocity[k, 2]
        if far:
            vx = w0 * velocities[i0, 0] + w1 * velocities[i1, 0] + w2 * velocities[i2, 0]
            vy = w0 * velocities[i0, 1] + w1 * velocities[i1, 1] + w2 * velocities[i2, 1]
            vz = w0 * velocities[i0, 2] + w1 * velocities[i1, 2] + w2 * velocities[i2, 2]
            closing = (nx * (ux - vx) + ny * (uy - vy) + nz * (uz - vz)) * dt
            ahead = now - offset
            if not (ahead <= band or (closing > band and ahead <= closing)):
                continue
        if now < offset - slack:
            offset = now
        vertices[m, 0], vertices[m, 1], vertices[m, 2] = i0, i1, i2
        kept_weights[m, 0], kept_weights[m, 1], kept_weights[m, 2] = w0, w1, w2
        kept_normals[m, 0], kept_normals[m, 1], kept_normals[m, 2] = nx, ny, nz
        offsets[m] = offset
        kept_velocity[m, 0], kept_velocity[m, 1], kept_velocity[m, 2] = ux, uy, uz
        m += 1
    return vertices[:m], kept_weights[:m], kept_normals[:m], offsets[:m], kept_velocity[:m]


class Family(NamedTuple):
    """One closest-point query's compiled pipeline: `contact` and `near`."""

    contact: Callable[..., tuple]
    near: Callable[..., tuple]


def _family(suffix: str, query: Callable[..., tuple]) -> Family:
    """The pipeline (`contact`, `near` and the helpers they call) compiled for one closest-point query:
    copies of the functions whose globals name `closest` the query, each under its own name so
    Numba's disk cache keeps the builds apart (as `solvers.jit.serial_and_parallel` does). A
    query chosen inside the kernels by the shape's kind would cost a sphere's contact more than
    the query itself: a call that passes the mesh's arrays, even in a branch never taken, pays
    for each of them on every call."""
    env = dict(globals())
    env["closest"] = query
    for name in ("_advance", "_solve", "_evaluate", "contact", "near"):
        source = globals()[name]
        copy = types.FunctionType(source.__code__, env, f"{name}_{suffix}", source.__defaults__, source.__closure__)
        copy.__qualname__ = f"{name}_{suffix}"
        copy.__doc__ = source.__doc__
        # no Numba IR inlining (`inline="always"`) of the sweep `_advance`: it saved a few per
        # cent of a sphere's contact time, about the noise of benchmarks/colliders.py, and cost
        # 4 s of compile time in every fresh process (CI runners, containers, Dask workers)
        env[name] = numba.njit(**JIT)(copy)
    return Family(contact=env["contact"], near=env["near"])


@numba.njit(**JIT)
def closest_only_plane(
    kind: int,
    params: np.ndarray,
    closed: bool,
    vertices: np.ndarray,
    triangles: np.ndarray,
    normals: np.ndarray,
    bounds: np.ndarray,
    nodes: np.ndarray,
    order: np.ndarray,
    tri_bounds: np.ndarray,
    tri: np.ndarray,
    i0: int,
    i1: int,
    i2: int,
    hint: float,
    limit: float,
    stack: np.ndarray,
) -> tuple[float, float, float, float, float, float, float, float, float, float, float]:
    """`closest_simple`'s signature answered for a plane alone (`closest_plane`): the query of
    the build for scenes whose colliders are all planes, no dispatch on the kind."""
    return closest_plane(params, tri, i0, i1, i2)


#: `contact` and `near` for planes alone, for planes, spheres and capsules, for boxes and for meshes
contact_plane, near_plane = _family("plane", closest_only_plane)
contact_simple, near_simple = _family("simple", closest_simple)
contact_box, near_box = _family("box", closest_box)
contact_mesh, near_mesh = _family("mesh", closest_mesh)
#: each build's `near`, by its `contact`
_NEAR = {contact_plane: near_plane, contact_simple: near_simple, contact_box: near_box, contact_mesh: near_mesh}


def near_kernel(kind: int, company: frozenset[int] = frozenset()) -> Callable[..., tuple]:
    """The compiled `near` of the build `contact_kernel(kind, company)` runs in."""
    return _NEAR[contact_kernel(kind, company)]


def contact_kernel(kind: int, company: frozenset[int] = frozenset()) -> Callable[..., tuple]:
    """The compiled `contact` for a shape kind among colliders of the kinds `company` (a
    scene's). Each build compiles the whole pipeline, seconds in a process with an empty compile
    cache, and every build answers planes: a plane runs in the build of a box or mesh in its
    company (unless a sphere or capsule needs the simple one anyway), so the ground beside a box
    or a mesh costs no second build; planes alone (a ground, walls) run in a build of their own,
    whose query is the plane's alone: no dispatch on the kind, cheaper to compile and to run than
    the simple build (docs/performance.md, "Planes alone in a build of their own"). The build
    changes no result (the same plane code, no fast-math)."""
    if kind == PLANE:
        if not company - {PLANE}:
            return contact_plane
        if not company & {SPHERE, CAPSULE}:
            kind = BOX if BOX in company else MESH
    if kind == MESH:
        return contact_mesh
    return contact_box if kind == BOX else contact_simple


@numba.njit(**JIT)
def respond(
    v: np.ndarray,
    inv_mass: np.ndarray,
    prims: np.ndarray,
    ids: np.ndarray,
    rows: np.ndarray,
    surface_v: np.ndarray,
    push: np.ndarray,
    friction: float,
    dt: float,
    touched: np.ndarray,
    sweeps: int,
) -> None:  # pragma: no cover - compiled
    """Contact velocities by sequential impulses (world frame): `sweeps` Gauss-Seidel
    sweeps over the contacts `ids` in order, each contact point (rows (C, 9): weights w, surface
    point q (not read), unit normal n; surface velocity surface_v (C, 3)) keeping an accumulated
    normal velocity change that stops its approach and is never negative (a contact only
    pushes), and an accumulated tangential one that brings its sliding to rest within Coulomb's
    cone, friction times the larger of that normal change and the push (C,) over dt (the normal
    change the position push stands for). Each change is spread over the point's vertices by
    weight and inverse mass, so the point's velocity changes by exactly it.

    Accumulated and clamped (Catto's sequential impulses), the contacts sharing a vertex settle
    on the least pushes that stop them all: one pass of independent corrections over-pushed a
    vertex that several touching edges and faces share (each lifted it by its own approach) and
    sent it off the obstacle every substep, so a cloth lying on a ball never came to rest. The
    first sweep is that pass. Then each vertex is settled (`_settle_vertices`).
    v (V, 3) is updated in place, touched (V,) marks the vertices changed."""
    count = ids.shape[0]
    normal_total = np.zeros(count)
    tangent_total = np.zeros((count, 3))
    v_before = v.copy()
    for sweep in range(sweeps):
        largest = 0.0  # the largest change of a contact point's velocity in this sweep (m/s)
        for k in range(count):
            p = ids[k]
            i0, i1, i2 = prims[p, 0], prims[p, 1], prims[p, 2]
            w0, w1, w2 = rows[k, 0], rows[k, 1], rows[k, 2]
            denom = w0 * w0 * inv_mass[i0] + w1 * w1 * inv_mass[i1] + w2 * w2 * inv_mass[i2]
            if not denom > 1e-300:
                continue
            nx, ny, nz = rows[k, 6], rows[k, 7], rows[k, 8]
            rx = w0 * v[i0, 0] + w1 * v[i1, 0] + w2 * v[i2, 0] - surface_v[k, 0]
            ry = w0 * v[i0, 1] + w1 * v[i1, 1] + w2 * v[i2, 1] - surface_v[k, 1]
            rz = w0 * v[i0, 2] + w1 * v[i1, 2] + w2 * v[i2, 2] - surface_v[k, 2]
            vn = rx * nx + ry * ny + rz * nz
            total = max(normal_total[k] - vn, 0.0)  # the approach stopped, never a pull
            stop = total - normal_total[k]
            normal_total[k] = total
            # sliding after the normal change (along n only: the tangent is unchanged)
            tx, ty, tz = rx - vn * nx, ry - vn * ny, rz - vn * nz
            bound = friction * max(total, max(push[k], 0.0) / dt) if dt > 0.0 else friction * total
            # the tangential change that would bring the sliding to rest, added to the total so far,
            # clamped to the cone; what this visit adds is the clamped total less the one before
            gx = tangent_total[k, 0] - tx
            gy = tangent_total[k, 1] - ty
            gz = tangent_total[k, 2] - tz
            size = np.sqrt(gx * gx + gy * gy + gz * gz)
            if size > bound or (sweep == 0 and size <= 1e-12):  # the first pass leaves a sliver alone
                shrink = bound / size if size > 1e-12 else 0.0
                gx, gy, gz = gx * shrink, gy * shrink, gz * shrink
            dx = stop * nx + gx - tangent_total[k, 0]
            dy = stop * ny + gy - tangent_total[k, 1]
            dz = stop * nz + gz - tangent_total[k, 2]
            tangent_total[k, 0], tangent_total[k, 1], tangent_total[k, 2] = gx, gy, gz
            largest = max(largest, abs(dx) + abs(dy) + abs(dz))
            for i, wk in ((i0, w0), (i1, w1), (i2, w2)):
                f = wk * inv_mass[i] / denom
                if f != 0.0:
                    v[i, 0] += f * dx
                    v[i, 1] += f * dy
                    v[i, 2] += f * dz
                    touched[i] = True
        if sweep > 0 and largest <= SETTLED_SPEED:  # the contacts no longer change each other
            break
    _settle_vertices(v, v_before, inv_mass, prims, ids, rows, surface_v, touched)


#: a sweep of `respond` after the first that changes no contact point's velocity by more than this
#: (m/s, summed over the axes) ends the sweeps: contacts that share no vertex (a cloth on a plane)
#: settle in one
SETTLED_SPEED = 1e-9


@numba.njit(**JIT)
def _settle_vertices(
    v: np.ndarray,
    v_before: np.ndarray,
    inv_mass: np.ndarray,
    prims: np.ndarray,
    ids: np.ndarray,
    rows: np.ndarray,
    surface_v: np.ndarray,
    touched: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """`respond`'s last pass, vertex by vertex: each vertex of a contact (weight > 0) ends neither
    approaching its surface (normal n, relative to surface_v) nor leaving it faster than it did
    before the response (v_before (V, 3)), and slides along it no faster than before and not
    the other way. The sweeps converge slowly where many contacts share a vertex, and a face
    contact's change spread by inverse mass turns a light corner off the obstacle (or back along
    it) while its heavier corners still approach: a few per cent of the approach left over
    either way kept a cloth lying on a ball from ever coming to rest."""
    for k in range(ids.shape[0]):
        p = ids[k]
        nx, ny, nz = rows[k, 6], rows[k, 7], rows[k, 8]
        sx, sy, sz = surface_v[k, 0], surface_v[k, 1], surface_v[k, 2]
        for j in range(3):
            i = prims[p, j]
            if not (rows[k, j] > 0.0 and inv_mass[i] > 0.0):
                continue
            ax, ay, az = v[i, 0] - sx, v[i, 1] - sy, v[i, 2] - sz  # relative velocity now
            bx, by, bz = v_before[i, 0] - sx, v_before[i, 1] - sy, v_before[i, 2] - sz  # and before
            vn = ax * nx + ay * ny + az * nz
            vn_was = bx * nx + by * ny + bz * nz
            ax, ay, az = ax - vn * nx, ay - vn * ny, az - vn * nz  # the slides
            bx, by, bz = bx - vn_was * nx, by - vn_was * ny, bz - vn_was * nz
            along = bx * bx + by * by + bz * bz
            share = min(max((ax * bx + ay * by + az * bz) / along, 0.0), 1.0) if along > 1e-300 else 0.0
            normal = min(max(vn, 0.0), max(vn_was, 0.0))
            ux = normal * nx + share * bx + sx
            uy = normal * ny + share * by + sy
            uz = normal * nz + share * bz + sz
            if ux != v[i, 0] or uy != v[i, 1] or uz != v[i, 2]:
                v[i, 0], v[i, 1], v[i, 2] = ux, uy, uz
                touched[i] = True


@numba.njit(**JIT)
def acting_contacts(
    ids: np.ndarray,
    plane: np.ndarray,
    end: np.ndarray,
    d_end: np.ndarray,
    push: np.ndarray,
    touch: float,
    totals: np.ndarray,
    counts: np.ndarray,
) -> int:  # pragma: no cover - compiled
    """The contacts of `contact`'s result (ids (C,), plane and end (C, 9), d_end and push (C,))
    that act on the velocities, moved in order to the front of ids, plane and push (in place;
    returns their number A): those touching at the end (d_end <= touch, in local units) with
    their final closest point (w, q, n) in plane's row, and those only pushed (push > 0) with
    their time-of-impact plane. Adds the substep to totals (6,) int64 (`ContactStats`' fields:
    substeps, touching contacts, then `contact`'s counts (4,): swept, crossed, rounds, reverted).
    In place rather than into new arrays: an allocation's compiling costs a fresh process more
    than the copy."""
    acting = 0
    touching = 0
    for k in range(ids.shape[0]):
        touches = d_end[k] <= touch
        if not (touches or push[k] > 0.0):
            continue
        touching += 1 if touches else 0
        ids[acting] = ids[k]
        push[acting] = push[k]
        for j in range(9):  # row `acting` <= k: already read
            plane[acting, j] = end[k, j] if touches else plane[k, j]
        acting += 1
    totals[0] += 1
    totals[1] += touching
    for j in range(4):
        totals[2 + j] += counts[j]
    return acting


@numba.njit(**JIT)
def copy_rows(target: np.ndarray, source: np.ndarray, mask: np.ndarray) -> None:  # pragma: no cover - compiled
    """target[mask] = source[mask] for (V, 3) arrays and a (V,) mask, in place."""
    for i in range(mask.shape[0]):
        if mask[i]:
            target[i, 0] = source[i, 0]
            target[i, 1] = source[i, 1]
            target[i, 2] = source[i, 2]


@numba.njit(**JIT)
def restart_paths(
    previous: np.ndarray, positions: np.ndarray, velocities: np.ndarray, mask: np.ndarray, dt: float
) -> None:  # pragma: no cover - compiled
    """previous[mask] = positions[mask] - velocities[mask] * dt ((V, 3) each, in place): the
    vertices a contact changed start the next substep's path where their new velocity says."""
    for i in range(mask.shape[0]):
        if mask[i]:
            for k in range(3):
                previous[i, k] = positions[i, k] - velocities[i, k] * dt
