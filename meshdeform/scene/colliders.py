"""Colliders: ground/plane, sphere, box, capsule and static triangle meshes, as Constraints.

Each shape answers a vectorised closest-surface query in its own rest frame: signed distance
(negative inside), outward unit normal. `Collider.project` runs after every solver substep:
vertices closer than `thickness` to the surface (or inside it) are pushed out along the normal
to exactly `thickness`, their velocity into the surface is removed and their tangential velocity
(relative to a moving collider) is reduced by Coulomb friction. Fast vertices are also tested at
points along their path from the previous position, so thin colliders are not tunnelled through.
Colliders can follow keyframes (rigid motion plus uniform scale) like pins.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.spatial import cKDTree

from meshdeform.model import SpringModel, State
from meshdeform.scene.base import Constraint, Remappable
from meshdeform.scene.pins import Keyframes
from meshdeform.topology import is_closed


def _unit(v: Sequence[float]) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def _normalise_rows(v: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    length = np.sqrt(np.einsum("ij,ij->i", v, v))
    ok = length > 1e-12
    out = np.empty_like(v)
    out[ok] = v[ok] / length[ok, None]
    out[~ok] = fallback
    return out


class Shape:
    """A solid (or, for open meshes, two-sided) surface in its rest frame."""

    #: True when the inside is well defined (a vertex behind the surface is pushed out to the front)
    solid: bool = True

    def query(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Signed distance (N,) and outward unit normal (N, 3) of the nearest surface point."""
        raise NotImplementedError

    def bounds(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Axis-aligned bounds of the surface, None for unbounded shapes (planes)."""
        return None

    @property
    def center(self) -> np.ndarray:
        b = self.bounds()
        return np.zeros(3) if b is None else 0.5 * (b[0] + b[1])


class Plane(Shape):
    """The half-space behind a plane through `point` with `normal` (the ground)."""

    def __init__(self, point: Sequence[float], normal: Sequence[float]) -> None:
        self.point = np.asarray(point, dtype=np.float64)
        self.normal = _unit(normal)

    def query(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # a writable (N, 3) copy, not a broadcast view: the swept test overwrites rows of it
        return (points - self.point) @ self.normal, np.tile(self.normal, (points.shape[0], 1))

    @property
    def center(self) -> np.ndarray:
        return self.point


class Sphere(Shape):
    def __init__(self, center: Sequence[float], radius: float) -> None:
        self.c = np.asarray(center, dtype=np.float64)
        self.radius = float(radius)

    def query(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d = points - self.c
        length = np.sqrt(np.einsum("ij,ij->i", d, d))
        return length - self.radius, _normalise_rows(d, np.array([0.0, 1.0, 0.0]))

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self.c - self.radius, self.c + self.radius


class Box(Shape):
    """An axis-aligned box (rotate it with keyframes)."""

    def __init__(self, lo: Sequence[float], hi: Sequence[float]) -> None:
        self.lo = np.asarray(lo, dtype=np.float64)
        self.hi = np.asarray(hi, dtype=np.float64)

    def query(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        c = 0.5 * (self.lo + self.hi)
        h = 0.5 * (self.hi - self.lo)
        p = points - c
        q = np.abs(p) - h
        outside = np.maximum(q, 0.0)
        out_len = np.sqrt(np.einsum("ij,ij->i", outside, outside))
        inside = np.minimum(q.max(axis=1), 0.0)
        dist = out_len + inside
        sign = np.where(p < 0, -1.0, 1.0)
        normal = np.empty_like(p)
        is_out = out_len > 0
        normal[is_out] = outside[is_out] * sign[is_out] / out_len[is_out, None]
        axis = np.argmax(q[~is_out], axis=1)
        inner = np.zeros((axis.shape[0], 3))
        inner[np.arange(axis.shape[0]), axis] = sign[~is_out][np.arange(axis.shape[0]), axis]
        normal[~is_out] = inner
        return dist, normal

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self.lo, self.hi


class Capsule(Shape):
    """All points within `radius` of the segment a-b."""

    def __init__(self, a: Sequence[float], b: Sequence[float], radius: float) -> None:
        self.a = np.asarray(a, dtype=np.float64)
        self.b = np.asarray(b, dtype=np.float64)
        self.radius = float(radius)

    def query(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ab = self.b - self.a
        denom = float(ab @ ab)
        t = np.clip((points - self.a) @ ab / denom, 0.0, 1.0) if denom > 0 else np.zeros(points.shape[0])
        d = points - (self.a + t[:, None] * ab)
        length = np.sqrt(np.einsum("ij,ij->i", d, d))
        fallback = np.cross(ab, [1.0, 0.0, 0.0]) if denom > 0 else np.array([0.0, 1.0, 0.0])
        if np.linalg.norm(fallback) < 1e-12:
            fallback = np.cross(ab, [0.0, 1.0, 0.0])
        return length - self.radius, _normalise_rows(d, _unit(fallback))

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return np.minimum(self.a, self.b) - self.radius, np.maximum(self.a, self.b) + self.radius


def closest_points_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Closest point on triangle (a, b, c) to p, row by row (Ericson, Real-Time Collision Detection 5.1.5)."""
    ab = b - a
    ac = c - a
    ap = p - a
    d1 = np.einsum("ij,ij->i", ab, ap)
    d2 = np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3 = np.einsum("ij,ij->i", ab, bp)
    d4 = np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5 = np.einsum("ij,ij->i", ab, cp)
    d6 = np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = 1.0 / (va + vb + vc)
        v = vb * denom
        w = vc * denom
        result = a + ab * v[:, None] + ac * w[:, None]  # inside the face
        # edge bc
        w_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        m = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
        result[m] = b[m] + w_bc[m, None] * (c[m] - b[m])
        # edge ac
        w_ac = d2 / (d2 - d6)
        m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        result[m] = a[m] + w_ac[m, None] * ac[m]
        # edge ab
        v_ab = d1 / (d1 - d3)
        m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        result[m] = a[m] + v_ab[m, None] * ab[m]
    # vertex regions last, they take precedence
    m = (d6 >= 0) & (d5 <= d6)
    result[m] = c[m]
    m = (d3 >= 0) & (d4 <= d3)
    result[m] = b[m]
    m = (d1 <= 0) & (d2 <= 0)
    result[m] = a[m]
    return result


class TriangleMesh(Shape):
    """A static triangle mesh. Closed meshes are solids (behind the nearest triangle = inside);
    open ones are thin two-sided sheets whose side is remembered from the previous position.

    Closest points: the `candidates` triangles with the nearest centroids (scipy cKDTree) are
    tested exactly; exact for the usual evenly meshed colliders, approximate where very large
    and very small triangles sit side by side.
    """

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray, candidates: int = 16) -> None:
        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.triangles = np.asarray(triangles, dtype=np.int64)
        if self.triangles.shape[0] == 0:
            raise ValueError("a mesh collider needs at least one triangle")
        a, b, c = (self.vertices[self.triangles[:, i]] for i in range(3))
        self.a, self.b, self.c = a, b, c
        normals = np.cross(b - a, c - a)
        length = np.linalg.norm(normals, axis=1)
        self.face_normals = normals / np.where(length > 0, length, 1.0)[:, None]
        self.tree = cKDTree((a + b + c) / 3.0)
        self.k = int(min(candidates, self.triangles.shape[0]))
        self.solid = is_closed(self.triangles)

    def nearest(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Closest surface points (N, 3), their triangle (N,) and unsigned distances (N,)."""
        n = points.shape[0]
        _, cand = self.tree.query(points, k=self.k)
        cand = np.asarray(cand).reshape(n, self.k)
        flat = cand.ravel()
        rep = np.repeat(points, self.k, axis=0)
        cp = closest_points_on_triangles(rep, self.a[flat], self.b[flat], self.c[flat])
        d2 = np.einsum("ij,ij->i", rep - cp, rep - cp).reshape(n, self.k)
        best = np.argmin(d2, axis=1)
        rows = np.arange(n)
        tri = cand[rows, best]
        closest = cp.reshape(n, self.k, 3)[rows, best]
        return closest, tri, np.sqrt(d2[rows, best])

    def query(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        closest, tri, dist = self.nearest(points)
        fn = self.face_normals[tri]
        offset = points - closest
        side = np.where(np.einsum("ij,ij->i", offset, fn) < 0, -1.0, 1.0)
        direction = offset / np.where(dist > 1e-12, dist, np.inf)[:, None]
        normal = np.where((dist > 1e-9)[:, None], direction * side[:, None], fn)
        return side * dist, normal

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self.vertices.min(axis=0), self.vertices.max(axis=0)


class Collider(Constraint, Remappable):
    """A shape as a Constraint: keeps vertices `thickness` outside it, with Coulomb friction.

    friction: 0 (ice) .. 1 and above (sticky); thickness: metres kept between surface and vertices;
    keys: optional animation (rigid motion plus uniform scale, pivot in the keys).
    """

    def __init__(
        self, shape: Shape, friction: float = 0.2, thickness: float = 0.01, keys: Keyframes | None = None
    ) -> None:
        if keys is not None and not keys.uniform_scale:
            raise ValueError("collider animation must scale uniformly")
        self.shape = shape
        self.friction = float(friction)
        self.thickness = float(thickness)
        self.keys = keys
        self._side: np.ndarray | None = None

    # -- frames ---------------------------------------------------------------------------------
    def _to_local(self, points: np.ndarray, time: float) -> np.ndarray:
        return points if self.keys is None else self.keys.inverse(points, time)

    def _to_world(self, points: np.ndarray, time: float) -> np.ndarray:
        return points if self.keys is None else self.keys.apply(points, time)

    def _scale(self, time: float) -> float:
        return 1.0 if self.keys is None else float(self.keys.scale_at(time)[0])

    def signed_distance(self, points: np.ndarray, time: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """World signed distance (N,) and outward world normals (N, 3) at a time."""
        local = self._to_local(np.asarray(points, dtype=np.float64), time)
        dist, normal = self.shape.query(local)
        if self.keys is not None:
            dist = dist * self._scale(time)
            normal = normal @ self.keys.rotation(time).T
        return dist, normal

    def remap(self, model: SpringModel, index_map: np.ndarray) -> None:
        """After a tear (`index_map`: new vertex -> old): copies remember their original's side."""
        if self._side is not None and self._side.shape[0] > int(index_map.max(initial=-1)):
            self._side = self._side[index_map]

    # -- the constraint -------------------------------------------------------------------------
    def _candidates(self, x: np.ndarray, prev: np.ndarray, time: float, dt: float) -> np.ndarray:
        """Vertices whose path this substep comes near the shape's bounds (cheap culling)."""
        b = self.shape.bounds()
        if b is None:
            return np.arange(x.shape[0])
        margin = self.thickness / self._scale(time) + 1e-9
        lo, hi = b[0] - margin, b[1] + margin
        lx, lp = self._to_local(x, time), self._to_local(prev, time - dt)
        near = np.all((np.maximum(lx, lp) >= lo) & (np.minimum(lx, lp) <= hi), axis=1)
        return np.flatnonzero(near)

    def project(self, model: SpringModel, state: State, time: float, dt: float) -> None:
        movable = model.inv_mass > 0
        if isinstance(self.shape, TriangleMesh) and not self.shape.solid:
            self._project_sheet(state, np.flatnonzero(movable), time, dt)
            return
        idx = self._candidates(state.positions, state.previous, time, dt)
        idx = idx[movable[idx]]
        if idx.size == 0:
            return
        x = state.positions[idx]
        prev = state.previous[idx]
        dist, normal = self.signed_distance(x, time)
        contact = dist < self.thickness
        # swept test: fast vertices that passed into or through the shape within this substep
        travel = np.sqrt(np.einsum("ij,ij->i", x - prev, x - prev))
        fast = np.flatnonzero(~contact & (travel > max(self.thickness, 1e-6)))
        if fast.size:
            samples = int(min(16, np.ceil(travel[fast].max() / max(self.thickness, 1e-3))))
            for s in range(1, samples):
                f = s / samples
                probe = prev[fast] + f * (x[fast] - prev[fast])
                d_probe, n_probe = self.signed_distance(probe, time - dt + f * dt)
                entered = (d_probe < self.thickness) & ~contact[fast]
                if entered.any():
                    rows = fast[entered]
                    contact[rows] = True
                    # signed distance of the end point from the tangent plane where it entered
                    dist[rows] = np.einsum("ij,ij->i", x[rows] - probe[entered], n_probe[entered]) + d_probe[entered]
                    normal[rows] = n_probe[entered]
        rows = np.flatnonzero(contact)
        if rows.size:
            push = self.thickness - dist[rows]
            self._respond(state, idx[rows], x[rows] + push[:, None] * normal[rows], normal[rows], push, time, dt)

    def _project_sheet(self, state: State, idx: np.ndarray, time: float, dt: float) -> None:
        """Open triangle mesh: two-sided, each vertex kept on the side it was last seen clear of."""
        shape = self.shape
        assert isinstance(shape, TriangleMesh)
        n_all = state.positions.shape[0]
        if idx.size == 0:
            return
        x = state.positions[idx]
        prev = state.previous[idx]
        scale = self._scale(time)
        c_local, tri, d_local = shape.nearest(self._to_local(x, time))
        closest = self._to_world(c_local, time)
        fn = shape.face_normals[tri]
        if self.keys is not None:
            fn = fn @ self.keys.rotation(time).T
        dist = d_local * scale
        offset = x - closest
        along = np.einsum("ij,ij->i", offset, fn)
        here = np.where(along < 0, -1.0, 1.0)
        if self._side is None or self._side.shape[0] != n_all:
            self._side = np.zeros(n_all)
        unknown = np.flatnonzero(self._side[idx] == 0)
        if unknown.size:  # first sight: the side the previous position was on
            pc_local, ptri, _ = shape.nearest(self._to_local(prev[unknown], time - dt))
            pfn = shape.face_normals[ptri]
            if self.keys is not None:
                pfn = pfn @ self.keys.rotation(time - dt).T
            offset_prev = prev[unknown] - self._to_world(pc_local, time - dt)
            self._side[idx[unknown]] = np.where(np.einsum("ij,ij->i", offset_prev, pfn) < 0, -1.0, 1.0)
        side = self._side[idx]
        interior = (np.abs(along) >= 0.999 * dist) | (dist < 1e-9)
        travel = np.sqrt(np.einsum("ij,ij->i", x - prev, x - prev))
        crossed = (here != side) & interior & (dist < self.thickness + travel)
        contact = (dist < self.thickness) | crossed
        self._side[idx] = np.where(contact, side, here)
        rows = np.flatnonzero(contact)
        if rows.size == 0:
            return
        away = offset[rows] / np.where(dist[rows] > 1e-12, dist[rows], np.inf)[:, None]
        use_face = interior[rows] | (dist[rows] <= 1e-12)
        normal = np.where(use_face[:, None], fn[rows] * side[rows, None], away)
        new_x = closest[rows] + self.thickness * normal
        push = np.einsum("ij,ij->i", new_x - x[rows], normal)
        self._respond(state, idx[rows], new_x, normal, push, time, dt)

    def _respond(
        self, state: State, vi: np.ndarray, new_x: np.ndarray, n: np.ndarray, push: np.ndarray, time: float, dt: float
    ) -> None:
        """Move contacts to new_x; remove approaching normal velocity, apply Coulomb friction."""
        if self.keys is not None and dt > 0:
            anchor = self._to_local(new_x, time)
            surface_v = (self._to_world(anchor, time) - self._to_world(anchor, time - dt)) / dt
        else:
            surface_v = np.zeros_like(new_x)
        v_rel = state.velocities[vi] - surface_v
        vn = np.einsum("ij,ij->i", v_rel, n)
        vn_out = np.maximum(vn, 0.0)
        vt = v_rel - vn[:, None] * n
        vt_len = np.sqrt(np.einsum("ij,ij->i", vt, vt))
        # normal velocity change this contact stands for: the approach stopped or the push applied
        impulse = np.maximum(-np.minimum(vn, 0.0), np.maximum(push, 0.0) / dt if dt > 0 else 0.0)
        keep = np.clip(1.0 - self.friction * impulse / np.where(vt_len > 1e-12, vt_len, np.inf), 0.0, 1.0)
        v_new = surface_v + vt * keep[:, None] + vn_out[:, None] * n
        state.positions[vi] = new_x
        state.velocities[vi] = v_new
        state.previous[vi] = new_x - v_new * dt
