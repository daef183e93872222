"""Compiled contact of a cloth's vertices, edges and triangles with one collider shape (Numba).

The cloth is a list of primitives, rows (i0, i1, i2) of vertex indices: a triangle, an edge
(a, b, b) or a vertex (a, a, a). Every query works in the collider's rest frame ("local"):
positions (V, 3) at the start (x0) and at the end (x1) of the substep, the path between them
linear. A shape is a `ShapeArrays`: a plane, a sphere, a capsule or a triangle mesh (`Surface`,
with its BVH); boxes are 12-triangle closed meshes.

`closest` gives, for one primitive in one configuration, the signed clearance d (negative:
inside a solid, or on the far side of an open sheet from the side it keeps), the contact point
on the cloth as weights (w0, w1, w2) on its vertices, the surface point q and the outward unit
normal n, with d = n . (p - q) for the cloth point p = sum w_k x_k. The contact asks for
d >= h (h: the collider's thickness in local units).

`sweep` is conservative advancement (Mirtich 1996; Zhang et al., "Continuous collision
detection for articulated models using Taylor models and temporal culling", 2007): along the
path a point of the primitive moves at most L = max_k |x1_k - x0_k| (its vertices move
linearly), so after the clearance d at path parameter s it cannot come nearer than h - gap
before s + (d - h + gap) / L. Stepping by that never passes through anything, whatever the
speed and however thin the shape; the first configuration found within h is the time of
impact, and its (w, n, q) a plane the end position must stay in front of. `solve` enforces
those planes and the closest-point contacts at the end position by Gauss-Seidel position
corrections weighted by the contact weights and inverse masses (position-based dynamics:
lambda = depth / sum_k w_k^2 m_k^-1, dx_k = lambda w_k m_k^-1 n). `respond` removes the
approaching normal velocity of every contact point (relative to the surface) and applies
Coulomb friction, spread over the vertices the same way. Everything runs serially in the
primitives' order: the same input gives the same bytes.
"""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np

from meshdeform.contact.bvh import closest_to_point, closest_to_triangle
from meshdeform.contact.primitives import point_triangle_weights
from meshdeform.contact.surface import FEATURE_EPS, Surface, pseudo_normal
from meshdeform.contact.triangle_distance import segment_triangle_closest

_JIT = {"cache": True, "error_model": "numpy"}

PLANE = 0
SPHERE = 1
CAPSULE = 2
MESH = 3

#: distances below this count as touching: the direction from surface to cloth is not used
TOUCH = 1e-12


class ShapeArrays(NamedTuple):
    """A shape as the kernels read it, in its rest frame.

    kind: PLANE, SPHERE, CAPSULE or MESH. point, normal (3,): the plane (a point and the unit
    normal), the sphere's centre (point), the capsule's fallback normal (normal: a unit vector
    across its axis, used when a cloth point lies on the axis). axis (2, 3): the capsule's ends.
    radius: sphere or capsule. surface: the mesh (a one-triangle placeholder for other kinds).
    """

    kind: int
    point: np.ndarray
    normal: np.ndarray
    axis: np.ndarray
    radius: float
    surface: Surface


@numba.njit(**_JIT)
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


@numba.njit(**_JIT)
def _triangle_normal(tri: np.ndarray) -> tuple[float, float, float, bool]:
    ux, uy, uz = tri[1, 0] - tri[0, 0], tri[1, 1] - tri[0, 1], tri[1, 2] - tri[0, 2]
    vx, vy, vz = tri[2, 0] - tri[0, 0], tri[2, 1] - tri[0, 1], tri[2, 2] - tri[0, 2]
    nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    length = np.sqrt(nx * nx + ny * ny + nz * nz)
    if length > 0.0:
        return nx / length, ny / length, nz / length, True
    return 0.0, 1.0, 0.0, False


@numba.njit(**_JIT)
def closest(
    shape: ShapeArrays, tri: np.ndarray, i0: int, i1: int, i2: int, hint: float, limit: float
) -> tuple[float, float, float, float, float, float, float, float, float, float, float]:
    """(d, w0, w1, w2, qx, qy, qz, nx, ny, nz, side) of the primitive whose current corners are
    the rows of tri (3, 3) (vertex indices i0, i1, i2 tell edges and vertices apart).

    limit: clearance beyond which the caller needs no exact answer; a mesh then returns
    d = limit and a zero normal. hint: for an open sheet, the side (+1 / -1 along the face
    normals) the primitive keeps, 0 when unknown; side: the side used (0 for other shapes)."""
    vertex = i0 == i1 and i1 == i2
    kind = shape.kind
    if kind == PLANE:  # a half-space: the distance is linear over the primitive, least at a corner
        nx, ny, nz = shape.normal[0], shape.normal[1], shape.normal[2]
        best = np.inf
        corner = 0
        for k in range(3):
            dk = (
                (tri[k, 0] - shape.point[0]) * nx
                + (tri[k, 1] - shape.point[1]) * ny
                + (tri[k, 2] - shape.point[2]) * nz
            )
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
    if kind in (SPHERE, CAPSULE):
        if kind == SPHERE:
            ax, ay, az = shape.point[0], shape.point[1], shape.point[2]
            w0, w1, w2 = point_triangle_weights(ax, ay, az, tri, 0, 1, 2)
        else:
            _, u, w0, w1, w2 = segment_triangle_closest(shape.axis, 0, 1, tri, 0, 1, 2)
            ax = shape.axis[0, 0] + u * (shape.axis[1, 0] - shape.axis[0, 0])
            ay = shape.axis[0, 1] + u * (shape.axis[1, 1] - shape.axis[0, 1])
            az = shape.axis[0, 2] + u * (shape.axis[1, 2] - shape.axis[0, 2])
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
                    nx, ny, nz = shape.normal[0], shape.normal[1], shape.normal[2]
        r = shape.radius
        w0, w1, w2 = _merge(i0, i1, i2, w0, w1, w2)
        return length - r, w0, w1, w2, ax + r * nx, ay + r * ny, az + r * nz, nx, ny, nz, 0.0
    # a triangle mesh
    surface = shape.surface
    verts = surface.vertices
    tris = surface.triangles
    limit2 = limit * limit if limit < np.inf else np.inf
    if vertex:
        d2, t, m0, m1, m2 = closest_to_point(surface.bvh, verts, tris, tri[0, 0], tri[0, 1], tri[0, 2], limit2)
        w0, w1, w2 = 1.0, 0.0, 0.0
    else:
        d2, t, w0, w1, w2, m0, m1, m2 = closest_to_triangle(surface.bvh, verts, tris, tri, 0, 1, 2, limit2)
    if t < 0:
        return limit, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, hint
    px = w0 * tri[0, 0] + w1 * tri[1, 0] + w2 * tri[2, 0]
    py = w0 * tri[0, 1] + w1 * tri[1, 1] + w2 * tri[2, 1]
    pz = w0 * tri[0, 2] + w1 * tri[1, 2] + w2 * tri[2, 2]
    a, b, c = tris[t, 0], tris[t, 1], tris[t, 2]
    qx = m0 * verts[a, 0] + m1 * verts[b, 0] + m2 * verts[c, 0]
    qy = m0 * verts[a, 1] + m1 * verts[b, 1] + m2 * verts[c, 1]
    qz = m0 * verts[a, 2] + m1 * verts[b, 2] + m2 * verts[c, 2]
    gx, gy, gz = pseudo_normal(surface, t, m0, m1, m2)
    glen = np.sqrt(gx * gx + gy * gy + gz * gz)
    if glen > 0.0:
        gx, gy, gz = gx / glen, gy / glen, gz / glen
    else:
        gx, gy, gz = 0.0, 1.0, 0.0
    vx, vy, vz = px - qx, py - qy, pz - qz
    du = np.sqrt(d2)
    along = vx * gx + vy * gy + vz * gz
    w0, w1, w2 = _merge(i0, i1, i2, w0, w1, w2)
    if surface.closed:
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
        fn = surface.face_normals[t]
        return -du, w0, w1, w2, qx, qy, qz, side * fn[0], side * fn[1], side * fn[2], side
    if du > TOUCH:
        return du, w0, w1, w2, qx, qy, qz, vx / du, vy / du, vz / du, side
    return 0.0, w0, w1, w2, qx, qy, qz, side * gx, side * gy, side * gz, side


@numba.njit(**_JIT)
def _fill(tri: np.ndarray, x0: np.ndarray, x1: np.ndarray, i0: int, i1: int, i2: int, s: float) -> None:
    for k in range(3):
        tri[0, k] = x0[i0, k] + s * (x1[i0, k] - x0[i0, k])
        tri[1, k] = x0[i1, k] + s * (x1[i1, k] - x0[i1, k])
        tri[2, k] = x0[i2, k] + s * (x1[i2, k] - x0[i2, k])


@numba.njit(**_JIT)
def candidates(
    x0: np.ndarray,
    x1: np.ndarray,
    prims: np.ndarray,
    movable: np.ndarray,
    shape: ShapeArrays,
    lo: np.ndarray,
    hi: np.ndarray,
    margin: float,
) -> np.ndarray:  # pragma: no cover - compiled
    """Ids of the primitives with a movable vertex whose swept box comes within `margin` of
    the shape: of its bounds lo, hi (3,), or for a plane of the plane itself."""
    keep = np.zeros(prims.shape[0], dtype=np.bool_)
    for p in range(prims.shape[0]):
        i0, i1, i2 = prims[p, 0], prims[p, 1], prims[p, 2]
        if not (movable[i0] or movable[i1] or movable[i2]):
            continue
        if shape.kind == PLANE:
            near = False
            for i in (i0, i1, i2):
                for x in (x0, x1):
                    d = (
                        (x[i, 0] - shape.point[0]) * shape.normal[0]
                        + (x[i, 1] - shape.point[1]) * shape.normal[1]
                        + (x[i, 2] - shape.point[2]) * shape.normal[2]
                    )
                    if d < margin:
                        near = True
            keep[p] = near
            continue
        inside = True
        for k in range(3):
            pmin = min(x0[i0, k], x0[i1, k], x0[i2, k], x1[i0, k], x1[i1, k], x1[i2, k])
            pmax = max(x0[i0, k], x0[i1, k], x0[i2, k], x1[i0, k], x1[i1, k], x1[i2, k])
            if pmax < lo[k] - margin or pmin > hi[k] + margin:
                inside = False
        keep[p] = inside
    return np.flatnonzero(keep)


@numba.njit(**_JIT)
def sweep(
    shape: ShapeArrays,
    x0: np.ndarray,
    x1: np.ndarray,
    prims: np.ndarray,
    ids: np.ndarray,
    hint: np.ndarray,
    h: float,
    gap: float,
    max_steps: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover
    """Conservative advancement of the primitives `ids` from x0 to x1 (local (V, 3)).

    Returns hit (C,) bool, s (C,) the path parameter of the first configuration within h,
    d0 (C,) the clearance at the start, and at the hit the weights w (C, 3), surface point q
    (C, 3) and normal n (C, 3). A primitive still advancing after max_steps steps (a path
    grazing the shell) counts as hit where it stands, whose plane holds only if it is crossed.
    hint (P,) is updated in place where it was 0 (an open sheet's side at the start)."""
    c_count = ids.shape[0]
    hit = np.zeros(c_count, dtype=np.bool_)
    s_hit = np.ones(c_count)
    d0 = np.empty(c_count)
    w = np.zeros((c_count, 3))
    q = np.zeros((c_count, 3))
    n = np.zeros((c_count, 3))
    tri = np.empty((3, 3))
    exact_start = shape.kind == MESH and shape.surface.closed
    for k in range(c_count):
        p = ids[k]
        i0, i1, i2 = prims[p, 0], prims[p, 1], prims[p, 2]
        vertex = i0 == i1 and i1 == i2
        travel = 0.0
        for i in (i0, i1, i2):
            dx, dy, dz = x1[i, 0] - x0[i, 0], x1[i, 1] - x0[i, 1], x1[i, 2] - x0[i, 2]
            travel = max(travel, np.sqrt(dx * dx + dy * dy + dz * dz))
        s = 0.0
        steps = 0
        while True:
            _fill(tri, x0, x1, i0, i1, i2, s)
            # a vertex deep inside a solid mesh is farther from its surface than any limit
            limit = np.inf if (steps == 0 and vertex and exact_start) else h + gap + (1.0 - s) * travel
            d, a0, a1, a2, qx, qy, qz, nx, ny, nz, side = closest(shape, tri, i0, i1, i2, hint[p], limit)
            if steps == 0:
                d0[k] = d
                if hint[p] == 0.0:
                    hint[p] = side
            if d <= h or steps >= max_steps:
                hit[k] = True
                s_hit[k] = s
                w[k, 0], w[k, 1], w[k, 2] = a0, a1, a2
                q[k, 0], q[k, 1], q[k, 2] = qx, qy, qz
                n[k, 0], n[k, 1], n[k, 2] = nx, ny, nz
                break
            if s >= 1.0 or d - (1.0 - s) * travel > h:
                break
            steps += 1
            s = min(1.0, s + (d - h + gap) / travel)
    return hit, s_hit, d0, w, q, n


@numba.njit(**_JIT)
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


@numba.njit(**_JIT)
def solve(
    shape: ShapeArrays,
    x: np.ndarray,
    inv_mass: np.ndarray,
    prims: np.ndarray,
    ids: np.ndarray,
    plane_w: np.ndarray,
    plane_q: np.ndarray,
    plane_n: np.ndarray,
    hint: np.ndarray,
    h: float,
    gap: float,
    plane_sweeps: int,
    joint_sweeps: int,
    push: np.ndarray,
    moved: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """Gauss-Seidel over the contacts `ids` (C,), in order: first `plane_sweeps` sweeps over the
    time-of-impact planes (n . (sum w_k x_k - q) >= h), then `joint_sweeps` over the planes and
    the closest-point contacts at the current positions. x (V, 3) local positions, updated in
    place; push (C,) accumulates how far each contact point was moved; moved (V,) marks the
    vertices that were."""
    tri = np.empty((3, 3))
    for sweep_index in range(plane_sweeps + joint_sweeps):
        for k in range(ids.shape[0]):
            p = ids[k]
            i0, i1, i2 = prims[p, 0], prims[p, 1], prims[p, 2]
            w0, w1, w2 = plane_w[k, 0], plane_w[k, 1], plane_w[k, 2]
            nx, ny, nz = plane_n[k, 0], plane_n[k, 1], plane_n[k, 2]
            along = 0.0
            for j in range(3):
                pj = w0 * x[i0, j] + w1 * x[i1, j] + w2 * x[i2, j]
                along += (pj - plane_q[k, j]) * plane_n[k, j]
            if along < h:
                push[k] += _correct(x, inv_mass, i0, i1, i2, w0, w1, w2, nx, ny, nz, h - along, moved)
            if sweep_index >= plane_sweeps:
                _fill(tri, x, x, i0, i1, i2, 0.0)
                d, a0, a1, a2, _, _, _, mx, my, mz, _ = closest(shape, tri, i0, i1, i2, hint[p], h + gap)
                if d < h:
                    push[k] += _correct(x, inv_mass, i0, i1, i2, a0, a1, a2, mx, my, mz, h - d, moved)


@numba.njit(**_JIT)
def evaluate(
    shape: ShapeArrays, x: np.ndarray, prims: np.ndarray, ids: np.ndarray, hint: np.ndarray, limit: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """Clearance d (C,), weights w (C, 3), surface points q (C, 3) and normals n (C, 3) of the
    primitives `ids` at local positions x (clearances beyond `limit` come back as `limit`)."""
    c_count = ids.shape[0]
    d = np.empty(c_count)
    w = np.zeros((c_count, 3))
    q = np.zeros((c_count, 3))
    n = np.zeros((c_count, 3))
    tri = np.empty((3, 3))
    for k in range(c_count):
        p = ids[k]
        i0, i1, i2 = prims[p, 0], prims[p, 1], prims[p, 2]
        _fill(tri, x, x, i0, i1, i2, 0.0)
        d[k], w[k, 0], w[k, 1], w[k, 2], q[k, 0], q[k, 1], q[k, 2], n[k, 0], n[k, 1], n[k, 2], _ = closest(
            shape, tri, i0, i1, i2, hint[p], limit
        )
    return d, w, q, n


@numba.njit(**_JIT)
def respond(
    v: np.ndarray,
    inv_mass: np.ndarray,
    prims: np.ndarray,
    ids: np.ndarray,
    w: np.ndarray,
    n: np.ndarray,
    surface_v: np.ndarray,
    push: np.ndarray,
    friction: float,
    dt: float,
    touched: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """Contact velocities, Gauss-Seidel over the contacts `ids` in order (world frame): at each
    contact point (weights w (C, 3), unit normal n (C, 3), surface velocity surface_v (C, 3))
    the velocity into the surface is removed and the tangential one reduced by Coulomb friction,
    friction times the normal velocity change the contact stands for (the approach stopped, or
    the push (C,) over dt), both spread over the vertices by weight and inverse mass.
    v (V, 3) is updated in place, touched (V,) marks the vertices changed."""
    for k in range(ids.shape[0]):
        p = ids[k]
        i0, i1, i2 = prims[p, 0], prims[p, 1], prims[p, 2]
        w0, w1, w2 = w[k, 0], w[k, 1], w[k, 2]
        denom = w0 * w0 * inv_mass[i0] + w1 * w1 * inv_mass[i1] + w2 * w2 * inv_mass[i2]
        if not denom > 1e-300:
            continue
        nx, ny, nz = n[k, 0], n[k, 1], n[k, 2]
        rx = w0 * v[i0, 0] + w1 * v[i1, 0] + w2 * v[i2, 0] - surface_v[k, 0]
        ry = w0 * v[i0, 1] + w1 * v[i1, 1] + w2 * v[i2, 1] - surface_v[k, 1]
        rz = w0 * v[i0, 2] + w1 * v[i1, 2] + w2 * v[i2, 2] - surface_v[k, 2]
        vn = rx * nx + ry * ny + rz * nz
        tx, ty, tz = rx - vn * nx, ry - vn * ny, rz - vn * nz
        vt = np.sqrt(tx * tx + ty * ty + tz * tz)
        stop = max(-vn, 0.0)
        impulse = max(stop, max(push[k], 0.0) / dt) if dt > 0.0 else stop
        slow = min(vt, friction * impulse)
        scale = slow / vt if vt > 1e-12 else 0.0
        dx = stop * nx - scale * tx
        dy = stop * ny - scale * ty
        dz = stop * nz - scale * tz
        for i, wk in ((i0, w0), (i1, w1), (i2, w2)):
            f = wk * inv_mass[i] / denom
            if f != 0.0:
                v[i, 0] += f * dx
                v[i, 1] += f * dy
                v[i, 2] += f * dz
                touched[i] = True


@numba.njit(**_JIT)
def fail_safe(
    shape: ShapeArrays,
    x0: np.ndarray,
    x1: np.ndarray,
    prims: np.ndarray,
    ids: np.ndarray,
    hint: np.ndarray,
    floor: float,
    limit: float,
    movable: np.ndarray,
    reverted: np.ndarray,
    moved: np.ndarray,
) -> int:  # pragma: no cover - compiled
    """The last resort, after the corrections: every primitive of `ids` still nearer than
    `floor` at x1 (one the corrections could not free, typically pierced by an edge of the
    shape while sliding along it) has its movable vertices put back at their start x0 (local:
    they move with the collider this substep), which was clear; repeated until no primitive
    with a vertex left at its end position fails (at worst every vertex of the failing region
    goes back, and the start was clear). Returns how many vertices went back; reverted and
    moved (V,) mark them."""
    tri = np.empty((3, 3))
    count = 0
    changed = True
    while changed:
        changed = False
        for k in range(ids.shape[0]):
            p = ids[k]
            i0, i1, i2 = prims[p, 0], prims[p, 1], prims[p, 2]
            free = False
            for i in (i0, i1, i2):
                if movable[i] and not reverted[i]:
                    free = True
            if not free:
                continue
            _fill(tri, x1, x1, i0, i1, i2, 0.0)
            d = closest(shape, tri, i0, i1, i2, hint[p], limit)[0]
            if d < floor:
                for i in (i0, i1, i2):
                    if movable[i] and not reverted[i]:
                        x1[i, 0], x1[i, 1], x1[i, 2] = x0[i, 0], x0[i, 1], x0[i, 2]
                        reverted[i] = True
                        moved[i] = True
                        count += 1
                changed = True
    return count
